"""Report writing shared by every case and by ``mpmref verify``.

Cases use :func:`snapshot`, :func:`write_series` and :func:`save_figure` to write the VTK series of their
representative runs and their PNG plots (the energy ledger's stacked areas with :func:`plot_ledger_areas`) (each PNG
carries its caption, the sentence that says what to look for, in its ``Description`` text chunk:
:func:`figure_caption`). ``mpmref verify`` turns each case's :class:`~verification.framework.registry.Outcome` into a
:class:`CaseRecord` (:func:`case_record`: the backends it ran, its findings, its figures, the one that carries its main
claim) and writes the per-case ``report.md`` (:func:`case_page`) and ``index.html`` (:func:`write_case_report`) and the
top-level ``report.md`` (:func:`index_page`), ``index.html`` and ``results.json`` (:func:`write_index`). The Markdown
pages are :class:`~verification.framework.page.Page` objects, rendered as the cases' own pages are. Every file is
written atomically (:mod:`mpmref.io.atomic`).
"""

import datetime
import json
import math
import os
import platform
import sys
import traceback
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from mpmref.io.atomic import atomic_path, write_text_atomic
from mpmref.io.vtk import write_particles_vtu, write_pvd

from . import html_report, registry
from .common import backend_sentence, cell, check_header, failed, summary_sentence, verdict_word
from .page import Checks, Figure, Heading, Items, Page, Table, Text, write_page

#: the outputs (names of ``[output] fields``, :data:`mpmref.scene.parsers.OUTPUT_FIELDS`) that the VTK frames of
#: verification runs record
FRAME_OUTPUTS = ("velocity", "mass", "J", "material")
#: seconds a file's modification time may lag the clock that timed the case's start
MTIME_SLACK = 1.0


# --------------------------------------------------------------------------------- helpers for cases
def snapshot(sim, fields=FRAME_OUTPUTS):
    """The current particles of ``sim`` as one VTK frame ``(time, x, point_data)`` (copies)."""
    return sim.time, sim.x.copy(), {k: v.copy() for k, v in sim.point_data(fields).items()}


def write_series(folder, frames):
    """Write ``frames`` = [(time, x, point_data), ...] as ``particles_NNNN.vtu`` plus ``particles.pvd``."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    entries = []
    for i, (time, x, data) in enumerate(frames):
        name = f"particles_{i:04d}.vtu"
        write_particles_vtu(folder / name, x, data)
        entries.append((float(time), name))
    write_pvd(folder / "particles.pvd", entries)
    return folder / "particles.pvd"


def pyplot():
    """``matplotlib.pyplot`` on the non-interactive Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig, path, caption=None, dpi=110):
    """Save a matplotlib figure as PNG atomically and close it.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        The figure (closed afterwards).
    path : str or Path
        Where the PNG goes.
    caption : str, optional
        What to look for in the figure, in a sentence or two. It is stored in the PNG's ``Description``
        text chunk, so the figure carries it into every report that shows it (:func:`figure_caption`).
    dpi : int
        Resolution.

    Returns
    -------
    Path
        ``path``.
    """
    metadata = {"Description": caption} if caption else None
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=dpi, bbox_inches="tight", metadata=metadata)
    pyplot().close(fig)
    return Path(path)


#: a colour per term of the energy ledger (:data:`mpmref.observe.ledger.ASYNC_TERMS`), the same in every figure
LEDGER_COLOURS = {"p2g_transfer": "tab:blue", "boundary": "tab:brown", "g2p_transfer": "tab:orange",
                  "advection": "tab:purple", "plastic": "tab:red", "rigid_bodies": "tab:gray",
                  "integration": "tab:green", "interface": "tab:olive", "inflow": "tab:cyan", "outflow": "tab:pink"}


def plot_ledger_areas(ax, t, terms, change):
    """A run's cumulative energy ledger as stacked areas against time, on the axes ``ax``.

    At each time the terms that have added energy so far are stacked upwards from zero and those that have taken it
    downwards, each in its colour of :data:`LEDGER_COLOURS`; the black line is ``change``, the change of total energy
    :math:`E(t) - E_0` that the diagnostics measure, which is the sum of all of them (the top edge plus the bottom
    edge). A term that stays zero over the run gets no area.

    Parameters
    ----------
    ax : matplotlib Axes
    t : (n,) array       times
    terms : dict         ``{term: (n,) cumulative joules}`` over :data:`mpmref.observe.ledger.TERMS` (and
                         ``interface``, :data:`mpmref.observe.ledger.ASYNC_TERMS`, for an asynchronous run)
    change : (n,) array  the measured :math:`E(t) - E_0`
    """
    up, down = np.zeros(len(t)), np.zeros(len(t))
    for term, values in terms.items():
        values = np.asarray(values, dtype=float)
        if not np.any(values):
            continue
        gain, loss = np.maximum(values, 0.0), np.minimum(values, 0.0)
        ax.fill_between(t, up, up + gain, color=LEDGER_COLOURS[term], alpha=0.75, lw=0, label=term)
        ax.fill_between(t, down, down + loss, color=LEDGER_COLOURS[term], alpha=0.75, lw=0)
        up, down = up + gain, down + loss
    ax.plot(t, change, "k-", lw=1.2, label="measured E(t) - E0")
    ax.axhline(0.0, color="k", lw=0.5)


def ledger_figure(panels, path, ylabel, caption, cols=3):
    """A figure of :func:`plot_ledger_areas` panels, one per run, with one legend, saved with its ``caption``.

    ``panels`` is a list of ``(title, t, terms, change, dots)``: the arguments of :func:`plot_ledger_areas`, and
    ``dots``, ``None`` or ``(times, values)`` of the change measured another way, drawn as dots.
    """
    plt = pyplot()
    cols = min(cols, len(panels))
    rows = -(-len(panels) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.0 * cols, 3.1 * rows), squeeze=False)
    for ax, (title, t, terms, change, dots) in zip(axes.flat, panels):
        plot_ledger_areas(ax, t, terms, change)
        if dots is not None:
            ax.plot(*dots, "wo", ms=3.5, mec="k", label="diagnostics' E - E0")
        ax.set_title(title, fontsize=8)
        ax.tick_params(labelsize=7)
        ax.locator_params(axis="x", nbins=4)
        ax.grid(True, alpha=0.3)
    for ax in axes.flat[len(panels):]:
        ax.set_visible(False)
    handles = {h.get_label(): h for ax in axes.flat for h in ax.get_legend_handles_labels()[0]}
    fig.supxlabel("time [s]")
    fig.supylabel(ylabel)
    fig.tight_layout()
    fig.legend(handles.values(), handles.keys(), loc="upper center", ncol=5, fontsize=8, bbox_to_anchor=(0.5, 0.0))
    return save_figure(fig, path, caption=caption)


#: what the reports say under a figure saved without a caption
NO_CAPTION = "(The case gives no caption for this figure.)"


def figure_caption(path):
    """The caption stored in a PNG by :func:`save_figure`, or ``None`` when it has none."""
    from PIL import Image

    with Image.open(path) as image:
        return image.text.get("Description") or None


def aspect_ratio(path):
    """Width over height of a PNG."""
    from PIL import Image

    with Image.open(path) as image:
        return image.width / image.height


# ------------------------------------------------------------------------------------------ machine
def machine():
    """What ran the cases, for reports: host, CPU, cores, load average now, OS, Python and NumPy versions
    (and Numba's version, thread count and kernel builds when a case used it: its timings depend on them)."""
    info = {"host": platform.node(), "cpu": _cpu_model(), "cores": os.cpu_count(),
            "load average (1, 5, 15 min)": " / ".join(f"{x:.2f}" for x in os.getloadavg()),
            "os": platform.platform(), "python": sys.version.split()[0], "numpy": np.__version__}
    numba = sys.modules.get("numba")
    if numba is not None:
        from mpmref.backends.numba import twin
        from mpmref.backends.numba.threads import describe_threads

        info.update({"numba": numba.__version__, "numba threads": describe_threads(),
                     "numba kernel builds": twin.mode()})
    return info


def _cpu_model():
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


# ------------------------------------------------------------------------------------ case records
@dataclass
class CaseRecord:
    """What the reports say about one case.

    Attributes
    ----------
    outcome : verification.framework.registry.Outcome
        The case's run: checks, timing, error.
    backends : tuple of str
        The backends the case ran: its ``backends_run(result, backend)`` (by default the backend it was asked
        for; the cases that compare backends name them all); only the one asked for when the case stopped with
        an error.
    findings : tuple of verification.framework.common.Finding
        Its ``findings(result)``: measured behaviour reported, not judged.
    figures : tuple of (Path, str)
        Each PNG written by this run (relative to the case folder) with its caption.
    tables : dict
        Its ``tables(result)``: ``{name: [row dict, ...]}`` for ``results.json`` (none when it stopped with an error).
    main_figure : (Path, str, float) or None
        The figure that carries the case's main claim, its caption and its width over its height: the case's
        ``main_figure`` (a file name in the case folder) where it declares one and wrote it, else its first
        figure; ``None`` when it wrote none.
    """

    outcome: object
    backends: tuple
    findings: tuple
    figures: tuple
    main_figure: tuple = None
    tables: dict = field(default_factory=dict)

    @property
    def name(self):
        return self.outcome.name


def case_record(outcome, case_dir):
    """The :class:`CaseRecord` of ``outcome``; the case's figures are read from ``case_dir``.

    An exception in the case's ``backends_run``, ``findings`` or ``tables`` is kept in ``outcome.error`` (the case
    then counts as stopped with an error), like one in its ``run``.
    """
    case = outcome.case if outcome.case is not None else registry.load(outcome.name)
    backends, findings, tables = (outcome.backend,), (), {}
    if outcome.error is None and outcome.result is not None:
        try:
            backends = tuple(case.backends_run(outcome.result, outcome.backend))
            findings = tuple(case.findings(outcome.result))
            tables = dict(case.tables(outcome.result))
        except Exception:  # reported like an exception in the case's run
            outcome.error = traceback.format_exc()
    pngs, _, _ = _files_by_kind(case_dir, outcome.started)
    figures = tuple((p, figure_caption(Path(case_dir) / p) or NO_CAPTION) for p in pngs)
    main = next((f for f in figures if f[0].as_posix() == case.main_figure), figures[0] if figures else None)
    if main is not None:
        main = (*main, aspect_ratio(Path(case_dir) / main[0]))
    return CaseRecord(outcome, backends, findings, figures, main, tables)


# ------------------------------------------------------------------------------------ case reports
def _files_by_kind(case_dir, since):
    """PNG, PVD and table files under ``case_dir`` written at or after ``since`` (older runs' files are stale)."""
    files = sorted(p.relative_to(case_dir) for p in Path(case_dir).rglob("*")
                   if p.is_file() and p.stat().st_mtime >= since - MTIME_SLACK)
    return ([f for f in files if f.suffix == ".png"], [f for f in files if f.suffix == ".pvd"],
            [f for f in files if f.suffix in (".md", ".csv") and f.name != "report.md"])


def _findings_table(findings, with_case):
    """The table of ``findings`` = ``[(case name, Finding), ...]``, with a case column if asked."""
    head = ("case",) * with_case + ("finding", "figure", "what it shows")
    return Table(head, tuple((case,) * with_case + (f.name, f"{f.value:.6g}", f.sentence) for case, f in findings))


def _links(files):
    """A list of links to ``files`` (paths relative to the page)."""
    return Items(tuple(f"[{f.as_posix()}]({f.as_posix()})" for f in files))


def case_page(record, case_dir):
    """The :class:`~.page.Page` of one case's ``report.md``: set-up, findings, checks, what did not apply, figures,
    VTK series, other files."""
    outcome = record.outcome
    page = Page(outcome.name, [Text(outcome.title), Text(
        f"Preset `{outcome.preset}`, backends run: {', '.join(record.backends)}, wall time {outcome.wall_s:.1f} s, "
        f"verdict **{outcome.verdict}**."), Heading("Parameters")])
    params = asdict(outcome.params).items() if outcome.params is not None else ()
    page.add(Table(("parameter", "value"), tuple((k, v) for k, v in params)))
    if outcome.error is not None:
        page.add(Heading("Error"), *([Text(f"Raised in {outcome.error_line}")] if outcome.error_line else []),
                 Text(f"```text\n{outcome.error.rstrip()}\n```"))
    if record.findings:
        page.add(Heading("Findings (measured, not judged)"),
                 _findings_table([(outcome.name, f) for f in record.findings], with_case=False))
    page.add(Heading("Checks"), Checks(tuple(outcome.checks)) if outcome.checks else Text("(none)"))
    page.add(*_not_applicable_sections(outcome))
    _, series, others = _files_by_kind(case_dir, outcome.started)
    if record.figures:
        page.add(Heading("Figures"))
        for path, caption in record.figures:
            page.add(Figure(path.as_posix(), path.stem), Text(caption))
    if series:
        page.add(Heading("VTK series (open in ParaView)"), _links(series))
    if others:
        page.add(Heading("Tables and details"), _links(others))
    return page


def _not_applicable_sections(outcome):
    """The case's sections on what did not apply to the backend and what was adapted to it (none: no sections)."""
    sections = []
    if outcome.not_applicable:
        sections += [Heading("Not applicable to this backend"),
                     Text("Checks, or runs and the checks they carry, that the backend does not implement "
                          "(never a failure):"),
                     Table(("not applicable", "why"), tuple((item.name, item.why) for item in outcome.not_applicable))]
    if outcome.adapted:
        sections += [Heading("Adapted to this backend"),
                     Text("Runs made on a scene fitted to what the backend implements, within what the claim allows "
                          "(the case's docstring says why each keeps its claim):"),
                     Table(("runs", "what changed"),
                           tuple((", ".join(a.names), " ".join(c.rstrip(".") + "." for c in a.changes))
                                 for a in outcome.adapted))]
    return sections


def write_case_report(record, case_dir):
    """Write ``case_dir/report.md`` and ``case_dir/index.html`` for one case's :class:`CaseRecord`."""
    case_dir = Path(case_dir)
    case_dir.mkdir(parents=True, exist_ok=True)
    path = write_page(case_page(record, case_dir), case_dir / "report.md")
    _, series, others = _files_by_kind(case_dir, record.outcome.started)
    write_text_atomic(case_dir / "index.html", html_report.case_html(record, series, others))
    return path


# -------------------------------------------------------------------------------------------- index
def _check_rows(records):
    for r in records:
        if r.outcome.error is not None:
            yield r.outcome, None
        for c in r.outcome.checks:
            yield r.outcome, c


def _summary(records):
    outcomes = [r.outcome for r in records]
    return {"cases": len(outcomes), "checks": sum(len(o.checks) for o in outcomes),
            "failing": sum(len(failed(o.checks)) for o in outcomes),
            "errors": sum(o.error is not None for o in outcomes),
            "findings": sum(len(r.findings) for r in records),
            "not_applicable": sum(len(o.not_applicable) for o in outcomes),
            "cases_not_applicable": sum(not o.applicable and o.error is None for o in outcomes)}


def _all_backends(records):
    return list(dict.fromkeys(b for r in records for b in r.backends))


def index_page(records, meta):
    """The :class:`~.page.Page` of the top-level ``report.md``: the verdict and the failures, the cases, the findings,
    then every check (the order of ``index.html``)."""
    n = _summary(records)
    page = Page("mpmref verification report", [
        Text(f"**{verdict_word(n)}**: {summary_sentence(n)}."),
        Text(f"Preset `{meta['preset']}`; backends run: {', '.join(_all_backends(records))} (per case below); "
             f"sweeps run in {meta['executor']}; total wall time {meta['wall_s']:.1f} s. {backend_sentence(meta)}"),
        Text("Machine: " + ", ".join(f"{k} {v}" for k, v in meta["machine"].items()) + "."), Heading("Failures")])
    failing = [(o, c) for o, c in _check_rows(records) if c is None or not c.passed]
    page.add(_case_checks(failing) if failing else Text("None: every check of every case passes."))
    page.add(Heading("Cases"), Table(("case (its report)", "backends", "checks", "verdict", "wall time [s]"), tuple(
        (f"[{r.name}]({r.name}/report.md)", ", ".join(r.backends), len(r.outcome.checks), r.outcome.verdict,
         f"{r.outcome.wall_s:.1f}") for r in records)))
    page.add(*_index_not_applicable(records), Heading("Findings (measured, not judged)"))
    findings = [(r.name, f) for r in records for f in r.findings]
    page.add(_findings_table(findings, with_case=True) if findings else Text("(none in these cases)"))
    return page.add(Heading("Every check"), _case_checks(list(_check_rows(records))))


def _case_checks(rows):
    """The checks table with a case column of ``rows`` = ``[(outcome, check or None), ...]``; ``None``: the case
    stopped with an error."""
    return Text("\n".join(check_header(True) + [_error_row(o) if c is None else c.line(o.name) for o, c in rows]))


def _index_not_applicable(records):
    """The index's section on what was not applicable, case by case (nothing when everything applied)."""
    items = [(r.name, item) for r in records for item in r.outcome.not_applicable]
    if not items:
        return []
    return [Heading("Not applicable to this backend"),
            Table(("case", "not applicable", "why"), tuple((case, item.name, item.why) for case, item in items))]


def _error_row(outcome):
    where = f"{outcome.error_line}; " if outcome.error_line else ""
    return (f"| {outcome.name} | (the case stopped with an error) | — | — | FAIL | {cell(where)}see "
            f"{outcome.name}/report.md |")


def index_html(records, meta):
    """``index.html`` (:func:`verification.framework.html_report.index_html`)."""
    return html_report.index_html(records, meta, _summary(records), _all_backends(records))


# ------------------------------------------------------------------------------------- results.json
#: schema name of ``results.json``
SCHEMA = "mpmref-verify/1"


def json_number(x):
    """A float for JSON: itself when finite, else ``"nan"``, ``"inf"`` or ``"-inf"`` (JSON has no such numbers)."""
    x = float(x)
    return x if math.isfinite(x) else str(x)


def results(records, meta):
    """The machine-readable report (schema :data:`SCHEMA`) as a dict.

    Keys: ``schema``, ``created_utc``, ``preset``, ``backend`` (the backend under test: ``backend`` as given,
    ``class``, ``version``; ``null`` if not described), ``executor``, ``wall_s``, ``machine``, ``summary``
    (counts of cases, checks, failing checks, cases stopped with an error, findings, items not applicable to the
    backend, cases wholly not applicable); ``cases`` (per case: ``case``, ``title``, ``backends``, ``verdict``,
    ``passed``, ``applicable`` (false when no check of it applies), ``wall_s``, ``error``: the traceback or ``null``,
    ``error_line``: the scene and stage it was raised in, and the error, or ``null``, ``not_applicable``: ``name`` and
    ``reasons`` of each check or run the backend cannot do, ``adapted``: the ``runs`` made on a scene fitted to the
    backend and its ``changes``, ``figures``: ``path`` and ``caption``, ``tables``: its tables by name, each a list of
    rows, a row an object of column to number or string); ``checks`` (every check: ``case``, ``name``, ``figure``,
    ``relation``, ``bound``, ``verdict`` ``"pass"``/``"FAIL"``, ``reason``); ``findings`` (``case``, ``name``,
    ``figure``, ``sentence``); ``not_applicable`` (every item: ``case``, ``name``, ``reasons``). A non-finite figure or
    bound is the string ``"nan"``, ``"inf"`` or ``"-inf"``.
    """
    return {
        "schema": SCHEMA, "created_utc": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "preset": meta["preset"], "backend": meta.get("backend"), "executor": meta["executor"],
        "wall_s": meta["wall_s"], "machine": meta["machine"], "summary": _summary(records),
        "cases": [{"case": r.name, "title": r.outcome.title, "backends": list(r.backends),
                   "verdict": r.outcome.verdict, "passed": r.outcome.passed, "applicable": r.outcome.applicable,
                   "wall_s": r.outcome.wall_s, "error": r.outcome.error, "error_line": r.outcome.error_line,
                   "not_applicable": [_na_json(item) for item in r.outcome.not_applicable],
                   "adapted": [{"runs": list(a.names), "changes": list(a.changes)} for a in r.outcome.adapted],
                   "figures": [{"path": f"{r.name}/{p.as_posix()}", "caption": c} for p, c in r.figures],
                   "tables": {name: [_json_row(row) for row in rows] for name, rows in r.tables.items()}}
                  for r in records],
        "checks": [{"case": r.name, "name": c.name, "figure": json_number(c.value), "relation": c.relation,
                    "bound": json_number(c.bound), "verdict": "pass" if c.passed else "FAIL", "reason": c.reason}
                   for r in records for c in r.outcome.checks],
        "findings": [{"case": r.name, "name": f.name, "figure": json_number(f.value), "sentence": f.sentence}
                     for r in records for f in r.findings],
        "not_applicable": [{"case": r.name, **_na_json(item)} for r in records for item in r.outcome.not_applicable],
    }


def _na_json(item):
    return {"name": item.name, "reasons": list(item.reasons)}


def _json_row(row):
    """A table row for JSON: its numbers through :func:`json_number` (integers and strings as they are)."""
    return {k: json_number(v) if isinstance(v, float) else v for k, v in row.items()}


def write_index(out_dir, records, meta):
    """Write ``out_dir/report.md``, ``index.html`` and ``results.json`` atomically; returns their paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = out / "report.md", out / "index.html", out / "results.json"
    write_page(index_page(records, meta), paths[0])
    write_text_atomic(paths[1], index_html(records, meta))
    write_text_atomic(paths[2], json.dumps(results(records, meta), indent=2, allow_nan=False) + "\n")
    return paths
