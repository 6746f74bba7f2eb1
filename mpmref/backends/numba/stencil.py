r"""Per-particle kernel stencils for the Numba backend.

The same B-splines as :mod:`mpmref.physics.kernels`, evaluated one particle and one axis at a time, as
tuples (values a compiled loop keeps in registers). ``kernel`` codes: 0 linear hat, 1 quadratic, 2 cubic
B-spline. A particle at grid
coordinate :math:`\xi = (x_p - o)/\Delta x` touches the nodes ``base + k``, ``k = 0 .. S-1`` per axis, with
``base = floor(xi - shift)`` (``shift`` 0, 1/2, 1).
"""

import numpy as np
from numba import njit

KERNEL_CODES = {"linear": 0, "quadratic": 1, "cubic": 2}
BASE_SHIFT = {"linear": 0.0, "quadratic": 0.5, "cubic": 1.0}


@njit(cache=True)
def quadratic_axis(xi):
    r"""Quadratic B-spline on one axis (:class:`mpmref.physics.kernels.QuadraticBSpline`, Steffen et al. 2008 §3).

    Returns ``(base, fx, w, dw)``: the lowest stencil node ``floor(xi - 1/2)``, ``fx = xi - base``, the three
    weights :math:`N(fx - k)` and their derivatives in grid units, as tuples.
    """
    base = np.floor(xi - 0.5)
    fx = xi - base
    w = (0.5 * (1.5 - fx) ** 2, 0.75 - (fx - 1.0) ** 2, 0.5 * (fx - 0.5) ** 2)
    return int(base), fx, w, (fx - 1.5, -2.0 * (fx - 1.0), fx - 0.5)


@njit(cache=True)
def cubic_axis(xi):
    r"""Cubic B-spline on one axis (:class:`mpmref.physics.kernels.CubicBSpline`), base ``floor(xi) - 1``."""
    base = np.floor(xi) - 1.0
    fx = xi - base
    s, t = fx - 1.0, 2.0 - fx
    s3, t3 = s * s * s, t * t * t  # the reference's operation order (see CubicBSpline.weights)
    w = (t3 / 6.0, 0.5 * s3 - s * s + 2.0 / 3.0, 0.5 * t3 - t * t + 2.0 / 3.0, s3 / 6.0)
    return int(base), fx, w, (-0.5 * t * t, 1.5 * s * s - 2.0 * s, -1.5 * t * t + 2.0 * t, 0.5 * s * s)


@njit(cache=True)
def linear_axis(xi):
    r"""Linear hat on one axis (:class:`mpmref.physics.kernels.LinearHat`), base ``floor(xi)``."""
    base = np.floor(xi)
    fx = xi - base
    return int(base), fx, (1.0 - fx, fx), (-1.0, 1.0)


@njit(cache=True, inline="always")
def kernel_axis(kernel, xi):
    """The stencil of one axis for kernel code ``kernel``: ``(base, fx, w, dw)``.

    Inlined into its caller before typing, so with a constant ``kernel`` only one branch (and one tuple
    length) remains.
    """
    if kernel == 1:
        return quadratic_axis(xi)
    if kernel == 2:
        return cubic_axis(xi)
    return linear_axis(xi)


@njit(cache=True)
def polypic_axis_basis(w, fx, dx, q, norm):
    r"""Per-axis orthogonal polynomials of :func:`mpmref.physics.polypic.axis_basis`.

    :math:`q_0 \dots q_{S-2}` by the three-term recurrence
    :math:`q_0 = 1,\ q_{j+1} = (\delta - \alpha_j) q_j - \beta_j q_{j-1}` with
    :math:`\alpha_j = \langle \delta q_j, q_j\rangle / \langle q_j, q_j\rangle`,
    :math:`\beta_j = \langle q_j, q_j\rangle / \langle q_{j-1}, q_{j-1}\rangle`,
    :math:`\langle f, g\rangle_a = \sum_k N_{a,k} f_k g_k`, :math:`\delta_k = (k - f_a)\Delta x` (Gautschi 2004
    §2.2.3; Fu et al. 2017 §4 for their use in PolyPIC); the top one in closed form,
    :math:`q_{S-1}(\delta_k) = \lambda d_k / N_k` (:func:`polypic_top_polynomial`). Fills ``q[a, j, k]`` and
    ``norm[a, j]``.
    """
    d, S = w.shape
    for a in range(d):
        nrm = 0.0
        for k in range(S):
            q[a, 0, k] = 1.0
            nrm += w[a, k]
        norm[a, 0] = nrm
        for j in range(S - 2):
            num = 0.0
            for k in range(S):
                num += w[a, k] * ((k - fx[a]) * dx) * q[a, j, k] * q[a, j, k]
            alpha = num / norm[a, j] if norm[a, j] > 0 else 0.0
            beta = 0.0
            if j > 0 and norm[a, j - 1] > 0:
                beta = norm[a, j] / norm[a, j - 1]
            nrm = 0.0
            for k in range(S):
                nxt = (((k - fx[a]) * dx) - alpha) * q[a, j, k]
                if j > 0:
                    nxt -= beta * q[a, j - 1, k]
                q[a, j + 1, k] = nxt
                nrm += w[a, k] * nxt * nxt
            norm[a, j + 1] = nrm
        polypic_top_polynomial(w, dx, a, q, norm)


@njit(cache=True)
def polypic_top_polynomial(w, dx, a, q, norm):
    r"""Top polynomial of axis ``a`` in closed form (:func:`mpmref.physics.polypic.top_polynomial`).

    :math:`q_{S-1}(\delta_k) = \lambda d_k / N_k`, :math:`\lambda = L / \sum_k d_k^2 / N_k`, norm
    :math:`\lambda L`, :math:`L = (S-1)!\,\Delta x^{S-1}`, :math:`d_k = (-1)^{S-1-k}\binom{S-1}{k}`; all zero
    where a weight of the axis is exactly 0 (the tie rule).

    Docs: docs/transfers.md#conditioning-of-the-top-modes
    """
    S = w.shape[1]
    top = S - 1
    L = 1.0
    for j in range(top):
        L *= (j + 1.0)
    power = 1.0
    for _ in range(top):
        power *= dx
    L = L * power
    inside = True
    for k in range(S):
        if not w[a, k] > 0:
            inside = False
    if not inside:
        for k in range(S):
            q[a, top, k] = 0.0
        norm[a, top] = 0.0
        return
    total = 0.0
    for k in range(S):
        dk = difference_coefficient(top, k)
        total += dk * dk / w[a, k]
    lam = L / total
    for k in range(S):
        q[a, top, k] = lam * difference_coefficient(top, k) / w[a, k]
    norm[a, top] = lam * L


@njit(cache=True)
def difference_coefficient(order, k):
    r""":math:`(-1)^{order-k}\binom{order}{k}`, the ``k``-th coefficient of the ``order``-th forward difference."""
    c = 1.0
    for j in range(k):
        c = c * (order - j) / (j + 1.0)
    return c if (order - k) % 2 == 0 else -c


@njit(cache=True, inline="always")
def offsets(f, dx, S):
    """Node offsets :math:`(k - f)\\Delta x`, ``k = 0 .. S-1``, of one axis as a tuple."""
    if S == 2:
        return ((0.0 - f) * dx, (1.0 - f) * dx)
    if S == 3:
        return ((0.0 - f) * dx, (1.0 - f) * dx, (2.0 - f) * dx)
    return ((0.0 - f) * dx, (1.0 - f) * dx, (2.0 - f) * dx, (3.0 - f) * dx)


@njit(cache=True, inline="always")
def scaled(t, s, S):
    """``s * t`` for a tuple ``t`` of ``S`` = 2 to 4 values."""
    if S == 2:
        return (s * t[0], s * t[1])
    if S == 3:
        return (s * t[0], s * t[1], s * t[2])
    return (s * t[0], s * t[1], s * t[2], s * t[3])


@njit(cache=True, inline="always")
def cast(t, real, S):
    """A tuple ``t`` of ``S`` = 2 to 4 values converted to the scalar type ``real`` (so a float32 run's
    per-node arithmetic stays in float32)."""
    if S == 2:
        return (real(t[0]), real(t[1]))
    if S == 3:
        return (real(t[0]), real(t[1]), real(t[2]))
    return (real(t[0]), real(t[1]), real(t[2]), real(t[3]))


@njit(cache=True, inline="always")
def axis_stencil(KERNEL, x_a, origin_a, dx, inv_dx, real, S):
    r"""One axis ``a`` of a particle's transfer stencil, the set-up that P2G and G2P share: the base node
    :math:`b`, the fraction :math:`f = (x_a - o_a)/\Delta x - b`, the weights :math:`N_k` (as the kernel gives
    them), and cast to the run's scalar type ``real`` the node offsets :math:`(k - f)\Delta x`, the weight
    derivatives :math:`N'_k/\Delta x` and the weights (:func:`kernel_axis`)."""
    b, f, w, dw = kernel_axis(KERNEL, (x_a - origin_a) / dx)
    return b, f, w, cast(offsets(f, dx, S), real, S), cast(scaled(dw, inv_dx, S), real, S), cast(w, real, S)
