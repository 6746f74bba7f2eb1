"""Asynchronous against synchronous stepping on the stiff/soft stork and the snow slope (the talk's Part IV claims,
~3.3x on the stork, 9.8x on the slope).

Each case runs an example scene asynchronously (with its declared level interfaces, conservative by
default), then synchronously at the finest step the asynchronous run took, on the same backend and thread
count, to the same end time; then asynchronously once more with ``time.interface = "reference"``, for the
cost of the conservative treatment (stage time per level update that has ghosts, one against the other). Reported:
particle updates (ghosts included, and the particles' own steps), median wall time of ``repeats`` runs of each
(the stepping only: set-up and the run's start and end diagnostics are not timed, nor compilation: one short
warm-up run of each first; the runs in rounds, every configuration once per round, :func:`in_rounds`), their
ratios, and the agreement at the end — total energy relative to the initial
energy, and the largest position difference (particles matched by id) in Δx.

Two more runs make the comparison fair (docs/async.md, "Cost: where the time goes"): synchronous stepping at
its own CFL step (``time.cfl`` as the asynchronous run's, no fixed step), which is what a user would run
instead; and the **one-level control**, the asynchronous stepper with ``time.levels`` capped at the finest step
taken, so that every block steps at it: no level saves anything, and its wall time over synchronous stepping at
that step is the asynchronous machinery's own cost. The ratios are those of regional time stepping's accounting:
the ideal ratio (the particles' own steps, no ghosts), the work ratio (ghosts included) and the wall ratio, with
the two efficiencies between them, work over ideal (what the ghosts cost) and wall over work (what the
implementation costs). What the bookkeeping visited, per level update and per tick, comes from the stepper's
counts (:class:`mpmref.steppers.asynchronous.WorkRecord`, :data:`~mpmref.steppers.asynchronous.COUNTS`), and what
a level update costs, in the step's stages and in the bookkeeping around them (µs per update), from its times.

With ``full`` (``mpmref bench --full``) the stork series goes on to larger grids (:data:`SERIES_CASES`: 2D up to
205 000 particles, 3D up to 127 000), far enough to show where the wall ratio meets the work ratio; long, so not
a test. :func:`plot_async` draws the series (``--plot``).
"""

import numpy as np

from ..run.simulation import Simulation
from ..scene.factories import example_with_time
from .timing import set_threads

#: case -> (example, cells along the first axis, simulated time of a timed run: full, quick). The 2D stork
#: is also run at 2x and 4x the example's resolution (4x and 16x the particles), the 3D one at 4x: a series over
#: particle count that shows where the particles' work, not the per-update orchestration, dominates a step and
#: async starts to pay. The snow slope is the talk's second scene (examples/snow_slope2d.toml), also at 256 cells
#: (43 031 particles, beside the 2D stork at 256).
ASYNC_CASES = {"stork2d": ("stork2d", 64, 0.02, 0.002), "stork2d-128": ("stork2d", 128, 0.008, 0.001),
               "stork2d-256": ("stork2d", 256, 0.004, 0.0005),
               "stork3d": ("stork3d", 32, 0.01, 0.001), "stork3d-128": ("stork3d", 128, 0.025, 0.002),
               "snow_slope2d": ("snow_slope2d", 128, 0.1, 0.01), "snow_slope2d-256": ("snow_slope2d", 256, 0.05, 0.005)}
#: the series' larger storks, run with ``full``: 108 000 and 205 000 particles in 2D, 4 700 and 127 000 in 3D
SERIES_CASES = {"stork2d-384": ("stork2d", 384, 0.002, 0.0005), "stork2d-528": ("stork2d", 528, 0.001, 0.0002),
                "stork3d-64": ("stork3d", 64, 0.02, 0.002), "stork3d-192": ("stork3d", 192, 0.004, 0.0005)}


def ghost_us(stepper):
    """Microseconds in the step's stages per level update that had ghosts."""
    return 1e6 * stepper.work.ghost_stage_seconds / max(stepper.work.ghost_level_updates, 1)


def stepping(scene, backend):
    """Run ``scene`` to its end; ``(wall time of the stepping alone, the simulation)`` (the run summary's
    ``wall_s``: neither the set-up nor the start and end diagnostics)."""
    sim = Simulation(scene, backend=backend)
    return sim.run()["wall_s"], sim


def timing(first_s, times):
    """A timing record: the warm-up run's wall time (``first_call_s``, compilation included), the timed runs'
    (``times_s``, in order) and their median (``median_s``)."""
    return {"first_call_s": first_s, "times_s": times, "median_s": float(np.median(times))}


def in_rounds(first, makers, t_end, backend, repeats):
    """The runs of a case, timed in rounds. ``first`` (a ``make_scene(t_end)``: the asynchronous run) is warmed up (a
    run to ``t_end / 10``: compilation) and run once; ``makers(sim)``, given that run's simulation, gives the other
    configurations (``{name: make_scene}``, which may depend on it: the finest step it took), each warmed up in turn.
    Then ``repeats`` rounds run every configuration once each, ``first`` included (its run above is the first
    round's), so that a change of the machine's load during the case weighs on every configuration alike rather
    than on the one that ran then. Returns ``{name: (timing record, the last run's simulation)}``, ``first`` as
    ``"first"``."""
    warm = {"first": stepping(first(t_end / 10), backend)[0]}
    wall, sim = stepping(first(t_end), backend)
    times, last = {"first": [wall]}, {"first": sim}
    makers = {"first": first, **makers(sim)}
    for name, make in makers.items():
        if name != "first":
            warm[name], times[name] = stepping(make(t_end / 10), backend)[0], []
    for k in range(repeats):
        for name, make in makers.items():
            if k > 0 or name != "first":  # the first round's "first" ran above
                wall, last[name] = stepping(make(t_end), backend)
                times[name].append(wall)
    return {name: (timing(warm[name], times[name]), last[name]) for name in makers}


def time_case(case, t_end, backend, threads, repeats):
    """One case: the runs timed, updates counted, end states compared (a dict; the module docstring)."""
    name, cells = {**ASYNC_CASES, **SERIES_CASES}[case][:2]
    set_threads(backend, threads)

    def scene(**kwargs):
        return lambda t: example_with_time(name, t, cells=cells, **kwargs)

    def others(a):
        finest = a.stepper.summary(a.state)["finest_dt_ticks"]
        # sync at the finest async step, at its own CFL step, and the one-level control (every block at the finest
        # step: the machinery alone)
        return {"sync": scene(dt=finest * a_scene.time.tick), "sync_cfl": scene(cfl_sync=True),
                "one_level": scene(levels=finest.bit_length() - 1)}

    a_scene = example_with_time(name, t_end, cells=cells)
    runs = in_rounds(scene(), others, t_end, backend, repeats)
    (rec_a, a), (rec_s, s), (rec_c, c), (rec_o, o) = (runs[k] for k in ("first", "sync", "sync_cfl", "one_level"))
    rec_r, r = in_rounds(scene(interface="reference"), lambda _: {}, t_end, backend, 1)["first"]
    summary = a.stepper.summary(a.state)
    record = a.stepper.work
    stages_s, n_updates = record.stage_seconds, record.level_updates
    dt = summary["finest_dt_ticks"] * a_scene.time.tick
    s_scene = example_with_time(name, t_end, dt=dt, cells=cells)
    e_a, e_s = a.diagnostics()["total_energy"], s.diagnostics()["total_energy"]
    e0 = Simulation(s_scene).diagnostics()["total_energy"]
    xa, xs = a.x[np.argsort(a.id)], s.x[np.argsort(s.id)]
    sync_updates = s.n_particles * s.step_count
    ideal, work, wall = (sync_updates / summary["own_updates"], sync_updates / summary["particle_updates"],
                         rec_s["median_s"] / rec_a["median_s"])
    return {"case": case, "backend": backend, "threads": threads, "particles": a.n_particles, "t_end": t_end,
            "levels": sorted(set(a.particles.level.tolist())), "sync_dt": dt,
            "async": {**rec_a, "updates": summary["particle_updates"], "own_updates": summary["own_updates"],
                      "level_updates": n_updates, "stages_s": stages_s, "stepping_s": record.seconds,
                      "stages_us_per_update": 1e6 * stages_s / max(n_updates, 1),
                      "bookkeeping_us_per_update": 1e6 * (record.seconds - stages_s) / max(n_updates, 1),
                      "interface": a_scene.time.interface,
                      "ghost_stages_us_per_update": ghost_us(a.stepper),
                      "counts": {k: int(v) for k, v in record.counts.items()}},
            "reference_interface": {**rec_r, "ghost_stages_us_per_update": ghost_us(r.stepper)},
            "interface_cost_ratio": ghost_us(a.stepper) / max(ghost_us(r.stepper), 1e-300),
            "sync": {**rec_s, "updates": sync_updates},
            "sync_cfl": {**rec_c, "steps": c.step_count, "updates": c.n_particles * c.step_count},
            "one_level": {**rec_o, "levels": sorted(set(o.particles.level.tolist())),
                          "updates": o.stepper.summary(o.state)["particle_updates"],
                          "bookkeeping_us_per_update": 1e6 * (o.stepper.work.seconds - o.stepper.work.stage_seconds)
                          / max(o.stepper.work.level_updates, 1)},
            "updates_ratio": work, "own_updates_ratio": ideal, "wall_ratio": wall,
            "ghost_efficiency": work / ideal, "implementation_efficiency": wall / work,
            "cfl_wall_ratio": rec_c["median_s"] / rec_a["median_s"],
            "one_level_overhead": rec_o["median_s"] / rec_s["median_s"],
            "energy_difference": abs(e_a - e_s) / abs(e0),
            "position_difference_dx": float(np.max(np.linalg.norm(xa - xs, axis=1))) / a_scene.grid.dx}


def run_async(quick, backends, threads, repeats, log=print, full=False):
    """The ``async`` section: every case of :data:`ASYNC_CASES` (and with ``full`` of :data:`SERIES_CASES`) on every
    backend at the largest thread count."""
    cases = {**ASYNC_CASES, **(SERIES_CASES if full else {})}
    results = []
    for case, (_, _, t_full, t_quick) in cases.items():
        for backend in backends:
            k = 1 if backend == "numpy" else max(threads)
            log(f"async: {case} {backend} ({k} thread{'s' if k > 1 else ''})")
            results.append(time_case(case, t_quick if quick else t_full, backend, k, repeats))
    return {"results": results}


def render_async(section):
    """Two tables: per case, updates and wall time of both runs, their ratios, the agreement, and what one level
    update of the asynchronous run cost (in the step's stages, and in the bookkeeping around them); then the
    accounting (ideal, work and wall ratios, the efficiencies between them, sync at its CFL step, the one-level
    control with its bookkeeping per update) and what the bookkeeping visited; then each stork's series."""
    lines = ["Async vs sync at the finest async step; updates include ghosts (own steps in brackets); per level "
             "update: us in the step's stages / us of bookkeeping; 'itf x': stage time per update with ghosts, "
             "conservative over reference interfaces; wall times of the stepping alone",
             f"{'case':17}{'backend':8}{'levels':>13}{'sync upd':>11}{'async upd':>20}{'upd x':>7}"
             f"{'sync s':>9}{'async s':>9}{'wall x':>8}{'dE/E0':>10}{'dx':>8}{'updates':>9}{'us/update':>15}"
             f"{'itf x':>7}"]
    for r in section["results"]:
        a = r["async"]
        lines.append(f"{r['case']:17}{r['backend']:8}{str(r['levels']):>13}{r['sync']['updates']:>11}"
                     f"{a['updates']:>11} ({a['own_updates']:>7}){r['updates_ratio']:>6.2f}x"
                     f"{r['sync']['median_s']:>9.3f}{a['median_s']:>9.3f}{r['wall_ratio']:>7.2f}x"
                     f"{r['energy_difference']:>10.2e}{r['position_difference_dx']:>8.3f}{a['level_updates']:>9}"
                     f"{a['stages_us_per_update']:>8.0f} / {a['bookkeeping_us_per_update']:<5.0f}"
                     f"{r['interface_cost_ratio']:>6.2f}x")
    lines += ["",
              "Accounting: ideal x = sync updates / own steps, work x = with ghosts, wall x = sync at the finest step "
              "/ async; work/ideal (ghosts) and wall/work (implementation); 'cfl x': sync at its own CFL step / async; "
              "'1-level': the async stepper on one level / sync at that step (its own cost), and its bookkeeping in "
              "us per update; bookkeeping visits per level update (ghost candidates, ghost-zone nodes) and per tick "
              "(due blocks)",
              f"{'case':17}{'backend':8}{'ideal x':>9}{'work x':>8}{'wall x':>8}{'work/id':>9}{'wall/wk':>9}"
              f"{'cfl x':>8}{'1-level':>9}{'us/upd':>8}{'cand/upd':>10}{'zone/upd':>10}{'blocks/tick':>13}"]
    for r in section["results"]:
        counts, n = r["async"]["counts"], max(r["async"]["level_updates"], 1)
        lines.append(f"{r['case']:17}{r['backend']:8}{r['own_updates_ratio']:>8.2f}x{r['updates_ratio']:>7.2f}x"
                     f"{r['wall_ratio']:>7.2f}x{r['ghost_efficiency']:>9.2f}{r['implementation_efficiency']:>9.2f}"
                     f"{r['cfl_wall_ratio']:>7.2f}x{r['one_level_overhead']:>8.2f}x"
                     f"{r['one_level'].get('bookkeeping_us_per_update', float('nan')):>8.0f}"
                     f"{counts['ghost_candidates'] / n:>10.0f}{counts['zone_nodes'] / n:>10.0f}"
                     f"{counts['due_blocks'] / max(counts['ticks'], 1):>13.0f}")
    lines += ["", "Over particle count (the series of each stork): wall x (work x), and where async starts to pay "
              "(wall x >= 1)"]
    for (dim, backend), rows in stork_series(section).items():
        pays = next((f"from {r['particles']:,} particles" for r in rows if r["wall_ratio"] >= 1.0),
                    "not in this series")
        points = ", ".join(f"{r['particles']:,}: {r['wall_ratio']:.2f}x ({r['updates_ratio']:.2f}x)" for r in rows)
        lines.append(f"  stork {dim}D {backend}: {points}; pays {pays}")
    return "\n".join(lines)


def stork_series(section):
    """The stork results of ``section`` by ``(dimension, backend)``, each in order of particle count."""
    series = {}
    for r in section["results"]:
        if r["case"].startswith("stork"):
            series.setdefault((int(r["case"][5]), r["backend"]), []).append(r)
    return {key: sorted(rows, key=lambda r: r["particles"]) for key, rows in sorted(series.items())}


def plot_async(section, path):
    """Write the stork series as a PNG: per dimension, the ideal, work and wall ratios (and sync at its own CFL step
    over async) against the particle count, with the one-level control; where the wall ratio meets the work ratio,
    the implementation costs nothing more than its particles' work."""
    import matplotlib
    import matplotlib.ticker

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    series = stork_series(section)
    dims = sorted({dim for dim, _ in series})
    fig, axes = plt.subplots(1, max(len(dims), 1), figsize=(5.5 * max(len(dims), 1), 4), squeeze=False)
    for ax, dim in zip(axes[0], dims):
        for (d, backend), rows in series.items():
            if d != dim:
                continue
            n = [r["particles"] for r in rows]
            for key, label, style in (("own_updates_ratio", "ideal (own steps)", "k--"),
                                      ("updates_ratio", "work (ghosts included)", "b-s"),
                                      ("wall_ratio", "wall: sync at the finest step / async", "r-o"),
                                      ("cfl_wall_ratio", "wall: sync at its CFL step / async", "m-^")):
                ax.semilogx(n, [r[key] for r in rows], style, label=f"{label}, {backend}")
            ax.semilogx(n, [1.0 / r["one_level_overhead"] for r in rows], "g:x", label=f"sync / one-level, {backend}")
        ax.axhline(1.0, color="grey", lw=0.8)
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())  # decades only: the minor labels collide
        ax.set_xlabel("particles")
        ax.set_ylabel("ratio (higher: async cheaper)")
        ax.set_title(f"stork {dim}D, {rows[0]['threads']} thread(s)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_snow_slope(path, backend="numba", times=(0.01, 0.1, 0.2, 0.3)):
    """Write the snow slope (examples/snow_slope2d.toml) run asynchronously as a PNG: the particles at ``times``,
    coloured by their level (log2 of their last step in ticks), turned from the slope's frame to the world's (the
    slope 30 degrees down to the right); each panel says the update and own-update ratios so far."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..scene.builder import Scene
    from ..scene.factories import EXAMPLES

    sim = Simulation(Scene.from_toml(EXAMPLES / "snow_slope2d.toml"), backend=backend)
    angle = np.radians(-30.0)
    turn = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    levels = range(sim.scene.time.levels + 1)
    fig, axes = plt.subplots(1, len(times), figsize=(3.0 * len(times) + 1.0, 2.4), squeeze=False,
                             layout="constrained")
    for ax, t in zip(axes[0], times):
        if t > sim.time:
            sim.run(t_end=t)
        x = sim.x @ turn.T
        shown = ax.scatter(x[:, 0], x[:, 1], c=sim.particles.level, s=0.4, cmap="viridis", vmin=min(levels),
                           vmax=max(levels))
        slope = np.array([[0.0, 0.1], [1.0, 0.1]]) @ turn.T
        ax.plot(slope[:, 0], slope[:, 1], "k-", lw=1)
        summary = sim.stepper.summary(sim.state) if sim.step_count else None
        ratios = "" if summary is None else (f"\nupdates {summary['update_ratio']:.2f}x fewer "
                                             f"(own steps {summary['own_update_ratio']:.2f}x)")
        ax.set_title(f"t = {sim.time:.2f} s{ratios}", fontsize=8)
        ax.set_aspect("equal")
        ax.set_xticks([])
        ax.set_yticks([])
    fig.colorbar(shown, ax=axes[0].tolist(), label="level (log2 of the step in ticks)", shrink=0.9)
    fig.savefig(path, dpi=110)
    plt.close(fig)
