r"""Materials of the GPU backend: each particle's stress, return map and wave speed by its material's declared law.

A material declares its law next to its reference class (:class:`mpmref.physics.materials.CompiledLaw`): the pointwise
functions of :mod:`mpmref.backends.pointwise.laws` (compiled for the device by
:func:`~mpmref.backends.pointwise.on_device`) and its parameter row. A kernel reads a particle's law from its
material's *code*, the index of the law among the scene's, and its parameters from the
material's row of the float64 parameter table (:func:`~mpmref.backends.pointwise.laws.laws_of`,
:func:`~mpmref.backends.pointwise.laws.parameter_table`). Only the laws of the materials a scene declares are compiled
in (:func:`make_materials` takes them): nothing here names a material.
"""

from functools import lru_cache
from types import SimpleNamespace

from ..pointwise.laws import functions
from .launch import device, device_function, real_types
from .runtime import load


@lru_cache(maxsize=None)
def make_materials(dtype, dim, laws):
    r"""The material device functions in ``dtype`` for ``dim`` × ``dim`` deformation gradients, with the ``laws``
    (:class:`~mpmref.physics.materials.CompiledLaw`, in the order of their codes) compiled in. A namespace of:

    * ``stress(code, prm, F, J, Jp, tau, work)``: the Kirchhoff stress of a particle of law ``code`` with parameters
      ``prm`` (its material's row) into the local array ``tau``; ``F`` a local copy of its deformation gradient,
      ``J`` and ``Jp`` its volume ratios; ``work`` a local (:data:`~mpmref.backends.pointwise.laws.WORK`, d, d)
      array;
    * ``return_map(code, prm, F, Jp, work)``: the plastic projection of ``F`` (in place), returning the new
      :math:`J_P` (``Jp`` itself for an elastic law);
    * ``wave_speed(code, prm, F, J, Jp)``: the current wave speed :math:`c_p` in float64 (the CFL rule's);
    * ``load_state(p, F, J, Jp, Fp)``: particle ``p``'s ``F`` copied into the local ``Fp`` (the identity where the
      scene has none) and its ``(J, Jp)`` (1 where the scene has none), from the particle arrays.
    """
    load()
    T, _ = real_types(dtype)
    one, zero = T(1.0), T(0.0)

    @device_function
    def no_stress(code, *args):
        """No law has ``code`` (never reached: every material's code is one of the laws')."""

    @device_function
    def elastic(code, prm, F, Jp, work):
        """No plastic law has ``code``: ``Jp`` as it is."""
        return Jp

    @device_function
    def no_speed(code, *args):
        """No law has ``code`` (never reached)."""
        return 0.0

    stress, return_map, wave_speed = no_stress, elastic, no_speed
    for code, law in enumerate(functions(law) for law in laws):
        stress = case(code, device(law.stress), stress)
        wave_speed = case(code, device(law.wave_speed), wave_speed)
        if law.return_map is not None:
            return_map = case(code, device(law.return_map), return_map)

    @device_function
    def load_state(p, F, J, Jp, Fp):
        """Particle ``p``'s deformation gradient into the local ``Fp`` (the identity where the scene has none: a law of
        :math:`J` does not read it) and its ``J``, ``Jp`` (1 where the scene has none)."""
        for a in range(dim):
            for b in range(dim):
                Fp[a, b] = F[p, a, b] if F.shape[0] > 0 else (one if a == b else zero)
        return (J[p] if J.shape[0] > 0 else one), (Jp[p] if Jp.shape[0] > 0 else one)

    return SimpleNamespace(stress=stress, return_map=return_map, wave_speed=wave_speed, load_state=load_state)


def case(code, law, otherwise):
    """A device function ``f(rule, *args)``: the device function ``law(*args)`` where ``rule`` is ``code``,
    ``otherwise(rule, *args)`` elsewhere (one link of the chain of a scene's laws)."""

    @device_function
    def pick(rule, *args):
        if rule == code:
            return law(*args)
        return otherwise(rule, *args)

    return pick
