r"""A sixth material, added the way docs/materials.md says, and nothing in either compiled backend: St. Venant–Kirchhoff
elasticity, whose reference class is exercise 4's (:mod:`exercises.solutions.ex04_new_material`, the energy, the
stress and their sources there), with its declaration for the compiled backends and its pointwise stress here:

.. math:: \tau = F\,S\,F^T, \qquad S = 2\mu E + \lambda\operatorname{tr}(E)\,I, \qquad E = \tfrac12(F^TF - I),

:math:`E` the Green strain, :math:`S` the second Piola–Kirchhoff stress, :math:`\mu, \lambda` the Lamé parameters
(Bonet & Wood 2008 §6.4.2). Its wave speed is the elastic solids' rule
(:func:`mpmref.physics.materials.elastic_wave_speeds`), whose pointwise function it names (imported here, so that its
law's functions are all found in this module).
"""

from dataclasses import dataclass

from exercises.solutions import ex04_new_material as exercise
from mpmref.backends.pointwise import pointwise
from mpmref.backends.pointwise.laws import elastic_wave_speed  # noqa: F401 - named by the declaration below
from mpmref.physics.materials import CompiledLaw

#: its scene name (the ``type`` of a ``[materials.NAME]`` table)
KIND = "st_venant_kirchhoff"


@dataclass(frozen=True)
class StVenantKirchhoff(exercise.StVenantKirchhoff):
    """Exercise 4's St. Venant–Kirchhoff solid, declared for the compiled backends."""

    compiled = CompiledLaw("svk_stress", "elastic_wave_speed", ("mu", "lam", "rho"), module=__name__)


@pointwise(inline=True)
def svk_stress(prm, F, J, Jp, tau, work):
    r"""``tau`` = :math:`F(2\mu E + \lambda\operatorname{tr}E\,I)F^T`, :math:`E = \tfrac12(F^TF - I)`; ``prm`` =
    :math:`(\mu, \lambda, \rho)`; ``work[0]`` holds :math:`E`, then :math:`S`."""
    real = tau.dtype.type
    mu, lam = real(prm[0]), real(prm[1])
    d = F.shape[0]
    S = work[0]
    trace = real(0.0)
    for a in range(d):
        for b in range(d):
            s = real(0.0)
            for c in range(d):
                s += F[c, a] * F[c, b]
            S[a, b] = real(0.5) * (s - (real(1.0) if a == b else real(0.0)))
        trace += S[a, a]
    for a in range(d):
        for b in range(d):
            S[a, b] = real(2.0) * mu * S[a, b] + (lam * trace if a == b else real(0.0))
    for a in range(d):
        for b in range(d):
            s = real(0.0)
            for c in range(d):
                for e in range(d):
                    s += F[a, c] * S[c, e] * F[b, e]
            tau[a, b] = s
