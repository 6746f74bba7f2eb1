"""The momentum case (verification/momentum.py): its quick preset, a broken transfer, its report."""

from dataclasses import replace

import numpy as np
import pytest

from mpmref.backends.numpy import backend as numpy_backend
from verification import momentum as case
from verification.framework.common import failed


@pytest.fixture(scope="module")
def result():
    return case.run(case.Params.quick())


def test_every_check_of_the_quick_preset_holds(result):
    failing = [c.line() for c in failed(case.checks(result))]
    assert not failing, "\n".join(failing)


def test_every_variant_has_a_linear_and_an_angular_check(result):
    names = [c.name for c in case.checks(result)]
    for v in case.VARIANTS:
        assert sum(name.startswith(v.label + ":") for name in names) == 2, v.label


@pytest.mark.parametrize("key", ["pic", "flip"])
def test_pic_and_flip_lose_spin_at_the_predicted_rate(result, key):
    """The measured loss per step is within 25 % of (1-α)·2DM/I (measured: PIC +6 %, FLIP(0.95) +15 %)."""
    r, v = result["runs"][key], case.VARIANT[key]
    measured = case.decay_rate(case.spin(r) / case.spin(r)[0])
    predicted = v.pic_fraction * r["spin_loss_rate"]
    assert abs(measured / predicted - 1.0) <= 0.25


def test_dropping_the_affine_term_in_p2g_fails_the_angular_momentum_check(monkeypatch):
    """MLS-MPM whose P2G ignores C_p (a broken APIC transfer) must fail angular momentum, not linear."""
    original, original_fused = numpy_backend.NumpyBackend.p2g, numpy_backend.NumpyBackend.p2g_fused

    def p2g_without_affine(self, particles, prepared=None):
        return original(self, particles.with_(C=np.zeros_like(particles.C)), prepared)

    def p2g_fused_without_affine(self, particles, dt, prepared=None):  # the P2G the steps run
        return original_fused(self, particles.with_(C=np.zeros_like(particles.C)), dt, prepared)

    monkeypatch.setattr(numpy_backend.NumpyBackend, "p2g", p2g_without_affine)
    monkeypatch.setattr(numpy_backend.NumpyBackend, "p2g_fused", p2g_fused_without_affine)
    broken = case.checks(case.run(replace(case.Params.quick(), steps=40, variants=("mls",))))
    linear = next(c for c in broken if "linear momentum" in c.name)
    angular = next(c for c in broken if "angular momentum" in c.name)
    assert linear.passed  # the affine term of P2G sums to zero over the nodes: P is unaffected
    assert not angular.passed and angular.value > 1e6 * angular.bound


def test_report_writes_plots_vtk_series_and_table(result, tmp_path):
    paths = case.report(result, tmp_path)
    assert all(p.exists() for p in paths)
    assert (tmp_path / "momentum_drift.png").stat().st_size > 10_000
    for key in case.Params.quick().variants:
        pvd = (tmp_path / "vtk" / key / "particles.pvd").read_text()
        assert pvd.count("<DataSet") == case.Params.quick().frames + 1
    text = (tmp_path / "momentum.md").read_text()
    assert all(f"| {v.label} |" in text for v in case.VARIANTS) and "FAIL" not in text
