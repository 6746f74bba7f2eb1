r"""PolyPIC's top mode next to a stencil switch: the cause of the backends' PolyPIC divergence, in a few particles.

Cause (measured): where a particle sits within :math:`10^{-5}` cells of the point at which its
stencil switches (:math:`f = 1/2` for the quadratic kernel, :math:`f = 1` or 2 for the cubic), one per-axis
weight :math:`N_{min}` is tiny and the top orthogonal polynomial :math:`q_{S-1}` is tiny at the other nodes.
The three-term recurrence forms those small values as differences of O(1) terms, so they carry an absolute
error of an ulp and a relative one of ulp / :math:`N_{min}`; G2P divides by the mode's norm (also
:math:`\propto N_{min}`) and the coefficient comes out with that relative error. Two backends that round
differently then disagree by ulp / :math:`N_{min}` (the backends case's PolyPIC failure, 7.2e-10), and so do
two runs of the reference from positions an ulp apart. No wall was involved: no particle's stencil reached a
wall band in that trajectory.

The coefficient itself is well-conditioned: the projection onto the top mode is the divided difference
:math:`\sum_k d_k v_k / L` of the node velocities, which does not depend on the weights at all
(:func:`mpmref.physics.polypic.top_polynomial`). The fix computes :math:`q_{S-1}` in closed form. These tests
compare the coefficient with exact rational arithmetic (``fractions``: Gram–Schmidt on monomials under the
exact weights, then the projection), and keep the recurrence's version of the top polynomial beside it to
show the loss it had.

Bound. A coefficient is :math:`c_r = \sum_i g_{ri} v_i` with the dual weights
:math:`g_{ri} = w_{ip} s_r(x_i) / N_r`; each term is formed with at most :math:`m` roundings (per axis: the
weight, the polynomial value, the norm; a product over the axes; one multiplication by :math:`v_i`), and
the sum of :math:`S^d` terms adds :math:`S^d - 1` more, so
:math:`|\hat c_r - c_r| \le (m + S^d)\,u \sum_i |g_{ri} v_i|` to first order (Higham 2002, *Accuracy and
Stability of Numerical Algorithms*, §3.1 and §4.2), :math:`u = 2^{-53}`. With :math:`m \le 12d + 8` (five
roundings in a weight, four in a closed-form polynomial value or recurrence step, three in a norm) this is
below :math:`64\,u` for the 2D quadratic and :math:`96\,u` for the 2D cubic kernel; the test uses
``(12 d + 8 + S^d) u``.
"""

from fractions import Fraction
from itertools import product

import numpy as np
import pytest

from mpmref import SceneBuilder
from mpmref.backends import BACKENDS, make_backend
from mpmref.physics.kernels import KERNELS, compute_stencil
from mpmref.physics.polypic import axis_basis, higher_modes
from mpmref.state import Particles

U = 2.0**-53
CELLS = 16


def exact_weights(kernel, f):
    """Per-axis B-spline weights at the exact offset ``f`` (a Fraction), in exact arithmetic."""
    if kernel == "quadratic":
        return [Fraction(1, 2) * (Fraction(3, 2) - f) ** 2, Fraction(3, 4) - (f - 1) ** 2,
                Fraction(1, 2) * (f - Fraction(1, 2)) ** 2]
    a, b = f - 1, 2 - f
    return [b**3 / 6, a**3 / 2 - a * a + Fraction(2, 3), b**3 / 2 - b * b + Fraction(2, 3), a**3 / 6]


def exact_axis_basis(kernel, f, dx):
    """Gram–Schmidt on 1, δ, δ², … under the exact weights: polynomial values (S, S) and squared norms (S,)."""
    N = exact_weights(kernel, f)
    S = len(N)
    delta = [(k - f) * dx for k in range(S)]
    dot = lambda a, b: sum(N[k] * a[k] * b[k] for k in range(S))
    basis = []
    for j in range(S):
        q = [delta[k] ** j for k in range(S)]
        for prev in basis:
            c = dot(q, prev) / dot(prev, prev)
            q = [q[k] - c * prev[k] for k in range(S)]
        basis.append(q)
    return N, basis, [dot(q, q) for q in basis]


def exact_modes(kernel, fx, dx, v_nodes, modes):
    """Exact projections ``c_r`` (M, d) of node velocities ``v_nodes`` (S, …, S, d) onto the modes, and the
    scale :math:`\\sum_i |g_{ri} v_i|` of each (M, d)."""
    axes = [exact_axis_basis(kernel, Fraction(float(f)), Fraction(dx)) for f in fx]
    dim, S = len(fx), len(axes[0][0])
    c = np.zeros((len(modes), dim))
    scale = np.zeros((len(modes), dim))
    for m, r in enumerate(modes):
        for comp in range(dim):
            total, size = Fraction(0), Fraction(0)
            for node in product(range(S), repeat=dim):
                g = Fraction(1)
                for a, k in enumerate(node):
                    N, q, norm = axes[a]
                    g *= N[k] * q[r[a]][k] / norm[r[a]]
                term = g * Fraction(float(v_nodes[node + (comp,)]))
                total += term
                size += abs(term)
            c[m, comp], scale[m, comp] = float(total), float(size)
    return c, scale


def recurrence_top_coefficient(w, fx, dx, v):
    """The top mode's coefficient as the code computed it before the fix: one more step of the recurrence."""
    S = len(w)
    delta = (np.arange(S) - fx) * dx
    q = [np.ones(S)]
    norms = [np.sum(w)]
    for j in range(S - 1):
        alpha = np.sum(w * delta * q[j] * q[j]) / norms[j]
        nxt = (delta - alpha) * q[j] - (norms[j] / norms[j - 1] * q[j - 1] if j > 0 else 0.0)
        q.append(nxt)
        norms.append(np.sum(w * nxt * nxt))
    return np.sum(w * q[-1] * v) / norms[-1]


#: offsets next to each stencil switch, and one far from it (the smallest weight: ~1e-14 .. 0.1)
NEAR_SWITCH = {"quadratic": [0.5 + 1e-7, 1.5 - 1e-7, 0.5 + 1e-4, 1.0],
               "cubic": [1.0 + 1e-5, 2.0 - 1e-5, 1.0 + 1e-3, 1.5]}


@pytest.mark.parametrize("kernel", ["quadratic", "cubic"])
def test_recurrence_loses_the_top_coefficient_and_the_closed_form_keeps_it(kernel):
    """One axis: the top coefficient is the divided difference Σ d_k v_k / L whatever the weights; the recurrence
    loses ulp / N_min of it next to a switch, the closed form stays within the round-off bound."""
    rng = np.random.default_rng(7)
    dx = 1.0 / CELLS
    for f in NEAR_SWITCH[kernel]:
        stencil = compute_stencil(KERNELS[kernel], np.array([[(f + 3) * dx]]), np.zeros(1), dx)
        w, fx = stencil.w[0, 0], stencil.fx[0, 0]
        assert abs(fx - f) < 1e-12
        S = len(w)
        v = rng.standard_normal(S)
        exact, scale = exact_top_coefficient(kernel, fx, dx, v)
        q, norm = axis_basis(stencil.w, stencil.fx, dx)
        closed = np.sum(w * q[0, 0, S - 1] * v) / norm[0, 0, S - 1]
        bound = (12 + 8 + S) * U * scale
        assert abs(closed - exact) <= bound, (f, closed, exact)
        if w.min() < 1e-9:  # next to the switch the recurrence is off by orders of magnitude more
            assert abs(recurrence_top_coefficient(w, stencil.fx[0, 0], dx, v) - exact) > 1e4 * bound


def exact_top_coefficient(kernel, f, dx, v):
    """Exact projection of node values ``v`` onto the top polynomial at offset ``f``, and its scale Σ|g_k v_k|."""
    N, q, norm = exact_axis_basis(kernel, Fraction(float(f)), Fraction(dx))
    terms = [N[k] * q[-1][k] * Fraction(float(v[k])) / norm[-1] for k in range(len(N))]
    return float(sum(terms)), float(sum(abs(t) for t in terms))


def _scene(kernel):
    return (SceneBuilder(dim=2, name="switch").grid(size=1.0, cells=CELLS).method("polypic", kernel=kernel)
            .material("m", "fixed_corotated", E=1e3, nu=0.3, rho=1.0)
            .points("m", np.full((1, 2), 0.5), particle_volume=1e-4).walls("open").time(dt=1e-4, steps=1).build())


@pytest.mark.parametrize("backend", list(BACKENDS))
@pytest.mark.parametrize("kernel", ["quadratic", "cubic"])
def test_g2p_modes_of_particles_at_a_stencil_switch_are_exact_to_round_off(backend, kernel):
    """A handful of particles, each next to a stencil switch on one axis or both, G2P of a random grid velocity:
    every mode coefficient within the round-off bound of the exact projection, on every backend."""
    scene = _scene(kernel)
    grid, dx = scene.grid, scene.grid.dx
    offsets = NEAR_SWITCH[kernel]
    cells = [(6, 7), (8, 8), (9, 6), (7, 9)]
    fx = np.array([[offsets[i % 4], offsets[(i + 1) % 4]] for i in range(len(cells))])
    base = np.array(cells, dtype=float) - (1 if kernel == "cubic" else 0)
    x = grid.origin + (base + fx) * dx
    n = len(x)
    modes = higher_modes(2, scene.kernel.support)
    particles = Particles(x=x, v=np.zeros((n, 2)), mass=np.ones(n), vol0=np.full(n, 1e-4),
                          material=np.zeros(n, dtype=np.int32), C=np.zeros((n, 2, 2)), F=np.tile(np.eye(2), (n, 1, 1)),
                          modes=np.zeros((n, len(modes), 2)))
    rng = np.random.default_rng(23)
    v_grid = rng.standard_normal((grid.n_nodes, 2))
    new = make_backend(backend, scene).g2p(particles, v_grid, np.zeros_like(v_grid), 0.0)
    st = compute_stencil(scene.kernel, x, grid.origin, dx)
    S = scene.kernel.support
    for p in range(n):
        nodes = np.zeros((S, S, 2))
        for k in product(range(S), repeat=2):
            nodes[k] = v_grid[(st.base[p] + np.array(k)) @ grid.strides]
        c, scale = exact_modes(kernel, st.fx[p], dx, nodes, modes)
        bound = (12 * 2 + 8 + S**2) * U * scale
        assert np.all(np.abs(new.modes[p] - c) <= bound), (backend, p, np.max(np.abs(new.modes[p] - c) / scale))
