"""Conservation and reproduction suite of the NumPy reference transfers, for every valid
scheme x force x kernel x dimension (Jiang et al. 2015; Fu et al. 2017; Hu et al. 2018)."""

from dataclasses import replace

import numpy as np
import pytest
from helpers import box_scene, random_particles, valid_methods
from hypothesis import given
from hypothesis import strategies as st

from mpmref.backends.numpy import NumpyBackend
from mpmref.observe.diagnostics import angular_momentum

METHODS = valid_methods()
IDS = [f"{m['scheme']}-{m['force']}-{m['kernel']}" for m in METHODS]
AFFINE = [m for m in METHODS if m["scheme"] in ("apic", "polypic", "mls")]
AFFINE_IDS = [f"{m['scheme']}-{m['force']}-{m['kernel']}" for m in AFFINE]


def test_the_valid_set_is_what_the_rules_say():
    """pic, flip: {mls, classic} x {quadratic, cubic} + classic-linear = 5 each; apic, polypic: 4 each
    (no linear kernel); mls: the MLS force only, quadratic or cubic = 2. Total 20."""
    names = {tuple(m.values()) for m in METHODS}
    assert ("mls", "classic", "quadratic") not in names
    assert ("apic", "classic", "linear") not in names and ("pic", "mls", "linear") not in names
    assert ("pic", "classic", "linear") in names and ("flip", "classic", "linear") in names
    assert ("polypic", "classic", "cubic") in names
    assert len(METHODS) == 5 + 5 + 4 + 4 + 2


def inertia(scene):
    return scene.kernel.inertia_factor * scene.grid.dx**2 if scene.kernel.inertia_factor else 0.0


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("method", METHODS, ids=IDS)
@given(seed=st.integers(0, 2**31 - 1))
def test_p2g_conserves_mass_and_momentum(dim, method, seed):
    """Σ_i m_i = Σ_p m_p and Σ_i (mv)_i = Σ_p m_p v_p to round-off (Σ w = 1; Σ w (x_i-x_p) = 0; Σ w s_r = 0)."""
    rng = np.random.default_rng(seed)
    scene = box_scene(dim, **method)
    p = random_particles(scene, 60, rng)
    gs = NumpyBackend(scene).p2g(p)
    assert abs(gs.mass.sum() - p.mass.sum()) <= 1e-13 * p.mass.sum()
    ref = (p.mass[:, None] * p.v).sum(axis=0)
    scale = np.abs(p.mass[:, None] * p.v).sum()
    np.testing.assert_allclose(gs.momentum.sum(axis=0), ref, rtol=0, atol=1e-13 * scale)


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("method", METHODS, ids=IDS)
def test_internal_forces_are_momentum_and_torque_free(dim, method, rng):
    """Σ_i f_i = 0 always; Σ_i x_i × f_i = 0 for symmetric τ when Σ_i g_ip (x_i - x_p)^T = I."""
    scene = box_scene(dim, **method)
    p = random_particles(scene, 60, rng)
    gs = NumpyBackend(scene).p2g(p)
    scale = np.abs(gs.force).sum()
    assert scale > 0
    np.testing.assert_allclose(gs.force.sum(axis=0), 0.0, atol=1e-13 * scale)
    x = scene.grid.node_positions()
    torque = x[:, 0] * gs.force[:, 1] - x[:, 1] * gs.force[:, 0]
    assert abs(torque.sum()) <= 1e-13 * np.abs(torque).sum()


def transfer_round_trip(scene, p):
    """P2G then G2P with Δt = 0 (no forces, no motion): the pure transfer."""
    be = NumpyBackend(scene)
    gs = be.p2g(p)
    v, v_tilde = be.grid_update(gs, 0.0)
    return be, gs, v, be.g2p(p, v, v_tilde, 0.0)


def grid_angular_momentum(grid, gs_mass, v):
    x = grid.node_positions()
    m_v = gs_mass[:, None] * v
    if grid.dim == 2:
        return np.sum(x[:, 0] * m_v[:, 1] - x[:, 1] * m_v[:, 0])
    return np.cross(x, m_v).sum(axis=0)


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("method", AFFINE, ids=AFFINE_IDS)
@given(seed=st.integers(0, 2**31 - 1))
def test_affine_schemes_conserve_angular_momentum_through_transfers(dim, method, seed):
    """Particle L (with the affine part m D ε:C) = grid L after P2G = particle L after G2P (Jiang 2015 §5.3)."""
    rng = np.random.default_rng(seed)
    scene = box_scene(dim, **method)
    p = random_particles(scene, 50, rng)
    _, gs, v, q = transfer_round_trip(scene, p)
    D = inertia(scene)
    L0 = angular_momentum(p, D)
    scale = np.sum(p.mass * np.linalg.norm(p.x, axis=1) * np.linalg.norm(p.v, axis=1))
    np.testing.assert_allclose(grid_angular_momentum(scene.grid, gs.mass, v), L0, atol=1e-13 * scale)
    np.testing.assert_allclose(angular_momentum(q, D), L0, atol=1e-13 * scale)


def test_apic_without_its_affine_p2g_term_fails_angular_momentum(rng):
    """The angular-momentum check can fail: drop C_p (x_i - x_p) from APIC's P2G and L is not kept."""
    scene = box_scene(2, "apic")
    p = random_particles(scene, 200, rng)
    broken = replace(scene, method=replace(scene.method, scheme="pic"))  # same particles, P2G without C
    be = NumpyBackend(broken)
    gs = be.p2g(p)
    v, _ = be.grid_update(gs, 0.0)
    L0 = angular_momentum(p, inertia(scene))
    scale = np.sum(p.mass * np.linalg.norm(p.x, axis=1) * np.linalg.norm(p.v, axis=1))
    suite_tolerance = 1e-13 * scale  # what test_affine_schemes_conserve_angular_momentum_through_transfers allows
    assert abs(grid_angular_momentum(scene.grid, gs.mass, v) - L0) > 1e6 * suite_tolerance


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("kernel", ["quadratic", "cubic"])
def test_pic_loses_angular_momentum_measurably(dim, kernel, rng):
    """PIC has no affine term: one round trip of a rigid rotation loses a measurable share of L."""
    scene = box_scene(dim, "pic", kernel=kernel)
    p = random_particles(scene, 400, rng)
    r = p.x - p.x.mean(axis=0)
    p.v = np.stack([-r[:, 1], r[:, 0]] + ([np.zeros(len(r))] if dim == 3 else []), axis=1)
    _, _, _, q = transfer_round_trip(scene, p)
    L0 = np.atleast_1d(angular_momentum(p, 0.0))[-1]
    L1 = np.atleast_1d(angular_momentum(q, 0.0))[-1]
    # the w*w smoothing of a rotation at dx = 1/16 on a 0.4-wide box loses about a percent per cycle
    assert 1 - L1 / L0 > 1e-3


def assert_momentum_field(gs, field, rtol=1e-13):
    """Nodal momentum equals m_i * field(x_i), relative to the largest nodal momentum.

    Momentum is what P2G produces; nodal *velocity* m_i^-1 (mv)_i amplifies round-off on nearly empty
    nodes (PolyPIC's top mode has a norm that vanishes with the smallest per-axis weight)."""
    ref = gs.mass[:, None] * field
    np.testing.assert_allclose(gs.momentum, ref, rtol=0, atol=rtol * np.max(np.abs(ref)))


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("method", AFFINE, ids=AFFINE_IDS)
def test_affine_field_is_reproduced_exactly(dim, method, rng):
    """v(x) = a + Bx with C_p = B (higher modes 0) is put on the grid exactly and is a fixed point."""
    scene = box_scene(dim, **method)
    p = random_particles(scene, 200, rng)
    a, B = rng.standard_normal(dim), rng.standard_normal((dim, dim))
    p.v = a + p.x @ B.T
    p.C = np.broadcast_to(B, p.C.shape).copy()
    if p.modes is not None:
        p.modes = np.zeros_like(p.modes)
    be, gs, v, q = transfer_round_trip(scene, p)
    field = a + scene.grid.node_positions() @ B.T
    assert_momentum_field(gs, field)
    np.testing.assert_allclose(q.v, p.v, rtol=0, atol=1e-13 * np.max(np.abs(p.v)))
    np.testing.assert_allclose(q.C, p.C, rtol=0, atol=1e-12 * np.max(np.abs(B)))
    assert_momentum_field(be.p2g(q), field)  # the second cycle puts the same field back


def per_axis_quadratic_field(x):
    """A field of per-axis degree ≤ 2 (in PolyPIC's span for quadratic splines), beyond APIC's affine span."""
    v = np.empty_like(x)
    v[:, 0] = 1.0 + x[:, 0] ** 2 * x[:, 1] ** 2 - 2.0 * x[:, 0] * x[:, 1]
    v[:, 1] = x[:, 1] ** 2 - 3.0 * x[:, 0] ** 2 * x[:, 1]
    if x.shape[1] == 3:
        v[:, 2] = x[:, 2] ** 2 * x[:, 0]
        v[:, 0] += x[:, 0] * x[:, 1] * x[:, 2]
    return v


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("kernel", ["quadratic", "cubic"])
def test_polypic_reproduces_its_higher_modes_and_apic_does_not(dim, kernel, rng):
    """Particles given the G2P projection of a per-axis-quadratic field put it back on the grid exactly."""
    for scheme in ("polypic", "apic"):
        scene = box_scene(dim, scheme, kernel=kernel)
        p = random_particles(scene, 200, rng)
        be = NumpyBackend(scene)
        exact = per_axis_quadratic_field(scene.grid.node_positions())
        p = be.g2p(p, exact, exact, 0.0)  # particles take the field's projection onto their modes
        gs = be.p2g(p)
        if scheme == "polypic":
            assert_momentum_field(gs, exact)
        else:
            with pytest.raises(AssertionError):
                assert_momentum_field(gs, exact)


def test_polypic_restricted_to_affine_modes_equals_apic(rng):
    """With its higher modes zeroed, PolyPIC's P2G is APIC's, and its G2P gives APIC's v and C."""
    poly, apic = box_scene(2, "polypic"), box_scene(2, "apic")
    p = random_particles(poly, 200, rng)
    p.modes = np.zeros_like(p.modes)
    _, gs_poly, v_poly, q_poly = transfer_round_trip(poly, p)
    _, gs_apic, v_apic, q_apic = transfer_round_trip(apic, p.with_(modes=None))
    np.testing.assert_allclose(gs_poly.momentum, gs_apic.momentum, rtol=0, atol=1e-14)
    np.testing.assert_allclose(q_poly.v, q_apic.v, rtol=0, atol=1e-14)
    np.testing.assert_allclose(q_poly.C, q_apic.C, rtol=0, atol=1e-12)


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("force", ["mls", "classic"])
def test_velocity_gradient_is_chosen_apart_from_the_force(dim, force, rng):
    """``method.velocity_gradient`` swaps only the F/J update of G2P: with the other force's gradient,
    F equals that of the other force's scheme (G2P's F does not depend on the force), and x, v, C equal those
    of the declared force (they do not depend on the gradient). P2G is the declared force's."""
    other = {"mls": "classic", "classic": "mls"}[force]
    crossed = box_scene(dim, "apic", force=force)
    crossed = replace(crossed, method=replace(crossed.method, velocity_gradient=other))
    plain, donor = box_scene(dim, "apic", force=force), box_scene(dim, "apic", force=other)
    assert crossed.transfer.gradient == other and crossed.transfer.mls_force == (force == "mls")
    p = random_particles(plain, 40, rng)
    dt = 1e-3
    results = {}
    v = rng.standard_normal((crossed.grid.n_nodes, dim))  # the same grid velocities for the three
    for name, scene in (("crossed", crossed), ("plain", plain), ("donor", donor)):
        be = NumpyBackend(scene)
        results[name] = be.g2p(p, v, v, dt), be.p2g(p)
    (crossed_p, crossed_g), (plain_p, plain_g), (donor_p, _) = results["crossed"], results["plain"], results["donor"]
    np.testing.assert_array_equal(crossed_p.F, donor_p.F)
    assert not np.allclose(crossed_p.F, plain_p.F)
    for name in ("x", "v", "C"):
        np.testing.assert_array_equal(getattr(crossed_p, name), getattr(plain_p, name))
    np.testing.assert_array_equal(crossed_g.force, plain_g.force)
