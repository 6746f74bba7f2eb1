"""What the CPIC case measures (:mod:`verification.cpic`): one dataclass per kind of run, and the case's result.

Every run is watched for crossings (:class:`Watched`, from :func:`verification.cpic.measurements.run_watching`);
each kind of run adds what it measures.
"""

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Watched:
    """A run watched for crossings of its bodies (or of fixed lines).

    Attributes
    ----------
    crossings : int
        Particles whose offset from a segment's line (a triangle's plane) changed sign between two steps while
        they projected onto it, over the run.
    far_side : int
        Particles on the other side at the end than at the start, of a segment they project onto both times.
    frames : list of (float, numpy.ndarray, dict)
        VTK frames ``(time, x, point_data)``.
    n_particles : int
        Particles at the end.
    steps : int
        Steps taken.
    bodies : list
        The bodies' shapes where the run ends (or the fixed lines watched).
    """

    crossings: int
    far_side: int
    frames: list
    n_particles: int
    steps: int
    bodies: list


@dataclass(frozen=True)
class Collision(Watched):
    """The jelly ball onto the free plate.

    Attributes
    ----------
    drift : float
        Largest :math:`|P_{particles} + P_{plate} - P_0|` over the run, relative to :math:`m_{ball}|v|`.
    history : numpy.ndarray
        Per step: time, the particles' momentum (x, y), the plate's momentum (x, y), the plate's vertical
        velocity, kinetic plus elastic energy of the particles, the plate's kinetic energy.
    plate_v : float
        The plate's vertical velocity at the end.
    ball_v : float
        The ball's mean vertical velocity at the end.
    p0 : float
        :math:`m_{ball}|v|` at the start.
    energy0, energy_end : float
        Kinetic, elastic and plate kinetic energy at the start and at the end.
    """

    drift: float
    history: np.ndarray
    plate_v: float
    ball_v: float
    p0: float
    energy0: float
    energy_end: float


@dataclass(frozen=True)
class Cut(Watched):
    """A block cut by blades: ``components``, its connected components at the end (particles linked when closer
    than one cell)."""

    components: int


@dataclass(frozen=True)
class Sliding(Watched):
    r"""The block sliding on a segment with friction.

    Attributes
    ----------
    com : numpy.ndarray
        Per step: time, the centre of mass (x, y) and its velocity (x, y).
    stop_time : float
        When the centre of mass's velocity fell below 1 % of the initial speed (NaN if it never did).
    distance : float
        The centre of mass's travel until then (until the end if it never stopped).
    stopped : bool
        Whether it stopped.
    expected : float
        :math:`v^2/(2\mu g)`.
    """

    com: np.ndarray
    stop_time: float
    distance: float
    stopped: bool
    expected: float


@dataclass(frozen=True)
class Wheel(Watched):
    r"""The sand wheel.

    Attributes
    ----------
    history : numpy.ndarray
        Per step: time, the wheel's angular velocity, the sand particles inside the ring, all particles, the
        deepest inside (Δx).
    inside_max : int
        Most sand particles inside the ring at one step.
    floor : float
        The check's floor of :math:`|\omega|` (:func:`verification.cpic.scenes.wheel_omega_floor`).
    late_min : float
        Smallest :math:`\operatorname{sign}(\omega_{end})\,\omega` over the last half of the run.
    omega_end : float
        The angular velocity at the end.
    entered : int
        Sand particles found inside the ring by any margin, over the run.
    entry_blade_distance : float
        Largest distance (Δx) to the nearest blade of a particle when first found inside the ring.
    depth_max : float
        Deepest sand inside the ring at any step (Δx).
    t_end : float
        End of the run.
    """

    history: np.ndarray
    inside_max: int
    floor: float
    late_min: float
    omega_end: float
    entered: int
    entry_blade_distance: float
    depth_max: float
    t_end: float


@dataclass(frozen=True)
class Baseline(Cut):
    """One baseline over the vertical cut line: its ``kind`` and strip ``width`` (cells, of
    :func:`verification.cpic.scenes.baseline_scene`) and the fraction of the block's mass lost, ``mass_lost``."""

    kind: str
    width: float
    mass_lost: float


@dataclass(frozen=True)
class CpicResult:
    """Every run of the case; those of the default and full presets only are ``None`` (or empty) in the quick one.

    Attributes
    ----------
    params : verification.cpic.scenes.Params
        The parameters, with the backend every run used.
    backend : str
        That backend.
    drop, sand, impact : Watched
        The no-crossing runs: jelly onto a fixed segment, a blade through sand, the hard impact.
    exact, default : Collision
        The ball onto the free plate, momentum-exact and default variants.
    cut : Cut
        Jelly onto the wedge blade.
    cut3d : Cut
        The 3D block onto two crossed blades.
    friction : Sliding
        The block sliding with friction.
    wheel : Wheel
        The sand wheel.
    sand_2e4 : Watched or None
        The blade through sand with the reference's pushing force 2e4.
    exact_reference : Collision or None
        The exact collision with the reference's ghost velocities (``ghost_force = false``).
    friction_reference : Sliding or None
        The sliding block with the reference's ghost velocities.
    rotor : Watched or None
        The spinning plate.
    baselines : tuple of Baseline
        The baselines, in the order of :data:`verification.cpic.scenes.BASELINES`.
    """

    params: object
    backend: str
    drop: Watched
    sand: Watched
    impact: Watched
    exact: Collision
    default: Collision
    cut: Cut
    cut3d: Cut
    friction: Sliding
    wheel: Wheel
    sand_2e4: Watched = None
    exact_reference: Collision = None
    friction_reference: Sliding = None
    rotor: Watched = None
    baselines: tuple = ()
