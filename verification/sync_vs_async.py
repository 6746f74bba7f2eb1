r"""Synchronous against asynchronous (regional) time stepping (Fang, Hu, Hu & Jiang, SCA 2018).

Parts (each on the backend the case is run with, the first on both):

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
  updates (ghosts included) and wall time of both runs, energy and position difference.

Bounds: bit equality for one level; :math:`10^{-12}` relative for free fall (a few hundred steps of
round-off); energy within 2 % of the synchronous curve and final positions within 0.5 Δx (targets set
from the AsyncMPM reference's reported agreement); at least 3× fewer particle updates on the
2D stork (the talk reports 3.3× on its stork). No particle may be lost: the census raises otherwise.
"""

from dataclasses import dataclass, replace
from pathlib import Path
from time import perf_counter

import numpy as np

from mpmref import SceneBuilder, Simulation
from mpmref.bench.asynchronous import example_scene
from mpmref.io.atomic import write_text_atomic
from mpmref.steppers import AsynchronousStepper
from mpmref.steppers.asynchronous import _Interval

from .common import Check, Finding, checks_table
from .report import pyplot, save_figure, snapshot, write_series

#: the figure that carries this case's main claim (the one ``index.html`` shows)
MAIN_FIGURE = "energy_stork2d.png"

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

    @classmethod
    def quick(cls):
        return cls(census_ticks=10_000, ball_cells=24, ball_t_end=0.04, stork_t_end=0.002, stork3d_t_end=0.001,
                   stork3d_cells=24, frames=3)

    @classmethod
    def full(cls):
        return cls(ball_cells=64, ball_t_end=0.2, stork_t_end=0.05, stork3d_t_end=0.02)


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
        if name in ("id", "level", "mass", "vol0", "material"):
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
    shadows sub-cycled to the fine particles' time keep the velocity field uniform.
    """
    g = -10.0
    scene = two_bodies(cfl=0.4, tick=1e-5, levels=6, gravity=g, walls="open", bonded=True, steps=1)
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


class _FrozenShadows(_Interval):
    def refresh_shadows(self, proposals):
        """Broken on purpose: shadows stay at the coarse step's start (no sub-cycling)."""


class FrozenShadows(AsynchronousStepper):
    """A deliberately broken variant for the case's tests: shadows are never refreshed."""

    interval = _FrozenShadows


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
    sim.stepper.trace = []
    sim.step()
    sim.step()
    trace = [(e["tick"], e["level"], e["active"], e["level_ghosts"], e["shadow_ghosts"]) for e in sim.stepper.trace]
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


def run_pair(make_scene, backend, frames=6, stepper=None):
    """Run a scene asynchronously, then synchronously at its finest step; compare at synchronised times.

    ``make_scene(stepping, dt)`` builds the scene (``dt`` only for ``"sync"``); ``stepper`` replaces the
    asynchronous stepper class (the tests' broken variant). Returns both records, the position difference
    at the end (by id, in Δx), updates and wall times.
    """
    a = Simulation(make_scene("async", None), backend=backend)
    if stepper is not None:
        with_stepper(a, stepper)
    t_end = a.scene.time.t_end
    rec_a, shots_a, start = [_record(a)], [_frame(a)], perf_counter()
    ticks, next_frame = [0], t_end / max(frames, 1)
    while a.time < t_end * (1.0 - 1e-12):
        a.step()
        rec_a.append(_record(a))
        ticks.append(a.state.tick)
        if frames and a.time >= next_frame * (1.0 - 1e-12):
            shots_a.append(_frame(a))
            next_frame += t_end / frames
    wall_a = perf_counter() - start
    summary = a.stepper.summary(a.state)
    finest = summary["finest_dt_ticks"]
    tick = a.scene.time.tick
    s = Simulation(make_scene("sync", finest * tick), backend=backend)
    rec_s, start, k = [_record(s)], perf_counter(), 0
    targets = set(ticks[1:])
    while k * finest < ticks[-1]:
        s.step()
        k += 1
        if k * finest in targets:
            rec_s.append(_record(s))
    wall_s = perf_counter() - start
    order_a, order_s = np.argsort(a.id), np.argsort(s.id)
    dx = a.scene.grid.dx
    pos = float(np.max(np.linalg.norm(a.x[order_a] - s.x[order_s], axis=1))) / dx
    return {"async": rec_a, "sync": rec_s, "position_dx": pos, "wall_async": wall_a, "wall_sync": wall_s,
            "updates_async": summary["particle_updates"], "own_updates": summary["own_updates"],
            "updates_sync": s.n_particles * s.step_count, "finest_ticks": finest, "stale": summary["stale_shadows"],
            "n": a.n_particles, "levels": sorted(set(a.particles.level.tolist())), "frames": shots_a}


def compare(pair):
    """Energy difference (relative to the initial energy) and momentum drifts of a :func:`run_pair` result."""
    ea = np.array([r["energy"] for r in pair["async"]])
    es = np.array([r["energy"] for r in pair["sync"]])
    n = min(len(ea), len(es))
    e0 = abs(es[0])

    def drift(recs, key):
        first, vals = recs[0][key], [r[key] for r in recs]
        return max(float(np.linalg.norm(np.subtract(v, first))) for v in vals)

    return {"energy_rel": float(np.max(np.abs(ea[:n] - es[:n]))) / e0, "energy_async": ea, "energy_sync": es,
            "times": np.array([r["time"] for r in pair["async"]]),
            "P_drift_async": drift(pair["async"], "P"), "P_drift_sync": drift(pair["sync"], "P"),
            "L_drift_async": drift(pair["async"], "L"), "L_drift_sync": drift(pair["sync"], "L")}


def ball_pair(params, backend):
    def make(stepping, dt):
        if stepping == "async":
            return balls(params, "async", cfl=0.4, tick=1e-6, levels=10, t_end=params.ball_t_end)
        return balls(params, "sync", dt=dt, t_end=params.ball_t_end)
    return run_pair(make, backend, params.frames)


def stork_pair(name, t_end, backend, frames, stepper=None, cells=None):
    """The example ``name`` (at ``cells`` cells if given) asynchronously and synchronously (:func:`run_pair`)."""
    return run_pair(lambda stepping, dt: example_scene(name, t_end, dt if stepping == "sync" else None, cells),
                    backend, frames, stepper)


def census_scene():
    """The id census's scene: a spinning ball on four levels, on a 16-cell grid (:func:`schedule`)."""
    return (SceneBuilder(dim=2).grid(size=1.0, cells=16, block=4).method("mls")
            .material("m", "fixed_corotated", E=50.0, nu=0.3, rho=1.0)
            .ball("m", center=[0.5, 0.5], radius=0.2, ppc=1, velocity=[0.6, -0.4], angular_velocity=3.0)
            .walls(type="separate").time(stepping="async", cfl=0.5, tick=1e-4, levels=4, steps=1).build())


def compiled_scenes(params, backend="numpy"):
    """``[(backend, scene)]`` this case runs on Numba whatever ``backend`` is: the one-level comparison's
    two scenes and the census (see :mod:`verification.warmup`)."""
    return [("numba", two_bodies(cfl=0.5, tick=ONE_LEVEL_TICK, levels=0, steps=1, block=ONE_LEVEL_BLOCK)),
            ("numba", two_bodies(stepping="sync", dt=ONE_LEVEL_TICK, steps=1, block=ONE_LEVEL_BLOCK)),
            ("numba", census_scene())]


# --------------------------------------------------------------------------------------------- run
def run(params=Params(), backend="numpy"):
    """Every part of the case (see the module docstring)."""
    out = {"params": params, "backend": backend}
    out["one_level"] = [one_level(params, b) for b in ("numpy", "numba")]
    out["free_fall"] = free_fall(params, backend)
    out["schedule"] = schedule(params, backend)
    out["balls"] = ball_pair(params, backend)
    out["stork2d"] = stork_pair("stork2d", params.stork_t_end, backend, params.frames)
    out["stork3d"] = stork_pair("stork3d", params.stork3d_t_end, backend, params.frames, cells=params.stork3d_cells)
    for key in ("balls", "stork2d", "stork3d"):
        out[key]["compare"] = compare(out[key])
    return out


# ------------------------------------------------------------------------------------------ checks
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
    for key in ("stork2d", "stork3d"):
        pair, cmp = result[key], result[key]["compare"]
        out.append(Check(f"{key}: max |E_async - E_sync| / E_0 at sync times", cmp["energy_rel"], "<=", 0.02,
                         "AsyncMPM target: energy within 2 % of the synchronous curve"))
        out.append(Check(f"{key}: max position difference at the end (Δx)", pair["position_dx"], "<=", 0.5,
                         "AsyncMPM target: positions within half a cell"))
    s2 = result["stork2d"]
    out.append(Check("stork2d: sync particle updates / async own particle steps",
                     s2["updates_sync"] / s2["own_updates"], ">=", 3.0,
                     "AsyncMPM target: the talk reports 3.3x on its stork (ghost updates are reported apart)"))
    return out


def findings(result):
    """Measured behaviour that is not a pass/fail check: the colliding balls' interface error, the ghost cost."""
    b, c = result["balls"], result["balls"]["compare"]
    s2 = result["stork2d"]
    return [
        Finding("balls: max |E_async - E_sync| / E_0", c["energy_rel"],
                f"colliding balls (E ratio {result['params'].ball_E_ratio:g}, levels {b['levels']}) end "
                f"{b['position_dx']:.2f} dx apart from sync, with linear momentum drift {c['P_drift_async']:.2e} "
                f"(sync {c['P_drift_sync']:.1e}): MPM's grid contact exchanges momentum on shared nodes once per "
                "step, so bodies in contact on different levels exchange it at different rates (not an O(dt) error)."),
        Finding("stork2d: sync updates / async updates, ghosts included", s2["updates_sync"] / s2["updates_async"],
                f"ghost updates cost {s2['updates_async'] - s2['own_updates']} of {s2['updates_async']}; counting "
                f"only the particles' own steps the saving is {s2['updates_sync'] / s2['own_updates']:.2f}x."),
    ]


def backends_run(result):
    """The one-level part runs on NumPy and Numba; the rest on the requested backend."""
    return sorted({"numpy", "numba", result["backend"]})


# ------------------------------------------------------------------------------------------ report
def _energy_plot(result, key, path):
    plt = pyplot()
    cmp = result[key]["compare"]
    fig, ax = plt.subplots(figsize=(6, 3.5))
    n = min(len(cmp["energy_sync"]), len(cmp["times"]))
    ax.plot(cmp["times"][:n], cmp["energy_sync"][:n], "k-", label="sync at the finest async step")
    ax.plot(cmp["times"], cmp["energy_async"], "C1o", ms=3, label="async (synchronised times)")
    ax.set(xlabel="time [s]", ylabel="total energy", title=f"{key}: energy, sync vs async")
    ax.legend()
    save_figure(fig, path, caption=f"{key}: total energy of the synchronous run (line) and of the asynchronous run at "
                "its synchronised times (dots). On bonded bodies (the storks) the dots sit on the line; for bodies in "
                "grid contact on different levels (the balls) they leave it.")
    return path


def table(result):
    rows = ["| scene | particles | levels (log2 ticks) | updates sync | updates async (own) | saved | wall sync [s] | "
            "wall async [s] | energy diff | position diff [Δx] | P drift sync / async | L drift sync / async | "
            "stale shadows |", "|---" * 13 + "|"]
    for key in [k for k in ("balls", "stork2d", "stork3d") if k in result]:
        p, c = result[key], result[key]["compare"]
        rows.append(f"| {key} | {p['n']} | {p['levels']} | {p['updates_sync']} | {p['updates_async']} "
                    f"({p['own_updates']}) | {p['updates_sync'] / p['updates_async']:.2f}x | {p['wall_sync']:.2f} | "
                    f"{p['wall_async']:.2f} | {c['energy_rel']:.2e} | {p['position_dx']:.3f} | "
                    f"{c['P_drift_sync']:.2e} / {c['P_drift_async']:.2e} | {c['L_drift_sync']:.2e} / "
                    f"{c['L_drift_async']:.2e} | {p['stale']} |")
    return "\n".join(rows)


def report(result, out_dir):
    """Energy plots, the VTK series of each async run (point data ``dt_level``), and ``sync_vs_async.md``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for key in ("balls", "stork2d", "stork3d"):
        paths.append(_energy_plot(result, key, out / f"energy_{key}.png"))
        paths.append(write_series(out / "vtk" / key, result[key]["frames"]))
    sc = result["schedule"]
    ol = ", ".join(f"{r['backend']}: bitwise {r['bitwise']}, max rel. diff {r['max_rel']:.1e}" for r in result["one_level"])
    text = (f"# Sync vs async (backend {result['backend']}; the one-level part on numpy and numba)\n\n"
            f"One level: {ol}.\n\nFree fall: max relative error of v_com {result['free_fall']['max_rel']:.2e} on "
            f"levels {result['free_fall']['levels']}.\n\nSchedule: worked example reproduced: {sc['matches']}; census "
            f"over {sc['census_ticks']} ticks ({sc['census_intervals']} synchronised intervals, levels "
            f"{sc['census_levels']}): {sc['lost']} lost, {sc['duplicated']} duplicated.\n\n"
            f"## Paired runs\n\nSync runs at the finest async step. 'updates' count every particle a substep "
            f"moves, ghosts included (own: the particles' own steps). Wall times include compilation on a "
            f"first run and are from this machine, not a benchmark (see `mpmref bench --only async`).\n\n"
            f"{table(result)}\n\n" + "\n".join(f"![{k}](energy_{k}.png)" for k in ("balls", "stork2d", "stork3d"))
            + "\n\n## Findings\n\n" + "\n".join(f"- {f.name}: {f.value:.3g}. {f.sentence}" for f in findings(result))
            + f"\n\n## Checks\n\n{checks_table(checks(result))}\n")
    write_text_atomic(out / "sync_vs_async.md", text)
    return paths + [out / "sync_vs_async.md"]
