"""The backends case (verification/backends.py): NumPy against Numba, one step and a trajectory."""

from dataclasses import replace

import pytest

from mpmref.backends import BACKENDS
from helpers import assert_every_figure_has_a_caption
from verification import backends as case
from verification.common import failed
from verification import momentum

pytestmark = pytest.mark.skipif("numba" not in BACKENDS, reason="no Numba backend")


@pytest.fixture(scope="module")
def result():
    return case.run(case.Params.quick())


#: An open finding, kept visible instead of hidden: the PolyPIC trajectory's mode difference stays at
#: 1e-15 for 12 steps, then jumps (5.1e-12 at step 13, 2.4e-10 at step 15, back to 6e-12 at step 16)
#: while x, v and F stay within 2e-13. Cause (measured): at step 12-14 a particle's smallest per-axis
#: B-spline weight falls to 8.8e-9, then 7.8e-11 (it sits almost on a cell face). PolyPIC's top modes are
#: then ill-conditioned: their coefficients divide by stencil norms that go to zero with that weight, and
#: their node values come out of a cancellation, so round-off in them grows like eps / w_min, not eps. It
#: is not a backend disagreement: the reference run from x (1 + 2^-52) jumps at the same step (1e-13 ->
#: 3.8e-12, fixed_corotated.modes), and no wall or yield branch is involved. The n·1e-12 bound assumes
#: well-conditioned steps, which PolyPIC's top modes are not near cell faces; a bound scaled by the
#: measured conditioning is the mend, not yet built. Every other check must pass; this one may fail.
KNOWN_FAILURE = "2D quadratic PolyPIC: 20-step trajectory, max relative difference (fixed_corotated.modes)"


def test_every_check_of_the_quick_preset_holds_but_the_known_polypic_branch(result):
    failing = [c.name for c in failed(case.checks(result))]
    assert set(failing) <= {KNOWN_FAILURE}, "\n".join(failing)


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
    assert [line for line in text.splitlines() if "FAIL" in line and KNOWN_FAILURE not in line] == []
    assert_every_figure_has_a_caption(tmp_path)
    assert case.backends_run(result) == ("numpy", "numba")
