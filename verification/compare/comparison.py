"""A whole comparison: read the code's frames, run the ensemble, compute the statistics, judge every frame."""

import sys
import time
from dataclasses import dataclass, field

import numpy as np
from tqdm import tqdm

from mpmref import Scene
from mpmref.errors import ArgumentError
from mpmref.exchange import FrameError, initial_particles, read_frames

from ..framework.executor import Executor
from .ensemble import PERTURBATION_ULPS, Member, run_member
from .statistics import extent, frame_statistics, scales, speed_scale
from .verdict import ROUNDOFF_ULPS, FrameLabel, judge

#: the ensemble's default size: members besides the control (docs/comparing_runs.md: time and false alarms)
DEFAULT_MEMBERS = 20
#: the smallest ensemble the tests can judge with (the principal components need samples beyond their count)
MIN_MEMBERS = 7
#: a frame's time may be this many steps off a whole number of steps (a float32 code's accumulated time)
STEP_SLACK = 0.25


@dataclass
class Comparison:
    """Everything ``mpmref compare`` found: the scene in the code's precision, the frames, what the verdict is made of
    (``measures``, a :class:`Measures`: the statistics, their round-off floors, the particle distances) and the
    verdict of each frame (:class:`~.verdict.FrameVerdict`)."""

    scene: object
    frames: list
    backend: str
    members: int
    seed: int
    measures: object = field(repr=False)
    verdicts: list = field(default_factory=list)
    wall_s: float = 0.0
    where: str = ""

    @property
    def passed(self):
        return all(v.passed for v in self.verdicts)

    @property
    def first_failure(self):
        """The first frame where the code leaves the ensemble (a :class:`~.verdict.FrameVerdict`), or ``None``."""
        return next((v for v in self.verdicts if not v.passed), None)

    @property
    def dtype(self):
        return self.scene.dtype


def scene_in_precision(scene, dtype):
    """``scene`` in ``dtype`` (the code's precision), itself if it is already."""
    if dtype is None or np.dtype(dtype) == scene.dtype:
        return scene
    return Scene.from_dict({**scene.source, "dtype": np.dtype(dtype).name}, base_dir=scene.base_dir)


def code_precision(frames, scene, dtype=None):
    """The code's precision: ``dtype`` if given, else float32 when its frames store float32 positions, else the
    scene's."""
    if dtype is not None:
        return np.dtype(dtype)
    if any(f.dtype == np.float32 for f in frames):
        return np.dtype(np.float32)
    return scene.dtype


def frame_stops(scene, frames):
    """Where the ensemble records each frame: ``("step", k)`` with a fixed Δt (a frame's step, or its time over Δt),
    ``("time", t)`` with the CFL rule; :class:`FrameError` for a frame that cannot be placed."""
    dt = scene.time.dt
    stops = []
    for frame in frames:
        if dt is None:
            if frame.time is None:
                raise FrameError(frame.path, "says its step but not its time, and the scene's Δt comes from the CFL "
                                 "rule: write each frame's time (a .pvd timestep, or 'time')")
            stops.append(("time", frame.time))
            continue
        if frame.step is not None:
            stops.append(("step", frame.step))
            continue
        steps = frame.time / dt
        if abs(steps - round(steps)) > STEP_SLACK:
            raise FrameError(frame.path, f"is at t = {frame.time!r}, {steps:.3f} steps of the scene's dt = {dt!r}: "
                             "not a whole number of steps")
        stops.append(("step", int(round(steps))))
    return tuple(stops)


def frame_labels(scene, frames):
    """Each frame's step (its own, or the one its time is with a fixed Δt) and time."""
    return [FrameLabel(value if kind == "step" else frame.step, frame.time)
            for frame, (kind, value) in zip(frames, frame_stops(scene, frames))]


def _refuse_changing_particles(scene):
    if scene.emitters:
        raise ArgumentError("scene", scene.name, "a scene without [[emitters]]: compare follows the particles of the "
                            "start through every frame, and emitters add particles")


def _members(scene, backend, count, seed, stops, workers):
    threads = 1 if workers > 1 else None
    return [Member(scene.source, str(scene.base_dir), backend, k, seed, stops, threads) for k in range(count + 1)]


class _Reduction:
    """The members' runs reduced as they arrive: their statistics, and each particle's largest distance from the
    control at each frame."""

    def __init__(self, control, bar):
        self.control = control
        self.stats = [control.stats]
        self.speeds = list(control.speeds)
        self.particle_spread = np.zeros(control.x.shape[:2])
        self.bar = bar

    def __call__(self, index, run):
        distance = np.abs(run.x - self.control.x).max(axis=2)
        np.maximum(self.particle_spread, distance, out=self.particle_spread)
        self.stats.append(run.stats)
        self.speeds += run.speeds
        self.bar.update(1)


@dataclass
class Ensemble:
    """The control's run, the statistics of every sample (the control first, then the members in the order they
    finished) and each particle's largest member distance from the control at each frame."""

    control: object
    stats: list
    speeds: list
    particle_spread: np.ndarray
    where: str


def run_ensemble(scene, stops, backend="numba", members=DEFAULT_MEMBERS, seed=0, executor=None, progress=False):
    """Run the control and ``members`` perturbed members of ``scene`` (in the code's precision) to ``stops``
    (:func:`frame_stops`); an :class:`Ensemble`."""
    if members < MIN_MEMBERS:
        raise ArgumentError("members", members, f"an integer >= {MIN_MEMBERS} (the principal-component test needs "
                            "more samples than components)")
    executor = executor or Executor()
    runs = _members(scene, backend, members, seed, stops, executor.workers)
    with tqdm(total=members + 1, desc="ensemble", unit="run", file=sys.stderr, disable=not progress) as bar:
        control = run_member(runs[0])
        bar.update(1)
        reduction = _Reduction(control, bar)
        executor.map(run_member, runs[1:], on_result=reduction)
    return Ensemble(control, reduction.stats, reduction.speeds, reduction.particle_spread, executor.describe())


def compare(scene, source, backend="numba", members=DEFAULT_MEMBERS, seed=0, dtype=None, executor=None,
            progress=False):
    """Judge the frames of ``source`` (what another code wrote from the start of ``scene``) against an ensemble.

    Parameters
    ----------
    scene : Scene
        The scene the code ran (its start exported by ``mpmref export``).
    source : str or pathlib.Path
        The code's frames: a ``.pvd``, a folder or a file (:func:`mpmref.exchange.read_frames`).
    backend : str
        The backend that runs the ensemble (default the Numba backend).
    members : int
        Perturbed members besides the control (at least :data:`MIN_MEMBERS`).
    seed : int
        Seed of the perturbations.
    dtype : str, optional
        The code's precision; default: float32 when its frames store float32 positions, else the scene's.
    executor : :class:`~verification.framework.executor.Executor`, optional
        Where the members run (default: local processes, one per core).
    progress : bool
        A progress bar on standard error, one tick per member.

    Returns
    -------
    Comparison
    """
    started = time.perf_counter()
    _refuse_changing_particles(scene)
    frames = read_frames(source, scene.dim, initial_particles(scene).id)
    scene = scene_in_precision(scene, code_precision(frames, scene, dtype))
    ensemble = run_ensemble(scene, frame_stops(scene, frames), backend, members, seed, executor, progress)
    return judged(scene, frames, ensemble, backend, members, seed, time.perf_counter() - started)


@dataclass
class Measures:
    """What the verdict is made of (:func:`~.verdict.judge`): the statistics ``names``, the ensemble's ``samples``
    (frames, n, p) and the ``code``'s (frames, p), their round-off ``floor`` (p,), the ensemble's and the code's
    largest particle distance from the control (``spreads``, ``deviations``), each particle's (``particle_spread``,
    ``particle_deviation``, (frames, n)) and the round-off limit :math:`R`."""

    names: list
    samples: np.ndarray
    code: np.ndarray
    floor: np.ndarray
    spreads: np.ndarray
    deviations: np.ndarray
    particle_spread: np.ndarray = field(default=None, repr=False)
    particle_deviation: np.ndarray = field(default=None, repr=False)
    roundoff_limit: float = 0.0


def measured(scene, frames, ensemble):
    """The :class:`Measures` of the code's ``frames`` against an :class:`Ensemble` of ``scene`` run to their stops."""
    start = initial_particles(scene)
    mass, material = start.mass.astype(np.float64), start.material
    code_stats = [frame_statistics(scene, f.x, f.fields, mass, material) for f in frames]
    control = ensemble.control
    names = [name for name in code_stats[0] if name in control.stats[0]]
    samples = np.array([[[run[f][name] for name in names] for run in ensemble.stats] for f in range(len(frames))])
    code = np.array([[stats[name] for name in names] for stats in code_stats])
    eps = float(np.finfo(scene.dtype).eps)
    floor = ROUNDOFF_ULPS * eps * scales(scene, names, mass, material, speed_scale(scene, ensemble.speeds))
    particle_deviation = np.array([np.abs(f.x - x).max(axis=1) for f, x in zip(frames, control.x)])
    return Measures(names, samples, code, floor, ensemble.particle_spread.max(axis=1), particle_deviation.max(axis=1),
                    ensemble.particle_spread, particle_deviation, ROUNDOFF_ULPS * eps * extent(scene))


def judged(scene, frames, ensemble, backend, members, seed, wall=0.0):
    """The :class:`Comparison` of the code's ``frames`` with an :class:`Ensemble` of ``scene`` run to their stops."""
    m = measured(scene, frames, ensemble)
    verdicts = judge(frame_labels(scene, frames), m)
    return Comparison(scene, frames, backend, members, seed, m, verdicts, wall, ensemble.where)


def describe_method(comparison):
    """The ensemble and the thresholds, in one sentence for the reports."""
    c = comparison
    return (f"ensemble of {c.members} members and the control, run by the {c.backend} backend in {c.dtype.name}, "
            f"initial positions perturbed by up to {PERTURBATION_ULPS:g} eps (relative; seed {c.seed}); "
            f"round-off phase while the ensemble's spread <= {c.measures.roundoff_limit:.3g} ({ROUNDOFF_ULPS:g} eps L)")
