"""The validated parts of a scene: what each section of a scene file declares, once checked.

The parsers (:mod:`mpmref.scene.parsers`, :mod:`~mpmref.scene.materials`, :mod:`~mpmref.scene.bodies`,
:mod:`~mpmref.scene.rigid_bodies`) build these; :class:`mpmref.scene.Scene` holds them.
"""

from dataclasses import dataclass


@dataclass(frozen=True)
class MethodSpec:
    """The declared transfer scheme, force discretisation and kernel (``Scene.transfer`` resolves them)."""

    scheme: str
    force: str
    kernel: str
    flip_alpha: float
    velocity_gradient: str = ""  # "" follows ``force`` (see ``parsers.parse_method``)

    def __post_init__(self):
        if not self.velocity_gradient:
            object.__setattr__(self, "velocity_gradient", self.force)


@dataclass(frozen=True)
class CpicSpec:
    """The CPIC coupling of a scene with ``[method] coupling = "cpic"`` (``Scene.cpic``; docs/cpic.md).

    Declared by the ``[method]`` keys ``pushing_force``, ``penalty``, ``momentum_exact``, ``ghost_force`` and
    ``cpic_fit`` (here ``fit``): the pushing force's strength, the penalty's rate (1/s), whether the bodies take
    every impulse after G2P (momentum-exact variant), whether ghost velocities include the particle's own
    internal force, and how a particle near several bodies gets its distance and normal (``"single"`` or
    ``"per_body"``).
    """

    pushing_force: float
    penalty: float
    momentum_exact: bool
    ghost_force: bool
    fit: str


@dataclass(frozen=True)
class WallSpec:
    type: str
    friction: float


@dataclass(frozen=True)
class BoundarySpec:
    width: int
    walls: dict  # "x_min" -> WallSpec
    domain_exit: str


@dataclass(frozen=True)
class TimeSpec:
    """Time stepping. ``stepping = "async"`` uses ``tick`` (seconds per integer time unit), ``levels``
    (block steps are ``2^k`` ticks, ``k = 0 .. levels``), ``cfl`` (the strength multiplier),
    ``advection_cfl`` (cells a particle may cross per step) and ``interface`` (how level interfaces exchange
    momentum: ``"conservative"``, impulse refluxing, or ``"reference"``, Fang et al. 2018 as published);
    see docs/async.md."""

    dt: float | None
    cfl: float | None
    steps: int | None
    t_end: float | None
    stepping: str = "sync"
    tick: float | None = None
    levels: int | None = None
    advection_cfl: float | None = None
    interface: str | None = None


@dataclass(frozen=True)
class OutputSpec:
    """What a run with an output folder writes: a frame (and the checkpoint) every ``every`` steps, a row of
    ``diagnostics.csv`` every ``diagnostics_every`` steps (both also at the start and the end), the particle
    ``fields``, the ``grid`` frames over ``grid_region``, and the ``energy_ledger`` columns."""

    every: int
    diagnostics_every: int
    fields: tuple
    grid: bool
    checkpoint: bool
    grid_region: str = "active"
    energy_ledger: bool = False


@dataclass(frozen=True)
class BodySpec:
    index: int
    shape: str
    material: str
    params: dict


@dataclass(frozen=True)
class EmitterSpec:
    """A particle source (``[[emitters]]``): a disk (2D) or sphere (3D) of material released again and again.

    ``body`` is the release as a body at time 0 (sampled by :func:`mpmref.scene.sampling.sample_body`); a release
    is made at the first step that starts at or after each time ``start + k interval`` before ``until``
    (:mod:`mpmref.run.emitters`).
    """

    index: int
    body: BodySpec
    start: float
    interval: float
    until: float
