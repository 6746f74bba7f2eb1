"""The sync_vs_async verification case: its quick preset passes, and a broken stepper makes a check fail."""


import pytest

from verification import sync_vs_async as case
from verification.framework.common import failed


@pytest.fixture(scope="module")
def result():
    return case.run(case.Params.quick())


def test_every_check_of_the_quick_preset_holds(result):
    failing = [c.line() for c in failed(case.checks(result))]
    assert not failing, "\n".join(failing)


def test_report_writes_plots_series_and_findings(result, tmp_path):
    paths = case.report(result, tmp_path)
    assert all(p.exists() for p in paths)
    text = (tmp_path / "sync_vs_async.md").read_text()
    assert "## Findings" in text and "colliding balls" in text and "Pareto" in text
    assert (tmp_path / "vtk" / "stork2d_conservative" / "particles.pvd").exists()
    assert (tmp_path / case.MAIN_FIGURE).exists()


def test_the_ledger_part_books_the_measured_change_and_reports_the_interfaces(result):
    names = {c.name for c in case.checks(result)}
    assert {f"ledger, {itf}: max |booked - measured energy change| / E_0 per synchronised interval"
            for itf in ("conservative", "reference")} <= names
    for led in result["ledger"].values():
        assert led["terms"]["interface"] < 0.0 < -led["terms"]["energy_change"]  # the disks lose energy, some there
    assert any(f.name.startswith("ledger, conservative") for f in case.findings(result))


def test_both_interface_treatments_run_and_the_trade_has_a_front(result):
    assert set(result["isolated"]) == {"conservative", "reference"}
    assert result["isolated"]["reference"]["P"] > 1e6 * case.ROUND_OFF  # the drift the conservative one removes
    front = [r for r in result["trade"] if r["pareto"]]
    assert front and {r["kind"] for r in result["trade"]} == {"sync", "async"}
    # no run off the front is both faster and more accurate than a run on it
    for r in result["trade"]:
        assert not any(f["wall"] > r["wall"] and f["error_dx"] > r["error_dx"] for f in front)


@pytest.mark.parametrize("broken", ["applied twice", "dropped"])
def test_a_broken_conservative_interface_fails_the_momentum_check(broken, monkeypatch):
    """The recorded exchange applied twice, or dropped: the isolated scene's momentum check fails."""
    from mpmref.steppers import AsyncInterval

    class Broken(AsyncInterval):
        def close_registers(self, idx):
            if self.s.conservative and idx.size:
                self.dP[idx] *= 2.0 if broken == "applied twice" else 0.0
                self.dL[idx] *= 2.0 if broken == "applied twice" else 0.0
            super().close_registers(idx)

    monkeypatch.setattr(case.AsynchronousStepper, "interval_type", Broken)
    params = case.Params.quick()
    iso = {"conservative": case.isolated(params, "numpy", "conservative")}
    failing = {c.name for c in failed(case.checks({**_passing(params), "isolated": iso}))}
    assert "isolated, conservative: linear momentum drift / sum m|v|" in failing


def test_frozen_shadows_fail_the_free_fall_check():
    """Shadows never sub-cycled: the fine particles see their coarse neighbours at the coarse step's start."""
    params = case.Params.quick()
    broken = case.free_fall(params, "numpy", stepper=case.FrozenShadows)
    good = case.free_fall(params, "numpy")
    assert good["max_rel"] <= 1e-12 < broken["max_rel"]
    failing = {c.name for c in failed(case.checks({**_passing(params), "free_fall": broken}))}
    assert failing == {"free fall: |v_com - (v0 + g t)| / |g t| at sync times"}


def _passing(params):
    """A result whose other parts pass, so that only the part under test is judged."""
    pair = {"position_dx": 0.0, "updates_sync": 3, "own_updates": 1, "mass": 1.0,
            "compare": {"energy_rel": 0.0, "P_drift_async": 0.0}}
    pairs = {f"{key}/{itf}": pair for key in case.PAIRS for itf in params.interfaces}
    return {"params": params, "one_level": [{"backend": "numpy", "max_rel": 0.0}],
            "schedule": {"matches": True, "census_ticks": 1, "lost": 0, "duplicated": 0},
            "free_fall": {"max_rel": 0.0, "levels": [0, 1]}, **pairs,
            "isolated": {"conservative": {"P": 0.0, "L": 0.0, "levels": [0, 3]}},
            "bonded": [{"cfl": 0.4, "conservative": 0.0}]}
