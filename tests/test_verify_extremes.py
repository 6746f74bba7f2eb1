"""The stability-at-extremes case (verification/extremes.py) in its quick preset."""

from dataclasses import replace

import pytest
from helpers import assert_every_figure_has_a_caption

from verification import extremes as case
from verification.framework.common import failed


@pytest.fixture(scope="module")
def result():
    return case.run(case.Params.quick())


def test_every_check_of_the_quick_preset_holds(result):
    failing = [c.line() for c in failed(case.checks(result))]
    assert not failing, "\n".join(failing)


def test_every_scheme_and_condition_is_probed(result):
    p = result["params"]
    assert len(result["rows"]) == len(p.schemes) * len(p.conditions())
    assert set(result["crossing"]) == set(p.schemes)


def test_claiming_stability_beyond_the_linear_limit_fails():
    """CFL 2 exceeds sqrt(3), the lumped-mass limit of the quadratic B-spline: the runs must refute the claim."""
    params = replace(case.Params.quick(), schemes=("apic",), nus=(0.3,), youngs=(1.0e4,), ppcs=(4,),
                     guaranteed_cfl=2.0)
    broken = case.run(params)
    assert broken["rows"][0]["limit"] < 2.0
    assert [c.name for c in failed(case.checks(broken))] == ["apic, base (E = 10000, ν = 0.3, ppc = 4): "
                                                                     "largest stable CFL"]


def test_a_slow_block_does_not_fire_the_cell_crossing_detector():
    """At CFL 0.5 the block moves C V/(c + V) < 1 cell per step: the 'detector fires' check must fail."""
    params = replace(case.Params.quick(), schemes=("mls",), nus=(0.3,), youngs=(1.0e4,), ppcs=(4,), crossing_cfl=0.5)
    slow = case.run(params)
    assert slow["crossing"]["mls"]["crossing"] == pytest.approx(0.5 * 10 / 11, rel=1e-12)
    failing = [c.name for c in failed(case.checks(slow))]
    assert failing == ["mls: cell-crossing detector on the translating block"]


def test_the_report_writes_table_plot_and_a_breaking_run(result, tmp_path):
    path = case.report(result, tmp_path)
    text = path.read_text()
    assert "| condition | pic | flip | apic | mls | polypic |" in text and "FAIL" not in text
    assert (tmp_path / "extremes.png").is_file()
    assert len(list((tmp_path / "vtk_breaking").glob("particles_*.vtu"))) >= 2
    assert_every_figure_has_a_caption(tmp_path)


def test_each_schemes_limit_on_the_base_block_is_a_finding(result):
    params = case.Params.quick()
    found = {f.name.split(":")[0]: f for f in case.findings(result)}
    assert list(found) == list(params.schemes)
    for r in (r for r in result["rows"] if r["condition"] == params.base):
        assert found[r["scheme"]].value == r["limit"]
        assert f"{case.resolution(params):.3g}" in found[r["scheme"]].sentence
