"""The sync_vs_async verification case: its quick preset passes, and a broken stepper makes a check fail."""

from dataclasses import replace

import pytest

from verification import sync_vs_async as case
from verification.common import failed


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
    assert "## Findings" in text and "colliding balls" in text
    assert (tmp_path / "vtk" / "stork2d" / "particles.pvd").exists()


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
    pair = {"position_dx": 0.0, "updates_sync": 3, "own_updates": 1, "compare": {"energy_rel": 0.0}}
    return {"params": params, "one_level": [{"backend": "numpy", "max_rel": 0.0}],
            "schedule": {"matches": True, "census_ticks": 1, "lost": 0, "duplicated": 0},
            "stork2d": pair, "stork3d": pair}
