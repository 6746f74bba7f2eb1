r"""PolyPIC velocity modes (Fu, Guo, Gast, Jiang & Teran 2017, "A polynomial particle-in-cell method").

Each particle carries a polynomial velocity :math:`v_p(x_i) = \sum_r c_{pr}\, s_r(x_i - x_p)` over its
stencil nodes. The modes are tensor products :math:`s_r = \prod_a q^{(a)}_{r_a}` of per-axis polynomials
:math:`q_0 = 1, q_1 = \delta, q_2, \dots, q_{S-1}` (:math:`\delta = x_{i,a} - x_{p,a}`, :math:`S` the
kernel support) made orthogonal under the particle's own weights (Gram–Schmidt, computed by the
equivalent three-term recurrence),
:math:`\langle f, g\rangle_a = \sum_k N_{a,k} f_k g_k` (Fu et al. 2017 §4 builds the same
orthogonality for quadratic splines). Because :math:`w_{ip} = \prod_a N_{a,k_a}`, the :math:`S^d`
modes are orthogonal under :math:`\sum_i w_{ip}\, \cdot\,\cdot`, so G2P is a projection:

.. math:: c_{pr} = \frac{\sum_i w_{ip}\, s_r(x_i)\, v_i}{\sum_i w_{ip}\, s_r(x_i)^2}.

:math:`r = 0` gives the PIC velocity, the linear modes :math:`r = e_a` give APIC's
:math:`C_p = B_p D_p^{-1}`; the remaining :math:`S^d - 1 - d` modes are what particles store as
``modes``. With all :math:`S^d` modes the particle reproduces every stencil node's velocity, so a
P2G → G2P cycle with :math:`\Delta t = 0` is a fixed point after the first cycle.
"""

from functools import lru_cache
from itertools import product
from math import comb, factorial

import numpy as np


@lru_cache(maxsize=None)
def higher_modes(dim, support):
    """Multi-indices ``r`` of the modes beyond constant and linear, shape (S^d - 1 - d, d)."""
    modes = [r for r in product(range(support), repeat=dim) if sum(r) > 1 or max(r) > 1]
    return np.array(modes, dtype=np.int64).reshape(-1, dim)


def axis_basis(w, fx, dx):
    r"""Per-axis orthogonal polynomials at the stencil nodes and their squared norms.

    The monic polynomials orthogonal under :math:`\langle f, g\rangle_a = \sum_k N_{a,k} f_k g_k` are
    built by the three-term (Stieltjes) recurrence

    .. math::

        q_0 = 1,\quad q_{j+1} = (\delta - \alpha_j)\, q_j - \beta_j\, q_{j-1},\qquad
        \alpha_j = \frac{\langle \delta q_j, q_j\rangle}{\langle q_j, q_j\rangle},\quad
        \beta_j = \frac{\langle q_j, q_j\rangle}{\langle q_{j-1}, q_{j-1}\rangle}

    (Gautschi 2004, *Orthogonal Polynomials: Computation and Approximation*, §2.2.3), with
    :math:`\delta_k = (k - f_a)\Delta x` the node offsets. In exact arithmetic these are Gram–Schmidt
    applied to :math:`1, \delta, \delta^2, \dots`; the recurrence avoids the cancellation of Gram–Schmidt on
    monomials, which for the cubic spline (outer weights down to ~1e-6 of the inner ones) loses about seven
    digits in the highest mode. The recurrence gives :math:`q_0 \dots q_{S-2}`; the top polynomial
    :math:`q_{S-1}` comes from its closed form (:func:`top_polynomial`), because the recurrence computes it
    by cancellation where the particle sits next to a stencil switch.

    Parameters
    ----------
    w : (n, d, S) array   per-axis kernel weights :math:`N_{a,k}`
    fx : (n, d) array     particle offset from its base node, in cells
    dx : float            grid spacing

    Returns
    -------
    q : (n, d, S, S)      ``q[p, a, j, k]`` = :math:`q_j` of axis ``a`` at node ``k``
    norm : (n, d, S)      :math:`\langle q_j, q_j\rangle_a`
    """
    n, d, S = w.shape
    delta = (np.arange(S, dtype=w.dtype) - fx[..., None]) * dx  # (n, d, S)
    q = np.empty((n, d, S, S), dtype=w.dtype)
    norm = np.empty((n, d, S), dtype=w.dtype)
    q[:, :, 0] = 1.0
    norm[:, :, 0] = np.sum(w, axis=-1)
    for j in range(S - 2):
        alpha = _ratio(np.sum(w * delta * q[:, :, j] * q[:, :, j], axis=-1), norm[:, :, j])
        q[:, :, j + 1] = (delta - alpha[..., None]) * q[:, :, j]
        if j > 0:
            q[:, :, j + 1] -= _ratio(norm[:, :, j], norm[:, :, j - 1])[..., None] * q[:, :, j - 1]
        norm[:, :, j + 1] = np.sum(w * q[:, :, j + 1] * q[:, :, j + 1], axis=-1)
    q[:, :, S - 1], norm[:, :, S - 1] = top_polynomial(w, dx)
    return q, norm


def difference_stencil(S):
    r"""Coefficients :math:`d_k = (-1)^{S-1-k}\binom{S-1}{k}` of the :math:`(S-1)`-th forward difference."""
    return np.array([(-1) ** (S - 1 - k) * comb(S - 1, k) for k in range(S)], dtype=np.float64)


def top_polynomial(w, dx):
    r"""The top orthogonal polynomial :math:`q_{S-1}` of each axis at its stencil nodes, in closed form, and its norm.

    On :math:`S` equally spaced nodes the only vector orthogonal (in the plain dot product) to every
    polynomial of degree below :math:`S-1` is the :math:`(S-1)`-th difference stencil :math:`d_k`
    (:func:`difference_stencil`: :math:`(1, -2, 1)` for the quadratic kernel, :math:`(-1, 3, -3, 1)` for the
    cubic). Orthogonality under the weights therefore fixes :math:`N_k\, q_{S-1}(\delta_k) = \lambda\, d_k`,
    and the monic normalisation (leading coefficient = the :math:`(S-1)`-th divided difference
    :math:`\sum_k d_k q_k / L = 1`, :math:`L = (S-1)!\,\Delta x^{S-1}`) fixes :math:`\lambda`:

    .. math::

        q_{S-1}(\delta_k) = \frac{\lambda\, d_k}{N_k},\qquad
        \lambda = \frac{L}{\sum_k d_k^2 / N_k},\qquad
        \langle q_{S-1}, q_{S-1}\rangle = \lambda L .

    Every quantity is a product, quotient or sum of positive terms, so it carries a relative error of a few
    ulps however small the smallest weight is; the recurrence instead forms the small values at the heavy
    nodes as differences of O(1) terms (an absolute error of an ulp, a relative one of ulp / :math:`N_{min}`).
    The G2P projection onto this mode, :math:`\sum_k N_k q_k v_k / \langle q, q\rangle`, becomes
    :math:`\sum_k d_k v_k / L`: the divided difference of the node velocities, which does not depend on the
    weights (Fu et al. 2017 write the quadratic kernel's top mode with this coefficient,
    :math:`(v_0 - 2 v_1 + v_2) / (2\Delta x^2)`). **Tie rule**: a particle with a weight exactly 0 on an axis
    (it sits on the stencil switch, e.g. :math:`f = 1/2` for the quadratic kernel) has
    :math:`\lambda = 0`; the mode's values and norm are 0, and G2P gives it the coefficient 0, which P2G then
    multiplies by weights that are 0 at that node and values that are 0 elsewhere (docs/transfers.md,
    "Conditioning of the top modes").

    Parameters
    ----------
    w : (n, d, S) array   per-axis kernel weights :math:`N_{a,k}`
    dx : float            grid spacing :math:`\Delta x`

    Returns
    -------
    q : (n, d, S)   :math:`q_{S-1}(\delta_k)`;  norm : (n, d)   :math:`\langle q_{S-1}, q_{S-1}\rangle_a`

    Docs: docs/transfers.md#conditioning-of-the-top-modes
    """
    S = w.shape[-1]
    d = difference_stencil(S).astype(w.dtype)
    L = factorial(S - 1) * _power(dx, S - 1)
    inside = np.all(w > 0, axis=-1)
    w_safe = np.where(inside[..., None], w, 1.0)
    lam = np.where(inside, L / np.sum(d * d / w_safe, axis=-1), 0.0)
    return lam[..., None] * d / w_safe, lam * L


def _power(x, k):
    """``x**k`` as a product of ``k`` factors (the order the Numba backend uses)."""
    out = 1.0
    for _ in range(k):
        out *= x
    return out


def _ratio(a, b):
    """``a / b`` where ``b > 0``, else 0."""
    return np.divide(a, b, out=np.zeros_like(a), where=b > 0)


def mode_values(q, offset, modes):
    """:math:`s_r(x_i)` at the node ``base + offset`` for each mode in ``modes``: shape (n, M)."""
    out = np.ones((q.shape[0], len(modes)), dtype=q.dtype)
    for a in range(q.shape[1]):
        out *= q[:, a, modes[:, a], offset[a]]
    return out


def mode_norms(norm, modes):
    r""":math:`\sum_i w_{ip} s_r(x_i)^2 = \prod_a \langle q_{r_a}, q_{r_a}\rangle_a` per mode, shape (n, M).

    Docs: docs/mpm_cycle.md#polypic, docs/transfers.md#polypic
    """
    out = np.ones((norm.shape[0], len(modes)), dtype=norm.dtype)
    for a in range(norm.shape[1]):
        out *= norm[:, a, modes[:, a]]
    return out
