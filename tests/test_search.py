"""``mpmref conformance search`` (mpmref/conformance/search.py): it finds the planted bugs of tests/planted_extremes.py,
shrinks each to a state of a few particles, saves it as a case file that ``conformance check --case`` replays, and says
how many states it tried, by region, when it finds nothing."""

import argparse

import numpy as np
import pytest
from planted_extremes import PLANTED, IntBaseNode, QuirkySvd, SkipsAtYieldSurface

from mpmref.conformance import add_parser, check
from mpmref.conformance.casefile import load_case, save_case
from mpmref.conformance.search import DEFAULT_BUDGET, ROUND, search
from mpmref.conformance.strategies import MAX_PARTICLES

#: each planted bug, the stage a quick search looks at
QUICK = {"quirky-svd": "stress", "int-base-node": "p2g", "skips-at-yield-surface": "return_map",
         "gradient-sign-on-face": "g2p"}


def cli(argv):
    parser = argparse.ArgumentParser(prog="mpmref")
    add_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return args.func(args)


@pytest.mark.parametrize("bug", ["quirky-svd", "int-base-node", "skips-at-yield-surface"])
def test_a_search_of_the_bugs_stage_finds_it_and_shrinks_it_to_few_particles(bug, tmp_path):
    """Within two rounds of its stage; the shrunk state has at most three particles (most often one), fails on the
    reference's own terms when replayed from its file, and the reference passes it."""
    report = search(PLANTED[bug], stages=(QUICK[bug],), budget=2 * ROUND, out_dir=tmp_path)
    (found,) = report.found
    inputs = found.case.inputs()
    assert len(inputs["x"]) <= 3 and found.after <= 2 * ROUND
    replayed = load_case(found.path)
    assert check(PLANTED[bug], [replayed]).failures() and check("numpy", [replayed]).passed
    assert np.array_equal(replayed.inputs()["x"], inputs["x"])


def test_the_reference_agrees_with_itself_on_every_state_and_the_summary_says_where_it_looked():
    report = search("numpy", stages=("stress", "grid_update", "step"), budget=3 * ROUND)
    assert not report.found and report.total >= 3 * ROUND
    text = report.text()
    assert "nothing found" in text and f"tried {report.total} states" in text
    for region in ("F rest", "F near-symmetric", "x on a line", "node states", "Δt at the stability limit"):
        assert region in text


def test_a_case_file_replays_from_the_command_line(tmp_path, capsys):
    """check --case runs the saved case: it fails for the bug and passes for the reference; a file that is not a case
    is refused in one line."""
    report = search(QuirkySvd, stages=("stress",), budget=2 * ROUND, out_dir=tmp_path)
    path = str(report.found[0].path)
    assert cli(["conformance", "check", "--backend", "planted_extremes:QuirkySvd", "--case", path,
                "--no-progress"]) == 1
    assert "FAILED: 0 of 1" in capsys.readouterr().out
    assert cli(["conformance", "check", "--backend", "numpy", "--case", path, "--no-progress"]) == 0
    np.savez(tmp_path / "other.npz", x=np.zeros(2))
    from mpmref.cli import main

    assert main(["conformance", "check", "--backend", "numpy", "--case", str(tmp_path / "other.npz")]) == 2
    assert "not a conformance case file" in capsys.readouterr().err


def test_the_search_command_prints_and_saves_what_it_finds(tmp_path, capsys):
    """Exit status 1 with the shrunk state and the command that replays it; 0 when nothing is found."""
    out = tmp_path / "found"
    assert cli(["conformance", "search", "--backend", "planted_extremes:SkipsAtYieldSurface", "--stage", "return_map",
                "--budget", str(ROUND), "--out", str(out), "--no-progress"]) == 1
    text = capsys.readouterr().out
    assert "FOUND return_map-" in text and "particle 0 (snow" in text and "replay: mpmref conformance check" in text
    assert len(list(out.glob("*.npz"))) == 1
    assert cli(["conformance", "search", "--backend", "numpy", "--stage", "stress", "--budget", str(ROUND),
                "--no-progress"]) == 0
    assert "nothing found" in capsys.readouterr().out


def test_a_saved_case_is_a_regression_case():
    """A case saved and loaded is the same case: same inputs, same reference, and the check's verdict on it."""
    report = search(IntBaseNode, stages=("p2g",), budget=ROUND)
    case = report.found[0].case
    assert len(case.inputs()["x"]) <= MAX_PARTICLES


@pytest.mark.slow
@pytest.mark.parametrize("bug", list(PLANTED))
def test_the_default_search_finds_every_planted_bug(bug, tmp_path):
    """Every stage, the default budget: the bug is found, in the stage it lives in, and shrunk to a state of at most
    three particles."""
    report = search(PLANTED[bug], budget=DEFAULT_BUDGET, out_dir=tmp_path)
    assert report.found, report.text()
    assert any(f.case.stage == QUICK[bug] or bug == "gradient-sign-on-face" for f in report.found)
    assert all(len(f.case.inputs().get("x", [])) <= 3 for f in report.found)


def test_save_case_round_trips_a_drawn_case(tmp_path):
    """Any case saves: a drawn catalogue case comes back with its inputs, stage, scene and the check's verdict."""
    from mpmref.conformance import make_cases

    case = make_cases(dims=(2,), stages=("stress",))[0]
    path = save_case(case, tmp_path / "c.npz")
    back = load_case(path)
    assert back.name == case.name and back.scene_dict == case.scene_dict
    assert all(np.array_equal(back.inputs()[k], case.inputs()[k]) for k in case.inputs())
    assert check(SkipsAtYieldSurface, [back]).passed
