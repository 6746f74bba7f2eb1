"""Constitutive models (mpmref.physics.materials).

Every check compares against an independently derived value: a finite-difference derivative of the
energy, the hand-derived energy/stress of a simple deformation, a rotation applied by the test, or a
closed-form formula written out here (Lamé parameters, wave speeds, mpm88's pressure term).
"""

import math
import warnings
from pathlib import Path

import numpy as np
import pytest
from helpers import fd_gradient, independent_lame, random_deformations
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from mpmref.physics.catalogue import MATERIALS
from mpmref.physics.materials import (
    FixedCorotated,
    NeoHookean,
    WeaklyCompressibleFluid,
    lame_parameters,
    polar_rotation,
)

E, NU, RHO = 1.0e3, 0.3, 2.0
SOLIDS = [FixedCorotated(E=E, nu=NU, rho=RHO), NeoHookean(E=E, nu=NU, rho=RHO)]
SOLID_IDS = ["fixed_corotated", "neo_hookean"]
FLUIDS = [WeaklyCompressibleFluid(K=400.0, gamma=1.0, rho=1.0), WeaklyCompressibleFluid(K=50.0, gamma=7.0, rho=1.5)]
FLUID_IDS = ["fluid_gamma1", "fluid_gamma7"]


def _rot2(theta):
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s], [s, c]])


def _fluid_energy_of_F(mat):
    return lambda F: mat.energy_density(np.linalg.det(F))


def _fluid_tau_of_F(mat, F):
    return mat.kirchhoff_stress_from_J(np.linalg.det(F), F.shape[1])


# --------------------------------------------------------------------------------------------------
# P = dPsi/dF by finite differences
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("mat", SOLIDS, ids=SOLID_IDS)
@pytest.mark.parametrize("dim", [2, 3])
def test_solid_first_piola_is_energy_gradient(mat, dim):
    rng = np.random.default_rng(11 * dim + len(type(mat).__name__))
    F = random_deformations(rng, 40, dim, scale=0.3)
    h = 1e-6 * max(1.0, float(np.abs(F).max()))
    P_fd = fd_gradient(mat.energy_density, F, h)
    P = mat.first_piola(F)
    scale = np.linalg.norm(P_fd, axis=(1, 2))
    err = np.linalg.norm(P - P_fd, axis=(1, 2))
    assert np.all(err <= 1e-6 * np.maximum(scale, mat.mu * 1e-3)), err.max()
    # tau = P F^T from the finite-difference P, too
    tau_fd = P_fd @ F.transpose(0, 2, 1)
    tau = mat.kirchhoff_stress(F)
    err_tau = np.linalg.norm(tau - tau_fd, axis=(1, 2))
    assert np.all(err_tau <= 1e-6 * np.maximum(np.linalg.norm(tau_fd, axis=(1, 2)), mat.mu * 1e-3))


@pytest.mark.parametrize("dim", [2, 3])
def test_fixed_corotated_first_piola_inverted_elements(dim):
    """Fixed-corotated is defined for det F < 0 (signed singular values); P must still be dPsi/dF."""
    mat = SOLIDS[0]
    rng = np.random.default_rng(77 + dim)
    F = random_deformations(rng, 30, dim, scale=0.3)
    F[:, 0, :] *= -1.0  # reflect: det F < 0
    assert np.all(np.linalg.det(F) < 0)
    P_fd = fd_gradient(mat.energy_density, F, 1e-6)
    P = mat.first_piola(F)
    err = np.linalg.norm(P - P_fd, axis=(1, 2))
    assert np.all(err <= 1e-6 * np.linalg.norm(P_fd, axis=(1, 2))), err.max()


@pytest.mark.parametrize("mat", FLUIDS, ids=FLUID_IDS)
@pytest.mark.parametrize("dim", [2, 3])
def test_fluid_stress_is_energy_gradient(mat, dim):
    rng = np.random.default_rng(5 * dim + int(mat.gamma))
    F = random_deformations(rng, 40, dim, min_det=0.4, scale=0.3)
    h = 1e-6
    P_fd = fd_gradient(_fluid_energy_of_F(mat), F, h)
    tau = _fluid_tau_of_F(mat, F)
    P = tau @ np.linalg.inv(F).transpose(0, 2, 1)
    scale = np.linalg.norm(P_fd, axis=(1, 2))
    err = np.linalg.norm(P - P_fd, axis=(1, 2))
    assert np.all(err <= 1e-6 * np.maximum(scale, mat.K * 1e-3)), err.max()


@pytest.mark.parametrize("mat", FLUIDS, ids=FLUID_IDS)
def test_fluid_pressure_is_minus_dpsi_dJ(mat):
    J = np.linspace(0.5, 1.6, 23)
    h = 1e-6
    dpsi = (mat.energy_density(J + h) - mat.energy_density(J - h)) / (2.0 * h)
    np.testing.assert_allclose(-dpsi, mat.pressure(J), rtol=1e-6, atol=1e-6 * mat.K)


# --------------------------------------------------------------------------------------------------
# Rotation invariance and objectivity
# --------------------------------------------------------------------------------------------------

_perturb = st.floats(min_value=-0.3, max_value=0.3, allow_nan=False, allow_infinity=False)
_entry = st.floats(min_value=-1.0, max_value=1.0, allow_nan=False, allow_infinity=False)


def _rot3_from(entries):
    """Proper rotation from the QR decomposition of a 3x3 matrix (signs fixed, det forced to +1)."""
    A = np.asarray(entries, dtype=float).reshape(3, 3)
    Q, Rr = np.linalg.qr(A)
    Q = Q * np.sign(np.diag(Rr))[None, :]
    if np.linalg.det(Q) < 0:
        Q[:, 0] *= -1.0
    return Q


def _well_conditioned(entries):
    """Reject (near-)singular draws before QR so the drawn rotation is well defined."""
    A = np.asarray(entries, dtype=float).reshape(3, 3)
    sv = np.linalg.svd(A, compute_uv=False)
    return sv[-1] > 0.05


def _check_invariance(mat, F, R):
    F = F[None]
    RF = R[None] @ F
    psi = mat.energy_density(F)[0]
    psi_r = mat.energy_density(RF)[0]
    assert abs(psi_r - psi) <= 1e-10 * max(abs(psi), mat.mu * 1e-3)
    tau = mat.kirchhoff_stress(F)[0]
    tau_r = mat.kirchhoff_stress(RF)[0]
    expected = R @ tau @ R.T
    assert np.linalg.norm(tau_r - expected) <= 1e-10 * max(np.linalg.norm(tau), mat.mu * 1e-3)


@settings(derandomize=True, max_examples=50, deadline=None)
@given(
    theta=st.floats(min_value=-math.pi, max_value=math.pi, allow_nan=False, allow_infinity=False),
    p=st.lists(_perturb, min_size=4, max_size=4),
)
@pytest.mark.parametrize("mat", SOLIDS, ids=SOLID_IDS)
def test_solid_rotation_invariance_2d(mat, theta, p):
    F = np.eye(2) + np.asarray(p).reshape(2, 2)
    assume(np.linalg.det(F) > 0.2)
    R = _rot2(theta)
    # sanity of the test's own rotation
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-14)
    _check_invariance(mat, F, R)


@settings(derandomize=True, max_examples=50, deadline=None)
@given(
    a=st.lists(_entry, min_size=9, max_size=9),
    p=st.lists(_perturb, min_size=9, max_size=9),
)
@pytest.mark.parametrize("mat", SOLIDS, ids=SOLID_IDS)
def test_solid_rotation_invariance_3d(mat, a, p):
    assume(_well_conditioned(a))
    F = np.eye(3) + np.asarray(p).reshape(3, 3)
    assume(np.linalg.det(F) > 0.2)
    R = _rot3_from(a)
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-12)
    _check_invariance(mat, F, R)


@settings(derandomize=True, max_examples=50, deadline=None)
@given(
    a=st.lists(_entry, min_size=9, max_size=9),
    p=st.lists(_perturb, min_size=9, max_size=9),
    gamma=st.sampled_from([1.0, 7.0]),
)
def test_fluid_rotation_invariance_3d(a, p, gamma):
    assume(_well_conditioned(a))
    mat = WeaklyCompressibleFluid(K=100.0, gamma=gamma, rho=1.0)
    F = (np.eye(3) + np.asarray(p).reshape(3, 3))[None]
    assume(np.linalg.det(F[0]) > 0.2)
    R = _rot3_from(a)
    RF = R[None] @ F
    psi = mat.energy_density(np.linalg.det(F))[0]
    psi_r = mat.energy_density(np.linalg.det(RF))[0]
    assert abs(psi_r - psi) <= 1e-10 * max(abs(psi), 1e-3 * mat.K)
    tau = _fluid_tau_of_F(mat, F)[0]
    tau_r = _fluid_tau_of_F(mat, RF)[0]
    assert np.linalg.norm(tau_r - R @ tau @ R.T) <= 1e-10 * max(np.linalg.norm(tau), 1e-3 * mat.K)


# --------------------------------------------------------------------------------------------------
# Rest state and closed-form values
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("mat", SOLIDS, ids=SOLID_IDS)
@pytest.mark.parametrize("dim", [2, 3])
def test_solid_rest_state(mat, dim):
    F = np.broadcast_to(np.eye(dim), (3, dim, dim)).copy()
    np.testing.assert_allclose(mat.energy_density(F), 0.0, atol=1e-12 * E)
    np.testing.assert_allclose(mat.kirchhoff_stress(F), 0.0, atol=1e-12 * E)
    np.testing.assert_allclose(mat.first_piola(F), 0.0, atol=1e-12 * E)


@pytest.mark.parametrize("mat", FLUIDS, ids=FLUID_IDS)
@pytest.mark.parametrize("dim", [2, 3])
def test_fluid_rest_state(mat, dim):
    J = np.ones(4)
    np.testing.assert_allclose(mat.energy_density(J), 0.0, atol=1e-12 * mat.K)
    np.testing.assert_allclose(mat.pressure(J), 0.0, atol=1e-12 * mat.K)
    np.testing.assert_allclose(mat.kirchhoff_stress_from_J(J, dim), 0.0, atol=1e-12 * mat.K)


@pytest.mark.parametrize("dim", [2, 3])
def test_fixed_corotated_uniaxial_stretch(dim):
    """F = diag(s, 1, ..): sigma = (s, 1, ..), R = I, J = s.

    Psi = mu (s-1)^2 + lam/2 (s-1)^2;  tau = 2 mu (F - I) F^T + lam (s-1) s I.
    """
    mat = SOLIDS[0]
    mu, lam = independent_lame(E, NU)
    s = np.array([0.7, 1.0, 1.3, 2.0])
    F = np.zeros((len(s), dim, dim))
    F[:] = np.eye(dim)
    F[:, 0, 0] = s
    np.testing.assert_allclose(mat.energy_density(F), (mu + 0.5 * lam) * (s - 1.0) ** 2, rtol=1e-12, atol=1e-12)
    tau = mat.kirchhoff_stress(F)
    expected = np.zeros_like(F)
    expected[:] = np.eye(dim)
    expected *= (lam * (s - 1.0) * s)[:, None, None]
    expected[:, 0, 0] += 2.0 * mu * (s - 1.0) * s
    np.testing.assert_allclose(tau, expected, rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize("dim", [2, 3])
def test_neo_hookean_uniaxial_stretch(dim):
    """F = diag(s, 1, ..): tr(F^T F) - d = s^2 - 1, J = s.

    Psi = mu/2 (s^2 - 1) - mu ln s + lam/2 (ln s)^2;  tau = mu (F F^T - I) + lam ln s I.
    """
    mat = SOLIDS[1]
    mu, lam = independent_lame(E, NU)
    s = np.array([0.7, 1.0, 1.3, 2.0])
    F = np.zeros((len(s), dim, dim))
    F[:] = np.eye(dim)
    F[:, 0, 0] = s
    ls = np.log(s)
    np.testing.assert_allclose(
        mat.energy_density(F), 0.5 * mu * (s**2 - 1.0) - mu * ls + 0.5 * lam * ls**2, rtol=1e-12, atol=1e-10
    )
    expected = np.zeros_like(F)
    expected[:] = np.eye(dim)
    expected *= (lam * ls)[:, None, None]
    expected[:, 0, 0] += mu * (s**2 - 1.0)
    np.testing.assert_allclose(mat.kirchhoff_stress(F), expected, rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize("dim", [2, 3])
def test_fluid_gamma1_matches_mpm88_pressure_term(dim):
    """mpm88: stress = -dt * 4 * E * p_vol * (J - 1) / dx^2 with E = 400, i.e. tau = 400 (J - 1) I."""
    mat = WeaklyCompressibleFluid(K=400.0, gamma=1.0, rho=1.0)
    J = np.array([0.5, 0.9, 0.99, 1.0, 1.01, 1.2, 1.7])
    tau = mat.kirchhoff_stress_from_J(J, dim)
    expected = 400.0 * (J - 1.0)[:, None, None] * np.eye(dim)
    np.testing.assert_allclose(tau, expected, rtol=1e-13, atol=1e-12)
    # the MLS-MPM force term of mpm88 with arbitrary dt, p_vol, dx
    dt, p_vol, dx = 2e-4, (0.5 / 128) ** 2, 1.0 / 128
    mpm88_stress = -dt * 4 * 400.0 * p_vol * (J - 1.0) / dx**2
    np.testing.assert_allclose(-dt * p_vol * 4.0 / dx**2 * tau[:, 0, 0], mpm88_stress, rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("K,gamma", [(400.0, 1.0), (50.0, 7.0), (2.0e3, 3.0)])
def test_fluid_pressure_formula(K, gamma):
    mat = WeaklyCompressibleFluid(K=K, gamma=gamma, rho=1.0)
    J = np.array([0.5, 0.8, 1.0, 1.25, 2.0])
    expected = np.array([K * (j ** (-gamma) - 1.0) for j in J])
    np.testing.assert_allclose(mat.pressure(J), expected, rtol=1e-13, atol=1e-12 * K)
    # tau = -p J I = K (J - J^(1-gamma)) I
    tau = mat.kirchhoff_stress_from_J(J, 3)
    np.testing.assert_allclose(
        tau, (K * (J - J ** (1.0 - gamma)))[:, None, None] * np.eye(3), rtol=1e-12, atol=1e-12 * K
    )
    # gamma = 7 spot values: p(0.5) = K (2^7 - 1) = 127 K
    if gamma == 7.0:
        assert mat.pressure(np.array([0.5]))[0] == pytest.approx(127.0 * K, rel=1e-14)


# --------------------------------------------------------------------------------------------------
# Wave speeds and Lamé parameters
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("cls", [FixedCorotated, NeoHookean])
@pytest.mark.parametrize("E_,nu_,rho_", [(1.0e3, 0.3, 2.0), (5.0e4, 0.2, 1000.0), (10.0, 0.45, 0.5), (7.0, 0.0, 3.0)])
def test_solid_wave_speed(cls, E_, nu_, rho_):
    mat = cls(E=E_, nu=nu_, rho=rho_)
    # P-wave modulus M = lam + 2 mu = E (1 - nu) / ((1 + nu)(1 - 2 nu))
    M = E_ * (1.0 - nu_) / ((1.0 + nu_) * (1.0 - 2.0 * nu_))
    assert mat.wave_speed() == pytest.approx(math.sqrt(M / rho_), rel=1e-13)
    mu, lam = independent_lame(E_, nu_)
    mu_c, lam_c = lame_parameters(E_, nu_)
    assert mu_c == pytest.approx(mu, rel=1e-14)
    assert lam_c == pytest.approx(lam, rel=1e-14, abs=1e-300)
    assert mat.mu == pytest.approx(mu, rel=1e-14)
    assert mat.lam == pytest.approx(lam, rel=1e-14, abs=1e-300)


def test_lame_parameters_known_values():
    # E = 1, nu = 0.25: mu = 1/2.5 = 0.4, lam = 0.25 / (1.25 * 0.5) = 0.4
    mu, lam = lame_parameters(1.0, 0.25)
    assert mu == pytest.approx(0.4, rel=1e-15)
    assert lam == pytest.approx(0.4, rel=1e-15)


@pytest.mark.parametrize("K,gamma,rho", [(400.0, 1.0, 1.0), (50.0, 7.0, 1.5), (2.2e9, 7.0, 1000.0)])
def test_fluid_wave_speed(K, gamma, rho):
    mat = WeaklyCompressibleFluid(K=K, gamma=gamma, rho=rho)
    assert mat.wave_speed() == pytest.approx(math.sqrt(gamma * K / rho), rel=1e-14)
    # independent route: bulk modulus -J dp/dJ at J = 1 by finite differences
    h = 1e-6
    bulk = -(mat.pressure(np.array([1.0 + h])) - mat.pressure(np.array([1.0 - h])))[0] / (2.0 * h)
    assert mat.wave_speed() == pytest.approx(math.sqrt(bulk / rho), rel=1e-6)


# --------------------------------------------------------------------------------------------------
# Polar decomposition
# --------------------------------------------------------------------------------------------------


def _check_polar(F):
    R, sigma = polar_rotation(F.copy())
    n, d, _ = F.shape
    eye = np.broadcast_to(np.eye(d), (n, d, d))
    np.testing.assert_allclose(R.transpose(0, 2, 1) @ R, eye, atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    S = R.transpose(0, 2, 1) @ F
    np.testing.assert_allclose(S, S.transpose(0, 2, 1), atol=1e-12 * np.abs(F).max())
    np.testing.assert_allclose(R @ S, F, atol=1e-12 * np.abs(F).max())
    # signed singular values: |sigma| are the singular values, prod(sigma) = det F
    np.testing.assert_allclose(np.sort(np.abs(sigma), axis=1), np.sort(np.linalg.svd(F, compute_uv=False), axis=1),
                               rtol=1e-12)
    np.testing.assert_allclose(np.prod(sigma, axis=1), np.linalg.det(F), rtol=1e-10, atol=1e-14)
    # eigenvalues of the symmetric factor S are the signed singular values
    np.testing.assert_allclose(np.sort(np.linalg.eigvalsh(0.5 * (S + S.transpose(0, 2, 1))), axis=1),
                               np.sort(sigma, axis=1), rtol=1e-10, atol=1e-12)
    return R, sigma


@pytest.mark.parametrize("dim", [2, 3])
def test_polar_rotation_random(dim):
    rng = np.random.default_rng(42 + dim)
    F = np.eye(dim) + 0.5 * rng.standard_normal((60, dim, dim))
    # include some inverted elements explicitly (reflect the first row)
    F[:20, 0, :] *= -1.0
    assert np.any(np.linalg.det(F) < 0) and np.any(np.linalg.det(F) > 0)
    _check_polar(F)


@pytest.mark.parametrize("dim", [2, 3])
def test_polar_rotation_recovers_known_factors(dim):
    """F = Q S0 with a known rotation Q and SPD S0 returns R = Q."""
    rng = np.random.default_rng(1234 + dim)
    if dim == 2:
        Q = np.array([_rot2(t) for t in rng.uniform(-math.pi, math.pi, 10)])
    else:
        Q = np.array([_rot3_from(rng.uniform(-1, 1, 9)) for _ in range(10)])
    A = rng.uniform(-0.3, 0.3, size=(10, dim, dim))
    S0 = np.eye(dim) + 0.5 * (A + A.transpose(0, 2, 1))
    assert np.all(np.linalg.eigvalsh(S0) > 0)
    R, sigma = _check_polar(Q @ S0)
    np.testing.assert_allclose(R, Q, atol=1e-12)
    np.testing.assert_allclose(np.sort(sigma, axis=1), np.linalg.eigvalsh(S0), rtol=1e-12)


@pytest.mark.parametrize("dim", [2, 3])
def test_polar_rotation_inverted_element(dim):
    """An inverted element F = diag(-2, 1, ..): R must be proper, so S gets one negative eigenvalue."""
    F = np.eye(dim)[None].copy()
    F[0, 0, 0] = -2.0
    R, sigma = _check_polar(F)
    assert np.linalg.det(R[0]) == pytest.approx(1.0, abs=1e-13)
    assert np.prod(sigma[0]) == pytest.approx(-2.0, rel=1e-13)
    assert np.sum(sigma[0] < 0) == 1
    # fixed-corotated energy of the inverted element uses the signed sigma:
    # the negative entry must be the smallest-magnitude one (Irving et al. 2004), so sigma = (-1, 2[, 1])
    # and Psi = mu ((-1-1)^2 + (2-1)^2) + lam/2 (-2-1)^2  (for d = 3 the extra sigma = 1 adds 0)
    mu, lam = independent_lame(E, NU)
    np.testing.assert_allclose(np.sort(sigma[0]), np.sort([-1.0, 2.0] + [1.0] * (dim - 2)), atol=1e-13)
    psi = SOLIDS[0].energy_density(F)[0]
    assert psi == pytest.approx(mu * (4.0 + 1.0) + 0.5 * lam * 9.0, rel=1e-12)


def test_polar_rotation_does_not_modify_input():
    F = np.array([[[-1.0, 0.2], [0.1, 1.5]]])
    F0 = F.copy()
    polar_rotation(F)
    np.testing.assert_array_equal(F, F0)


# -------------------------------------------------------------------------- an inverted or collapsed particle
def test_an_inverted_or_collapsed_particle_has_no_log_and_numpy_says_nothing():
    """ln J is not defined for J <= 0: the Neo-Hookean stress and energy and the γ = 1 fluid's energy are NaN (J < 0)
    or infinite (J = 0) there, as the Numba backend's are, and NumPy's RuntimeWarning ("invalid value encountered in
    log") does not reach the user: the run reports the non-finite state itself."""
    inverted = np.array([[[-1.0, 0.0], [0.0, 1.0]], [[0.0, 0.0], [0.0, 1.0]], [[1.1, 0.0], [0.0, 0.9]]])
    fluid = WeaklyCompressibleFluid(K=400.0, gamma=1.0, rho=1.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        tau = NeoHookean(E=E, nu=NU, rho=RHO).kirchhoff_stress(inverted)
        energy = NeoHookean(E=E, nu=NU, rho=RHO).energy_density(inverted)
        fluid_energy = fluid.energy_density(np.array([-0.5, 0.0, 0.99]))
    assert np.isnan(tau[0]).any() and not np.isfinite(tau[1]).all() and np.isfinite(tau[2]).all()
    assert np.isnan(energy[0]) and not np.isfinite(energy[1]) and np.isfinite(energy[2])
    assert np.isnan(fluid_energy[0]) and not np.isfinite(fluid_energy[1]) and np.isfinite(fluid_energy[2])


def test_a_neo_hookean_scene_that_blows_up_stops_with_its_own_error_only(tmp_path, capsys):
    """The docs' rubber disk (Neo-Hookean) at Δt = 0.005, a CFL number of 6: its particles invert and the run stops
    with exit status 3 and a NonFiniteError; standard error has the run's own lines and no NumPy warning."""
    from mpmref.cli import main

    root = Path(__file__).resolve().parent.parent
    scene = tmp_path / "disk.toml"
    scene.write_text((root / "docs" / "breathing_disk.toml").read_text().replace("cfl = 0.4", "dt = 0.005"))
    assert main(["run", str(scene), "--out", str(tmp_path / "out"), "--no-progress"]) == 3
    err = capsys.readouterr().err
    assert "NonFiniteError" in err and "encountered" not in err, err


@pytest.mark.parametrize("kind", sorted(MATERIALS))
@pytest.mark.parametrize("rho,c", [(1.0, 36.7), (1000.0, 1.16), (2.5, 4.0e3)])
def test_a_material_made_for_a_wave_speed_has_that_speed_and_keeps_what_is_given(kind, rho, c):
    """``with_wave_speed``: the material of each type with the density and rest P-wave speed asked for, whatever
    parameters are given beside (a code's fixed ones), is valid and has that speed; a given stiffness is kept."""
    cls = MATERIALS[kind]
    given = {"gamma": 1.0} if kind == "fluid" else {"nu": 0.2}
    material = cls(**cls.with_wave_speed(rho, c, given))
    assert material.rho == rho and material.wave_speed() == pytest.approx(c, rel=1e-13)
    assert all(getattr(material, k) == v for k, v in given.items())
    stiffness = "K" if kind == "fluid" else "E"
    assert cls.with_wave_speed(rho, c, {stiffness: 7.0})[stiffness] == 7.0
