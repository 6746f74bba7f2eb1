"""The backends case (verification/backends.py): NumPy against Numba, one step and a trajectory."""

import json
import os
import subprocess
import sys
from dataclasses import replace

import pytest
from helpers import assert_every_figure_has_a_caption

from mpmref.backends import BACKENDS
from verification import backends as case
from verification import momentum
from verification.framework.common import failed

pytestmark = pytest.mark.skipif("numba" not in BACKENDS, reason="no Numba backend")


@pytest.fixture(scope="module")
def result():
    return case.run(case.Params.quick())


def test_every_check_of_the_quick_preset_holds(result):
    """Every scheme, PolyPIC included: its top modes next to a stencil switch are computed in closed form, so
    the two backends agree to round-off there too (tests/test_polypic_conditioning.py has the cause)."""
    assert [c.name for c in failed(case.checks(result))] == []


def test_every_scheme_and_material_is_compared(result):
    assert {r["key"] for r in result["runs"]} == {v.key for v in momentum.VARIANTS}
    for r in result["runs"]:
        assert set(r["history"][0]) == set(case.MATERIALS)
        assert {"x", "v", "F"} <= set(r["history"][0]["fixed_corotated"]) and "J" in r["history"][0]["fluid"]
        assert "Jp" in r["history"][0]["snow"] and ("modes" in r["history"][0]["sand"]) == (r["key"] == "polypic")


def test_a_candidate_off_by_1e_10_fails_the_one_step_check(monkeypatch):
    from mpmref.backends.numba import backend as numba_backend

    original = numba_backend.NumbaBackend.g2p

    def g2p_off(self, *args, **kwargs):
        new = original(self, *args, **kwargs)
        return new.with_(v=new.v * (1.0 + 1e-10))

    monkeypatch.setattr(numba_backend.NumbaBackend, "g2p", g2p_off)
    broken = case.checks(case.run(replace(case.Params.quick(), variants=("mls",), steps=2)))
    one_step = next(c for c in broken if "one step" in c.name)
    assert not one_step.passed and one_step.value > 50 * one_step.bound


def test_report_writes_plot_vtk_series_and_table(result, tmp_path):
    paths = case.report(result, tmp_path)
    assert all(p.exists() for p in paths)
    assert (tmp_path / "vtk" / "2d_quadratic_mls" / "particles.pvd").exists()
    text = (tmp_path / "backends.md").read_text()
    assert text.count("| 2 | quadratic |") == len(momentum.VARIANTS)
    assert [line for line in text.splitlines() if "FAIL" in line] == []
    assert_every_figure_has_a_caption(tmp_path)
    assert case.backends_run(result, "numpy") == ("numpy", "numba")


@pytest.mark.slow  # compiles every kernel of the case from an empty cache: about a minute of one core
def test_quick_preset_passes_from_an_empty_numba_cache_and_again_from_the_filled_one(tmp_path):
    """`mpmref verify backends --quick` in a fresh process with an empty Numba cache (kernels compiled), then
    again with the cache it filled (kernels loaded): exit 0 both times, every check passing, and the same bits
    in every figure, since a cached kernel is the compiled kernel."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    figures = []
    for run in ("cold", "warm"):
        out = tmp_path / run
        done = subprocess.run([sys.executable, "-m", "mpmref.cli", "verify", "backends", "--quick", "--no-progress",
                               "--out", str(out)], env=env, capture_output=True, text=True, timeout=600)
        assert done.returncode == 0, done.stdout + done.stderr
        results = json.loads((out / "results.json").read_text())
        assert results["summary"]["failing"] == 0 and results["summary"]["checks"] > 0
        figures.append({c["name"]: c["figure"] for c in results["checks"]})
    assert figures[0] == figures[1]
