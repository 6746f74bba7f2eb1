"""Report writing shared by every case and by ``mpmref verify``.

Cases use :func:`snapshot`, :func:`write_series` and :func:`save_figure` to write the VTK series of their
representative runs and their PNG plots; ``mpmref verify`` uses :func:`write_case_report` and
:func:`write_index` for the per-case ``report.md`` and the top-level ``report.md`` / ``index.html``.
Every file is written atomically (:mod:`mpmref.io.atomic`).
"""

import html
import os
import platform
import sys
from dataclasses import asdict
from pathlib import Path

from mpmref.io.atomic import atomic_path, write_text_atomic
from mpmref.io.vtk import write_particles_vtu, write_pvd

from .common import failed

#: particle fields recorded in the VTK frames of verification runs
FRAME_FIELDS = ("velocity", "mass", "J", "material")
#: seconds a file's modification time may lag the clock that timed the case's start
MTIME_SLACK = 1.0


# --------------------------------------------------------------------------------- helpers for cases
def snapshot(sim, fields=FRAME_FIELDS):
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


def save_figure(fig, path):
    """Save a matplotlib figure as PNG atomically and close it."""
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110, bbox_inches="tight")
    pyplot().close(fig)
    return Path(path)


# ------------------------------------------------------------------------------------------ machine
def machine():
    """What ran the cases, for reports: host, CPU, cores, OS, Python and NumPy versions (and Numba's
    version and thread count when a case used it: its timings depend on them)."""
    import numpy as np

    info = {"host": platform.node(), "cpu": _cpu_model(), "cores": os.cpu_count(),
            "os": platform.platform(), "python": sys.version.split()[0], "numpy": np.__version__}
    numba = sys.modules.get("numba")
    if numba is not None:
        info.update({"numba": numba.__version__, "numba threads": numba.get_num_threads()})
    return info


def _cpu_model():
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


# ------------------------------------------------------------------------------------ case reports
def _files_by_kind(case_dir, since):
    """PNG, PVD and table files under ``case_dir`` written at or after ``since`` (older runs' files are stale)."""
    files = sorted(p.relative_to(case_dir) for p in Path(case_dir).rglob("*")
                   if p.is_file() and p.stat().st_mtime >= since - MTIME_SLACK)
    return ([f for f in files if f.suffix == ".png"], [f for f in files if f.suffix == ".pvd"],
            [f for f in files if f.suffix in (".md", ".csv") and f.name != "report.md"])


def case_summary_md(outcome, case_dir):
    """Markdown text of one case's ``report.md``: set-up, checks, figures, VTK series, other files."""
    lines = [f"# {outcome.name}", "", outcome.title, "",
             f"Preset `{outcome.preset}`, backend `{outcome.backend}`, wall time {outcome.wall_s:.1f} s, "
             f"verdict **{outcome.verdict}**.", "", "## Parameters", "", "| parameter | value |", "|---|---|"]
    lines += [f"| {k} | {_cell(v)} |" for k, v in asdict(outcome.params).items()] if outcome.params is not None else []
    if outcome.error is not None:
        lines += ["", "## Error", "", "```text", outcome.error.rstrip(), "```"]
    lines += ["", "## Checks", ""] + (_checks_md(outcome.checks) if outcome.checks else ["(none)"])
    figures, series, others = _files_by_kind(case_dir, outcome.started)
    if figures:
        lines += ["", "## Figures", ""] + [f"![{f.stem}]({f.as_posix()})" for f in figures]
    if series:
        lines += ["", "## VTK series (open in ParaView)", ""] + [f"- [{f.as_posix()}]({f.as_posix()})" for f in series]
    if others:
        lines += ["", "## Tables and details", ""] + [f"- [{f.as_posix()}]({f.as_posix()})" for f in others]
    return "\n".join(lines) + "\n"


def write_case_report(outcome, case_dir):
    """Write ``case_dir/report.md`` for one case's :class:`~verification.registry.Outcome`."""
    case_dir = Path(case_dir)
    case_dir.mkdir(parents=True, exist_ok=True)
    path = case_dir / "report.md"
    write_text_atomic(path, case_summary_md(outcome, case_dir))
    return path


# -------------------------------------------------------------------------------------------- tables
def _cell(text):
    """Markdown table cell text: pipes escaped, so a check named ``|P|`` cannot split the row."""
    return str(text).replace("|", "\\|")


def _check_header(with_case):
    head = ["case"] * with_case + ["check", "figure", "bound", "verdict", "why this bound"]
    return ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]


def _check_row(c, case=None):
    cells = [] if case is None else [_cell(case)]
    cells += [_cell(c.name), f"{c.value:.6g}", f"{c.relation} {c.bound:.6g}", "pass" if c.passed else "FAIL",
              _cell(c.reason)]
    return "| " + " | ".join(cells) + " |"


def _checks_md(checks):
    return _check_header(False) + [_check_row(c) for c in checks]


# -------------------------------------------------------------------------------------------- index
def _check_rows(outcomes):
    for o in outcomes:
        if o.error is not None:
            yield o, None
        for c in o.checks:
            yield o, c


def index_md(outcomes, meta):
    """Markdown of the top-level ``report.md``: verdicts per case, then every check."""
    n_checks = sum(len(o.checks) for o in outcomes)
    n_failed = sum(len(failed(o.checks)) for o in outcomes)
    lines = ["# mpmref verification report", "",
             f"{len(outcomes)} cases, {n_checks} checks, {n_failed} failing; "
             f"{sum(1 for o in outcomes if o.error)} cases stopped with an error.", "",
             f"Preset `{meta['preset']}`, backend `{meta['backend']}`, executor: {meta['executor']}, "
             f"total wall time {meta['wall_s']:.1f} s.", "",
             "Machine: " + ", ".join(f"{k} {v}" for k, v in meta["machine"].items()) + ".", "",
             "| case | checks | verdict | wall time [s] | report |", "|---|---|---|---|---|"]
    lines += [f"| {o.name} | {len(o.checks)} | {o.verdict} | {o.wall_s:.1f} | "
              f"[{o.name}/report.md]({o.name}/report.md) |" for o in outcomes]
    lines += ["", "## Every check", ""] + _check_header(True)
    for o, c in _check_rows(outcomes):
        if c is None:
            lines.append(f"| {o.name} | (the case stopped with an error) | — | — | FAIL | see {o.name}/report.md |")
        else:
            lines.append(_check_row(c, case=o.name))
    return "\n".join(lines) + "\n"


def _html_check_row(o, c):
    e = html.escape
    if c is None:
        return (f"<tr class='fail'><td>{e(o.name)}</td><td>(the case stopped with an error)</td>"
                "<td>—</td><td>—</td><td>FAIL</td><td></td></tr>")
    return (f"<tr class='{'pass' if c.passed else 'fail'}'><td>{e(o.name)}</td><td>{e(c.name)}</td>"
            f"<td>{c.value:.6g}</td><td>{e(c.relation)} {c.bound:.6g}</td>"
            f"<td>{'pass' if c.passed else 'FAIL'}</td><td>{e(c.reason)}</td></tr>")


def index_html(outcomes, meta):
    """A standalone HTML page with the same content as :func:`index_md`, plus the cases' figures."""
    e = html.escape
    rows = [_html_check_row(o, c) for o, c in _check_rows(outcomes)]
    cases = "".join(f"<tr class='{'pass' if o.passed else 'fail'}'><td><a href='{e(o.name)}/report.md'>{e(o.name)}</a>"
                    f"</td><td>{len(o.checks)}</td><td>{e(o.verdict)}</td><td>{o.wall_s:.1f}</td></tr>"
                    for o in outcomes)
    figures = "".join(f"<figure><img src='{e(p)}' alt='{e(p)}'><figcaption>{e(p)}</figcaption></figure>"
                      for p in meta["figures"])
    machine = ", ".join(f"{e(k)} {e(str(v))}" for k, v in meta["machine"].items())
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>mpmref verification report</title>
<style>body{{font-family:sans-serif;margin:2em}} table{{border-collapse:collapse}}
td,th{{border:1px solid #ccc;padding:3px 6px;text-align:left}} tr.fail td{{background:#fdd}}
tr.pass td:nth-child(5){{color:#070}} img{{max-width:640px}} figure{{display:inline-block}}</style></head>
<body><h1>mpmref verification report</h1>
<p>Preset <code>{e(meta['preset'])}</code>, backend <code>{e(meta['backend'])}</code>, executor: {e(meta['executor'])},
total wall time {meta['wall_s']:.1f} s.</p><p>Machine: {machine}.</p>
<h2>Cases</h2><table><tr><th>case</th><th>checks</th><th>verdict</th><th>wall time [s]</th></tr>{cases}</table>
<h2>Every check</h2><table><tr><th>case</th><th>check</th><th>figure</th><th>bound</th><th>verdict</th>
<th>why this bound</th></tr>{''.join(rows)}</table>
<h2>Figures</h2>{figures}
</body></html>
"""


def write_index(out_dir, outcomes, meta):
    """Write ``out_dir/report.md`` and ``out_dir/index.html``; returns their paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    figures = [p.relative_to(out).as_posix() for o in outcomes for p in sorted((out / o.name).rglob("*.png"))
               if p.stat().st_mtime >= o.started - MTIME_SLACK]
    meta = {**meta, "figures": figures}
    write_text_atomic(out / "report.md", index_md(outcomes, meta))
    write_text_atomic(out / "index.html", index_html(outcomes, meta))
    return out / "report.md", out / "index.html"
