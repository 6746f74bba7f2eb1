"""The HTML pages of the verification report: ``index.html`` (read in five minutes) and one page per case.

``index.html`` opens with the verdict and the failures, then shows one figure per case (the plot that
carries the case's main claim, its ``main_figure``, with its caption), then the findings, then every
check. Each case's own page, ``CASE/index.html``, one click away, holds all its figures, checks, findings,
parameters, VTK series and tables. The pages are self-contained: one inline style sheet, relative links
only, nothing fetched from a network.
"""

import html
from dataclasses import asdict

from .common import backend_sentence, failed, summary_sentence, verdict_word

e = html.escape

#: one style sheet for both kinds of page; narrow screens get one column of cases
STYLE = """
:root{--ok:#0a6b2d;--ok-bg:#e7f5ec;--bad:#a3150f;--bad-bg:#fde8e6;--line:#d0d4d9;--muted:#5a6270}
*{box-sizing:border-box}
body{font:15px/1.45 system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;margin:0 auto;max-width:1280px;
padding:1.2em 1.6em 3em;color:#1d2127}
h1{font-size:1.6em;margin:.2em 0 .4em} h2{font-size:1.25em;margin:1.6em 0 .5em;border-bottom:1px solid var(--line);
padding-bottom:.2em} h3{font-size:1.05em;margin:0 0 .3em}
a{color:#0b57a4}
.verdict{border-radius:8px;padding:.8em 1.1em;margin:.4em 0 .8em;font-size:1.15em}
.verdict.pass{background:var(--ok-bg);border:1px solid #9fd3b2} .verdict.fail{background:var(--bad-bg);
border:1px solid #f0a9a3} .verdict strong{font-size:1.2em}
.verdict.pass strong{color:var(--ok)} .verdict.fail strong{color:var(--bad)}
.meta{color:var(--muted);font-size:.9em;margin:.2em 0} details.meta summary{cursor:pointer}
nav.toc{display:flex;flex-wrap:wrap;gap:.4em;margin:.6em 0 0}
.chip{display:inline-block;border-radius:999px;padding:.1em .7em;font-size:.85em;text-decoration:none;
border:1px solid var(--line);white-space:nowrap}
.chip.pass{background:var(--ok-bg);color:var(--ok);border-color:#9fd3b2}
.chip.fail{background:var(--bad-bg);color:var(--bad);border-color:#f0a9a3}
.chip.na{background:#f1f2f4;color:var(--muted)} .verdict.na{background:#f1f2f4;border:1px solid var(--line)}
.cases{display:grid;grid-template-columns:repeat(auto-fill,minmax(560px,1fr));gap:1.2em}
@media (max-width:700px){.cases{grid-template-columns:1fr}}
article.case{border:1px solid var(--line);border-radius:8px;padding:.9em 1em;background:#fff}
article.case.wide{grid-column:1/-1} article.case.wide figure img{width:auto;max-width:100%}
article.case.fail{border-color:#f0a9a3}
article.case .title{color:var(--muted);margin:0 0 .6em;font-size:.92em}
figure{margin:0} figure img{width:100%;height:auto;border:1px solid #eceef1;border-radius:4px}
figcaption{font-size:.9em;color:#333;margin:.4em 0 .2em}
.more{font-size:.9em;margin:.5em 0 0}
table{border-collapse:collapse;width:100%;font-size:.9em}
td,th{border:1px solid var(--line);padding:4px 7px;text-align:left;vertical-align:top}
th{background:#f3f5f7} td.num{font-variant-numeric:tabular-nums;white-space:nowrap}
tr.fail td{background:var(--bad-bg)} td.pass{color:var(--ok)} td.FAIL{color:var(--bad);font-weight:600}
.figures{display:grid;grid-template-columns:repeat(auto-fill,minmax(480px,1fr));gap:1.2em}
pre{background:#f6f8fa;padding:.8em;overflow:auto;font-size:.85em}
"""


#: a main figure wider than this (width / height) gets the whole width of the page
WIDE = 2.4


def page(title, body):
    """A standalone HTML document with the report's style sheet."""
    return (f"<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\"><title>{e(title)}</title>"
            f"<style>{STYLE}</style></head>\n<body>\n{body}\n</body></html>\n")


def _status(ok):
    return "pass" if ok else "fail"


def _case_status(outcome):
    """The style of a case: ``pass``, ``fail``, or ``na`` when nothing of it applies to the backend."""
    if outcome.error is None and not outcome.applicable:
        return "na"
    return _status(outcome.passed)


def figure_html(src, caption):
    """A figure that opens at full size when clicked, with its caption."""
    return (f"<figure><a href='{e(src)}'><img src='{e(src)}' alt='{e(caption)}' loading='lazy'></a>"
            f"<figcaption>{e(caption)}</figcaption></figure>")


def _check_row(c, case=None):
    verdict = "pass" if c.passed else "FAIL"
    first = "" if case is None else f"<td>{e(case)}</td>"
    return (f"<tr class='{_status(c.passed)}'>{first}<td>{e(c.name)}</td><td class='num'>{c.value:.6g}</td>"
            f"<td class='num'>{e(c.relation)} {c.bound:.6g}</td><td class='{verdict}'>{verdict}</td>"
            f"<td>{e(c.reason)}</td></tr>")


def _checks_table(rows, with_case):
    head = "<th>case</th>" * with_case + ("<th>check</th><th>figure</th><th>bound</th><th>verdict</th>"
                                           "<th>why this bound</th>")
    return f"<table><tr>{head}</tr>{''.join(rows)}</table>"


def _findings_table(findings, with_case):
    if not findings:
        return "<p>(none in these cases)</p>"
    head = "<th>case</th>" * with_case + "<th>finding</th><th>figure</th><th>what it shows</th>"
    rows = "".join("<tr>" + (f"<td>{e(case)}</td>" if with_case else "") + f"<td>{e(f.name)}</td>"
                   f"<td class='num'>{f.value:.6g}</td><td>{e(f.sentence)}</td></tr>" for case, f in findings)
    return f"<table><tr>{head}</tr>{rows}</table>"


def _verdict_box(summary):
    word = verdict_word(summary)
    style = {"PASS": "pass", "FAIL": "fail"}.get(word, "na")
    return f"<div class='verdict {style}'><strong>{word}</strong> — {e(summary_sentence(summary))}.</div>"


def _not_applicable(records, with_case):
    """The table of what was not applicable to the backend (``""`` when everything applied)."""
    items = [(r.name, item) for r in records for item in r.outcome.not_applicable]
    if not items:
        return ""
    head = "<th>case</th>" * with_case + "<th>not applicable</th><th>why</th>"
    rows = "".join("<tr>" + (f"<td>{e(case)}</td>" if with_case else "") + f"<td>{e(item.name)}</td>"
                   f"<td>{e(item.why)}</td></tr>" for case, item in items)
    return (f"<h2 id='not-applicable'>Not applicable to this backend</h2><p>Checks, or runs and the checks they "
            f"carry, that the backend does not implement: never a failure.</p><table><tr>{head}</tr>{rows}</table>")


def _adapted(outcome):
    """The table of the runs made on a scene fitted to the backend (``""`` when none)."""
    if not outcome.adapted:
        return ""
    rows = "".join(f"<tr><td>{e(', '.join(a.names))}</td><td>{e(' '.join(a.changes))}</td></tr>"
                   for a in outcome.adapted)
    return (f"<h2>Adapted to this backend</h2><table><tr><th>runs</th><th>what changed</th></tr>{rows}</table>")


def _failures(records):
    """The failing checks and the cases that stopped with an error, or a line saying there are none."""
    rows = [_check_row(c, r.name) for r in records for c in failed(r.outcome.checks)]
    errors = [r for r in records if r.outcome.error is not None]
    if not rows and not errors:
        return "<h2 id='failures'>Failures</h2><p>None: every check of every case passes.</p>"
    parts = ["<h2 id='failures'>Failures</h2>"]
    if rows:
        parts.append(_checks_table(rows, with_case=True))
    for r in errors:
        last = r.outcome.error_line or r.outcome.error.strip().splitlines()[-1]
        parts.append(f"<p><strong>{e(r.name)}</strong> stopped with an error: <code>{e(last)}</code> "
                     f"(<a href='{e(r.name)}/index.html'>its page</a> has the traceback).</p>")
    return "".join(parts)


def _case_card(record):
    o = record.outcome
    main = record.main_figure
    figure = (figure_html(f"{o.name}/{main[0].as_posix()}", main[1]) if main is not None
              else "<p>(This case writes no figure.)</p>")
    n = len(record.figures)
    more = (f"All {n} figures, " if n > 1 else "") + "the checks, parameters, VTK series and tables"
    wide = " wide" if main is not None and main[2] > WIDE else ""
    return (f"<article class='case {_case_status(o)}{wide}' id='case-{e(o.name)}'><h3>{e(o.name)} "
            f"<span class='chip {_case_status(o)}'>{e(o.verdict)}</span></h3><p class='title'>{e(o.title)}</p>"
            f"{figure}<p class='more'><a href='{e(o.name)}/index.html'>{more} of this case →</a></p></article>")


def index_html(records, meta, summary, backends):
    """``index.html``: verdict and failures, one figure per case, findings, then every check."""
    toc = "".join(f"<a class='chip {_case_status(r.outcome)}' href='#case-{e(r.name)}'>{e(r.name)}: "
                  f"{e(r.outcome.verdict)}</a>" for r in records)
    machine = "".join(f"<li>{e(k)}: {e(str(v))}</li>" for k, v in meta["machine"].items())
    findings = [(r.name, f) for r in records for f in r.findings]
    checks = [_check_row(c, r.name) for r in records for c in r.outcome.checks]
    body = (f"<h1>mpmref verification report</h1>{_verdict_box(summary)}"
            f"<p class='meta'>Preset <code>{e(meta['preset'])}</code>; backends run: {e(', '.join(backends))}; "
            f"sweeps in {e(meta['executor'])}; total wall time {meta['wall_s']:.1f} s. "
            f"{e(backend_sentence(meta).replace('`', ''))} Also as <a href='report.md'>report.md</a> and "
            "<a href='results.json'>results.json</a>.</p>"
            f"<details class='meta'><summary>Machine</summary><ul>{machine}</ul></details>"
            f"<nav class='toc'>{toc}</nav>{_failures(records)}{_not_applicable(records, with_case=True)}"
            f"<h2 id='cases'>Cases: the figure that carries each claim</h2>"
            f"<div class='cases'>{''.join(_case_card(r) for r in records)}</div>"
            f"<h2 id='findings'>Findings (measured, not judged)</h2>{_findings_table(findings, True)}"
            f"<h2 id='checks'>Every check</h2>{_checks_table(checks, with_case=True)}")
    return page("mpmref verification report", body)


def case_html(record, series, tables):
    """``CASE/index.html``: everything the case wrote, with relative links into its folder, in the index's order
    (verdict, failures, figures, findings, checks; then the VTK series, tables and parameters)."""
    o = record.outcome
    params = ("".join(f"<tr><td>{e(k)}</td><td>{e(str(v))}</td></tr>" for k, v in asdict(o.params).items())
              if o.params is not None else "")
    parts = ["<p class='meta'><a href='../index.html'>← the whole report</a></p>",
             f"<h1>{e(o.name)} <span class='chip {_case_status(o)}'>{e(o.verdict)}</span></h1>",
             f"<p>{e(o.title)}</p><p class='meta'>Preset <code>{e(o.preset)}</code>, backends run: "
             f"{e(', '.join(record.backends))}, wall time {o.wall_s:.1f} s. Also as "
             "<a href='report.md'>report.md</a>.</p>"]
    if o.error is not None:
        where = f"<p><code>{e(o.error_line)}</code></p>" if o.error_line else ""
        parts.append(f"<h2>Error</h2>{where}<pre>{e(o.error.rstrip())}</pre>")
    failing = failed(o.checks)
    if failing:
        parts.append("<h2>Failures</h2>" + _checks_table([_check_row(c) for c in failing], with_case=False))
    if record.figures:
        parts.append("<h2>Figures</h2><div class='figures'>"
                     + "".join(figure_html(p.as_posix(), caption) for p, caption in record.figures) + "</div>")
    if record.findings:
        parts.append("<h2>Findings (measured, not judged)</h2>"
                     + _findings_table([(o.name, f) for f in record.findings], with_case=False))
    parts.append("<h2>Checks</h2>" + (_checks_table([_check_row(c) for c in o.checks], with_case=False)
                                      if o.checks else "<p>(none)</p>"))
    parts.append(_not_applicable([record], with_case=False) + _adapted(o))
    if series:
        parts.append("<h2>VTK series (open in ParaView)</h2><ul>"
                     + "".join(f"<li><a href='{e(f.as_posix())}'>{e(f.as_posix())}</a></li>" for f in series) + "</ul>")
    if tables:
        parts.append("<h2>Tables and details</h2><ul>"
                     + "".join(f"<li><a href='{e(f.as_posix())}'>{e(f.as_posix())}</a></li>" for f in tables) + "</ul>")
    if params:
        parts.append(f"<h2>Parameters</h2><table><tr><th>parameter</th><th>value</th></tr>{params}</table>")
    return page(f"mpmref verification: {o.name}", "".join(parts))
