"""Moment identities of the quadratic B-spline stencil (mpmref.physics.kernels).

For the quadratic B-spline every particle ``p`` and its 3**d stencil nodes ``i`` satisfy, exactly:

* partition of unity            sum_i w_ip = 1
* first moment                  sum_i w_ip (x_i - x_p) = 0
* gradients sum to zero         sum_i grad w_ip = 0
* APIC inertia tensor           sum_i w_ip (x_i - x_p)(x_i - x_p)^T = dx^2/4 I   (Jiang et al. 2015)
* linear-field reproduction     sum_i grad w_ip (x_i - x_p)^T = I

The expected values (1, 0, 0, dx^2/4 I, I) are derived by hand, not from the code under test.
"""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mpmref.physics.kernels import QuadraticBSpline, compute_stencil

KERNEL = QuadraticBSpline()
TOL = 1e-13


def _moments(x, origin, dx):
    """Accumulate the five stencil sums for particles ``x`` (n, d)."""
    stn = compute_stencil(KERNEL, x, origin, dx)
    n, d = x.shape
    offsets = stn.offsets
    assert offsets.shape == (3**d, d)
    w_sum = np.zeros(n)
    m1 = np.zeros((n, d))
    g_sum = np.zeros((n, d))
    m2 = np.zeros((n, d, d))
    gx = np.zeros((n, d, d))
    for off in offsets:
        w = stn.node_weight(off)
        g = stn.node_gradient(off)
        r = stn.node_offset_vector(off)
        w_sum += w
        m1 += w[:, None] * r
        g_sum += g
        m2 += w[:, None, None] * r[:, :, None] * r[:, None, :]
        gx += g[:, :, None] * r[:, None, :]
    return stn, w_sum, m1, g_sum, m2, gx


def _check_identities(x, origin, dx):
    n, d = x.shape
    stn, w_sum, m1, g_sum, m2, gx = _moments(x, origin, dx)
    eye = np.eye(d)
    # partition of unity (dimensionless)
    np.testing.assert_allclose(w_sum, 1.0, rtol=0, atol=TOL)
    # first moment is a length: compare in units of dx
    np.testing.assert_allclose(m1 / dx, 0.0, rtol=0, atol=TOL)
    # gradient sum has units 1/length: compare in units of 1/dx
    np.testing.assert_allclose(g_sum * dx, 0.0, rtol=0, atol=TOL)
    # APIC inertia tensor D_p = dx^2/4 I (length^2: compare in units of dx^2)
    np.testing.assert_allclose(m2 / dx**2, np.broadcast_to(0.25 * eye, (n, d, d)), rtol=0, atol=TOL)
    # gradient reproduces linear fields (dimensionless)
    np.testing.assert_allclose(gx, np.broadcast_to(eye, (n, d, d)), rtol=0, atol=TOL)
    # the stencil's advertised inertia scalar is the same dx^2/4
    assert stn.inertia == pytest.approx(dx * dx / 4.0, rel=1e-15)


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("dx", [1.0, 0.1, 1.0 / 64.0, 0.037])
def test_moment_identities_random_particles(dim, dx):
    rng = np.random.default_rng(20240601 + dim)
    origin = rng.uniform(-2.0, 2.0, size=dim)
    n_cells = 32
    # keep particles in the admissible band [0.5, n_cells - 0.5) in grid coordinates
    xi = rng.uniform(0.5, n_cells - 0.5, size=(500, dim))
    x = origin + xi * dx
    _check_identities(x, origin, dx)


@pytest.mark.parametrize("dim", [2, 3])
def test_moment_identities_at_special_offsets(dim):
    """Particles exactly on nodes, cell centres and the stencil switch point fx = 0.5."""
    dx = 0.25
    origin = np.zeros(dim)
    vals = np.array([0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.25, 3.75])
    grids = np.meshgrid(*([vals] * dim), indexing="ij")
    xi = np.stack([g.ravel() for g in grids], axis=1)
    _check_identities(xi * dx, origin, dx)


@settings(derandomize=True, max_examples=50, deadline=None)
@given(
    dim=st.sampled_from([2, 3]),
    dx=st.floats(min_value=1e-3, max_value=10.0, allow_nan=False, allow_infinity=False),
    origin_scale=st.floats(min_value=-5.0, max_value=5.0, allow_nan=False, allow_infinity=False),
    xi=st.lists(
        st.floats(min_value=0.5, max_value=15.49, allow_nan=False, allow_infinity=False),
        min_size=3,
        max_size=3,
    ),
)
def test_moment_identities_hypothesis(dim, dx, origin_scale, xi):
    origin = np.full(dim, origin_scale * dx)
    x = (origin + np.asarray(xi[:dim]) * dx)[None, :]
    _check_identities(x, origin, dx)


def _reference_N(r):
    """Quadratic B-spline N(r) from the textbook piecewise formula (Stomakhin et al. 2013 Eq. 10)."""
    a = np.abs(r)
    return np.where(a < 0.5, 0.75 - a**2, np.where(a < 1.5, 0.5 * (1.5 - a) ** 2, 0.0))


@pytest.mark.parametrize("dim", [2, 3])
def test_weights_match_piecewise_formula_and_base_node(dim):
    rng = np.random.default_rng(7 + dim)
    dx = 0.05
    origin = rng.uniform(-1.0, 1.0, size=dim)
    xi = rng.uniform(0.5, 19.5, size=(200, dim))
    x = origin + xi * dx
    stn = compute_stencil(KERNEL, x, origin, dx)
    xi_code = (x - origin) / dx
    # base node = floor(xi - 1/2), so fx = xi - base lies in [0.5, 1.5)
    np.testing.assert_array_equal(stn.base, np.floor(xi_code - 0.5).astype(np.int64))
    assert np.all(stn.fx >= 0.5) and np.all(stn.fx < 1.5)
    for off in stn.offsets:
        node = stn.base + off
        expected = np.prod(_reference_N(xi_code - node), axis=1)
        np.testing.assert_allclose(stn.node_weight(off), expected, rtol=0, atol=1e-14)
        # x_i - x_p from the absolute node position
        np.testing.assert_allclose(stn.node_offset_vector(off), (origin + node * dx) - x, rtol=0, atol=1e-13)


@pytest.mark.parametrize("dim", [2, 3])
def test_weight_derivative_matches_central_difference(dim):
    rng = np.random.default_rng(99 + dim)
    # stay 1e-6 away from the ends of [0.5, 1.5) so fx +- h never leaves the piece
    fx = rng.uniform(0.5 + 1e-6, 1.5 - 1e-6, size=(300, dim))
    h = 1e-7
    _, dw = KERNEL.weights(fx)
    wp, _ = KERNEL.weights(fx + h)
    wm, _ = KERNEL.weights(fx - h)
    fd = (wp - wm) / (2.0 * h)
    assert dw.shape == (300, dim, 3)
    np.testing.assert_allclose(dw, fd, rtol=0, atol=1e-8)


@pytest.mark.parametrize("dim", [2, 3])
def test_node_gradient_matches_central_difference_in_position(dim):
    """grad w_ip (physical units) equals d w_ip / d x_p by central differences at fixed nodes."""
    rng = np.random.default_rng(3 + dim)
    dx = 0.1
    origin = np.zeros(dim)
    # keep fx away from the switch point 0.5/1.5 so the stencil base does not change under +-h
    base = rng.integers(1, 10, size=(100, dim))
    fx = rng.uniform(0.55, 1.45, size=(100, dim))
    x = origin + (base + fx) * dx
    stn = compute_stencil(KERNEL, x, origin, dx)
    h = 1e-7 * dx
    for off in stn.offsets:
        g = stn.node_gradient(off)
        for a in range(dim):
            e = np.zeros(dim)
            e[a] = h
            sp = compute_stencil(KERNEL, x + e, origin, dx)
            sm = compute_stencil(KERNEL, x - e, origin, dx)
            np.testing.assert_array_equal(sp.base, stn.base)
            np.testing.assert_array_equal(sm.base, stn.base)
            fd = (sp.node_weight(off) - sm.node_weight(off)) / (2.0 * h)
            np.testing.assert_allclose(g[:, a] * dx, fd * dx, rtol=0, atol=1e-8)
