"""The energy case (verification/energy.py): its quick preset, an energy-injecting G2P, its report."""

from dataclasses import replace

import pytest
from helpers import assert_every_figure_has_a_caption

from mpmref.backends.numpy import backend as numpy_backend
from verification import energy as case
from verification.framework.common import failed


@pytest.fixture(scope="module")
def result():
    return case.run(case.Params.quick())


def test_every_check_of_the_quick_preset_holds(result):
    failing = [c.line() for c in failed(case.checks(result))]
    assert not failing, "\n".join(failing)


def test_checks_cover_every_problem_and_scheme(result):
    names = [c.name for c in case.checks(result)]
    for problem in case.PROBLEMS:
        for v in case.VARIANTS:
            assert f"{problem}: {v.label} energy gain max(E-E0)/E0" in names
        assert f"{problem}: PIC loses more than MLS-MPM (APIC, MLS force)" in names


def test_pic_loses_a_sizeable_fraction_and_polypic_almost_nothing(result):
    """Measured budget (quick): PIC loses 41 % (disks) and 99 % (jelly), PolyPIC under 5 %."""
    for problem in case.PROBLEMS:
        assert case.budget(result["runs"][problem]["pic"])["lost"] > 0.3
        assert abs(case.budget(result["runs"][problem]["polypic"])["lost"]) < 0.05


def test_the_ledger_of_every_run_adds_up_to_its_energy_change(result):
    """The stacked terms of the ledger figures are each scheme's change of total energy, step by step (to round-off
    of E0, over a few hundred steps); PIC's transfers take most of its loss (the ledger chapter's table)."""
    for runs in result["runs"].values():
        for r in runs.values():
            e0 = r["total"][0]
            assert sum(r["ledger"].values()) == pytest.approx(r["total"] - e0, abs=1e-12 * e0)
        pic = runs["pic"]
        transfers = pic["ledger"]["p2g_transfer"][-1] + pic["ledger"]["g2p_transfer"][-1]
        assert transfers / (pic["total"][-1] - pic["total"][0]) > 0.8


def test_a_g2p_that_injects_energy_fails_the_gain_check(monkeypatch):
    """Scaling every G2P velocity by 1.01 adds about 2 % kinetic energy per step: the gain check must fail."""
    original = numpy_backend.NumpyBackend.g2p

    def g2p_injecting(self, *args, **kwargs):
        new = original(self, *args, **kwargs)
        return new.with_(v=1.01 * new.v)

    monkeypatch.setattr(numpy_backend.NumpyBackend, "g2p", g2p_injecting)
    params = replace(case.Params.quick(), problems=("jelly",), variants=("mls",), jelly_t_end=0.02)
    gain = next(c for c in case.checks(case.run(params)) if "energy gain" in c.name)
    assert not gain.passed and gain.value > 2 * gain.bound


def test_report_writes_plots_vtk_series_and_budget(result, tmp_path):
    paths = case.report(result, tmp_path)
    assert all(p.exists() for p in paths)
    for problem in case.PROBLEMS:
        assert (tmp_path / f"energy_{problem}.png").stat().st_size > 10_000
        assert (tmp_path / f"energy_ledger_{problem}.png").stat().st_size > 10_000
        assert (tmp_path / "vtk" / problem / "mls" / "particles.pvd").exists()
    text = (tmp_path / "energy.md").read_text()
    assert "| lost fraction |" in text and "FAIL" not in text
    assert_every_figure_has_a_caption(tmp_path)
