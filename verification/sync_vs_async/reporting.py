"""The checks, findings, figures and tables of the sync-vs-async case (:mod:`verification.sync_vs_async`), from the
result of its :func:`~verification.sync_vs_async.run`.
"""

from pathlib import Path

from ..framework.common import Check, Finding
from ..framework.page import Checks, Figure, Heading, Items, Page, Table, Text, write_page
from ..framework.report import pyplot, save_figure, write_series
from .sweeps import fitted_slope

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
    out.append(Check("free fall: levels in use", len(ff["levels"]), ">=", 2,
                     "the two bodies must be on different levels"))
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
                           f"step, for steps {steps} ticks: {', '.join(f'{e:.3g}' for e in errors)} "
                           "of the impact speed."))
    own = [r["sync_vs_sync4"] for r in series if "sync_vs_sync4" in r]
    out += [] if not own else [Finding("balls: sync itself, |v(dt) - v(dt/4)| at the largest step", own[0],
                       "synchronous MPM on contact does not converge as the step shrinks (its transfers dissipate per "
                       "step): sync against sync at a 4x finer step, for the same steps: "
                       f"{', '.join(f'{e:.3g}' for e in own)}. "
                       "No rate for async against it can be derived, so these are findings.")]
    s2 = result[f"stork2d/{result['params'].interfaces[0]}"]
    out.append(Finding("stork2d: sync updates / async updates, ghosts included",
                       s2["updates_sync"] / s2["updates_async"],
                       f"ghost updates cost {s2['updates_async'] - s2['own_updates']} of {s2['updates_async']}; "
                       "counting only the particles' own steps the saving is "
                       f"{s2['updates_sync'] / s2['own_updates']:.2f}x."))
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
    """The table of the paired runs: work, wall time and the differences between the synchronous and the
    asynchronous run."""
    header = ("scene", "interface", "particles", "levels (log2 ticks)", "updates sync", "updates async (own)", "saved",
              "wall sync [s]", "wall async [s]", "energy diff", "position diff [Δx]", "P drift sync / async",
              "L drift sync / async", "stale shadows")
    rows = []
    for key, itf, p in _pairs(result):
        c = p["compare"]
        rows.append((key, itf, p["n"], p["levels"], p["updates_sync"], f"{p['updates_async']} ({p['own_updates']})",
                     f"{p['updates_sync'] / p['updates_async']:.2f}x", f"{p['wall_sync']:.2f}",
                     f"{p['wall_async']:.2f}", f"{c['energy_rel']:.2e}", f"{p['position_dx']:.3f}",
                     f"{c['P_drift_sync']:.2e} / {c['P_drift_async']:.2e}",
                     f"{c['L_drift_sync']:.2e} / {c['L_drift_async']:.2e}", p["stale"]))
    return Table(header, tuple(rows))


def bonded_table(result):
    """The table of the bonded bodies: per CFL number, the largest energy difference per interface."""
    itfs = result["params"].bonded_interfaces
    return Table(("CFL", *itfs), tuple((r["cfl"], *(f"{r[i]:.2e}" for i in itfs)) for r in result["bonded"]))


def series_table(result):
    """The table of the balls over shrinking steps: per CFL number, the velocity differences per interface."""
    itfs = result["params"].series_interfaces
    return Table(("CFL", "finest step [ticks]", *itfs, "sync vs sync/4"), tuple(
        (r["cfl"], r["finest_ticks"],
         *(f"{r[i]['sync']:.3g} / {r[i].get('sync/4', float('nan')):.3g}" for i in itfs),
         f"{r.get('sync_vs_sync4', float('nan')):.3g}") for r in result["series"]))


def trade_table(result):
    """The table of error against wall time, with the runs on the Pareto front."""
    return Table(("run", "wall [s]", "error [Δx]", "Pareto"), tuple(
        (r["label"], f"{r['wall']:.3f}", f"{r['error_dx']:.3g}", "yes" if r["pareto"] else "")
        for r in result["trade"]))


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
    ol = ", ".join(f"{r['backend']}: bitwise {r['bitwise']}, max rel. diff {r['max_rel']:.1e}"
                   for r in result["one_level"])
    iso = "; ".join(f"{itf}: linear {r['P']:.2e}, angular {r['L']:.2e} (levels {r['levels']})"
                    for itf, r in result["isolated"].items())
    page = Page(f"Sync vs async (backend {result['backend']}; the one-level part on numpy and numba)", [
        Text(f"One level: {ol}."),
        Text(f"Free fall: max relative error of v_com {result['free_fall']['max_rel']:.2e} on "
             f"levels {result['free_fall']['levels']}."),
        Text(f"Schedule: worked example reproduced: {sc['matches']}; census over {sc['census_ticks']} ticks "
             f"({sc['census_intervals']} synchronised intervals, levels {sc['census_levels']}): {sc['lost']} lost, "
             f"{sc['duplicated']} duplicated."),
        Text(f"Isolated pressed disks, momentum drift relative to its scale: {iso}."),
        Heading("Paired runs"),
        Text("Sync runs at the finest async step. 'updates' count every particle a substep moves, ghosts included "
             "(own: the particles' own steps). Wall times include compilation on a first run and are from this "
             "machine, not a benchmark (see `mpmref bench --only async`)."),
        table(result), *(Figure(f"energy_{k}.png", k) for k in PAIRS),
        Heading("Bonded bodies at every CFL number (stork2d, max |E_async - E_sync| / E_0)"), bonded_table(result),
        Heading("Balls over shrinking steps (end velocity difference / impact speed: vs sync at the same step / "
                "vs sync at a 4x finer step)"), series_table(result),
        Heading("Error against wall time (stork2d)"), trade_table(result), Figure("trade.png", "trade"),
        Heading("Findings"), Items(tuple(f"{f.name}: {f.value:.3g}. {f.sentence}" for f in findings(result))),
        Heading("Checks"), Checks(checks(result))])
    return paths + [write_page(page, out / "sync_vs_async.md")]
