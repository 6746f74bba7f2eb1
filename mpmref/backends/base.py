"""The contract every backend fulfils: six stages, and nothing that loops over steps.

A backend turns the equations of one MPM step into code, stage by stage; the steppers of
:mod:`mpmref.steppers` compose the stages into a step (synchronous, or per block for asynchronous
stepping), so the order P2G → grid update → G2P → return map is written once. The stages:

``prepare(particles)``
    what P2G and G2P of one step share (the NumPy reference: kernel stencils; Numba: the block sort);
``stress(particles)``
    Kirchhoff stress (n, d, d) of every particle, through :class:`MaterialTable`;
``p2g(particles, prepared=None)``
    node mass, momentum and internal force, a :class:`~mpmref.state.GridState`;
``grid_update(grid_state, dt, time)``
    node velocities after forces, gravity, walls and colliders: ``(v, v_tilde)``;
``g2p(particles, v_grid, v_tilde, dt, prepared=None)``
    new particles (velocity, affine matrix or modes, deformation, position);
``return_map(particles)``
    the plastic projection of the plastic materials' particles (new particles); the stage that finalises a step's
    deformation (``F``, ``J``, ``Jp``: G2P's for the elastic materials and the fluid, which it leaves as they are).

``running(n_particles)`` is a context manager in which a step's stages run (the Numba backend picks its
thread count there); it is not a stage.

Asynchronous stepping (:mod:`mpmref.steppers.asynchronous`) adds two stages, :data:`ASYNC_BACKEND_STAGES`:

``wave_speeds(particles, idx)``
    the P-wave speed of particles ``idx`` (the blocks' step limits);
``interface_kicks(grid_state, dt, kappa)``
    the node kicks of conservative level interfaces (:mod:`mpmref.physics.interface`).

A backend may give the level rule's wave speeds from the step itself (:func:`gives_wave_speeds`): its
``return_map(particles, wave_speed=None)`` (and ``return_map_rows(particles, rows, wave_speed=None)``) takes an
optional output ``wave_speed``, a float64 array with a row per particle, into which it writes each stepped particle's
current wave speed :math:`c_p` (:meth:`wave_speeds`' value, bit for bit) of its new state, where the deformation is
finalised: after the projection for the plastic materials, of G2P's state for the others. Asynchronous stepping asks
for it in every update, so that no pass over the particles is left for :math:`c_p` at a step boundary; the
synchronous step does not, and pays nothing. A backend without it is stepped as before, ``wave_speeds`` at every
boundary.

A backend that couples rigid bodies by CPIC (:class:`CoupledBackend`, docs/cpic.md) has three more,
:data:`CPIC_BACKEND_STAGES`: ``cpic_contact`` (the colored distance field, the particles' tags and the
step's contact, the backend's own object: :class:`mpmref.backends.numpy.cpic.NumpyContact` in the reference),
``cpic_impulses`` (what incompatible nodes did not receive, as impulses on the bodies) and ``cpic_g2p`` (G2P with ghost
velocities and the penalty). Every backend of :data:`mpmref.backends.BACKENDS` is both;
:func:`mpmref.backends.make_backend` checks it.

A backend may also have ``p2g_fused(particles, dt, prepared=None)`` (:class:`FusedBackend`): P2G with the step's
internal force folded into the momentum, (mv)_i + Δt f_i, in one scatter, returned as a
:class:`~mpmref.state.GridState` whose ``force`` is ``None`` (``grid_update`` then reads the momentum as folded and
returns no ``v_tilde``). The steppers use it where the scheme allows it and nothing in the run reads the force apart.
One that also takes ``classes`` (``p2g_fused(particles, dt, prepared=None, classes=None)``, the Numba backend's) sums
particle classes apart as ``p2g`` does, and ``interface_kicks`` then takes such a folded state: a level update of
conservative interfaces folds its force too (:func:`mpmref.steppers.pipeline.fuses_classes`).

A backend may also step **rows of persistent particle arrays** (:class:`RowBackend`, the optional stages
:data:`ROW_BACKEND_STAGES`), which asynchronous stepping's level updates use: the particles of a level are
contiguous rows of arrays the stepper keeps from update to update, and only their ghosts are copied into spare
rows after them (:mod:`mpmref.steppers.asynchronous`), so an update gathers and scatters nothing else:

``prepare_rows(particles, rows)``
    what P2G and G2P of a step of the particles ``rows`` (an int64 index array into ``particles``' arrays) share;
    given it, ``p2g`` (and ``p2g_fused``) scatter those particles only, and ``classes`` has one entry per row of
    ``rows``;
``g2p_rows(particles, v_grid, v_tilde, dt, prepared, out, kicks=None)``
    the new state of the particles ``rows``, written into the same rows of ``out`` (a :class:`~mpmref.state.Particles`
    as long, which may be ``particles`` itself: G2P in place); with ``kicks`` it returns each row's impulse and
    moment ``(dP, dL)``, in the order of ``rows``;
``return_map_rows(particles, rows, wave_speed=None)``
    the plastic projection of the particles ``rows``, in place (with ``wave_speed``, their wave speeds into its rows
    ``rows``, as ``return_map``'s).

A backend without them (the NumPy reference, a user's own code) steps the same updates through an adapter
(:func:`mpmref.steppers.pipeline.substep` with ``rows``) that gathers the rows into a new
:class:`~mpmref.state.Particles`, runs the six stages on it, and writes the results back: the same arithmetic in
the same order, so the same bits, at the cost of the copies.

These are the stages of a backend; the conformance harness has its own list of what it compares
(:data:`mpmref.conformance.CONFORMANCE_STAGES`), and the benchmarks name what they time
(:data:`mpmref.bench.table2.TABLE2_STAGES`, :data:`mpmref.bench.cpic.TIMED_CPIC_STAGES`).
"""

import inspect
from contextlib import nullcontext
from functools import lru_cache
from typing import Protocol, runtime_checkable

import numpy as np

#: the stages of every backend, in the order of a step
BACKEND_STAGES = ("prepare", "stress", "p2g", "grid_update", "g2p", "return_map")
#: the stages asynchronous stepping adds
ASYNC_BACKEND_STAGES = ("wave_speeds", "interface_kicks")
#: the stages of CPIC coupling to rigid bodies
CPIC_BACKEND_STAGES = ("cpic_contact", "cpic_impulses", "cpic_g2p")
#: the optional stage of a backend that folds the internal force into P2G (:class:`FusedBackend`)
FUSED_BACKEND_STAGES = ("p2g_fused",)
#: the optional stages of a backend that steps rows of persistent particle arrays (:class:`RowBackend`)
ROW_BACKEND_STAGES = ("prepare_rows", "g2p_rows", "return_map_rows")


@runtime_checkable
class Backend(Protocol):
    """Structural type of a backend (see the module docstring for each stage's meaning). The first line of each
    method's docstring is what the stage returns; :func:`stage_signature` quotes it in error messages."""

    name: str
    scene: object

    def prepare(self, particles):
        """-> what P2G and G2P of one step share (anything; ``None`` if nothing)"""

    def stress(self, particles):
        """-> Kirchhoff stress tau (n, d, d)"""

    def p2g(self, particles, prepared=None, contact=None, classes=None):
        """-> GridState(mass (N,), momentum (N, d), force (N, d))"""

    def grid_update(self, grid_state, dt, time=0.0):
        """-> (v, v_tilde), both (N, d): node velocity after forces, gravity, walls and colliders; before forces"""

    def g2p(self, particles, v_grid, v_tilde, dt, prepared=None, kicks=None):
        """-> new Particles (x, v and the fields the scene evolves)"""

    def return_map(self, particles):
        """-> Particles after the plastic projection (unchanged for elastic materials)"""

    def running(self, n_particles):
        """-> a context manager the step's stages run in (mpmref.backends.base.serial_context if nothing to set up)"""

    def wave_speeds(self, particles, idx):
        """-> P-wave speed (m,) of the particles idx (asynchronous stepping)"""

    def interface_kicks(self, grid_state, dt, kappa):
        """-> node kicks of conservative level interfaces (asynchronous stepping)"""


@runtime_checkable
class CoupledBackend(Backend, Protocol):
    """A backend that also couples rigid bodies by CPIC (see the module docstring)."""

    def cpic_contact(self, particles, prepared, rigid, dt):
        """-> (particles, contact): the colored distance field and the particles' tags"""

    def cpic_impulses(self, grid_state, contact, rigid, dt):
        """-> (J, L): impulses on the bodies of what incompatible nodes did not receive"""

    def cpic_g2p(self, particles, v_grid, dt, prepared, contact, rigid):
        """-> (Particles, (J, L)): G2P with ghost velocities and the penalty's impulses"""


@runtime_checkable
class FusedBackend(Backend, Protocol):
    """A backend that can also fold the step's internal force into P2G (optional: the steppers use it when the
    backend has it and nothing in the run reads the force apart; :func:`mpmref.steppers.pipeline.substep`)."""

    def p2g_fused(self, particles, dt, prepared=None):
        """-> GridState(mass (N,), momentum (N, d) = (mv)_i + dt f_i, force None)"""


@runtime_checkable
class RowBackend(Backend, Protocol):
    """A backend that can also step rows of persistent particle arrays (optional: asynchronous stepping uses these
    stages when the backend has them, and gathers the rows for the plain stages when it has not; see the module
    docstring)."""

    def prepare_rows(self, particles, rows):
        """-> what P2G and G2P of a step of the particles rows share (P2G then scatters those rows only)"""

    def g2p_rows(self, particles, v_grid, v_tilde, dt, prepared, out, kicks=None):
        """-> None, or (dP, dL) with kicks: the rows' new state written into the same rows of out"""

    def return_map_rows(self, particles, rows):
        """-> None: the plastic projection of the particles rows, in place"""


def steps_rows(backend):
    """Whether ``backend`` has the row stages of :class:`RowBackend` (looked up by name, as :func:`folds_force
    <mpmref.steppers.pipeline.folds_force>` looks up ``p2g_fused``: an ``isinstance`` test of the protocol costs
    tens of microseconds)."""
    return all(callable(getattr(backend, stage, None)) for stage in ROW_BACKEND_STAGES)


def gives_wave_speeds(backend):
    """Whether ``backend``'s return map takes the optional output ``wave_speed`` (see the module docstring), and its
    ``return_map_rows`` too where it has the row stages. Looked up once per backend class."""
    return _takes_wave_speed(type(backend))


@lru_cache(maxsize=None)
def _takes_wave_speed(cls):
    def takes(stage):
        method = getattr(cls, stage, None)
        return callable(method) and "wave_speed" in inspect.signature(method).parameters

    return takes("return_map") and (not callable(getattr(cls, "return_map_rows", None)) or takes("return_map_rows"))


def stage_signature(stage):
    """``stage(arguments) -> result`` as the protocol declares it, for messages (e.g. ``p2g(particles,
    prepared=None, contact=None, classes=None) -> GridState(...)``)."""
    method = getattr(CoupledBackend, stage, None) or getattr(FusedBackend, stage, None) or getattr(RowBackend, stage)
    arguments = list(inspect.signature(method).parameters.values())[1:]  # without self
    returns = (method.__doc__ or "").strip().splitlines()[0]
    return f"{stage}({', '.join(str(a) for a in arguments)}) {returns}".strip()


def required_calls(scene):
    """How the steppers call each stage for ``scene``: ``{stage: (positional argument count, keyword names)}``.

    Every scene needs the six stages and ``running``; asynchronous stepping adds its two stages and the keyword
    arguments of conservative interfaces (``classes`` in P2G, ``kicks`` in G2P); rigid bodies add the CPIC stages
    and P2G's ``contact``. A backend is checked against this before any work (:func:`mpmref.backends.make_backend`).
    """
    calls = {"prepare": (1, ()), "stress": (1, ()), "p2g": (2, ()), "grid_update": (3, ()), "g2p": (5, ()),
             "return_map": (1, ()), "running": (1, ())}
    if scene.time.stepping == "async":
        calls.update({"p2g": (2, ("classes",)), "g2p": (5, ("kicks",)), "wave_speeds": (2, ()),
                      "interface_kicks": (3, ())})
    if scene.rigid_bodies:
        calls.update({"p2g": (3, ()), "cpic_contact": (4, ()), "cpic_impulses": (4, ()), "cpic_g2p": (6, ())})
    return calls


#: wall (and collider) types as the compiled backends' kernels code them
WALL_CODES = {"open": 0, "sticky": 1, "slip": 2, "separate": 3}


def wall_table(boundary, dim):
    r"""The domain's walls as compiled kernels take them, in the order x_min, x_max, y_min, ...: their types
    (:data:`WALL_CODES`, int64) and Coulomb friction coefficients (float64), talk Eq. 25's :math:`\mu_b`."""
    walls = [boundary.walls[f"{'xyz'[a]}_{side}"] for a in range(dim) for side in ("min", "max")]
    return (np.array([WALL_CODES[w.type] for w in walls], dtype=np.int64),
            np.array([w.friction for w in walls], dtype=np.float64))


def serial_context(n_particles):
    """The ``running`` of a backend with nothing to set up."""
    return nullcontext()


class EachParticlesMaterial(tuple):
    """A :class:`MaterialTable` entry ``(stress, return_map[, wave_speed])`` whose kernels read each particle's
    parameters by its own material index: the table calls them once for every material of the class, with the
    particles' material indices in place of a material."""


class MaterialTable:
    """Per-material dispatch, written once: a backend's ``{material class: (stress, return_map)}`` kernels
    applied to each material's particles.

    A kernel table maps a material class to ``(stress, return_map)``, or ``(stress, return_map, wave_speed)``:

    * ``stress(material, particles, idx, tau)`` writes the Kirchhoff stress of particles ``idx`` into ``tau``;
    * ``return_map(material, F, Jp, idx)`` projects ``F`` and ``Jp`` of particles ``idx`` in place, or is
      ``None`` for elastic materials;
    * ``wave_speed(material, F, J, Jp, idx, out)`` (optional) writes the current wave speed :math:`c_p` of particles
      ``idx`` into ``out[idx]`` (float64), from their ``F``, ``J`` and ``Jp`` (``None`` where the scene has none): the
      optional output ``wave_speed`` of :meth:`return_map` and :meth:`return_map_rows` for an elastic material. With
      that output, a plastic material's ``return_map`` is called as ``return_map(material, F, Jp, idx, out)`` and
      writes the wave speed of the projected state itself (in the same pass, where the backend can).

    An entry that is a :class:`EachParticlesMaterial` reads each particle's parameters by its own material index: its
    kernels are given the particles' material indices (``particles.material``) in place of ``material``, and one call
    runs the particles of every material of that class (the storks' three fixed-corotated materials: one call per
    stage instead of three).

    Adding a material adds one entry to each backend's table; no caller tests material types.
    """

    def __init__(self, materials, kernels):
        self.materials = list(materials)
        missing = sorted({type(m).__name__ for m in self.materials if type(m) not in kernels})
        if missing:
            raise TypeError(f"no kernels for material(s) {missing} in this backend")
        self.kernels = [kernels[type(m)] for m in self.materials]
        # the calls of a stage: each material's, or one per class of materials whose kernels read each particle's
        calls = {}  # key -> (the first material, its kernels, the material indices it runs)
        for i, (material, entry) in enumerate(zip(self.materials, self.kernels)):
            key = id(entry) if isinstance(entry, EachParticlesMaterial) else ("material", i)
            calls.setdefault(key, (material, entry, []))[2].append(i)
        self.calls = list(calls.values())
        self.call_of = np.zeros(len(self.materials), dtype=np.int64)  # material index -> its call
        for c, (_, _, members) in enumerate(self.calls):
            self.call_of[members] = c

    @property
    def gives_wave_speeds(self):
        """Whether every material's kernels include ``wave_speed`` (the return map's optional output)."""
        return all(len(k) > 2 and k[2] is not None for k in self.kernels)

    def groups(self, particles, rows=None):
        """``(material, kernels, idx)`` for each call of a stage (:attr:`calls`: a material, or every material of a
        class whose kernels read each particle's) that has particles, in order, or that has some of the particles
        ``rows`` (``idx`` then lists those, in the order of ``rows``); ``material`` what the kernels take (the
        particles' material indices for an :class:`EachParticlesMaterial`)."""
        calls = [(particles.material if isinstance(k, EachParticlesMaterial) else m, k) for m, k, _ in self.calls]
        if len(calls) == 1:
            return [(*calls[0], np.arange(particles.n, dtype=np.int64) if rows is None else rows)]
        of_call = self.call_of[particles.material if rows is None else particles.material[rows]]
        return [(m, k, idx) for c, (m, k) in enumerate(calls)
                if (idx := np.flatnonzero(of_call == c) if rows is None else rows[of_call == c]).size]

    def stress(self, particles):
        """Kirchhoff stress (n, d, d) of every particle."""
        n, d = particles.x.shape
        tau = np.zeros((n, d, d), dtype=particles.x.dtype)
        self.stress_into(particles, None, tau)
        return tau

    def stress_into(self, particles, rows, tau):
        """Kirchhoff stress of every particle, or of the particles ``rows``, into their rows of ``tau`` (n, d, d)."""
        for material, (stress, *_), idx in self.groups(particles, rows):
            stress(material, particles, idx, tau)

    def return_map(self, particles, wave_speed=None):
        """Plastic projection of every plastic material's particles (a new state; the others untouched); with
        ``wave_speed`` (float64, (n,)), each particle's wave speed :math:`c_p` in its new state written there too."""
        if particles.Jp is None:
            if wave_speed is not None:
                self._speeds(particles, None, particles.F, None, wave_speed)
            return particles
        F, Jp = particles.F.copy(), particles.Jp.copy()
        self._project(particles, None, F, Jp, wave_speed)
        return particles.with_(F=F, Jp=Jp)

    def return_map_rows(self, particles, rows, wave_speed=None):
        """Plastic projection of the plastic materials' particles among ``rows``, in place; with ``wave_speed``
        (float64, as long as ``particles``' arrays), the wave speed :math:`c_p` of the particles ``rows`` in their new
        state written into its rows ``rows``."""
        if particles.Jp is not None:
            self._project(particles, rows, particles.F, particles.Jp, wave_speed)
        elif wave_speed is not None:
            self._speeds(particles, rows, particles.F, None, wave_speed)

    def _project(self, particles, rows, F, Jp, wave_speed=None):
        for material, kernels, idx in self.groups(particles, rows):
            return_map = kernels[1]
            if return_map is None:
                if wave_speed is not None:
                    kernels[2](material, F, particles.J, Jp, idx, wave_speed)
            elif wave_speed is None:
                return_map(material, F, Jp, idx)
            else:
                return_map(material, F, Jp, idx, wave_speed)

    def _speeds(self, particles, rows, F, Jp, wave_speed):
        for material, kernels, idx in self.groups(particles, rows):
            kernels[2](material, F, particles.J, Jp, idx, wave_speed)
