"""What a study writes: ``results.json``, ``results.csv``, the plots and ``index.html``, every file atomically.

``results.json`` (schema :data:`SCHEMA`) holds the study's settings, every run (``params`` {key: value},
``metrics`` {name: value}, ``exact``, ``error``, ``reused``, the file of its time series and its frames) and
``orders`` (:func:`verification.study.orders.observed_orders`); ``results.csv`` one row per run (parameters, then
metrics, then ``error``). The plots: ``order_<measure>.png`` for each measure with an order (its error against
the resolution on log-log axes, fitted lines, slopes in the legend), ``energy_change.png`` and ``drifts.png``
(every run's time series) and, with the ledger, ``ledger.png``. Each PNG carries its caption
(:func:`verification.framework.report.save_figure`); ``index.html`` is in the style of ``mpmref verify``'s report.

The page shows two figures side by side, each about 600 pixels wide: a figure is at most :data:`WIDTH` inches
wide (its text then reads at about its point size), runs are named by the keys that differ between them
(:func:`run_names`, the keys shared by every run said once), and the runs' tables are split by what they hold
(drifts, the ledger, the user's measures), with headers that wrap, so that they fit the page.
"""

import csv
import datetime
import html
import io
import json
import math
import textwrap
from pathlib import Path

import numpy as np

from mpmref.io.atomic import write_text_atomic
from mpmref.observe.ledger import ASYNC_TERMS

from ..framework.html_report import figure_html, page
from ..framework.report import LEDGER_COLOURS, NO_CAPTION, figure_caption, pyplot, save_figure
from .orders import TWO_POINTS, series_label
from .runs import METRICS, jsonable
from .variations import label

#: schema name of ``results.json``
SCHEMA = "mpmref-study/1"
#: the metrics the runs table of ``index.html`` shows first
SHOWN = ("energy_change", "energy_excursion", "momentum_drift", "angular_momentum_drift", "mass_drift", "steps",
         "final_time", "wall_s", "particle_steps_per_s")
#: the width of a figure (inches, at the report's 110 dpi): about the 600 pixels a figure gets on the page
WIDTH = 6.6
#: the size of a figure's small text (legends, run names), in points
SMALL = 8.5
e = html.escape


def write_report(out, meta, runs, orders):
    """Write every output of a study into ``out``; returns the paths of ``results.json``, ``results.csv`` and
    ``index.html``."""
    out = Path(out)
    figures = plot_orders(out, orders) + plot_series(out, runs) + plot_ledger(out, runs)
    data = results(meta, runs, orders)
    paths = out / "results.json", out / "results.csv", out / "index.html"
    write_text_atomic(paths[0], json.dumps(jsonable(data), indent=1, allow_nan=False) + "\n")
    write_text_atomic(paths[1], table_csv(runs))
    write_text_atomic(paths[2], index_html(meta, runs, orders, figures, out))
    return paths


def results(meta, runs, orders):
    """The machine-readable study (schema :data:`SCHEMA`)."""
    fields = ("id", "params", "metrics", "exact", "error", "reused", "result", "frames")
    return {"schema": SCHEMA, "created_utc": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
            **meta, "runs": [{k: r.get(k) for k in fields} for r in runs], "orders": orders}


def table_csv(runs):
    """``results.csv``: a row per run, its parameters, then its metrics (the union over the runs), then ``error``."""
    params = list(dict.fromkeys(k for r in runs for k in r["params"]))
    metrics = list(dict.fromkeys(k for r in runs for k in r.get("metrics", {})))
    buffer = io.StringIO()
    writer = csv.writer(buffer)
    writer.writerow(["id", *params, *metrics, "error"])
    for r in runs:
        error = r["error"].strip().splitlines()[-1] if r.get("error") else ""
        writer.writerow([r["id"], *(r["params"].get(k, "") for k in params),
                         *(r.get("metrics", {}).get(k, "") for k in metrics), error])
    return buffer.getvalue()


# ------------------------------------------------------------------------------------------------ plots
def plot_orders(out, orders):
    """``order_<measure>.png`` per measure with a fitted order: a panel per resolution key, a fitted line per
    refinement series (the orders table says why a measure has none)."""
    paths = []
    for measure in dict.fromkeys(row["measure"] for row in orders if math.isfinite(row["order"])):
        mine = [row for row in orders if row["measure"] == measure]
        keys = list(dict.fromkeys(row["key"] for row in mine))
        plt = pyplot()
        fig, axes = plt.subplots(len(keys), 1, figsize=(WIDTH, 4.6 * len(keys)), squeeze=False)
        for ax, key in zip(axes[:, 0], keys):
            for i, row in enumerate(r for r in mine if r["key"] == key):
                _order_panel(ax, row, f"C{i}")
            ax.set_xlabel(f"{next(r['abscissa'] for r in mine if r['key'] == key)} ({key})")
            ax.grid(True, which="both", alpha=0.3)
            if ax.get_legend_handles_labels()[0]:
                ax.legend(fontsize=SMALL, loc="best", framealpha=0.6)
            else:
                ax.text(0.5, 0.5, "no error to plot:\nthe measure is the same at every level",
                        transform=ax.transAxes, ha="center", va="center")
        against = {row["against"] for row in mine}
        fig.suptitle(f"{measure}: error against {' / '.join(sorted(against))}")
        fig.tight_layout()
        paths.append(save_figure(fig, out / f"order_{measure}.png", caption=_order_caption(measure, mine)))
    return paths


def _order_panel(ax, row, color):
    h = np.array(row["h"])
    errors = np.array([np.nan if x is None else x for x in row["errors"]], dtype=np.float64)
    shown = np.isfinite(errors) & (errors > 0)
    if not shown.any():
        return
    fitted = math.isfinite(row["order"])
    richardson = f", Richardson {row['richardson']:.2f}" if math.isfinite(row["richardson"]) else ""
    two = " (two points)" if row["fit"] == TWO_POINTS else ""
    text = f"order {row['order']:.2f}{two}{richardson}" if fitted else "no order"
    ax.loglog(h[shown], errors[shown], "o", color=color, label=f"{series_label(row)}: {text}")
    if fitted:
        ax.loglog(h[shown], np.exp(row["intercept"]) * h[shown] ** row["order"], "--", color=color, lw=1)
    ax.set_ylabel("|value − exact|" if row["against"] == "exact" else "|value − value on the finest run|")


def _order_caption(measure, rows):
    fits = "; ".join(f"{series_label(r)}: {r['order']:.2f}{' (' + TWO_POINTS + ')' if r['fit'] == TWO_POINTS else ''}"
                     for r in rows if math.isfinite(r["order"]))
    return (f"Observed order of {measure}: its error against the exact value (where given) or against the finest "
            f"run, on log-log axes against the resolution, with least-squares lines (dashed; fitted slope and "
            f"Richardson's estimate from the three finest levels in the legend; fitted: {fits or 'none'}). Look "
            "for points on a straight line: its slope is the order at which the measure converges, and a line "
            "that bends means the coarse levels are not yet in the asymptotic range. Against the finest run the "
            "fit reads high on few levels (first order reads 1.58 on three levels halving the resolution), so "
            "there trust Richardson's estimate; and two points always lie on a line, so their slope says nothing of "
            "whether the error follows a power of the resolution.")


def plot_series(out, runs):
    """``energy_change.png`` and ``drifts.png``: every finished run's time series."""
    done = [r for r in runs if r.get("series")]
    if not done:
        return []
    names, shared = run_names(done)
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(WIDTH, 4.4))
    for r, name in zip(done, names):
        ax.plot(r["series"]["time"], r["series"]["energy_change"], label=name)
    ax.set_xlabel("time")
    ax.set_ylabel("(E(t) − E(0)) / E(0)")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=SMALL, framealpha=0.6, title=shared, title_fontsize=SMALL)
    energy = save_figure(fig, out / "energy_change.png", caption=(
        "Relative change of the total energy (kinetic, affine, modes, elastic, gravitational) of every run "
        "over time. Look for how the change depends on the varied keys: a dissipative transfer loses energy "
        "steadily, faster on coarse grids, while an instability shows as growth."))
    fig, axes = plt.subplots(2, 1, figsize=(WIDTH, 7.0), sharex=True, layout="constrained")
    for ax, key, what in zip(axes, ("momentum_drift", "angular_momentum_drift"), ("|P(t) − P(0)| / S_P",
                                                                                  "|L(t) − L(0)| / S_L")):
        for r, name in zip(done, names):
            drift = np.array(r["series"][key])
            ax.plot(r["series"]["time"], np.where(drift > 0, drift, np.nan), ".-", label=name)
        ax.set_yscale("log")
        ax.set_ylabel(what)
        ax.grid(True, which="both", alpha=0.3)
    axes[1].set_xlabel("time")
    axes[0].legend(fontsize=SMALL, framealpha=0.6, title=shared, title_fontsize=SMALL)
    drifts = save_figure(fig, out / "drifts.png", caption=(
        "Drift of the linear (top) and angular (bottom) momentum of every run, relative to the sums of the "
        "particles' contributions, on a log scale (a drift of exactly zero is not drawn). Look for round-off "
        "(1e-16 to 1e-13) where a scheme conserves the quantity and nothing external acts; gravity and walls "
        "change momentum, and PIC and FLIP lose angular momentum."))
    return [energy, drifts]


def run_names(runs):
    """``(names, shared)``: each run named by the keys whose values differ between ``runs``, and the keys every run
    shares said once (``None`` when there are none), so that a legend or an axis shows what tells the runs apart."""
    keys = list(dict.fromkeys(k for r in runs for k in r["params"]))
    differ = [k for k in keys if len({repr(r["params"].get(k)) for r in runs}) > 1]
    names = [label({k: r["params"].get(k) for k in differ}) if differ else label(r["params"]) for r in runs]
    same = {k: runs[0]["params"][k] for k in keys if k not in differ}
    return names, (f"every run: {label(same)}" if same and differ else None)


def plot_ledger(out, runs):
    """``ledger.png``: each run's energy ledger at the end, a group of horizontal bars per run (one per term that is
    not zero in every run), on a symmetric log scale, when the runs booked it."""
    done = [r for r in runs if r.get("metrics") and f"ledger_{ASYNC_TERMS[0]}" in r["metrics"]]
    if not done:
        return []
    booked = [t for t in ASYNC_TERMS if all(f"ledger_{t}" in r["metrics"] for r in done)]  # interface: async only
    terms = [t for t in booked if any(r["metrics"][f"ledger_{t}"] for r in done)]
    if not terms:
        return []
    names, shared = run_names(done)
    plt = pyplot()
    height = 0.8 / len(terms)
    fig, ax = plt.subplots(figsize=(WIDTH, 1.8 + 0.17 * len(terms) * len(done) + 0.12 * len(done)),
                           layout="constrained")
    for i, term in enumerate(terms):
        ax.barh(np.arange(len(done)) + (i - len(terms) / 2 + 0.5) * height,
                [r["metrics"][f"ledger_{term}"] for r in done], height, label=term, color=LEDGER_COLOURS[term])
    ax.set_yticks(range(len(done)), names, fontsize=SMALL)
    ax.invert_yaxis()                                                  # the first run on top, as in the tables
    largest = max(abs(r["metrics"][f"ledger_{t}"]) for r in done for t in terms)
    ax.set_xscale("symlog", linthresh=10.0 ** math.floor(math.log10(1e-4 * largest)))
    ax.set_xlabel("energy booked / E(0) (symmetric log scale)")
    ax.axvline(0.0, color="k", lw=0.6)
    ax.grid(True, axis="x", alpha=0.3)
    zero = [t for t in booked if t not in terms]
    notes = [shared, f"zero in every run: {', '.join(zero)}" if zero else None]
    ax.set_title("\n".join(textwrap.fill(n, 60) for n in notes if n), fontsize=SMALL, loc="left")
    fig.legend(loc="outside upper center", ncol=min(len(terms), 4), fontsize=SMALL, framealpha=0.6)
    return [save_figure(fig, out / "ledger.png", caption=(
        "Where the energy went in each run: the energy ledger's terms at the end, relative to the initial energy "
        "(they add up to the run's energy change), a bar per term that is not zero in every run (those are named "
        "above the bars), on a symmetric log scale, linear below a power of ten at most 1e-4 of the largest term. "
        "Look for which stage carries the change: P2G and G2P transfers (dissipation of the transfer scheme), the "
        "boundary (walls and colliders), plasticity, or integration (the time integrator's own error, which falls "
        "with the step)."))]


# ------------------------------------------------------------------------------------------------ html
def index_html(meta, runs, orders, figures, out):
    """``index.html``: the study's settings, the orders, the figures, then every run."""
    failed = [r for r in runs if r.get("error")]
    reused = sum(bool(r.get("reused")) for r in runs)
    ok = not failed
    verdict = (f"<div class='verdict {'pass' if ok else 'fail'}'><strong>{len(runs) - len(failed)} of {len(runs)} "
               f"runs finished</strong> — {reused} reused from an earlier study, {len(failed)} failed; "
               f"{len(orders)} orders measured.</div>")
    settings = "".join(f"<li>{e(k)}: {e(_setting(v))}</li>" for k, v in meta.items()
                       if k not in ("machine", "vary", "same_computation"))
    machine = "".join(f"<li>{e(k)}: {e(str(v))}</li>" for k, v in meta["machine"].items())
    vary = "; ".join(f"<code>{e(':'.join(v['keys']))}</code> = "
                     f"{e(', '.join(':'.join(map(str, level)) for level in v['levels']))}"
                     for v in meta["vary"]) or "nothing (one run of the scene as it is)"
    body = (f"<h1>mpmref study: {e(meta['scene_name'])}</h1>{verdict}"
            f"<p class='meta'>Scene <code>{e(meta['scene'])}</code>; varied: {vary}; to t = {meta['t_end']}. "
            f"Also as <a href='results.json'>results.json</a> and <a href='results.csv'>results.csv</a>.</p>"
            f"<details class='meta'><summary>Settings</summary><ul>{settings}</ul></details>"
            f"<details class='meta'><summary>Machine</summary><ul>{machine}</ul></details>"
            f"{_same_html(meta.get('same_computation', []))}"
            f"{_failures_html(failed)}<h2 id='orders'>Observed orders</h2>{_orders_html(orders)}"
            f"<h2 id='figures'>Figures</h2><div class='figures'>{_figures_html(figures, out)}</div>"
            f"<h2 id='runs'>Runs</h2>{_runs_html(runs)}")
    return page(f"mpmref study: {meta['scene_name']}", body)


def _setting(value):
    """A setting of ``results.json`` as the page shows it: the backend with its class and version, lists joined."""
    if isinstance(value, dict) and "class" in value:
        return f"{value['backend']} ({value['class']}, version {value['version'] or 'not given'})"
    if isinstance(value, list):
        return ", ".join(map(str, value)) or "none"
    return "none" if value is None else str(value)


def _same_html(messages):
    """The warning that varied values make the same computation (their runs' numbers are equal)."""
    if not messages:
        return ""
    items = "".join(f"<li>{e(m)}</li>" for m in messages)
    return f"<div class='verdict fail'><strong>The same computation, run more than once</strong><ul>{items}</ul></div>"


def _failures_html(failed):
    if not failed:
        return ""
    items = "".join(f"<li><code>{e(label(r['params']))}</code>: <code>{e(r['error'].strip().splitlines()[-1])}"
                    f"</code></li>" for r in failed)
    return (f"<h2 id='failures'>Failed runs</h2><ul>{items}</ul><p class='meta'>Their tracebacks are in "
            "results.json; the other runs are kept, and the same command runs only these again.</p>")


def _number(x):
    return "—" if x is None or (isinstance(x, float) and math.isnan(x)) else (f"{x:.4g}" if isinstance(x, float)
                                                                              else str(x))


def _orders_html(orders):
    if not orders:
        return ("<p>(none: no resolution was varied, or no refinement series has two levels. Vary grid.cells, "
                "time.dt, time.cfl or bodies[i].ppc over three or more values to measure orders.)</p>")
    head = ("<tr><th>measure</th><th>refined</th><th>series</th><th>against</th><th>levels</th>"
            "<th>fitted order</th><th>Richardson</th><th>extrapolated</th><th>note</th></tr>")
    rows = "".join(f"<tr><td>{e(r['measure'])}</td><td>{e(r['key'])} ({e(r['abscissa'])})</td>"
                   f"<td>{e(series_label(r))}</td><td>{e(r['against'])}</td><td class='num'>{len(r['h'])}</td>"
                   f"<td class='num'>{_fitted_html(r)}</td><td class='num'>{_number(r['richardson'])}</td>"
                   f"<td class='num'>{_number(r['extrapolated'])}</td><td>{e(r['note'])}</td></tr>" for r in orders)
    return f"<table>{head}{rows}</table>"


def _fitted_html(row):
    """The fitted order's cell: the order and, under it, what it is the slope of (the line through two points, or
    the least-squares line through more)."""
    if not math.isfinite(row["order"]):
        return _number(row["order"])
    return f"{_number(row['order'])}<br><small>{e(row['fit'])}</small>"


def _figures_html(figures, out):
    return "".join(figure_html(p.name, figure_caption(Path(out) / p.name) or NO_CAPTION) for p in figures)


#: a heading between two tables: space above it
SPACED = "style='margin-top:1.2em'"


def _runs_html(runs):
    """The runs' tables, each with the runs' parameters first: the drifts, steps and timings; the energy ledger at
    the end; the user's measures. Split so that each fits the page."""
    names = list(dict.fromkeys(k for r in runs for k in r.get("metrics", {})))
    ledger = [m for m in names if m.startswith("ledger_")]
    parts = [_runs_table(runs, [m for m in SHOWN if m in names], files=True)]
    if ledger:
        parts.append(f"<h3 {SPACED}>The energy ledger at the end, over E(0)</h3>" + _runs_table(runs, ledger))
    measures = [m for m in names if m not in METRICS and m not in ledger]
    if measures:
        parts.append(f"<h3 {SPACED}>Your measures</h3>" + _runs_table(runs, measures))
    return "".join(parts)


def _runs_table(runs, metrics, files=False):
    """A table of the runs: their parameters, then ``metrics`` (headers wrap at underscores), then their files."""
    params = list(dict.fromkeys(k for r in runs for k in r["params"]))
    head = "".join(f"<th>{_wrappable(k)}</th>" for k in params + metrics) + ("<th>files</th>" if files else "")
    rows = []
    for r in runs:
        cells = "".join(f"<td class='num'>{e(_number(r['params'].get(k)))}</td>" for k in params)
        cells += "".join(f"<td class='num'>{e(_number(r.get('metrics', {}).get(m)))}</td>" for m in metrics)
        if files:
            cells += f"<td>{_files_html(r)}</td>"
        rows.append(f"<tr class='{'fail' if r.get('error') else ''}'>{cells}</tr>")
    return f"<div style='overflow-x:auto'><table><tr>{head}</tr>{''.join(rows)}</table></div>"


def _files_html(run):
    files = f"<a href='{e(run['result'])}'>result</a>" if run.get("metrics") else "failed"
    if run.get("frames"):
        files += f", <a href='{e(run['frames'])}/particles.pvd'>frames</a>"
    return files


def _wrappable(name):
    """A column name that may break after its underscores (``angular_<wbr>momentum_<wbr>drift``)."""
    return "<wbr>".join(e(part) for part in name.replace("_", "_\0").split("\0"))
