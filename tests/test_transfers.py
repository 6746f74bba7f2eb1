"""Conservation and reproduction properties of the NumPy reference transfers (Jiang et al. 2015)."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from helpers import box_scene, random_particles
from mpmref.backends.numpy import NumpyBackend
from mpmref.diagnostics import angular_momentum

SCHEMES = ["pic", "flip", "apic", "mls"]


def grid_angular_momentum(grid, gs_mass, v):
    x = grid.node_positions()
    m_v = gs_mass[:, None] * v
    if grid.dim == 2:
        return np.sum(x[:, 0] * m_v[:, 1] - x[:, 1] * m_v[:, 0])
    return np.cross(x, m_v).sum(axis=0)


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("scheme", SCHEMES)
@given(seed=st.integers(0, 2**31 - 1))
def test_p2g_conserves_mass_and_momentum(dim, scheme, seed):
    """Σ_i m_i = Σ_p m_p and Σ_i (mv)_i = Σ_p m_p v_p to round-off (partition of unity, Σ w (x_i-x_p) = 0)."""
    rng = np.random.default_rng(seed)
    scene = box_scene(dim, scheme)
    p = random_particles(scene, 200, rng)
    gs = NumpyBackend(scene).p2g(p)
    assert abs(gs.mass.sum() - p.mass.sum()) <= 1e-13 * p.mass.sum()
    ref = (p.mass[:, None] * p.v).sum(axis=0)
    scale = np.abs(p.mass[:, None] * p.v).sum()
    np.testing.assert_allclose(gs.momentum.sum(axis=0), ref, rtol=0, atol=1e-13 * scale)


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("scheme", SCHEMES)
def test_internal_forces_sum_to_zero(dim, scheme, rng):
    """Σ_i f_i = 0: internal forces do not change linear momentum (Σ_i w_ip (x_i - x_p) = 0)."""
    scene = box_scene(dim, scheme)
    p = random_particles(scene, 200, rng)
    gs = NumpyBackend(scene).p2g(p)
    scale = np.abs(gs.force).sum()
    assert scale > 0
    np.testing.assert_allclose(gs.force.sum(axis=0), 0.0, atol=1e-13 * scale)


def transfer_round_trip(scene, p):
    """P2G then G2P with Δt = 0 (no forces, no motion): the pure transfer."""
    be = NumpyBackend(scene)
    gs = be.p2g(p)
    v, v_tilde = be.grid_update(gs, 0.0)
    return be, gs, v, be.g2p(p, v, v_tilde, 0.0)


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("scheme", ["apic", "mls"])
@given(seed=st.integers(0, 2**31 - 1))
def test_affine_schemes_conserve_angular_momentum_through_transfers(dim, scheme, seed):
    """Particle L (with the affine part m D ε:C) = grid L after P2G = particle L after G2P (Jiang et al. 2015 §5.3)."""
    rng = np.random.default_rng(seed)
    scene = box_scene(dim, scheme)
    p = random_particles(scene, 150, rng)
    be, gs, v, q = transfer_round_trip(scene, p)
    D = scene.kernel.inertia_factor * scene.grid.dx**2
    L0 = angular_momentum(p, D)
    scale = np.sum(p.mass * np.linalg.norm(p.x, axis=1) * np.linalg.norm(p.v, axis=1))
    np.testing.assert_allclose(grid_angular_momentum(scene.grid, gs.mass, v), L0, atol=1e-13 * scale)
    np.testing.assert_allclose(angular_momentum(q, D), L0, atol=1e-13 * scale)


@pytest.mark.parametrize("dim", [2, 3])
def test_pic_loses_angular_momentum_measurably(dim, rng):
    """PIC has no affine term: one round trip of a rigid rotation loses a measurable share of L."""
    scene = box_scene(dim, "pic")
    p = random_particles(scene, 400, rng)
    center = p.x.mean(axis=0)
    r = p.x - center
    p.v = np.stack([-r[:, 1], r[:, 0]] + ([np.zeros(len(r))] if dim == 3 else []), axis=1)
    _, _, _, q = transfer_round_trip(scene, p)
    L0 = np.atleast_1d(angular_momentum(p, 0.0))[-1]
    L1 = np.atleast_1d(angular_momentum(q, 0.0))[-1]
    loss = 1 - L1 / L0
    # the smoothing w*w of a rotation field at dx = 1/16 on a 0.4-wide box loses a few percent per cycle
    assert loss > 1e-3


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("scheme", ["apic", "mls"])
def test_apic_reproduces_affine_field_exactly(dim, scheme, rng):
    """v(x) = a + Bx with C_p = B is reproduced on every massive node and back on the particles."""
    scene = box_scene(dim, scheme)
    p = random_particles(scene, 300, rng)
    a, B = rng.standard_normal(dim), rng.standard_normal((dim, dim))
    p.v = a + p.x @ B.T
    p.C = np.broadcast_to(B, p.C.shape).copy()
    _, gs, v, q = transfer_round_trip(scene, p)
    nodes = scene.grid.node_positions()[gs.mass > 0]
    np.testing.assert_allclose(v[gs.mass > 0], a + nodes @ B.T, rtol=0, atol=1e-12)
    np.testing.assert_allclose(q.v, p.v, rtol=0, atol=1e-12)
    np.testing.assert_allclose(q.C, p.C, rtol=0, atol=1e-11)


def test_broken_apic_fails_the_affine_check(rng, monkeypatch):
    """The reproduction test can fail: P2G without its affine term does not reproduce B."""
    scene = box_scene(2, "apic")
    p = random_particles(scene, 300, rng)
    B = rng.standard_normal((2, 2))
    p.v = p.x @ B.T
    p.C = np.broadcast_to(B, p.C.shape).copy()
    from dataclasses import replace

    broken = replace(scene, method=replace(scene.method, scheme="pic"))  # P2G drops C_p (x_i - x_p)
    be = NumpyBackend(broken)
    gs = be.p2g(p)
    v, _ = be.grid_update(gs, 0.0)
    nodes = scene.grid.node_positions()[gs.mass > 0]
    assert np.max(np.abs(v[gs.mass > 0] - nodes @ B.T)) > 1e-3
