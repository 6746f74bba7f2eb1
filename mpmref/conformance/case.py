"""One conformance case: a stage on a scene, with the seeded random state it is checked on.

The built-in catalogue (:mod:`.cases`) and the cases drawn from a user's scene (:mod:`~mpmref.conformance.scenes`) are
both made of :class:`ConformanceCase`; what they differ in is the scene and the :class:`~.states.Scales` of the state.
"""

import zlib
from dataclasses import dataclass, field
from functools import partial

import numpy as np

from ..backends import make_backend
from ..backends.capabilities import PARTS
from ..physics.interface import momentum_share
from ..scene import Scene
from ..state import GridState
from .cpic import RUNNERS, random_cpic_state, reference_grid_velocity
from .extremes import FROM_REST_STEPS, Extreme
from .stages import (
    ASYNC_CONFORMANCE_STAGES,
    CPIC_CONFORMANCE_STAGES,
    STAGES_WITH_DT,
    STAGES_WITH_TIME,
    composed_step,
    ledger_step,
    particles_from,
    run_stage,
    stage_method,
    unfused_then_force,
)
from .states import catalogue_scales, draw_time, random_classes, random_grid, random_particles, random_subset

#: default pass threshold on the relative error, per dtype. In float32 the reference itself lies within
#: 3.7e-6 of the float64 result on the same inputs (3.6e-6 measured, PolyPIC modes after a classic-force step;
#: 9.2e-7 on the unit box of 8 cells, where dx = 1/8 and the origin are exact in float32); 5e-5 leaves more than
#: ten times that for the candidate's own rounding (the Numba backend in float32: 3.6e-6 at most).
DEFAULT_RTOL = {"float64": 1.0e-12, "float32": 5.0e-5}

#: the parts of a scene (:data:`mpmref.backends.capabilities.PARTS`) that each stage's result depends on: a built-in
#: case is applicable to a backend that implements these parts of its scene (the stress does not see the walls, the
#: grid update neither the scheme nor the material); a case drawn from a user's scene asks for the whole scene
STAGE_PARTS = {
    **dict.fromkeys(("stress", "return_map", "wave_speeds"), ("dims", "materials", "stepping")),
    **dict.fromkeys(("p2g", "p2g_fused", "g2p", "p2g_classes", "g2p_kicks"),
                    ("dims", "method", "materials", "stepping")),
    "grid_update": ("dims", "boundary", "stepping"),
    "interface_kicks": ("dims", "method", "stepping"),
    **dict.fromkeys(("step", "ledger", *CPIC_CONFORMANCE_STAGES), PARTS),
}


@dataclass(frozen=True, eq=False)
class ConformanceCase:
    """One stage of a backend on one scene, with a seeded random state.

    Attributes
    ----------
    stage : str        one of :data:`~mpmref.conformance.stages.ALL_CONFORMANCE_STAGES`
    dim : int          2 or 3
    variant : str      what the case varies: a material set, a method ``scheme-force-kernel``, a boundary, or the
                       user's scene and the draw (``mpm88-3``)
    scene_dict : dict  the scene, as :meth:`mpmref.scene.Scene.from_dict` takes it
    dtype : str        ``"float64"`` or ``"float32"``
    scales : Scales    the magnitudes of the state (:class:`~.states.Scales`); ``None``: the built-in cases' own,
                       :func:`~.states.catalogue_scales`
    dt : float         the stage's Δt where the scene has no ``time.dt`` (asynchronous stepping); ``None``: the scene's
    source : str       the name of the user's scene the case was drawn from (:mod:`~mpmref.conformance.scenes`),
                       ``None`` for a built-in case; such a case is applicable only to a backend that implements that
                       whole scene
    extreme : Extreme  the family of extreme states the case holds (:mod:`~mpmref.conformance.extremes`), ``None`` for a
                       drawn state
    seed_label : str   what the case's draws are seeded by (:attr:`label`); ``None``: ``stage-<dim>d-variant``. A case
                       drawn from a scene is seeded by its stage and number, never by the scene's name
                       (:func:`seeded_label`)
    """

    stage: str
    dim: int
    variant: str
    scene_dict: dict = field(repr=False)
    dtype: str = "float64"
    scales: object = None
    dt: float | None = None
    source: str | None = None
    extreme: Extreme | None = None
    seed_label: str | None = None

    @property
    def name(self):
        """Unique, file-name safe: ``stage-<dim>d-variant`` (plus ``-f32`` in float32)."""
        suffix = "-f32" if self.dtype == "float32" else ""
        return f"{self.stage}-{self.dim}d-{self.variant}{suffix}"

    @property
    def label(self):
        """The label that seeds the case's draws of grid, Δt, time and state, which is :attr:`seed_label`, else the
        name without the dtype (a float32 case rounds the float64 state)."""
        return self.seed_label or f"{self.stage}-{self.dim}d-{self.variant}"

    @property
    def seed(self):
        """Seed of the state: CRC-32 of :attr:`label`."""
        return zlib.crc32(self.label.encode())

    @property
    def rtol(self):
        return DEFAULT_RTOL[self.dtype]

    @property
    def materials(self):
        """The material types of the case's scene (a set)."""
        return {m["type"] for m in self.scene_dict["materials"].values()}

    @property
    def parts(self):
        """The parts of its scene a backend must implement for this case to apply (:data:`STAGE_PARTS`; all of them
        for a case drawn from a user's scene)."""
        return PARTS if self.source else STAGE_PARTS[self.stage]

    def scene(self):
        """A new :class:`~mpmref.scene.Scene` of the case (what a candidate's factory is given)."""
        return Scene.from_dict(self.scene_dict)

    def __getstate__(self):
        """The fields without the caches of :meth:`parsed_scene` and :meth:`inputs` (a pickled case draws again)."""
        return {k: v for k, v in self.__dict__.items() if k not in ("_parsed_scene", "_drawn_state")}

    def parsed_scene(self):
        """The case's :class:`~mpmref.scene.Scene`, parsed once: the harness's own, read-only (the draw, the
        reference, what a case needs); a candidate gets its own, :meth:`scene`."""
        parsed = self.__dict__.get("_parsed_scene")
        if parsed is None:
            parsed = self.scene()
            object.__setattr__(self, "_parsed_scene", parsed)
        return parsed

    def step_dt(self, scene=None):
        """The case's Δt: :attr:`dt`, else the scene's ``time.dt``."""
        return self.dt if self.dt is not None else (scene or self.parsed_scene()).time.dt

    @property
    def steps(self):
        """The steps a ``step`` case runs: :data:`~.extremes.FROM_REST_STEPS` for a multi-step extreme, else 1."""
        return FROM_REST_STEPS[self.dim] if self.extreme is not None and self.extreme.multi_step else 1

    def inputs(self):
        """The stage's inputs as a flat dict of arrays (same result on every call: a copy of the one draw)."""
        return {k: np.array(a, copy=True) for k, a in self._drawn()[0].items()}

    def notes(self):
        """What each row of the state holds at the case's :attr:`extreme` (``"|S₀₁| = 1e-07"``), ``None`` for a drawn
        row; ``None`` for a case without one or one whose rows are nodes."""
        notes = self._drawn()[1]
        return None if notes is None else list(notes)

    def _drawn(self):
        """:meth:`_draw`, once per case (the draw is deterministic; a case's inputs and notes come from one draw)."""
        drawn = self.__dict__.get("_drawn_state")
        if drawn is None:
            drawn = self._draw()
            object.__setattr__(self, "_drawn_state", drawn)
        return drawn

    def _draw(self):
        """``(inputs, notes)``: the drawn state, put at the case's :attr:`extreme` if it has one."""
        scene, rng = self.parsed_scene(), np.random.default_rng(self.seed)
        scales = self.scales or catalogue_scales(scene)
        dt, time = self.step_dt(scene), draw_time(self.seed, scales.time)
        if self.stage in CPIC_CONFORMANCE_STAGES:
            return _as_dtype(cpic_inputs(self.stage, scene, rng, scales, dt, time), self.dtype), None
        if self.stage in ASYNC_CONFORMANCE_STAGES:
            return async_inputs(self.stage, scene, rng, scales, dt, time, self.dtype), None
        flat = random_grid(scene, rng, scales) if self.stage == "grid_update" else random_particles(scene, rng, scales)
        notes = None
        if self.extreme is not None and self.extreme.state is not None:
            flat, notes = self.extreme.state(scene, flat, rng, self.dtype)
        if self.steps > 1:
            flat["steps"] = np.array(self.steps)
        return completed(self.stage, scene, flat, dt, time, self.dtype), notes

    def reference(self, inputs=None):
        """The NumPy reference's outputs of the stage on ``inputs`` (default: :meth:`inputs`), a flat dict."""
        backend = make_backend("numpy", self.parsed_scene())
        fn = backend_stage(backend, self.stage)
        return run_stage(self.stage, fn, self.inputs() if inputs is None else inputs)


def completed(stage, scene, flat, dt, time, dtype):
    """The inputs of ``stage`` from a particle or grid state ``flat`` (float64): for G2P the reference's grid velocities
    of that state, Δt and the time where the stage takes them, the floating arrays in ``dtype``, and for P2G the
    reference's stress of the state (the input of a P2G that takes the stress, docs/conformance.md)."""
    flat = dict(flat)
    if stage == "g2p":
        flat.update(reference_grid_velocities(scene, flat, dt, time)[0])
    if stage in STAGES_WITH_DT:
        flat["dt"] = np.array(dt)
    if stage in STAGES_WITH_TIME:
        flat["time"] = np.array(time)
    flat = _as_dtype(flat, dtype)
    if stage in ("p2g", "p2g_fused"):
        flat["tau"] = make_backend("numpy", scene).stress(particles_from(flat))
    return flat


@dataclass(frozen=True, eq=False)
class GivenCase(ConformanceCase):
    """A case whose state is given rather than drawn: one a search found (:mod:`.search`), or one read from a case file
    (:func:`.casefile.load_case`).

    Attributes
    ----------
    given : dict        its inputs, complete (Δt, time and the reference's derived inputs included)
    given_notes : tuple what each particle holds (``None`` for one without a note), or ``None``
    """

    given: dict = field(default_factory=dict, repr=False)
    given_notes: tuple | None = None

    def _draw(self):
        notes = None if self.given_notes is None else list(self.given_notes)
        return {k: np.array(v) for k, v in self.given.items()}, notes


def seeded_label(label, base_seed=0):
    """The label a case's draws are seeded by, for the base seed ``base_seed`` (``--seed``): ``label`` itself for the
    default 0, so that the default cases are the same on every machine and in every version; ``label@<seed>``
    otherwise, a new draw of every case (grid, Δt, time and state)."""
    return label if base_seed == 0 else f"{label}@{base_seed}"


def backend_stage(backend, stage):
    """The callable of ``stage`` for a backend object (``step``: the pipeline over its stages; ``ledger``: that
    step's energy ledger; ``p2g_fused``: the unfused P2G plus Δt times its force, the truth of a fused one; the stages
    of asynchronous stepping: the backend method they call; CPIC stages: their runners of :mod:`mpmref.conformance.cpic`
    bound to it)."""
    if stage == "step":
        return partial(composed_step, backend)
    if stage == "p2g_fused":  # the truth is the unfused P2G plus dt times its force, whatever the backend folds
        return unfused_then_force(backend)
    if stage == "ledger":
        return partial(ledger_step, backend)
    if stage in CPIC_CONFORMANCE_STAGES:
        return partial(RUNNERS[stage], backend)
    return getattr(backend, stage_method(stage))


def _as_dtype(flat, dtype):
    """Floating arrays of ``flat`` in ``dtype``; integer arrays and 0-d scalars unchanged."""
    return {k: a.astype(dtype) if a.ndim and a.dtype.kind == "f" else a for k, a in flat.items()}


def reference_grid_velocities(scene, flat, dt, time, classes=None):
    """``grid_v`` and ``grid_v_tilde`` of the reference P2G (by particle ``classes`` if given) and grid update of the
    particles ``flat``, and with classes the P2G's grid state."""
    backend = make_backend("numpy", scene)
    particles = particles_from(flat)
    gs = backend.p2g(particles) if classes is None else backend.p2g(particles, classes=classes)
    v, v_tilde = backend.grid_update(gs, dt, time)
    return {"grid_v": v, "grid_v_tilde": v_tilde}, gs


def cpic_inputs(stage, scene, rng, scales, dt, time):
    """A CPIC stage's inputs: :func:`~.states.random_particles`, previous tags and bodies
    (:func:`.cpic.random_cpic_state`), ``dt``, ``time`` and, for ``cpic_g2p``, the reference's ``grid_v`` of that
    state."""
    flat = random_cpic_state(scene, rng, random_particles(scene, rng, scales), scales)
    flat["dt"], flat["time"] = np.array(dt), np.array(time)
    if stage == "cpic_g2p":
        flat["grid_v"] = reference_grid_velocity(scene, flat)
    return flat


def async_inputs(stage, scene, rng, scales, dt, time, dtype):
    r"""The inputs of a stage of asynchronous stepping (:mod:`mpmref.physics.interface`): particles of
    :func:`~.states.random_particles` and

    * ``wave_speeds``: ``idx``, about half the particles (:func:`~.states.random_subset`);
    * ``p2g_classes``: ``classes`` (:func:`~.states.random_classes`) and the reference's stress ``tau``;
    * ``interface_kicks``: the reference's P2G by those classes (``grid_mass``, ``grid_momentum``, ``grid_force``,
      ``class_sums``), ``dt`` and :math:`\kappa` (``kappa``, :func:`mpmref.physics.interface.momentum_share`);
    * ``g2p_kicks``: ``classes``, the reference's grid velocities after that P2G and a grid update at the case's
      time (``grid_v``, ``grid_v_tilde``), its node kicks ``kicks`` (2, N, d) and ``dt``.
    """
    flat = random_particles(scene, rng, scales)
    if stage == "wave_speeds":
        flat["idx"] = random_subset(rng, len(flat["x"]))
        return _as_dtype(flat, dtype)
    flat["classes"] = random_classes(rng, len(flat["x"]))
    flat = _as_dtype(flat, dtype)
    backend = make_backend("numpy", scene)
    if stage == "p2g_classes":
        flat["tau"] = backend.stress(particles_from(flat))
        return flat
    velocities, gs = reference_grid_velocities(scene, flat, dt, time, classes=flat["classes"])
    kappa = momentum_share(scene.transfer)
    flat["dt"] = np.array(dt)
    if stage == "interface_kicks":
        flat.update(grid_mass=gs.mass, grid_momentum=gs.momentum, grid_force=gs.force, class_sums=gs.class_sums,
                    kappa=np.array(kappa))
        return flat
    flat.update(velocities, kicks=backend.interface_kicks(GridState(gs.mass, gs.momentum, gs.force,
                                                                     class_sums=gs.class_sums), dt, kappa))
    return flat
