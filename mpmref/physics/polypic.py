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
    digits in the highest mode. A zero norm (a node with zero weight makes the top polynomial vanish on the
    support) ends the recurrence's use of that polynomial: its :math:`\beta` and :math:`\alpha` are taken as 0.

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
    for j in range(S - 1):
        alpha = _ratio(np.sum(w * delta * q[:, :, j] * q[:, :, j], axis=-1), norm[:, :, j])
        q[:, :, j + 1] = (delta - alpha[..., None]) * q[:, :, j]
        if j > 0:
            q[:, :, j + 1] -= _ratio(norm[:, :, j], norm[:, :, j - 1])[..., None] * q[:, :, j - 1]
        norm[:, :, j + 1] = np.sum(w * q[:, :, j + 1] * q[:, :, j + 1], axis=-1)
    return q, norm


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
