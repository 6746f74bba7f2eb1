"""What the NumPy reference does at the extremes, checked against independent computations (docs/conformance.md,
"Extremes"): its SVD and polar rotation at repeated, nearly repeated and vanishing singular values against mpmath at
40 digits; its kernels' partition of unity and reproduction of linear fields on nodes, faces, base switches and the
domain's edges; its stress laws' limits; what it refuses."""

import math

import mpmath
import numpy as np
import pytest

from mpmref.conformance.extremes import exactly_at
from mpmref.conformance.strategies import rotation
from mpmref.physics.catalogue import MATERIALS
from mpmref.physics.kernels import KERNELS, compute_stencil
from mpmref.physics.materials import polar_rotation, signed_svd
from mpmref.physics.svd import polar_rotation as fast_polar_rotation
from mpmref.physics.svd import signed_svd as fast_signed_svd

mpmath.mp.dps = 40
EPS = np.finfo(np.float64).eps
#: a backward-stable factorisation is exact for F + δF with |δF| <= c eps |F|; c = 8 bounds LAPACK's and the fast one's
BACKWARD = 8.0


def spectra(dim):
    """``(name, signed singular values)`` of the extreme spectra: all equal, two equal, nearly equal (gaps 1e-6 to
    1e-12), one vanishing (exactly and 1e-12), inverted."""
    pad = [1.0] * (dim - 2)
    out = [("identity", [1.0] * dim), ("all equal", [0.7] * dim), ("vanishing", [1.3] + pad[:dim - 2] + [0.0]),
           ("tiny", [1.3] + pad[:dim - 2] + [1e-12]), ("inverted", [1.2] + pad[:dim - 2] + [-0.4]),
           ("inverted and tiny", [1.2] + pad[:dim - 2] + [-1e-9])]
    out += [(f"gap {g:.0e}", [1.1, 1.1 * (1 - g)] + [0.9] * (dim - 2)) for g in (1e-6, 1e-9, 1e-12)]
    if dim == 3:
        out += [("two equal", [1.4, 0.8, 0.8]), ("two vanishing", [1.0, 0.0, 0.0])]
    return out


def exact_signed_svd(F):
    """Signed singular values and the polar rotation of ``F`` (its float64 entries taken exactly) in mpmath: the last
    singular value negative where det F < 0, R = U V^T a proper rotation."""
    A = mpmath.matrix(F.tolist())
    U, S, V = mpmath.svd_r(A)  # A = U diag(S) V (V already transposed)
    d = F.shape[0]
    sigma = [S[i] for i in range(d)]
    U = np.array(U.tolist(), dtype=object)
    Vt = np.array(V.tolist(), dtype=object)
    if mpmath.det(mpmath.matrix(U.tolist())) * mpmath.det(mpmath.matrix(Vt.tolist())) < 0:
        U[:, -1] = -U[:, -1]
        sigma[-1] = -sigma[-1]
    R = U.dot(Vt)
    return np.array([float(s) for s in sigma]), np.array([[float(r) for r in row] for row in R])


CASES = [(dim, name, sigma, seed) for dim in (2, 3) for name, sigma in spectra(dim) for seed in range(3)]


@pytest.mark.parametrize("implementation", ["lapack", "fast"])
@pytest.mark.parametrize("dim, name, sigma, seed", CASES, ids=[f"{d}d-{n}-{s}" for d, n, _, s in CASES])
def test_svd_and_polar_rotation_match_mpmath_at_degenerate_spectra(implementation, dim, name, sigma, seed):
    """Singular values within 8 eps |F| of the exact ones of the rounded F (Weyl: a backward-stable SVD moves them by
    at most |δF|); the polar rotation within 8 eps |F| · 2 / min(σ_i + σ_j) (its sensitivity, Li 1995), unique
    wherever that sum is positive; a rotation with det +1."""
    rng = np.random.default_rng(seed)
    U = rotation(dim, rng.uniform(-math.pi, math.pi, 3))
    V = rotation(dim, rng.uniform(-math.pi, math.pi, 3))
    F = (U * np.array(sigma)) @ V.T
    exact_sigma, exact_R = exact_signed_svd(F)
    svd, polar = (signed_svd, polar_rotation) if implementation == "lapack" else (fast_signed_svd, fast_polar_rotation)
    _, got_sigma, _ = svd(F[None])
    R, _ = polar(F[None])
    scale = np.linalg.norm(F, 2)
    assert np.abs(got_sigma[0] - exact_sigma).max() <= BACKWARD * EPS * scale
    assert np.linalg.det(R[0]) == pytest.approx(1.0, abs=1e-14)
    pair = min(exact_sigma[i] + exact_sigma[j] for i in range(dim) for j in range(i + 1, dim))
    if pair > 1e-6 * scale:  # R is unique, and its sensitivity finite
        assert np.abs(R[0] - exact_R).max() <= BACKWARD * EPS * scale * 2.0 / pair, (name, pair)


# ------------------------------------------------------------------------------------------------ kernels
def positions_on_lines(kernel, cells, dim, origin, dx):
    """Positions exactly on nodes, faces (one coordinate on a node line), base switches and the lowest and highest
    positions the kernel allows, as the reference computes their grid coordinates."""
    low, high = kernel.low_margin, cells - kernel.high_margin
    lines = [low, 3.0, 3.5, 3.0 + kernel.base_shift % 1, cells / 2]
    points = [[exactly_at(t, origin, dx, "float64") for _ in range(dim)] for t in lines]
    points.append([exactly_at(high, origin, dx, "float64", below=True)] * dim)
    points.append([exactly_at(low, origin, dx, "float64")] + [exactly_at(high, origin, dx, "float64",
                                                                          below=True)] * (dim - 1))
    return np.array(points)


@pytest.mark.parametrize("kernel", list(KERNELS.values()), ids=list(KERNELS))
@pytest.mark.parametrize("dim", [2, 3])
def test_kernels_are_a_partition_of_unity_and_reproduce_linear_fields_on_the_lines(kernel, dim):
    """On nodes, faces, base switches and the domain's edges: sum w = 1, sum w (x_i - x_p) = 0, sum grad w = 0 and
    sum (x_i - x_p) grad w^T = I (the moments every kernel has, docs/mpm_cycle.md), to round-off; the base node is
    inside the grid (the stencil fits) at the lowest and highest positions the kernel allows."""
    cells, origin, dx = 8, -1.2345, 0.173
    x = positions_on_lines(kernel, cells, dim, origin, dx)
    stencil = compute_stencil(kernel, x, np.full(dim, origin), dx)
    assert stencil.base.min() >= 0 and (stencil.base + kernel.support - 1).max() <= cells
    w = stencil.node_weights()                           # (K, n)
    offsets = stencil.node_offset_vectors()              # (K, n, d)
    grads = np.stack([stencil.node_gradient(o) for o in stencil.offsets])  # (K, n, d)
    assert np.abs(w.sum(axis=0) - 1.0).max() <= 4 * EPS
    assert np.abs(np.einsum("kn,knd->nd", w, offsets)).max() <= 16 * EPS * dx
    assert np.abs(grads.sum(axis=0)).max() <= 16 * EPS / dx
    moment = np.einsum("kna,knb->nab", offsets, grads)
    assert np.abs(moment - np.eye(dim)).max() <= 32 * EPS


# ------------------------------------------------------------------------------------------- stress laws
SOLIDS = {"fixed_corotated": {"E": 1e3, "nu": 0.3}, "neo_hookean": {"E": 2e3, "nu": 0.35},
          "snow": {"E": 1.4e3, "nu": 0.2}, "sand": {"E": 3.5e3, "nu": 0.3, "cohesion": 0.0}}


def stress(kind, F, Jp=1.0):
    material = MATERIALS[kind](**SOLIDS[kind])
    return material.kirchhoff_stress(*((F, np.full(len(F), Jp)) if material.plastic else (F,)))


@pytest.mark.parametrize("kind", list(SOLIDS))
@pytest.mark.parametrize("dim", [2, 3])
def test_a_solid_at_rest_or_rotated_is_stress_free(kind, dim):
    """F = I gives exactly zero stress (every law has Psi minimal there; snow at any J_P); a rotation gives zero to
    round-off of the stiffness: fixed-corotated's F - R, Neo-Hookean's F F^T - I and ln J, sand's ln sigma all
    vanish."""
    eye = np.eye(dim)[None]
    assert np.array_equal(stress(kind, eye, Jp=0.8), np.zeros((1, dim, dim)))
    R = rotation(dim, [0.3, -1.1, 2.0])[None]
    material = MATERIALS[kind](**SOLIDS[kind])
    assert np.abs(stress(kind, R)).max() <= 16 * EPS * (material.lam + 2 * material.mu)


def test_the_fluid_at_rest_is_stress_free_and_follows_tait_to_collapse():
    """J = 1 gives exactly zero; down to J = 1e-4 the stress is K (J - J^(1 - gamma)) to a few ulps of itself."""
    fluid = MATERIALS["fluid"](K=400.0, gamma=7.0)
    assert np.array_equal(fluid.kirchhoff_stress_from_J(np.ones(1), 2), np.zeros((1, 2, 2)))
    J = np.array([1e-1, 1e-2, 1e-3, 1e-4])
    exact = [float(400 * (mpmath.mpf(j) - mpmath.mpf(j) ** (1 - 7))) for j in J]
    got = fluid.kirchhoff_stress_from_J(J, 3)[:, 0, 0]
    assert np.allclose(got, exact, rtol=16 * EPS, atol=0.0)


def test_what_the_reference_refuses_at_the_extremes():
    """The Neo-Hookean stress of an inverted F is NaN (ln J of J < 0; the run stops with NonFiniteError there), and the
    extremes leave those rungs out; sand's Hencky strain floors its singular values at 1e-6, so an inverted or
    collapsed F has a finite, compressive stress; fixed-corotated and snow define one (the signed SVD)."""
    from mpmref.conformance.extremes import _finite_rungs, collapse_gradients

    inverted = (rotation(2, [0.4]) * np.array([1.0, -0.5])) @ rotation(2, [-1.0]).T
    assert np.isnan(np.diagonal(stress("neo_hookean", inverted[None])[0])).all()  # lambda ln J on the diagonal
    for kind in ("fixed_corotated", "snow", "sand"):
        assert np.isfinite(stress(kind, inverted[None])).all()
    assert np.trace(stress("sand", inverted[None])[0]) < 0
    ladder = collapse_gradients(np.random.default_rng(0), 2)
    kept = {note for _, note in _finite_rungs(MATERIALS["neo_hookean"](**SOLIDS["neo_hookean"]), ladder,
                                              {"Jp": np.ones(1)}, np.arange(1))}
    assert kept and not any("inverted" in note for note in kept)


@pytest.mark.parametrize("dim", [2, 3])
def test_return_maps_keep_states_inside_and_are_continuous_across_the_yield_surface(dim):
    """F = I is inside both yield surfaces and kept bit for bit; a snow state past its bound by delta is projected by
    a change of about delta of F, and one inside is kept: the map is continuous at the surface, so that a code rounding
    a state to the other side of it moves F by round-off only."""
    snow = MATERIALS["snow"](**SOLIDS["snow"])
    sand = MATERIALS["sand"](**{**SOLIDS["sand"], "cohesion": 0.01})
    eye = np.eye(dim)[None]
    for material in (snow, sand):
        F, Jp = material.return_map(eye.copy(), np.ones(1))
        assert np.array_equal(F, eye) and Jp[0] == 1.0
    U, V = rotation(dim, [0.2, 0.5, 0.9]), rotation(dim, [-0.7, 0.1, 0.4])
    hi = 1.0 + snow.theta_s
    for delta in (1e-10, 1e-7):
        past = (U * np.array([hi * (1 + delta)] + [1.0] * (dim - 1))) @ V.T
        F, _ = snow.return_map(past[None], np.ones(1))
        assert np.abs(F[0] - past).max() == pytest.approx(delta * hi, rel=0.5)
        inside = (U * np.array([hi * (1 - delta)] + [1.0] * (dim - 1))) @ V.T
        assert np.array_equal(snow.return_map(inside[None], np.ones(1))[0][0], inside)
