"""The convergence case (verification/convergence/__init__.py) in its quick preset, and the pieces it stands on."""

import math
from dataclasses import replace

import numpy as np
import pytest
from helpers import assert_every_figure_has_a_caption

from mpmref import SceneBuilder, Simulation
from mpmref.backends import make_backend
from mpmref.physics.materials import NeoHookean
from mpmref.scene.sampling import sample_particles
from verification import convergence as case
from verification.convergence.problems import AxisAlignedMMS, VibratingBar
from verification.convergence.stepping import advance
from verification.framework.common import failed


@pytest.fixture(scope="module")
def result():
    return case.run(case.Params.quick())


def test_every_check_of_the_quick_preset_holds(result):
    failing = [c.line() for c in failed(case.checks(result))]
    assert not failing, "\n".join(failing)


def test_every_series_with_an_expected_rate_is_checked(result):
    names = [c.name for c in case.checks(result)]
    judged = [r["series"] for r in result["rows"] if r["series"].expected_rate is not None]
    assert len(names) == 2 * len(judged) and len(judged) >= 5


def test_zeroing_the_nodes_at_the_fixed_end_fails_the_rate_two_check():
    """The crude fixed end (v_i = 0 for x_i <= 0) shifts the boundary by O(Δx): first order, so the check fails."""
    series = case.Series("bar", "apic", "classic", "quadratic", fixed_end="zero")
    broken = case.run(replace(case.Params.quick(), series=(series,)))
    slope = broken["rows"][0]["slope_u"]
    assert 0.7 < slope < 1.3
    failing = [c.name for c in failed(case.checks(broken))]
    assert any("fitted slope" in name for name in failing)


def _bar_start(bar, cells, method, dt):
    scene = bar.scene(cells, method, ppa=2)
    particles = sample_particles(scene)
    return scene, particles.x.copy(), case.initial_particles(bar, particles, dt)


def test_the_mirror_treatment_is_the_doubled_bar_run_by_the_engine():
    """Odd ghosts across x = 0 == the bar of length 2L on [-L, L] with no boundary, stepped by Simulation."""
    bar, cells, dt, steps = VibratingBar(), 16, 0.05, 20
    method = {"scheme": "apic", "force": "classic", "kernel": "quadratic"}
    scene, X, particles = _bar_start(bar, cells, method, dt)
    backend = make_backend("numpy", scene)
    for n in range(steps):
        particles = advance(backend, particles, dt, n * dt, bar.planes(cells), "mirror")

    dx = bar.length / cells
    doubled = (SceneBuilder(dim=2).grid(size=[2 * bar.length + 8 * dx, 4 * dx], dx=dx,
                                        origin=[-bar.length - 4 * dx, -2 * dx])
               .method(**method).material("bar", "fixed_corotated", E=bar.E, nu=0.0, rho=bar.rho)
               .box("bar", lower=[-bar.length, 0.0], upper=[bar.length, dx], ppc=4).walls("open", width=0)
               .time(dt=dt).build())
    sim = Simulation(doubled)
    sim.v, sim.C = bar.velocity(sim.x, -dt / 2), bar.velocity_gradient(sim.x, -dt / 2)
    right = sim.x[:, 0] > 0
    assert np.allclose(sim.x[right], X)  # same particles on the material side, same order
    for _ in range(steps):
        sim.step()
    assert np.max(np.abs(sim.x[right] - particles.x)) < 1e-12
    assert np.max(np.abs(sim.v[right] - particles.v)) < 1e-12


def test_the_strip_stays_one_dimensional():
    """Open transverse sides, ν = 0: no transverse motion, and both particle rows carry the same state."""
    bar, cells, dt = VibratingBar(), 16, 0.05
    scene, X, particles = _bar_start(bar, cells, {"scheme": "mls", "kernel": "cubic"}, dt)
    backend = make_backend("numpy", scene)
    for n in range(20):
        particles = advance(backend, particles, dt, n * dt, bar.planes(cells), "mirror")
    assert np.max(np.abs(particles.v[:, 1])) < 1e-14
    rows = [np.isclose(X[:, 1], y) for y in np.unique(X[:, 1])]
    assert len(rows) == 2
    assert np.max(np.abs(particles.x[rows[0], 0] - particles.x[rows[1], 0])) < 1e-13


def test_the_manufactured_body_force_balances_the_engine_stress():
    """b = ü - (1/ρ0) ∇·P, with ∇·P by central differences of the engine's Neo-Hookean P(F(X, t))."""
    mms = AxisAlignedMMS(amplitude=0.05)
    material = NeoHookean(E=mms.E, nu=mms.nu, rho=mms.rho)
    rng = np.random.default_rng(5)
    X, t, h = rng.random((7, 2)), 0.3 / mms.c, 1e-5

    def piola(X):
        F = np.einsum("na,ab->nab", 1.0 + 2 * math.pi * mms.amplitude * np.cos(2 * math.pi * X)
                      * math.sin(mms.c * math.pi * t), np.eye(2))
        return material.first_piola(F)

    div_P = np.zeros_like(X)
    for b in range(2):
        e = np.zeros(2)
        e[b] = h
        div_P += (piola(X + e)[:, :, b] - piola(X - e)[:, :, b]) / (2 * h)
    accel = (mms.displacement(X, t + h) - 2 * mms.displacement(X, t) + mms.displacement(X, t - h)) / h**2
    expected = accel - div_P / mms.rho
    assert np.allclose(mms.body_force(X, t), expected, rtol=1e-5, atol=1e-6 * np.max(np.abs(expected)))


def test_the_report_writes_plots_vtk_and_summary(result, tmp_path):
    path = case.report(result, tmp_path)
    text = path.read_text()
    assert "| APIC quadratic |" in text and "pass" in text and "FAIL" not in text
    for name in ("convergence_bar.png", "convergence_mms.png", "vtk_bar/particles.pvd", "vtk_mms/particles.pvd"):
        assert (tmp_path / name).is_file(), name
    assert len(list((tmp_path / "vtk_bar").glob("particles_*.vtu"))) == case.Params.quick().vtk_frames + 1
    assert_every_figure_has_a_caption(tmp_path)


def test_the_mls_quadratic_bar_slope_is_a_finding_not_a_check(result):
    """The series without an expected rate are findings with their fitted slope; they are not checked."""
    row = next(r for r in result["rows"] if r["series"].problem == "bar" and r["series"].label == "MLS-MPM quadratic")
    finding = next(f for f in case.findings(result) if f.name == "bar: MLS-MPM quadratic: fitted slope of e_u")
    assert finding.value == row["slope_u"] and len(case.findings(result)) == 1 + len(case.ablation_series())
    assert f"Δx^{row['slope_u']:.2f}" in finding.sentence and "MLS force" in finding.sentence
    assert not [c for c in case.checks(result) if "MLS-MPM quadratic" in c.name]


def test_the_ablation_puts_the_first_order_error_in_the_mls_force(result):
    """Force and F update switched apart (quadratic, 2 particles per cell per axis): the MLS force with the
    classic F update keeps MLS-MPM's first order, the classic force with the MLS F update is near second order,
    and MLS-MPM with 4 particles per axis is too. Bounds: halfway between first and second order (1.5) with
    the independent 1D computation's slopes (1.00; 1.69; about 1.9) on either side of it."""
    slope = {(r["series"].force, r["series"].gradient, r["series"].ppa): r["slope_u"] for r in result["rows"]
             if r["series"].problem == "bar" and r["series"].kernel == "quadratic"}
    assert slope[("mls", "classic", None)] < 1.2
    assert slope[("mls", None, None)] < 1.2
    assert slope[("classic", "mls", None)] > 1.5
    assert slope[("mls", None, 4)] > 1.7
