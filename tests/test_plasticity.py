"""Elastoplastic materials (mpmref.physics.plasticity): snow and Drucker-Prager sand.

Every check compares against an independently derived value: a finite-difference derivative of the
energy, a rotation applied by the test, NumPy's own SVD of the input, or a hand-derived return-map result
for a simple deformation (the derivation is written next to each case).
"""

import math

import numpy as np
import pytest
from helpers import fd_gradient, independent_lame, random_deformations

from mpmref.physics.plasticity import DruckerPragerSand, SnowPlasticity

E, NU, RHO = 1.0e3, 0.3, 2.0
SNOW = SnowPlasticity(E=E, nu=NU, rho=RHO)
SAND = DruckerPragerSand(E=E, nu=NU, rho=RHO)
MODELS = [SNOW, SAND]
MODEL_IDS = ["snow", "sand"]
SANDS = [SAND, DruckerPragerSand(E=E, nu=NU, rho=RHO, friction_angle=45.0, cohesion=0.02),
         DruckerPragerSand(E=E, nu=0.25, rho=RHO, friction_angle=0.0)]
SAND_IDS = ["phi30", "phi45_cohesive", "phi0"]


def _random_rotations(rng, n, dim):
    """Proper rotations from the QR decomposition of Gaussian matrices (signs fixed, det forced to +1)."""
    Q, Rr = np.linalg.qr(rng.standard_normal((n, dim, dim)))
    Q = Q * np.sign(np.diagonal(Rr, axis1=1, axis2=2))[:, None, :]
    Q[np.linalg.det(Q) < 0, :, 0] *= -1.0
    return Q


def _rotated_diag(rng, diag):
    """Q diag(diag) W^T with random rotations Q, W: singular values ``diag`` in known directions."""
    n, dim = diag.shape
    Q, W = _random_rotations(rng, n, dim), _random_rotations(rng, n, dim)
    return Q @ (diag[:, :, None] * W.transpose(0, 2, 1)), Q, W


def _cone(mat, F_new, dim):
    """Shifted trace tr(eps) - d c and yield value ||dev eps|| + alpha (d lam + 2 mu)/(2 mu) (tr eps - d c).

    Computed from NumPy's plain SVD of the mapped F (positive singular values), with alpha and the Lamé
    parameters written out here.
    """
    mu, lam = independent_lame(mat.E, mat.nu)
    s = math.sin(math.radians(mat.friction_angle))
    alpha = math.sqrt(2.0 / 3.0) * 2.0 * s / (3.0 - s)
    eps = np.log(np.linalg.svd(F_new, compute_uv=False))
    tr = eps.sum(axis=1) - dim * mat.cohesion
    dev = eps - eps.mean(axis=1, keepdims=True)
    return eps, tr, np.linalg.norm(dev, axis=1) + alpha * (dim * lam + 2.0 * mu) / (2.0 * mu) * tr


# --------------------------------------------------------------------------------------------------
# Both models: energy gradient, invariance, rest state, dtype
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("mat", MODELS, ids=MODEL_IDS)
@pytest.mark.parametrize("dim", [2, 3])
def test_kirchhoff_stress_is_energy_gradient_times_Ft(mat, dim):
    """tau = (dPsi/dF) F^T at fixed Jp, dPsi/dF by central differences."""
    rng = np.random.default_rng(31 * dim + len(MODEL_IDS[MODELS.index(mat)]))
    F = random_deformations(rng, 40, dim, scale=0.2)
    Jp = rng.uniform(0.8, 1.2, 40)
    P_fd = fd_gradient(lambda G: mat.energy_density(G, Jp), F)
    tau_fd = P_fd @ F.transpose(0, 2, 1)
    err = np.linalg.norm(mat.kirchhoff_stress(F, Jp) - tau_fd, axis=(1, 2))
    assert np.all(err <= 1e-6 * np.maximum(np.linalg.norm(tau_fd, axis=(1, 2)), mat.mu * 1e-3)), err.max()


@pytest.mark.parametrize("mat", MODELS, ids=MODEL_IDS)
@pytest.mark.parametrize("dim", [2, 3])
def test_rotation_invariance_and_objectivity(mat, dim):
    """Psi(R F, Jp) = Psi(F, Jp) and tau(R F, Jp) = R tau(F, Jp) R^T for random proper rotations R."""
    rng = np.random.default_rng(500 + dim)
    F = random_deformations(rng, 50, dim, scale=0.3)
    Jp = rng.uniform(0.8, 1.2, 50)
    R = _random_rotations(rng, 50, dim)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    psi = mat.energy_density(F, Jp)
    np.testing.assert_allclose(mat.energy_density(R @ F, Jp), psi, rtol=1e-10, atol=1e-10 * mat.mu)
    tau = mat.kirchhoff_stress(F, Jp)
    expected = R @ tau @ R.transpose(0, 2, 1)
    np.testing.assert_allclose(mat.kirchhoff_stress(R @ F, Jp), expected, rtol=0, atol=1e-10 * mat.mu)


@pytest.mark.parametrize("mat", MODELS, ids=MODEL_IDS)
@pytest.mark.parametrize("dim", [2, 3])
def test_rest_state_is_stress_free(mat, dim):
    F = np.broadcast_to(np.eye(dim), (4, dim, dim)).copy()
    Jp = np.array([0.6, 0.9, 1.0, 1.7])
    np.testing.assert_allclose(mat.energy_density(F, Jp), 0.0, atol=1e-12 * E)
    np.testing.assert_allclose(mat.kirchhoff_stress(F, Jp), 0.0, atol=1e-12 * E)
    F_new, Jp_new = mat.return_map(F, Jp)  # the identity is admissible for both models
    np.testing.assert_array_equal(F_new, F)
    np.testing.assert_array_equal(Jp_new, Jp)


@pytest.mark.parametrize("mat", MODELS, ids=MODEL_IDS)
@pytest.mark.parametrize("dim", [2, 3])
def test_float32_is_preserved(mat, dim):
    rng = np.random.default_rng(9)
    F = random_deformations(rng, 20, dim, scale=0.3).astype(np.float32)
    Jp = rng.uniform(0.8, 1.2, 20).astype(np.float32)
    F_new, Jp_new = mat.return_map(F, Jp)
    for out in (mat.energy_density(F, Jp), mat.kirchhoff_stress(F, Jp), F_new, Jp_new):
        assert out.dtype == np.float32
    np.testing.assert_allclose(mat.kirchhoff_stress(F, Jp), mat.kirchhoff_stress(F.astype(float), Jp.astype(float)),
                               rtol=0, atol=1e-4 * mat.mu * SNOW.hardening_factor(0.8))


# --------------------------------------------------------------------------------------------------
# Snow (Stomakhin et al. 2013)
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("dim", [2, 3])
def test_snow_return_map_clamps_singular_values_and_keeps_U_V(dim):
    rng = np.random.default_rng(70 + dim)
    F = random_deformations(rng, 200, dim, scale=0.1, min_det=0.5)
    Jp = rng.uniform(0.8, 1.2, 200)
    F_new, Jp_new = SNOW.return_map(F, Jp)
    lo, hi = 1.0 - SNOW.theta_c, 1.0 + SNOW.theta_s
    sv_new = np.linalg.svd(F_new, compute_uv=False)
    assert np.all(sv_new >= lo - 1e-12) and np.all(sv_new <= hi + 1e-12)
    # F_new = U clamp(Sigma) V^T with NumPy's own SVD of F (det F > 0, so U V^T is already proper)
    U, s, Vt = np.linalg.svd(F)
    np.testing.assert_allclose(F_new, U @ (np.clip(s, lo, hi)[:, :, None] * Vt), rtol=0, atol=1e-13)
    assert np.any(np.any((s < lo) | (s > hi), axis=1))  # the sample exercises the clamp
    # volume bookkeeping J_P det F_E is conserved where the J_P clamp is inactive ...
    expected = Jp * np.linalg.det(F) / np.linalg.det(F_new)
    free = (expected > SNOW.Jp_min) & (expected < SNOW.Jp_max)
    assert free.sum() > 150
    np.testing.assert_allclose((Jp_new * np.linalg.det(F_new))[free], (Jp * np.linalg.det(F))[free], rtol=1e-12)
    # ... and the clamp sets the bound where it is active
    np.testing.assert_allclose(Jp_new[~free], np.clip(expected[~free], SNOW.Jp_min, SNOW.Jp_max), rtol=1e-14)


@pytest.mark.parametrize("dim", [2, 3])
def test_snow_return_map_leaves_admissible_states_alone(dim):
    rng = np.random.default_rng(80 + dim)
    sigma = rng.uniform(1.0 - SNOW.theta_c, 1.0 + SNOW.theta_s, (50, dim))
    F, _, _ = _rotated_diag(rng, sigma)
    Jp = rng.uniform(0.7, 1.5, 50)
    F_new, Jp_new = SNOW.return_map(F, Jp)
    np.testing.assert_allclose(F_new, F, rtol=0, atol=1e-14)
    np.testing.assert_allclose(Jp_new, Jp, rtol=1e-14)


def test_snow_return_map_hand_cases():
    """Diagonal F, 2D, defaults theta_c = 0.025, theta_s = 0.0075, Jp in [0.6, 20].

    a) F = diag(1.02, 0.95): sigma -> (1.0075, 0.975), Jp = 1 * (1.02 * 0.95) / (1.0075 * 0.975).
    b) F = diag(0.9, 1.0), Jp = 0.61: Jp * 0.9 / 0.975 = 0.5631 < 0.6 -> 0.6.
    c) F = diag(1.1, 1.0), Jp = 19.9: Jp * 1.1 / 1.0075 = 21.73 > 20 -> 20.
    d) inverted F = diag(-1.2, 0.99): polar F = R S with R = -I, S = diag(1.2, -0.99) (signed singular
       values, the negative one the smallest in magnitude), so clamping gives
       F_new = -diag(1.0075, 0.975) (no longer inverted) and Jp * det F / det F_new < 0 -> Jp_min.
    """
    F = np.array([np.diag(v) for v in ([1.02, 0.95], [0.9, 1.0], [1.1, 1.0], [-1.2, 0.99])])
    Jp = np.array([1.0, 0.61, 19.9, 1.0])
    F_new, Jp_new = SNOW.return_map(F, Jp)
    expected_F = np.array([np.diag(v) for v in ([1.0075, 0.975], [0.975, 1.0], [1.0075, 1.0], [-1.0075, -0.975])])
    np.testing.assert_allclose(F_new, expected_F, rtol=0, atol=1e-14)
    np.testing.assert_allclose(Jp_new, [1.02 * 0.95 / (1.0075 * 0.975), 0.6, 20.0, 0.6], rtol=1e-14)


@pytest.mark.parametrize("dim", [2, 3])
def test_snow_hardening(dim):
    """mu(Jp) = mu0 exp(xi (1 - Jp)), lam(Jp) = lam0 exp(xi (1 - Jp)), evaluated on diagonal F = diag(s).

    Psi = mu(Jp) sum (s_i - 1)^2 + lam(Jp)/2 (J - 1)^2;  R = I, so
    tau_ii = 2 mu(Jp) (s_i - 1) s_i + lam(Jp) (J - 1) J.
    """
    mu0, lam0 = independent_lame(E, NU)
    Jp = np.array([0.6, 0.8, 1.0, 1.3, 5.0])
    h = np.array([math.exp(10.0 * (1.0 - j)) for j in Jp])
    np.testing.assert_allclose(SNOW.hardening_factor(Jp), h, rtol=1e-14)
    s = np.array([0.9, 1.05, 1.2][:dim])
    F = np.broadcast_to(np.diag(s), (len(Jp), dim, dim)).copy()
    J = np.prod(s)
    mu, lam = mu0 * h, lam0 * h
    psi = mu * np.sum((s - 1.0) ** 2) + 0.5 * lam * (J - 1.0) ** 2
    np.testing.assert_allclose(SNOW.energy_density(F, Jp), psi, rtol=1e-12)
    tau_diag = 2.0 * mu[:, None] * ((s - 1.0) * s)[None, :] + (lam * (J - 1.0) * J)[:, None]
    np.testing.assert_allclose(SNOW.kirchhoff_stress(F, Jp), tau_diag[:, :, None] * np.eye(dim), rtol=1e-12,
                               atol=1e-12 * E)


@pytest.mark.parametrize("E_,nu_,rho_,xi,jp_min", [(1.0e3, 0.3, 2.0, 10.0, 0.6), (1.4e5, 0.2, 400.0, 10.0, 0.6),
                                                   (50.0, 0.25, 1.0, 0.0, 0.9), (7.0, 0.0, 3.0, 5.0, 1.0)])
def test_snow_wave_speed_is_the_rest_states_and_each_particles_its_own(E_, nu_, rho_, xi, jp_min):
    """The speed a scene starts from is the unhardened one (J_P = 1), whatever the clamp ``Jp_min``; a particle's
    own speed follows its J_P (the hardened P-wave modulus at the current density), so a clamp the particles never
    reach (a code that never clamps declares Jp_min = 1e-300) does not shrink the step."""
    mat = SnowPlasticity(E=E_, nu=nu_, rho=rho_, hardening=xi, Jp_min=jp_min)
    M = E_ * (1.0 - nu_) / ((1.0 + nu_) * (1.0 - 2.0 * nu_))  # P-wave modulus lam + 2 mu
    assert mat.wave_speed() == pytest.approx(math.sqrt(M / rho_), rel=1e-13)
    unclamped = SnowPlasticity(E=E_, nu=nu_, rho=rho_, hardening=xi, Jp_min=1e-300, Jp_max=1e300)
    assert unclamped.wave_speed() == mat.wave_speed()
    F, Jp = np.eye(3)[None].repeat(2, axis=0), np.array([1.0, jp_min])
    J = Jp  # det F_E J_P: the current density is rho / J
    assert mat.wave_speeds(F, Jp) == pytest.approx(np.sqrt(M * np.exp(xi * (1.0 - Jp)) * J / rho_), rel=1e-13)


# --------------------------------------------------------------------------------------------------
# Drucker-Prager sand (Klar et al. 2016)
# --------------------------------------------------------------------------------------------------


def test_sand_alpha_known_values():
    # phi = 30 deg: sin = 1/2, alpha = sqrt(2/3) * 1 / 2.5;  phi = 0: alpha = 0
    assert DruckerPragerSand(E=1.0, nu=0.3, rho=1.0, friction_angle=30.0).alpha == pytest.approx(
        0.4 * math.sqrt(2.0 / 3.0), rel=1e-14)
    assert DruckerPragerSand(E=1.0, nu=0.3, rho=1.0, friction_angle=0.0).alpha == 0.0


@pytest.mark.parametrize("dim", [2, 3])
def test_sand_hencky_energy_and_stress_on_diagonal_F(dim):
    """F = diag(exp(a_i)): eps = a, Psi = mu sum a^2 + lam/2 (sum a)^2, tau = diag(2 mu a_i + lam sum a)."""
    mu, lam = independent_lame(E, NU)
    a = np.array([[0.1, -0.2, 0.05], [-0.3, 0.0, 0.2], [0.0, 0.0, 0.0]])[:, :dim]
    F = np.exp(a)[:, :, None] * np.eye(dim)
    Jp = np.ones(3)
    np.testing.assert_allclose(SAND.energy_density(F, Jp), mu * np.sum(a**2, 1) + 0.5 * lam * a.sum(1) ** 2,
                               rtol=1e-12, atol=1e-12 * E)
    expected = (2.0 * mu * a + lam * a.sum(1, keepdims=True))[:, :, None] * np.eye(dim)
    np.testing.assert_allclose(SAND.kirchhoff_stress(F, Jp), expected, rtol=1e-12, atol=1e-12 * E)


def test_sand_inverted_element_uses_the_singular_value_floor():
    """F = diag(-0.5, 1.2): polar F = R S with R = I and S = F (signed singular values 1.2 and -0.5, the
    negative one the smallest in magnitude). The Hencky strain of -0.5 is taken at the floor 1e-6:
    eps_x = ln 1e-6, eps_y = ln 1.2, so Psi = mu (eps_x^2 + eps_y^2) + lam/2 (eps_x + eps_y)^2 and
    tau = diag(2 mu eps_x + lam tr, 2 mu eps_y + lam tr), a strong compression along x.
    Return map (phi = 30, nu = 0.3: k = (2 lam + 2 mu)/(2 mu) = 2.5): ||dev eps|| = (eps_y - eps_x)/sqrt(2) = 9.90
    < -alpha k tr = 11.13, inside the cone, so F and Jp are kept. A collapsed F (a zero column) gets finite
    energy and stress too."""
    mu, lam = independent_lame(E, NU)
    ex, ey = math.log(1e-6), math.log(1.2)
    F = np.array([np.diag([-0.5, 1.2]), [[1.0, 0.0], [0.3, 0.0]]])
    Jp = np.ones(2)
    psi = SAND.energy_density(F, Jp)
    assert psi[0] == pytest.approx(mu * (ex**2 + ey**2) + 0.5 * lam * (ex + ey) ** 2, rel=1e-12)
    tau = SAND.kirchhoff_stress(F, Jp)
    np.testing.assert_allclose(tau[0], np.diag([2 * mu * ex + lam * (ex + ey), 2 * mu * ey + lam * (ex + ey)]),
                               rtol=1e-12, atol=1e-9)
    assert np.all(np.isfinite(psi)) and np.all(np.isfinite(tau))
    F_new, Jp_new = SAND.return_map(F[:1], Jp[:1])
    np.testing.assert_array_equal(F_new, F[:1])
    np.testing.assert_array_equal(Jp_new, Jp[:1])


@pytest.mark.parametrize("mat", SANDS, ids=SAND_IDS)
@pytest.mark.parametrize("dim", [2, 3])
def test_sand_return_map_lands_in_the_cone(mat, dim):
    """After the map: tr(eps) - d c <= 0 and ||dev eps|| + alpha (d lam + 2 mu)/(2 mu)(tr eps - d c) <= 0;
    states that were in tension sit exactly at the tip eps = c I; the volume bookkeeping holds."""
    rng = np.random.default_rng(600 + dim)
    F = random_deformations(rng, 300, dim, scale=0.3)
    Jp = rng.uniform(0.8, 1.2, 300)
    F_new, Jp_new = mat.return_map(F, Jp)
    eps, tr, y = _cone(mat, F_new, dim)
    assert np.all(tr <= 1e-12) and np.all(y <= 1e-10), (tr.max(), y.max())
    _, tr_before, y_before = _cone(mat, F, dim)
    tension = tr_before > 0
    assert tension.sum() > 20 and (~tension & (y_before > 0)).sum() > 20  # both projection cases occur
    np.testing.assert_allclose(eps[tension], mat.cohesion, rtol=0, atol=1e-12)
    np.testing.assert_allclose(Jp_new * np.linalg.det(F_new), Jp * np.linalg.det(F), rtol=1e-12)


@pytest.mark.parametrize("mat", SANDS, ids=SAND_IDS)
@pytest.mark.parametrize("dim", [2, 3])
def test_sand_return_map_is_idempotent(mat, dim):
    rng = np.random.default_rng(700 + dim)
    F = random_deformations(rng, 200, dim, scale=0.3)
    Jp = rng.uniform(0.8, 1.2, 200)
    F1, Jp1 = mat.return_map(F, Jp)
    F2, Jp2 = mat.return_map(F1, Jp1)
    np.testing.assert_allclose(F2, F1, rtol=0, atol=1e-12)
    np.testing.assert_allclose(Jp2, Jp1, rtol=1e-12)


@pytest.mark.parametrize("mat", SANDS[:2], ids=SAND_IDS[:2])
@pytest.mark.parametrize("dim", [2, 3])
def test_sand_states_inside_the_cone_are_unchanged(mat, dim):
    """eps = m 1 + r e with m < c, e a unit deviator and r < radius(m) = -alpha k (d m - d c) (k below):
    strictly inside, so F and Jp come back exactly."""
    rng = np.random.default_rng(800 + dim)
    mu, lam = independent_lame(mat.E, mat.nu)
    k = (dim * lam + 2.0 * mu) / (2.0 * mu)
    m = mat.cohesion - rng.uniform(0.01, 0.1, 50)
    e = rng.standard_normal((50, dim))
    e -= e.mean(axis=1, keepdims=True)
    e /= np.linalg.norm(e, axis=1, keepdims=True)
    r = 0.9 * mat.alpha * k * dim * (mat.cohesion - m) * rng.uniform(0.0, 1.0, 50)
    F, _, _ = _rotated_diag(rng, np.exp(m[:, None] + r[:, None] * e))
    Jp = rng.uniform(0.8, 1.2, 50)
    F_new, Jp_new = mat.return_map(F, Jp)
    np.testing.assert_array_equal(F_new, F)
    np.testing.assert_array_equal(Jp_new, Jp)


@pytest.mark.parametrize("mat", SANDS, ids=SAND_IDS)
@pytest.mark.parametrize("dim", [2, 3])
def test_sand_pure_volumetric_compression_is_elastic(mat, dim):
    """F = s R, s < 1: eps = ln(s) 1 has no deviator and tr eps - d c < 0, so dgamma = alpha k tr <= 0.

    For phi = 0 the cone has radius 0 and the SVD's round-off deviator (~1e-16) is removed, so F changes by
    round-off only; for phi > 0 the state is strictly inside and comes back bit for bit."""
    rng = np.random.default_rng(900 + dim)
    s = np.array([0.5, 0.8, 0.95, 0.999])
    F = s[:, None, None] * _random_rotations(rng, 4, dim)
    Jp = np.array([0.9, 1.0, 1.1, 1.2])
    F_new, Jp_new = mat.return_map(F, Jp)
    np.testing.assert_allclose(F_new, F, rtol=0, atol=1e-14)
    np.testing.assert_allclose(Jp_new, Jp, rtol=1e-14)
    if mat.alpha > 0:
        np.testing.assert_array_equal(F_new, F)
        np.testing.assert_array_equal(Jp_new, Jp)


@pytest.mark.parametrize("dim", [2, 3])
def test_sand_volumetric_expansion_goes_to_the_tip(dim):
    """F = s I, ln s > c: tension, eps_new = c 1, F_new = e^c I, Jp_new = Jp s^d / e^(d c).
    With c = 0.05, ln s = 0.03 stays elastic (sustained tension) while ln s = 0.08 and 0.3 are cut to 0.05;
    cohesionless sand (c = 0) goes back to F = I for every s > 1."""
    s = np.exp(np.array([0.03, 0.08, 0.3]))
    F = s[:, None, None] * np.eye(dim)
    Jp = np.array([1.0, 0.9, 1.1])
    F0, Jp0 = SAND.return_map(F, Jp)
    np.testing.assert_allclose(F0, np.broadcast_to(np.eye(dim), F.shape), rtol=0, atol=1e-14)
    np.testing.assert_allclose(Jp0, Jp * s**dim, rtol=1e-13)
    cohesive = DruckerPragerSand(E=E, nu=NU, rho=RHO, cohesion=0.05)
    Fc, Jpc = cohesive.return_map(F, Jp)
    stretch = np.array([s[0], math.exp(0.05), math.exp(0.05)])
    np.testing.assert_allclose(Fc, stretch[:, None, None] * np.eye(dim), rtol=0, atol=1e-14)
    np.testing.assert_allclose(Jpc, Jp * (s / stretch) ** dim, rtol=1e-13)


@pytest.mark.parametrize("dim", [2, 3])
def test_sand_frictionless_keeps_only_the_volumetric_strain(dim):
    """phi = 0: alpha = 0, so dgamma = ||dev eps|| and any deviator is removed completely:
    eps_new = (tr eps / d) 1.  F = Q diag(e^(b + a), e^(b - a)[, e^b]) W^T with b <= 0:
    tr eps = d b, so F_new = e^b Q W^T and Jp is unchanged (trace kept).  b = 0 is the purely
    deviatoric stretch: it comes back as the rotation Q W^T."""
    mat = SANDS[2]
    rng = np.random.default_rng(1000 + dim)
    a = np.array([0.05, 0.2, 0.4, 0.1])
    b = np.array([0.0, 0.0, -0.1, -0.3])
    eps = b[:, None] + np.array([1.0, -1.0, 0.0][:dim]) * a[:, None]
    F, Q, W = _rotated_diag(rng, np.exp(eps))
    Jp = np.array([0.9, 1.0, 1.1, 1.2])
    F_new, Jp_new = mat.return_map(F, Jp)
    np.testing.assert_allclose(F_new, np.exp(b)[:, None, None] * (Q @ W.transpose(0, 2, 1)), rtol=0, atol=1e-13)
    np.testing.assert_allclose(Jp_new, Jp, rtol=1e-13)


@pytest.mark.parametrize("dim", [2, 3])
def test_sand_shear_projection_by_hand(dim):
    """nu = 0.25 gives lam = mu, so k = (d lam + 2 mu)/(2 mu) = (d + 2)/2; phi = 30 deg, alpha = 0.4 sqrt(2/3).

    eps = -0.1 * 1 + t (1, -1[, 0]) with t = 0.2: tr eps = -0.1 d < 0 (no tension), dev eps = t (1, -1[, 0]),
    ||dev eps|| = t sqrt(2).  Cone radius at this trace: rad = -alpha k tr eps = 0.1 d alpha k
    (2D: 0.4 alpha = 0.1306, 3D: 0.75 alpha = 0.2449), below t sqrt(2) = 0.2828, so
    dgamma = t sqrt(2) - rad > 0 and the deviator is shortened to length rad, direction kept:
    eps_new = -0.1 * 1 + rad (1, -1[, 0]) / sqrt(2).  The trace is kept, so Jp is unchanged.
    """
    mat = DruckerPragerSand(E=E, nu=0.25, rho=RHO, friction_angle=30.0)
    rng = np.random.default_rng(1100 + dim)
    direction = np.array([1.0, -1.0, 0.0][:dim])
    eps = -0.1 + 0.2 * direction
    rad = 0.1 * dim * 0.4 * math.sqrt(2.0 / 3.0) * (dim + 2.0) / 2.0
    eps_new = -0.1 + rad * direction / math.sqrt(2.0)
    F, Q, W = _rotated_diag(rng, np.broadcast_to(np.exp(eps), (5, dim)))
    Jp = np.linspace(0.8, 1.2, 5)
    F_new, Jp_new = mat.return_map(F, Jp)
    expected = Q @ (np.exp(eps_new)[None, :, None] * W.transpose(0, 2, 1))
    np.testing.assert_allclose(F_new, expected, rtol=0, atol=1e-13)
    np.testing.assert_allclose(Jp_new, Jp, rtol=1e-13)
    _, _, y = _cone(mat, F_new, dim)
    np.testing.assert_allclose(y, 0.0, atol=1e-12)  # on the cone, not inside


@pytest.mark.parametrize("E_,nu_,rho_", [(1.0e3, 0.3, 2.0), (3.5e5, 0.3, 2200.0), (7.0, 0.0, 3.0)])
def test_sand_wave_speed(E_, nu_, rho_):
    M = E_ * (1.0 - nu_) / ((1.0 + nu_) * (1.0 - 2.0 * nu_))
    assert DruckerPragerSand(E=E_, nu=nu_, rho=rho_).wave_speed() == pytest.approx(math.sqrt(M / rho_), rel=1e-13)
