"""The exact parts of the sync-vs-async case (:mod:`verification.sync_vs_async`): one level against sync, free fall,
and the schedule (the worked two-block example and the id census), with the steppers that force, draw or freeze
levels and shadows.
"""

import numpy as np

from mpmref import Simulation
from mpmref.state import EVOLVING_FIELDS
from mpmref.steppers import AsynchronousStepper, AsyncInterval

from .scenes import SCHEDULE_DX, census_scene, two_bodies


# ---------------------------------------------------------------------------------------- one level
def max_relative_difference(a, b):
    """Largest ``|a - b| / max|b|`` over the evolving arrays of two particle states."""
    worst = 0.0
    for name, arr in b.arrays().items():
        if name not in EVOLVING_FIELDS:
            continue
        other = getattr(a, name).astype(np.float64)
        scale = max(float(np.max(np.abs(arr))), 1e-300)
        worst = max(worst, float(np.max(np.abs(other - arr))) / scale)
    return worst


#: the tick of the one-level comparison (s)
ONE_LEVEL_TICK = 2e-4

#: the block size of the one-level comparison: any size must give sync's bits with one level; 4 cells is the
#: default block, so on Numba the comparison runs on kernels the other cases compile too
ONE_LEVEL_BLOCK = 4


def one_level(params, backend):
    """Async with one level against sync at Δt = one tick: max relative difference and bit equality."""
    tick, steps = ONE_LEVEL_TICK, params.one_level_steps
    a = Simulation(two_bodies(cfl=0.5, tick=tick, levels=0, steps=steps, block=ONE_LEVEL_BLOCK), backend=backend)
    s = Simulation(two_bodies(stepping="sync", dt=tick, steps=steps, block=ONE_LEVEL_BLOCK), backend=backend)
    a.run()
    s.run()
    same = all(np.array_equal(arr, getattr(a.particles, k)) for k, arr in s.particles.arrays().items())
    return {"backend": backend, "max_rel": max_relative_difference(a.particles, s.particles), "bitwise": same}


# ---------------------------------------------------------------------------------------- free fall
def free_fall(params, backend, stepper=None):
    """Relative error of the centre-of-mass velocity against :math:`v_0 + g t` at every synchronised time.

    The stiff and the soft part are bonded, so the fine particles' nodes hold coarse ghosts (shadows): only
    shadows sub-cycled to the fine particles' time keep the velocity field uniform. It runs with the reference
    interfaces: the conservative ones keep the total momentum, so the centre-of-mass velocity, exact whatever
    the shadows, and the test would not see them.
    """
    g = -10.0
    scene = two_bodies(cfl=0.4, tick=1e-5, levels=6, gravity=g, walls="open", bonded=True, steps=1,
                       interface="reference")
    sim = Simulation(scene, backend=backend)
    if stepper is not None:
        with_stepper(sim, stepper)
    v0 = float(np.average(sim.v[:, 1], weights=sim.mass))
    errors, levels = [], set()
    for _ in range(params.free_fall_intervals):
        sim.step()
        levels |= set(sim.particles.level.tolist())
        d = sim.diagnostics()
        expected = v0 + g * sim.time
        errors.append(abs(d["momentum_y"] / d["mass"] - expected) / abs(g * sim.time))
    return {"max_rel": max(errors), "levels": sorted(levels), "time": sim.time}


# ----------------------------------------------------------------------------------------- schedule
class ForcedLevels(AsynchronousStepper):
    """Particles left of ``8.5 dx`` limited to 1 tick, the others to 2: the two-block worked example."""

    def particle_limits(self, particles, idx=None):
        x = particles.x if idx is None else particles.x[idx]
        return np.where(x[:, 0] < 8.5 * SCHEDULE_DX, 1.0, 2.0)


class RandomLevels(AsynchronousStepper):
    """Each block's limit drawn at random (1 .. 16 ticks, coarse ones more often) every time it is asked
    (seeded per stepper, so a census run is repeatable)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.rng = np.random.default_rng(7)

    def particle_limits(self, particles, idx=None):
        per_block = self.rng.choice(5, size=self.grid.n_blocks, p=[0.02, 0.03, 0.1, 0.25, 0.6])
        x = particles.x if idx is None else particles.x[idx]
        return np.exp2(per_block[self.owner_blocks(x)]).astype(float)


class _FrozenShadows(AsyncInterval):
    def refresh_shadows(self, proposals):
        """Broken on purpose: shadows stay at the coarse step's start (no sub-cycling)."""


class FrozenShadows(AsynchronousStepper):
    """A deliberately broken variant for the case's tests: shadows are never refreshed."""

    interval_type = _FrozenShadows


#: the worked example: (tick, level, active blocks, same-time ghost blocks, shadow ghosts (block, tick))
F_BLOCK, C_BLOCK = 0, 3
WORKED_EXAMPLE = [
    (0, 2, [C_BLOCK], [F_BLOCK], []),
    (0, 1, [F_BLOCK], [], [(C_BLOCK, 0)]),
    (1, 1, [F_BLOCK], [], [(C_BLOCK, 1)]),
    (2, 2, [C_BLOCK], [F_BLOCK], []),
    (2, 1, [F_BLOCK], [], [(C_BLOCK, 2)]),
    (3, 1, [F_BLOCK], [], [(C_BLOCK, 3)]),
]


def with_stepper(sim, cls):
    """Give ``sim`` a stepper of class ``cls`` (a subclass of the asynchronous stepper) from its initial state."""
    sim.stepper = cls(sim.scene, sim.backend)
    sim.state = sim.stepper.initial_state(sim.particles)
    return sim


def schedule(params, backend):
    """The worked example's update list (on ``backend``), and the id census under random level changes.

    The census checks the stepper's bookkeeping, which no backend sees; it runs on Numba, whose compiled
    stages make its thousands of tiny updates about 3x faster than the NumPy reference's.
    """
    sim = with_stepper(Simulation(two_bodies(cfl=0.5, tick=1e-4, levels=3, steps=2), backend=backend), ForcedLevels)
    sim.stepper.record_trace = True
    sim.step()
    sim.step()
    trace = [(e.tick, e.level, e.active, e.level_ghosts, e.shadow_ghosts) for e in sim.stepper.work.trace]
    census = with_stepper(Simulation(census_scene(), backend="numba"), RandomLevels)
    ids, levels, intervals = np.sort(census.id.copy()), set(), 0
    while census.state.tick < params.census_ticks:
        census.step()  # raises AsyncCensusError on a lost or duplicated id
        intervals += 1
        levels |= set(census.particles.level.tolist())
    lost = int(np.setdiff1d(ids, census.id).size)
    extra = int(census.id.size - np.unique(census.id).size)
    return {"trace": trace, "matches": trace == WORKED_EXAMPLE, "census_ticks": census.state.tick,
            "census_intervals": intervals, "census_levels": sorted(levels), "lost": lost, "duplicated": extra}
