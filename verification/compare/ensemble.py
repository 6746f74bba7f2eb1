r"""The ensemble: the scene run by mpmref itself, once as it is (the *control*) and ``N`` times with its initial
positions perturbed at round-off.

Member :math:`k \ge 1` starts from the exported start with each coordinate multiplied by :math:`1 + \delta`,
:math:`\delta` uniform in :math:`[-u\varepsilon, u\varepsilon]` (:math:`u` = :data:`PERTURBATION_ULPS`,
:math:`\varepsilon` the machine epsilon of the code's precision), drawn from a generator seeded by ``(seed, k)``:
a few units in the last place of every position, the size of the round-off by which two correct codes part in their
first step. This is the perturbation of the ensemble consistency test of CESM (Baker et al. 2015, who perturb the
initial temperature by :math:`O(10^{-14})`), applied to the particles' positions. Each member is a module-level
call on picklable arguments, so members run in local processes or on a ``dask.distributed`` cluster
(:class:`verification.framework.executor.Executor`).
"""

from dataclasses import dataclass

import numpy as np

from mpmref import Scene, Simulation
from mpmref.errors import MpmrefError

from .statistics import frame_statistics

#: the perturbation of the members' initial positions, in units of the precision's epsilon (relative)
PERTURBATION_ULPS = 4.0


@dataclass(frozen=True)
class Member:
    """One run of the ensemble: ``index`` 0 is the control (not perturbed).

    ``scene`` is the scene as declared (its ``dtype`` the code's precision), ``base_dir`` where its relative files
    are; ``stops`` the frames to record, each ``("step", k)`` or ``("time", t)``; ``threads`` the Numba threads of
    this run (``None``: Numba's default)."""

    scene: dict
    base_dir: str
    backend: str
    index: int
    seed: int
    stops: tuple
    threads: int | None = 1


@dataclass
class MemberRun:
    """What a member recorded at each stop: positions ``x`` (frames, n, d) in the order of the particles' ids, the
    statistics ``stats`` (:func:`~.statistics.frame_statistics`, a dict per frame) and the rms speed of each frame."""

    index: int
    x: np.ndarray
    stats: list
    speeds: list


def perturbed(x, index, seed):
    """Positions ``x`` of member ``index`` (module docstring); the control's (``index`` 0) unchanged."""
    if index == 0:
        return x
    eps = np.finfo(x.dtype).eps
    delta = np.random.default_rng([seed, index]).uniform(-1.0, 1.0, x.shape) * PERTURBATION_ULPS * eps
    return (x.astype(np.float64) * (1.0 + delta)).astype(x.dtype)


def frame_fields(particles):
    """The fields of ``particles`` that the statistics read (``v``, ``F``, ``J``, ``Jp`` where allocated), float64."""
    return {k: getattr(particles, k).astype(np.float64) for k in ("v", "F", "J", "Jp")
            if getattr(particles, k) is not None}


def advance(sim, stop):
    """Run ``sim`` to ``stop`` (``("step", k)`` or ``("time", t)``); nothing when it is there already."""
    kind, value = stop
    if kind == "step" and value > sim.step_count:
        sim.run(until_step=value)
    elif kind == "time" and value > sim.time:
        sim.run(t_end=value)


def run_member(member):
    """Run one :class:`Member` and record every stop: a :class:`MemberRun`."""
    if member.threads is not None and member.backend == "numba":
        from mpmref.backends.numba.threads import use_threads

        use_threads(member.threads)
    scene = Scene.from_dict(member.scene, base_dir=member.base_dir)
    sim = Simulation(scene, backend=member.backend)
    sim.x = perturbed(sim.x, member.index, member.seed)
    xs, stats, speeds, count = [], [], [], sim.n_particles
    for stop in member.stops:
        advance(sim, stop)
        p = sim.particles
        if p.n != count:
            raise MpmrefError(f"ensemble member {member.index} has {p.n} particles at step {sim.step_count}, the start "
                              f"{count} (boundary.domain_exit = {scene.boundary.domain_exit!r}): compare follows every "
                              "particle of the start through every frame")
        order = np.argsort(p.id, kind="stable")
        fields = {k: v[order] for k, v in frame_fields(p).items()}
        x = p.x[order].astype(np.float64)
        xs.append(x)
        stats.append(frame_statistics(scene, x, fields, p.mass[order].astype(np.float64), p.material[order]))
        speeds.append(float(np.sqrt(np.mean(np.sum(fields["v"] ** 2, axis=1)))))
    return MemberRun(member.index, np.array(xs), stats, speeds)
