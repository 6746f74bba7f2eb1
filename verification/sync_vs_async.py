r"""Synchronous against asynchronous (regional) time stepping (Fang, Hu, Hu & Jiang, SCA 2018).

Parts (the one-level comparison on both backends; the 2D pairs and the sweeps over steps on Numba, as they
compare stepping schemes, not backends, and time their runs; the rest on the backend the case is run with):

* **one level**: ``time.levels = 0`` forces every block to one tick; the asynchronous run must be the
  synchronous run at Δt = one tick, bit for bit (particle order is kept), after ``one_level_steps`` steps;
* **free fall**: a stiff and a soft body on different levels, gravity, no walls. Partition of unity makes a
  uniform velocity field exact in P2G and G2P whatever the ghosts, so the centre-of-mass velocity is
  :math:`v_0 + g t` at every synchronised time to round-off;
* **schedule**: the two-block worked example of Fang et al. (F at 1 tick, C at 2) reproduced update by
  update, and an id census over ``census_ticks`` ticks of random level changes;
* **balls**: two elastic balls of very different stiffness (E ratio ``ball_E_ratio``), no gravity, collide;
  synchronous stepping at the finest asynchronous step against asynchronous stepping, compared at every
  synchronised time: total energy, positions (matched by particle id) in units of Δx, linear and angular
  momentum drift of each — the error at level interfaces is measured, not assumed zero;
* **stork** (2D and 3D): the stiff/soft scene of ``examples/stork2d.toml`` / ``stork3d.toml``: particle
  updates (ghosts included) and wall time of both runs, energy and position difference;
* **isolated**: a soft and a stiff disk pressed together and spinning, in free space (no gravity, no wall
  reached): nothing external acts, so total linear and angular momentum must stay constant;
* **ledger**: the same disks with the energy ledger (:class:`mpmref.observe.ledger.LevelLedger`): at every synchronised
  time the change it books (each level update's active particles, and the registers) must be the change of total
  energy the diagnostics measure; how much of it crosses the level interfaces is a finding;
* **both interface treatments** (``time.interface``, :mod:`mpmref.physics.interface`) side by side in the
  paired runs: ``conservative`` (impulse refluxing) and ``reference`` (Fang et al. 2018 as published);
* **bonded at every CFL number**: the 2D stork at several CFL numbers, energy against sync;
* **balls over ticks**: the colliding balls at shrinking steps (the level ratio fixed), the end state of
  each treatment against sync at its finest step and at a 4x finer one, with fitted slopes;
* **trade**: error against wall time on the 2D stork for sync at several steps and async at several CFL
  numbers and level counts, against a reference sync run at a 4x finer step; the Pareto front marked.

Bounds: bit equality for one level; :math:`10^{-12}` relative for free fall (a few hundred steps of
round-off); energy within 2 % of the synchronous curve and final positions within 0.5 Δx (targets set
from the AsyncMPM reference's reported agreement); at least 3× fewer particle updates on the
2D stork (the talk reports 3.3× on its stork). No particle may be lost: the census raises otherwise.
With conservative interfaces, linear momentum (and angular momentum for MLS-MPM) is conserved to
:math:`10^{-12}` of :math:`\sum_p m_p |v_p|` on the isolated scene and on the balls (round-off of a few
hundred level updates), the ledger's booked energy change is the measured one to :math:`10^{-12}` of the
initial energy at every synchronised time, and bonded bodies stay within 1 % of sync in energy at every CFL number
(the target set for the conservative treatment). The reference treatment's drift is a finding. The balls' end-state difference is a
finding too, not a check: synchronous MPM on contact does not converge as Δt shrinks (its transfers
dissipate per step, measured in the case), so no rate against it can be derived.
"""

from dataclasses import dataclass
from pathlib import Path
from time import perf_counter

import numpy as np

from mpmref import Scene, SceneBuilder, Simulation
from mpmref.backends import BACKENDS
from mpmref.scene.factories import example_with_time
from mpmref.io.atomic import write_text_atomic
from mpmref.state import EVOLVING_FIELDS
from mpmref.steppers import AsynchronousStepper, AsyncInterval

from .framework.case import VerificationCase
from .framework.common import Check, Finding, checks_table
from .framework.report import pyplot, save_figure, snapshot, write_series

#: the figure that carries this case's main claim (the one ``index.html`` shows)
MAIN_FIGURE = "trade.png"

SCHEDULE_DX = 1.0 / 16


@dataclass(frozen=True)
class Params:
    one_level_steps: int = 100
    free_fall_intervals: int = 6
    census_ticks: int = 10_000
    ball_cells: int = 32
    ball_E: float = 1e3
    ball_E_ratio: float = 100.0
    ball_speed: float = 1.0
    ball_t_end: float = 0.12
    stork_t_end: float = 0.02
    stork3d_t_end: float = 0.004
    stork3d_cells: int = 32
    frames: int = 6
    interfaces: tuple = ("conservative", "reference")
    isolated_intervals: int = 4
    bonded_cfls: tuple = (0.4, 0.2, 0.1, 0.05)
    series_cfls: tuple = (0.4, 0.2, 0.1, 0.05, 0.025)
    series_t_end: float = 0.04
    trade_cfls: tuple = (0.4, 0.2, 0.1)
    trade_levels: tuple = (2, 4, 7)
    trade_reference_division: int = 16
    trade_sync_divisions: tuple = (1, 2, 4)
    bonded_interfaces: tuple = ("conservative", "reference")
    series_finer_rows: int = 99  # rows of the balls' series that also run sync at a 4x finer step
    series_interfaces: tuple = ("conservative", "reference")

    @classmethod
    def quick(cls):
        return cls(census_ticks=10_000, ball_cells=24, ball_t_end=0.04, stork_t_end=0.002, stork3d_t_end=0.001,
                   stork3d_cells=24, frames=3, series_cfls=(),
                   series_t_end=0.03, trade_cfls=(0.4,), trade_levels=(4, 7), trade_reference_division=4,
                   trade_sync_divisions=(1, 2), bonded_interfaces=("conservative",), bonded_cfls=(0.4, 0.2),
                   series_finer_rows=1, series_interfaces=("conservative",))

    @classmethod
    def full(cls):
        return cls(ball_cells=64, ball_t_end=0.2, stork_t_end=0.05, stork3d_t_end=0.02, series_t_end=0.06)


# ------------------------------------------------------------------------------------------ scenes
def two_bodies(stepping="async", gravity=0.0, walls="slip", bonded=False, block=8, **time):
    """A stiff and a soft elastic square side by side (16 cells, blocks of ``block`` cells, 8 by default: the two
    blocks per axis of the worked example): 3 cells apart and moving apart, or ``bonded`` (touching, one body of
    two materials)."""
    d = SCHEDULE_DX
    soft_from = 6 * d if bonded else 9 * d
    b = (SceneBuilder(dim=2, name="two_bodies").grid(size=1.0, cells=16, block=block).method("mls")
         .material("soft", "fixed_corotated", E=1e3, nu=0.3, rho=10.0)
         .material("stiff", "fixed_corotated", E=1e5, nu=0.3, rho=10.0)
         .box("stiff", lower=[2 * d, 2 * d], upper=[6 * d, 6 * d], velocity=[-0.2, 0.1])
         .box("soft", lower=[soft_from, 2 * d], upper=[soft_from + 4 * d, 6 * d],
              velocity=[-0.2 if bonded else 0.2, 0.1])
         .gravity([0.0, gravity]))
    b.walls(type=walls)
    b.time(stepping=stepping, **time)
    return b.build()


def balls(params, stepping, **time):
    """Two elastic balls of stiffness E and E·ratio flying at each other (no gravity, slip walls)."""
    r, v = 0.12, params.ball_speed
    return (SceneBuilder(dim=2, name="balls").grid(size=1.0, cells=params.ball_cells).method("mls")
            .material("soft", "fixed_corotated", E=params.ball_E, nu=0.3, rho=10.0)
            .material("stiff", "fixed_corotated", E=params.ball_E * params.ball_E_ratio, nu=0.3, rho=10.0)
            .ball("soft", center=[0.5 - r - 0.02, 0.5], radius=r, velocity=[v, 0.0], ppc=4)
            .ball("stiff", center=[0.5 + r + 0.02, 0.52], radius=r, velocity=[-v, 0.0], ppc=4)
            .walls(type="slip").time(stepping=stepping, **time).build())


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


# ------------------------------------------------------------------------------------- paired runs
def _record(sim):
    d = sim.diagnostics()
    L = d.get("angular_momentum", d.get("angular_momentum_z", 0.0))
    P = np.array([d[k] for k in d if k.startswith("momentum_")])
    return {"time": sim.time, "energy": d["total_energy"], "P": P, "L": L}


def _frame(sim):
    """A VTK frame coloured by level: velocity, material and ``dt_level`` (log2 of the particle's step in ticks)."""
    time, x, data = snapshot(sim, ("velocity", "material"))
    return time, x, {**data, "dt_level": sim.particles.level.astype(np.int32)}


def run_async(make_scene, backend, frames=6, stepper=None):
    """Run ``make_scene("async", None)`` to its end: records at every synchronised time, frames, wall time."""
    a = Simulation(make_scene("async", None), backend=backend)
    if stepper is not None:
        with_stepper(a, stepper)
    t_end = a.scene.time.t_end
    rec, shots, start = [_record(a)], [_frame(a)], perf_counter()
    ticks, next_frame = [0], t_end / max(frames, 1)
    while a.time < t_end * (1.0 - 1e-12):
        a.step()
        rec.append(_record(a))
        ticks.append(a.state.tick)
        if frames and a.time >= next_frame * (1.0 - 1e-12):
            shots.append(_frame(a))
            next_frame += t_end / frames
    return {"sim": a, "records": rec, "frames": shots, "ticks": ticks, "wall": perf_counter() - start,
            "summary": a.stepper.summary(a.state)}


def run_pair(make_scene, backend, frames=6, stepper=None):
    """Run a scene asynchronously, then synchronously at its finest step; compare at synchronised times.

    ``make_scene(stepping, dt)`` builds the scene (``dt`` only for ``"sync"``); ``stepper`` replaces the
    asynchronous stepper class (the tests' broken variant). Returns both records, the position difference
    at the end (by id, in Δx), updates and wall times.
    """
    run = run_async(make_scene, backend, frames, stepper)
    a, summary, ticks = run["sim"], run["summary"], run["ticks"]
    finest = summary["finest_dt_ticks"]
    s = Simulation(make_scene("sync", finest * a.scene.time.tick), backend=backend)
    rec_s, start, k = [_record(s)], perf_counter(), 0
    targets = set(ticks[1:])
    while k * finest < ticks[-1]:
        s.step()
        k += 1
        if k * finest in targets:
            rec_s.append(_record(s))
    wall_s = perf_counter() - start
    return {"async": run["records"], "sync": rec_s, "position_dx": position_difference(a, s), "wall_async": run["wall"],
            "wall_sync": wall_s, "updates_async": summary["particle_updates"], "own_updates": summary["own_updates"],
            "updates_sync": s.n_particles * s.step_count, "finest_ticks": finest, "stale": summary["stale_shadows"],
            "n": a.n_particles, "mass": float(np.sum(a.mass)), "levels": sorted(set(a.particles.level.tolist())),
            "frames": run["frames"]}


def position_difference(a, b):
    """Largest distance between the same particles (matched by id) of two runs, in Δx."""
    pa, pb = a.x[np.argsort(a.id)], b.x[np.argsort(b.id)]
    return float(np.max(np.linalg.norm(pa - pb, axis=1))) / a.scene.grid.dx


def drift(recs, key):
    """Largest change of a record's quantity ``key`` from its first value."""
    first = recs[0][key]
    return max(float(np.linalg.norm(np.subtract(r[key], first))) for r in recs)


def compare(pair):
    """Energy difference (relative to the initial energy) and momentum drifts of a :func:`run_pair` result."""
    ea = np.array([r["energy"] for r in pair["async"]])
    es = np.array([r["energy"] for r in pair["sync"]])
    n = min(len(ea), len(es))
    e0 = abs(es[0])
    return {"energy_rel": float(np.max(np.abs(ea[:n] - es[:n]))) / e0, "energy_async": ea, "energy_sync": es,
            "times": np.array([r["time"] for r in pair["async"]]),
            "P_drift_async": drift(pair["async"], "P"), "P_drift_sync": drift(pair["sync"], "P"),
            "L_drift_async": drift(pair["async"], "L"), "L_drift_sync": drift(pair["sync"], "L")}


def ball_pair(params, backend, interface="reference", cfl=0.4, t_end=None, frames=None):
    t_end = t_end or params.ball_t_end

    def make(stepping, dt):
        if stepping == "async":
            return balls(params, "async", cfl=cfl, tick=1e-6, levels=10, t_end=t_end, interface=interface)
        return balls(params, "sync", dt=dt, t_end=t_end)
    return run_pair(make, backend, params.frames if frames is None else frames)


def stork_pair(name, t_end, backend, frames, stepper=None, cells=None, interface="reference", cfl=None, levels=None):
    """The example ``name`` (at ``cells`` cells if given, ``time.cfl``/``levels`` if given) asynchronously with
    ``interface``, and synchronously (:func:`run_pair`)."""
    def make(stepping, dt):
        scene = example_with_time(name, t_end, dt if stepping == "sync" else None, cells)
        if stepping == "sync":
            return scene
        src = scene.source
        time = {**src["time"], "interface": interface, **({"cfl": cfl} if cfl else {}),
                **({"levels": levels} if levels is not None else {})}
        return scene.__class__.from_dict({**src, "time": time}, base_dir=scene.base_dir)
    return run_pair(make, backend, frames, stepper)


def census_scene():
    """The id census's scene: a spinning ball on four levels, on a 16-cell grid (:func:`schedule`)."""
    return (SceneBuilder(dim=2).grid(size=1.0, cells=16, block=4).method("mls")
            .material("m", "fixed_corotated", E=50.0, nu=0.3, rho=1.0)
            .ball("m", center=[0.5, 0.5], radius=0.2, ppc=1, velocity=[0.6, -0.4], angular_velocity=3.0)
            .walls(type="separate").time(stepping="async", cfl=0.5, tick=1e-4, levels=4, steps=1).build())


# --------------------------------------------------------------------------------------- isolated
def pressed_disks(interface="conservative", stepping="async", scheme="mls", method=None, intervals=1, **time):
    """A soft and a stiff disk (E ratio 100, levels three apart) pressed together by a cell and spinning, in free
    space (open walls, no gravity): nothing external acts on them. ``method`` holds extra ``[method]`` keys
    (e.g. ``flip_alpha``); ``intervals`` synchronised intervals; ``time`` the keys of a synchronous run."""
    b = (SceneBuilder(dim=2, name="pressed").grid(size=1.0, cells=20).method(scheme, **(method or {}))
         .material("soft", "fixed_corotated", E=1e3, nu=0.3, rho=10.0)
         .material("stiff", "fixed_corotated", E=1e5, nu=0.3, rho=10.0)
         .ball("soft", center=[0.38, 0.5], radius=0.13, velocity=[0.4, 0.1], angular_velocity=2.0)
         .ball("stiff", center=[0.62, 0.52], radius=0.13, velocity=[-0.4, 0.0], angular_velocity=-1.0)
         .walls("open"))
    if stepping == "async":
        return b.time(stepping="async", cfl=0.4, tick=1e-6, levels=10, steps=intervals, interface=interface).build()
    return b.time(**time).build()


def isolated(params, backend, interface):
    """Momentum drifts of the pressed disks over ``params.isolated_intervals`` synchronised intervals, relative to
    :math:`\\sum_p m_p|v_p|` (linear) and :math:`\\sum_p m_p|x_p||v_p|` (angular)."""
    sim = Simulation(pressed_disks(interface), backend=backend)
    speed = np.linalg.norm(sim.v, axis=1)
    scale_P = float(np.sum(sim.mass * speed))
    scale_L = float(np.sum(sim.mass * np.linalg.norm(sim.x, axis=1) * speed))
    recs, levels = [_record(sim)], set()
    for _ in range(params.isolated_intervals):
        sim.step()
        recs.append(_record(sim))
        levels |= set(sim.particles.level.tolist())
    return {"P": drift(recs, "P") / scale_P, "L": drift(recs, "L") / scale_L, "levels": sorted(levels),
            "ghost_updates": sim.stepper.summary(sim.state)["ghost_updates"]}


def ledger_split(params, backend, interface):
    """The pressed disks with the energy ledger over ``params.isolated_intervals`` synchronised intervals: the
    largest gap between the change it books and the change of total energy the diagnostics measure, per interval,
    and its cumulative terms, all relative to the initial energy."""
    src = pressed_disks(interface).source
    sim = Simulation(Scene.from_dict({**src, "output": {**src.get("output", {}), "energy_ledger": True}}),
                     backend=backend)
    e0 = sim.diagnostics()["total_energy"]
    gap = 0.0
    for _ in range(params.isolated_intervals):
        before = sim.diagnostics()["total_energy"]
        sim.step()
        measured = sim.diagnostics()["total_energy"] - before
        gap = max(gap, abs(sim.stepper.ledger.last["energy_change"] - measured) / abs(e0))
    d = sim.diagnostics()
    return {"gap": gap, "terms": {k[len("ledger_"):]: v / e0 for k, v in d.items() if k.startswith("ledger_")}}


# ------------------------------------------------------------------------------ bonded, series, trade
def bonded_at_cfls(params, backend):
    """The 2D stork at each CFL number of ``params.bonded_cfls``, both treatments: energy difference from sync."""
    out = []
    for cfl in params.bonded_cfls:
        row = {"cfl": cfl}
        for itf in params.bonded_interfaces:
            pair = stork_pair("stork2d", params.stork_t_end, backend, 0, interface=itf, cfl=cfl)
            row[itf] = compare(pair)["energy_rel"]
        out.append(row)
    return out


def body_velocities(sim):
    """Centre-of-mass velocity of each material's particles, (materials, d)."""
    p = sim.particles
    return np.array([np.average(p.v[p.material == m], axis=0, weights=p.mass[p.material == m])
                     for m in range(len(sim.scene.materials))])


def ball_series(params, backend):
    """The colliding balls at each CFL number of ``params.series_cfls`` (the level ratio fixed): each treatment's
    end state against sync at the same finest step and at a 4x finer one (the balls' velocity, and energy)."""
    rows = []
    for cfl in params.series_cfls:
        ends = {itf: run_async(lambda stepping, dt, itf=itf, cfl=cfl: balls(params, stepping, cfl=cfl, tick=1e-6,
                                                                              levels=10, t_end=params.series_t_end,
                                                                              interface=itf),
                               backend, frames=0) for itf in params.series_interfaces}
        finest = min(e["summary"]["finest_dt_ticks"] for e in ends.values())
        syncs = {}
        finer = len(rows) < params.series_finer_rows
        for name, dt in (("sync", finest * 1e-6), ("sync/4", finest * 1e-6 / 4))[:2 if finer else 1]:
            s = Simulation(balls(params, "sync", dt=dt, t_end=params.series_t_end), backend=backend)
            s.run()
            syncs[name] = s
        row = {"cfl": cfl, "finest_ticks": finest,
               "sync_velocity": body_velocities(syncs["sync"]).tolist(),
               "sync_energy": syncs["sync"].diagnostics()["total_energy"]}
        speed = params.ball_speed
        for itf, e in ends.items():
            v = body_velocities(e["sim"])
            row[itf] = {name: float(np.max(np.abs(v - body_velocities(s)))) / speed for name, s in syncs.items()}
        if finer:
            row["sync_vs_sync4"] = float(np.max(np.abs(body_velocities(syncs["sync"])
                                                       - body_velocities(syncs["sync/4"])))) / speed
        rows.append(row)
    return rows


def fitted_slope(steps, errors):
    """Least-squares slope of log(error) against log(step)."""
    return float(np.polyfit(np.log(steps), np.log(np.maximum(errors, 1e-300)), 1)[0])


def trade(params, backend):
    """Error against wall time on the 2D stork: sync at ``params.trade_sync_divisions`` times finer than async's
    finest step, async
    at each CFL number and level count of ``params``, against sync at a ``params.trade_reference_division`` times
    finer step than async's finest;
    each run's end positions (by id) in Δx, and its stepping loop's wall time."""
    t_end = params.stork_t_end
    runs = []
    for cfl in params.trade_cfls:
        for levels in params.trade_levels:
            run = run_async(lambda stepping, dt, cfl=cfl, levels=levels: _stork_async(t_end, cfl, levels), backend,
                            frames=0)
            runs.append({"kind": "async", "label": f"async cfl {cfl} levels {levels}", "sim": run["sim"],
                         "wall": run["wall"], "finest": run["summary"]["finest_dt_ticks"]})
    finest = min(r["finest"] for r in runs)
    tick = runs[0]["sim"].scene.time.tick
    for div in params.trade_sync_divisions:
        s = Simulation(example_with_time("stork2d", t_end, dt=finest * tick / div), backend=backend)
        start = perf_counter()
        s.run()
        runs.append({"kind": "sync", "label": f"sync dt {finest / div:g} ticks", "sim": s, "wall": perf_counter() - start})
    ref = Simulation(example_with_time("stork2d", t_end, dt=finest * tick / params.trade_reference_division),
                     backend=backend)
    ref.run()
    for r in runs:
        r["error_dx"] = position_difference(r.pop("sim"), ref)
    front = pareto_front([(r["wall"], r["error_dx"]) for r in runs])
    for i, r in enumerate(runs):
        r["pareto"] = i in front
    return runs


def _stork_async(t_end, cfl, levels):
    scene = example_with_time("stork2d", t_end)
    src = scene.source
    return scene.__class__.from_dict({**src, "time": {**src["time"], "cfl": cfl, "levels": levels}},
                                     base_dir=scene.base_dir)


def pareto_front(points):
    """Indices of the points (cost, error) that no other point beats in both (ties broken by position)."""
    return {i for i, (c, e) in enumerate(points)
            if not any((c2 <= c and e2 <= e) and (c2 < c or e2 < e) for c2, e2 in points)}


def compiled_scenes(params, backend="numpy"):
    """``[(backend, scene)]`` whose kernels this case needs compiled (see :mod:`verification.framework.warmup`), on Numba
    whatever ``backend`` is: the one-level comparison's two scenes and the census. Their kernels serve the 2D
    pairs and sweeps too, and their asynchronous bookkeeping (compiled with them) every asynchronous run of the
    case: it depends only on which particle fields a scene allocates."""
    return [("numba", two_bodies(cfl=0.5, tick=ONE_LEVEL_TICK, levels=0, steps=1, block=ONE_LEVEL_BLOCK)),
            ("numba", two_bodies(stepping="sync", dt=ONE_LEVEL_TICK, steps=1, block=ONE_LEVEL_BLOCK)),
            ("numba", census_scene())]


# --------------------------------------------------------------------------------------------- run
def run(params=Params(), backend="numpy", executor=None):
    """Every part of the case (see the module docstring), in this process (``executor`` is not used)."""
    out = {"params": params, "backend": backend}
    out["one_level"] = [one_level(params, b) for b in ("numpy", "numba")]
    out["free_fall"] = free_fall(params, backend)
    out["schedule"] = schedule(params, backend)
    out["isolated"] = {itf: isolated(params, backend, itf) for itf in params.interfaces}
    out["ledger"] = {itf: ledger_split(params, backend, itf) for itf in params.interfaces}
    # the 2D pairs and the sweeps over steps compare stepping schemes, not backends: they run compiled (the
    # trade's wall times are its cost axis, and the NumPy reference would take minutes); the 3D stork runs on
    # the requested backend
    sweeps = "numba" if "numba" in BACKENDS else backend
    for itf in params.interfaces:
        out[f"balls/{itf}"] = ball_pair(params, sweeps, itf)
        out[f"stork2d/{itf}"] = stork_pair("stork2d", params.stork_t_end, sweeps, params.frames, interface=itf)
        out[f"stork3d/{itf}"] = stork_pair("stork3d", params.stork3d_t_end, backend, params.frames,
                                           cells=params.stork3d_cells, interface=itf)
        for key in ("balls", "stork2d", "stork3d"):
            out[f"{key}/{itf}"]["compare"] = compare(out[f"{key}/{itf}"])
    out["bonded"] = bonded_at_cfls(params, sweeps)
    out["series"] = ball_series(params, sweeps)
    out["trade"] = trade(params, sweeps)
    out["sweeps_backend"] = sweeps
    return out


PAIRS = ("balls", "stork2d", "stork3d")


def _pairs(result):
    return [(key, itf, result[f"{key}/{itf}"]) for key in PAIRS for itf in result["params"].interfaces]


# ------------------------------------------------------------------------------------------ checks
ROUND_OFF = 1e-12


def checks(result):
    out = [Check(f"one level = sync after {result['params'].one_level_steps} steps, {r['backend']} (max rel. diff.)",
                 r["max_rel"], "<=", 1e-12, "same arithmetic in the same order: bit for bit; 1e-12 allows reordering")
           for r in result["one_level"]]
    ff = result["free_fall"]
    out.append(Check("free fall: |v_com - (v0 + g t)| / |g t| at sync times", ff["max_rel"], "<=", 1e-12,
                     "partition of unity: a uniform velocity field is transferred exactly; round-off only"))
    out.append(Check("free fall: levels in use", len(ff["levels"]), ">=", 2, "the two bodies must be on different levels"))
    sc = result["schedule"]
    out.append(Check("schedule: updates of the worked two-block example reproduced", float(sc["matches"]), ">=", 1.0,
                     "Fang et al. 2018's schedule: coarse first at shared ticks, shadows sub-cycled by the fine block"))
    out.append(Check(f"census: ids lost or duplicated over {sc['census_ticks']} ticks of random levels",
                     sc["lost"] + sc["duplicated"], "<=", 0, "every particle is stored once with its own clock"))
    iso = result["isolated"].get("conservative")
    if iso is not None:
        why = ("impulse refluxing applies every interface exchange with both signs: round-off of a few hundred level "
               "updates (docs/async.md, conservative interfaces)")
        out.append(Check("isolated, conservative: linear momentum drift / sum m|v|", iso["P"], "<=", ROUND_OFF, why))
        out.append(Check("isolated, conservative: angular momentum drift / sum m|x||v| (MLS-MPM)", iso["L"], "<=",
                         ROUND_OFF, why))
        out.append(Check("isolated: levels apart (log2)", max(iso["levels"]) - min(iso["levels"]), ">=", 2,
                         "the disks must step on levels at least 4x apart, so the interface is exercised"))
    for itf, led in result.get("ledger", {}).items():
        out.append(Check(f"ledger, {itf}: max |booked - measured energy change| / E_0 per synchronised interval",
                         led["gap"], "<=", ROUND_OFF, "every particle changes only in its own updates and its "
                         "registers, which the ledger books: round-off (docs/energy_ledger.md, asynchronous runs)"))
    for key, itf, pair in _pairs(result):
        cmp = pair["compare"]
        if key == "balls":
            if itf == "conservative":
                scale = result["params"].ball_speed * pair["mass"]
                out.append(Check("balls, conservative: linear momentum drift / sum m|v|", cmp["P_drift_async"] / scale,
                                 "<=", ROUND_OFF, "no gravity and no wall reached: only the interfaces could move it"))
            continue
        out.append(Check(f"{key}, {itf}: max |E_async - E_sync| / E_0 at sync times", cmp["energy_rel"], "<=", 0.02,
                         "AsyncMPM target: energy within 2 % of the synchronous curve"))
        out.append(Check(f"{key}, {itf}: max position difference at the end (Δx)", pair["position_dx"], "<=", 0.5,
                         "AsyncMPM target: positions within half a cell"))
    if "conservative" in result["params"].interfaces:
        for row in result["bonded"]:
            out.append(Check(f"stork2d (bonded), conservative, CFL {row['cfl']}: max |E_async - E_sync| / E_0",
                             row["conservative"], "<=", 0.01, "the target for bonded bodies: within 1 % of "
                             "sync at every CFL number"))
    s2 = result[f"stork2d/{result['params'].interfaces[0]}"]
    out.append(Check("stork2d: sync particle updates / async own particle steps",
                     s2["updates_sync"] / s2["own_updates"], ">=", 3.0,
                     "AsyncMPM target: the talk reports 3.3x on its stork (ghost updates are reported apart)"))
    return out


def findings(result):
    """Measured behaviour that is not a pass/fail check: the reference interface's drift, the balls over ticks,
    the ghost cost, the trade."""
    out = []
    ref = result["isolated"].get("reference")
    if ref is not None:
        out.append(Finding("isolated, reference interface: linear momentum drift / sum m|v|", ref["P"],
                           "Fang et al.'s scheme applies neither reaction at a level interface: momentum drifts "
                           f"(angular {ref['L']:.1e}) where the conservative treatment keeps it to round-off."))
    for itf, led in result.get("ledger", {}).items():
        t = led["terms"]
        out.append(Finding(f"ledger, {itf}: energy crossing the level interfaces / E_0", t["interface"],
                           f"the pressed disks change their energy by {t['energy_change']:.3g} E_0: transfers "
                           f"{t['p2g_transfer'] + t['g2p_transfer']:.3g} (P2G {t['p2g_transfer']:.3g}), integration "
                           f"{t['integration']:.3g}, interfaces {t['interface']:.3g}."))
    for itf in result["params"].interfaces:
        b, c = result[f"balls/{itf}"], result[f"balls/{itf}"]["compare"]
        out.append(Finding(f"balls, {itf}: max |E_async - E_sync| / E_0", c["energy_rel"],
                           f"colliding balls (E ratio {result['params'].ball_E_ratio:g}, levels {b['levels']}) end "
                           f"{b['position_dx']:.2f} dx apart from sync, linear momentum drift {c['P_drift_async']:.2e} "
                           f"(sync {c['P_drift_sync']:.1e})."))
    series = result["series"]
    steps = [r["finest_ticks"] for r in series]
    for itf in result["params"].series_interfaces if len(series) >= 2 else ():
        errors = [r[itf]["sync"] for r in series]
        out.append(Finding(f"balls over {len(series)} steps, {itf}: fitted slope of |v_async - v_sync| (end state)",
                           fitted_slope(steps, errors), "the balls' end velocities against sync at the same finest "
                           f"step, for steps {steps} ticks: {', '.join(f'{e:.3g}' for e in errors)} of the impact speed."))
    own = [r["sync_vs_sync4"] for r in series if "sync_vs_sync4" in r]
    out += [] if not own else [Finding("balls: sync itself, |v(dt) - v(dt/4)| at the largest step", own[0],
                       "synchronous MPM on contact does not converge as the step shrinks (its transfers dissipate per "
                       f"step): sync against sync at a 4x finer step, for the same steps: {', '.join(f'{e:.3g}' for e in own)}. "
                       "No rate for async against it can be derived, so these are findings.")]
    s2 = result[f"stork2d/{result['params'].interfaces[0]}"]
    out.append(Finding("stork2d: sync updates / async updates, ghosts included", s2["updates_sync"] / s2["updates_async"],
                       f"ghost updates cost {s2['updates_async'] - s2['own_updates']} of {s2['updates_async']}; counting "
                       f"only the particles' own steps the saving is {s2['updates_sync'] / s2['own_updates']:.2f}x."))
    front = [r for r in result["trade"] if r["pareto"]]
    out.append(Finding("trade: runs on the Pareto front (stork2d, error against wall time)", len(front),
                       "; ".join(f"{r['label']}: {r['error_dx']:.2g} dx in {r['wall']:.2f} s" for r in front)))
    return out


def backends_run(result, backend):
    """The one-level part runs on NumPy and Numba, the sweeps on Numba; the rest on the requested backend."""
    return sorted({"numpy", "numba", result["backend"], result["sweeps_backend"]})


# ------------------------------------------------------------------------------------------ report
def _energy_plot(result, key, path):
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6, 3.5))
    for i, itf in enumerate(result["params"].interfaces):
        cmp = result[f"{key}/{itf}"]["compare"]
        n = min(len(cmp["energy_sync"]), len(cmp["times"]))
        if i == 0:
            ax.plot(cmp["times"][:n], cmp["energy_sync"][:n], "k-", label="sync at the finest async step")
        ax.plot(cmp["times"], cmp["energy_async"], f"C{i + 1}o", ms=3, label=f"async, {itf} interfaces")
    ax.set(xlabel="time [s]", ylabel="total energy", title=f"{key}: energy, sync vs async")
    ax.legend(fontsize=8)
    return save_figure(fig, path, caption=(
        f"{key}: total energy of the synchronous run (line) and of the asynchronous runs at their synchronised "
        "times (dots), one per interface treatment. Look for the dots on the line for bonded bodies (the storks); "
        "for bodies in grid contact on different levels (the balls) they leave it."))


def _trade_plot(result, path):
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    runs = result["trade"]
    for kind, marker in (("sync", "s"), ("async", "o")):
        pts = [r for r in runs if r["kind"] == kind]
        ax.loglog([r["wall"] for r in pts], [max(r["error_dx"], 1e-6) for r in pts], marker, ls="none",
                  label=kind, ms=6, mfc="none")
    front = sorted((r for r in runs if r["pareto"]), key=lambda r: r["wall"])
    ax.loglog([r["wall"] for r in front], [max(r["error_dx"], 1e-6) for r in front], "k--", label="Pareto front")
    for r in front:
        ax.annotate(r["label"], (r["wall"], max(r["error_dx"], 1e-6)), fontsize=6, xytext=(3, 3),
                    textcoords="offset points")
    ax.set(xlabel="wall time of the run [s]", ylabel="position error at the end [Δx]",
           title="stork2d: error against wall time")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    return save_figure(fig, path, caption=(
        f"2D stork: each run's end positions against a synchronous run at a "
        f"{result['params'].trade_reference_division}x finer step than the finest "
        "asynchronous step, against its wall time, for synchronous stepping at "
        f"{', '.join(str(k) for k in result['params'].trade_sync_divisions)} times finer than that step and "
        "asynchronous stepping at several CFL numbers and level counts. Look for the runs on the "
        "dashed Pareto front: no other run is both faster and more accurate. Wall times are from this run of the "
        "case, on a machine that may be shared, not a benchmark (mpmref bench --only async is one)."))


def table(result):
    rows = ["| scene | interface | particles | levels (log2 ticks) | updates sync | updates async (own) | saved | "
            "wall sync [s] | wall async [s] | energy diff | position diff [Δx] | P drift sync / async | "
            "L drift sync / async | stale shadows |", "|---" * 14 + "|"]
    for key, itf, p in _pairs(result):
        c = p["compare"]
        rows.append(f"| {key} | {itf} | {p['n']} | {p['levels']} | {p['updates_sync']} | {p['updates_async']} "
                    f"({p['own_updates']}) | {p['updates_sync'] / p['updates_async']:.2f}x | {p['wall_sync']:.2f} | "
                    f"{p['wall_async']:.2f} | {c['energy_rel']:.2e} | {p['position_dx']:.3f} | "
                    f"{c['P_drift_sync']:.2e} / {c['P_drift_async']:.2e} | {c['L_drift_sync']:.2e} / "
                    f"{c['L_drift_async']:.2e} | {p['stale']} |")
    return "\n".join(rows)


def report(result, out_dir):
    """Energy plots, the trade plot, the VTK series of each async run (``dt_level``), and ``sync_vs_async.md``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = [_trade_plot(result, out / "trade.png")]
    for key in PAIRS:
        paths.append(_energy_plot(result, key, out / f"energy_{key}.png"))
        for itf in result["params"].interfaces:
            paths.append(write_series(out / "vtk" / f"{key}_{itf}", result[f"{key}/{itf}"]["frames"]))
    sc = result["schedule"]
    ol = ", ".join(f"{r['backend']}: bitwise {r['bitwise']}, max rel. diff {r['max_rel']:.1e}" for r in result["one_level"])
    iso = "; ".join(f"{itf}: linear {r['P']:.2e}, angular {r['L']:.2e} (levels {r['levels']})"
                    for itf, r in result["isolated"].items())
    bonded_itfs = result["params"].bonded_interfaces
    bonded = "\n".join(f"| {r['cfl']} | " + " | ".join(f"{r[i]:.2e}" for i in bonded_itfs) + " |"
                       for r in result["bonded"])
    series_itfs = result["params"].series_interfaces
    series = "\n".join(f"| {r['cfl']} | {r['finest_ticks']} | " + " | ".join(
        f"{r[i]['sync']:.3g} / {r[i].get('sync/4', float('nan')):.3g}" for i in series_itfs)
        + f" | {r.get('sync_vs_sync4', float('nan')):.3g} |" for r in result["series"])
    trade_rows = "\n".join(f"| {r['label']} | {r['wall']:.3f} | {r['error_dx']:.3g} | {'yes' if r['pareto'] else ''} |"
                           for r in result["trade"])
    text = (f"# Sync vs async (backend {result['backend']}; the one-level part on numpy and numba)\n\n"
            f"One level: {ol}.\n\nFree fall: max relative error of v_com {result['free_fall']['max_rel']:.2e} on "
            f"levels {result['free_fall']['levels']}.\n\nSchedule: worked example reproduced: {sc['matches']}; census "
            f"over {sc['census_ticks']} ticks ({sc['census_intervals']} synchronised intervals, levels "
            f"{sc['census_levels']}): {sc['lost']} lost, {sc['duplicated']} duplicated.\n\n"
            f"Isolated pressed disks, momentum drift relative to its scale: {iso}.\n\n"
            f"## Paired runs\n\nSync runs at the finest async step. 'updates' count every particle a substep "
            f"moves, ghosts included (own: the particles' own steps). Wall times include compilation on a "
            f"first run and are from this machine, not a benchmark (see `mpmref bench --only async`).\n\n"
            f"{table(result)}\n\n" + "\n".join(f"![{k}](energy_{k}.png)" for k in PAIRS)
            + "\n\n## Bonded bodies at every CFL number (stork2d, max |E_async - E_sync| / E_0)\n\n| CFL | "
            + " | ".join(bonded_itfs) + " |\n|---|" + "---|" * len(bonded_itfs) + f"\n{bonded}\n\n"
            + "## Balls over shrinking steps (end velocity difference / impact speed: vs sync at the same step / "
            "vs sync at a 4x finer step)\n\n| CFL | finest step [ticks] | " + " | ".join(series_itfs)
            + " | sync vs sync/4 |\n|---|---|" + "---|" * len(series_itfs) + f"---|\n{series}\n\n"
            + f"## Error against wall time (stork2d)\n\n| run | wall [s] | error [Δx] | Pareto |\n|---|---|---|---|\n"
            f"{trade_rows}\n\n![trade](trade.png)\n\n## Findings\n\n"
            + "\n".join(f"- {f.name}: {f.value:.3g}. {f.sentence}" for f in findings(result))
            + f"\n\n## Checks\n\n{checks_table(checks(result))}\n")
    write_text_atomic(out / "sync_vs_async.md", text)
    return paths + [out / "sync_vs_async.md"]


#: this case, for the registry
CASE = VerificationCase(__doc__, Params, run, checks, report, findings=findings, backends_run=backends_run,
                        compiled_scenes=compiled_scenes, main_figure=MAIN_FIGURE)
