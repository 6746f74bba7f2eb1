"""The verification report of ``mpmref verify``: results.json, the findings section, per-case backends,
figure captions and progress lines, on a toy case whose every figure is known (``verify_toy_case.py``)."""

import argparse
import html
import json
import re
from dataclasses import replace

import pytest
import verify_toy_case as toy

from verification.framework import registry
from verification.framework.cli import add_parser
from verification.framework.report import NO_CAPTION


def verify(argv):
    parser = argparse.ArgumentParser(prog="mpmref")
    add_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["verify", *argv])
    return args.func(args)


def strict_json(path):
    """Parse ``path`` as standard JSON: NaN and Infinity literals are refused."""
    def refuse(name):
        raise ValueError(f"non-standard JSON constant {name}")

    return json.loads(path.read_text(), parse_constant=refuse)


@pytest.fixture
def toy_case(monkeypatch):
    monkeypatch.setitem(registry.CASES, "toy", "verify_toy_case")


def run_toy(monkeypatch, tmp_path, slope=2.0, extra=()):
    monkeypatch.setattr(toy.Params, "quick", classmethod(lambda cls: replace(cls(), slope=slope)))
    return verify(["toy", "--quick", "--workers", "1", "--out", str(tmp_path), *extra])


def test_results_json_has_every_check_with_case_name_figure_bound_verdict_and_reason(toy_case, monkeypatch,
                                                                                      tmp_path):
    assert run_toy(monkeypatch, tmp_path, slope=3.0) == 1
    data = strict_json(tmp_path / "results.json")
    assert data["schema"] == "mpmref-verify/1" and data["preset"] == "quick"
    assert data["checks"] == [
        {"case": "toy", "name": "slope of the line", "figure": 3.0, "relation": "<=", "bound": 2.5, "verdict": "FAIL",
         "reason": "the toy's theory allows up to 2.5"},
        {"case": "toy", "name": "a value below an infinite bound", "figure": 1.0, "relation": "<", "bound": "inf",
         "verdict": "pass", "reason": "nothing is infinite here"}]
    assert data["summary"] == {"cases": 1, "checks": 2, "failing": 1, "errors": 0, "findings": 1, "not_applicable": 0,
                               "cases_not_applicable": 0}
    (case,) = data["cases"]
    assert case["verdict"] == "FAIL (1 of 2)" and case["passed"] is False and case["error"] is None
    assert not list(tmp_path.glob(".tmp-*"))  # written atomically: no temporary file left behind


def test_results_json_holds_exactly_the_checks_of_the_markdown_index(toy_case, monkeypatch, tmp_path):
    """Every check row of report.md, with its verdict, is in results.json, and nothing else is."""
    assert run_toy(monkeypatch, tmp_path, slope=1.0) == 0
    data = strict_json(tmp_path / "results.json")
    rows = [line.split(" | ") for line in (tmp_path / "report.md").read_text().splitlines()
            if line.startswith("| toy | ") and line.count(" | ") == 5]
    assert [(r[1], r[4]) for r in rows] == [(c["name"], c["verdict"]) for c in data["checks"]]


def test_the_index_reads_verdict_failures_figures_findings_then_checks(toy_case, monkeypatch, tmp_path):
    """index.html and report.md open with the verdict and the failures, then the cases (in index.html: one figure
    each), then the findings, then every check."""
    assert run_toy(monkeypatch, tmp_path, slope=3.0) == 1
    page = (tmp_path / "index.html").read_text()
    assert page.index("<strong>FAIL</strong> — 1 of 2 checks pass") < page.index("<h2 id='failures'>")
    assert (page.index("<h2 id='failures'>") < page.index("<h2 id='cases'>") < page.index("<h2 id='findings'>")
            < page.index("<h2 id='checks'>"))
    failures = page[page.index("<h2 id='failures'>"):page.index("<h2 id='cases'>")]
    assert "<td>slope of the line</td>" in failures and "infinite bound" not in failures
    assert "<td>curvature of the line</td><td class='num'>0</td>" in page
    md = (tmp_path / "report.md").read_text()
    assert md.index("**FAIL**") < md.index("## Failures") < md.index("## Cases") < md.index("## Findings") < md.index(
        "## Every check")
    assert "| toy | curvature of the line | 0 | The line is straight: measured, not judged. |" in md
    assert strict_json(tmp_path / "results.json")["findings"] == [
        {"case": "toy", "name": "curvature of the line", "figure": 0.0,
         "sentence": "The line is straight: measured, not judged."}]
    assert "## Findings (measured, not judged)" in (tmp_path / "toy" / "report.md").read_text()
    assert run_toy(monkeypatch, tmp_path, slope=1.0) == 0
    page = (tmp_path / "index.html").read_text()
    assert "<strong>PASS</strong> — 2 of 2 checks pass" in page and "None: every check of every case passes." in page


def test_the_index_shows_each_cases_main_figure_and_its_page_every_figure(toy_case, monkeypatch, tmp_path):
    assert run_toy(monkeypatch, tmp_path) == 0
    page = (tmp_path / "index.html").read_text()
    assert f"<img src='toy/{toy.MAIN_FIGURE}'" in page and "uncaptioned.png" not in page
    assert "<a href='toy/index.html'>All 2 figures" in page
    case_page = (tmp_path / "toy" / "index.html").read_text()
    assert "<img src='line.png'" in case_page and "<img src='uncaptioned.png'" in case_page
    assert f"<figcaption>{html.escape(NO_CAPTION)}</figcaption>" in case_page


def test_the_pages_are_self_contained(toy_case, monkeypatch, tmp_path):
    """No address outside the report folder, and every relative link or image resolves to a file."""
    assert run_toy(monkeypatch, tmp_path) == 0
    for path in (tmp_path / "index.html", tmp_path / "toy" / "index.html"):
        text = path.read_text()
        assert "http://" not in text and "https://" not in text
        for target in re.findall(r"(?:src|href)='([^'#]+)'", text):
            assert (path.parent / target).is_file(), (path, target)


def test_the_header_names_the_backends_each_case_ran(toy_case, monkeypatch, tmp_path):
    assert run_toy(monkeypatch, tmp_path) == 0
    md = (tmp_path / "report.md").read_text()
    assert "backend `numpy`" not in md and "backends run: numpy, numba (per case below)" in md
    assert "| [toy](toy/report.md) | numpy, numba | 2 | pass |" in md
    assert strict_json(tmp_path / "results.json")["cases"][0]["backends"] == ["numpy", "numba"]
    assert "backends run: numpy, numba" in (tmp_path / "toy" / "report.md").read_text()


def test_figures_carry_their_captions_not_their_paths(toy_case, monkeypatch, tmp_path):
    assert run_toy(monkeypatch, tmp_path) == 0
    page = (tmp_path / "index.html").read_text()
    assert f"<figcaption>{html.escape(toy.CAPTION)}</figcaption>" in page
    assert f"<figcaption>{html.escape(NO_CAPTION)}</figcaption>" in (tmp_path / "toy" / "index.html").read_text()
    assert "<figcaption>toy/line.png" not in page
    figures = strict_json(tmp_path / "results.json")["cases"][0]["figures"]
    assert figures == [{"path": "toy/line.png", "caption": toy.CAPTION},
                       {"path": "toy/uncaptioned.png", "caption": NO_CAPTION}]
    assert f"![line](line.png)\n\n{toy.CAPTION}" in (tmp_path / "toy" / "report.md").read_text()


def test_progress_goes_to_standard_error_and_can_be_turned_off(toy_case, monkeypatch, tmp_path, capsys):
    assert run_toy(monkeypatch, tmp_path, slope=3.0) == 1
    out, err = capsys.readouterr()
    assert "[1/1] toy: started (quick preset, --backend numpy)" in err
    assert "[1/1] toy: finished in " in err and "FAIL (1 of 2)" in err
    assert "toy: FAIL slope of the line: 3 (bound <= 2.5)" in out and "1 of 2 checks pass" in out
    assert "started" not in out
    assert run_toy(monkeypatch, tmp_path, slope=3.0, extra=["--no-progress"]) == 1
    out, err = capsys.readouterr()
    assert err == "" and "toy: FAIL slope of the line" in out


def test_an_exception_in_findings_stops_the_case_with_an_error(toy_case, monkeypatch, tmp_path):
    def broken(result):
        raise RuntimeError("deliberate failure in findings")

    monkeypatch.setattr(toy, "CASE", replace(toy.CASE, findings=broken))
    assert run_toy(monkeypatch, tmp_path) == 1
    (case,) = strict_json(tmp_path / "results.json")["cases"]
    assert case["verdict"] == "ERROR" and "deliberate failure in findings" in case["error"]


def test_the_one_check_table_escapes_pipes_in_every_text():
    """Every case's report and the index render checks through one function (``Check.line``): a check named after
    a norm, ``|P - P0|``, stays one row of five cells."""
    from verification.framework.common import Check, checks_table

    table = checks_table([Check("|P - P0| / S", 1e-15, "<=", 1e-12, "round-off |k n + N| u")])
    row = table.splitlines()[-1]
    assert len(re.findall(r"(?<!\\)\|", row)) == 6 and "\\|P - P0\\|" in row
