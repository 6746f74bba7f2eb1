r"""A particle's kernel stencil along one axis, for both compiled backends: B-spline weights, their slopes, and
PolyPIC's orthogonal polynomials.

The B-splines of :mod:`mpmref.physics.kernels`, with the reference's operations in the reference's order. A particle
at grid coordinate :math:`\xi = (x_p - o)/\Delta x` has the base node :math:`b` (``floor(xi)`` for the linear hat,
``floor(xi - 1/2)`` quadratic, ``floor(xi) - 1`` cubic) and the fraction :math:`f = \xi - b`; its stencil along the
axis is the nodes :math:`b + k`, :math:`k = 0 \dots S-1`, with weights :math:`N_k(f)`, slopes :math:`N'_k(f)` (grid
units) and offsets :math:`x_i - x_p = (k - f)\Delta x`. ``kernel`` is a code of :data:`KERNEL_CODES` (a compile-time
constant of the callers, so only its branch remains); ``real`` the type the caller computes in.
"""

import math

from . import pointwise

#: the kernels' codes in the compiled code
KERNEL_CODES = {"linear": 0, "quadratic": 1, "cubic": 2}
#: the quadratic B-spline's code (CPIC's distance field uses it whatever the transfer's kernel)
QUADRATIC = KERNEL_CODES["quadratic"]


@pointwise(inline=True)
def fraction(kernel, real, xi):
    """``(b, f)``: the lowest stencil node :math:`b` (an integer) and :math:`f = \\xi - b`."""
    if kernel == 1:
        base = int(math.floor(xi - real(0.5)))
    elif kernel == 2:
        base = int(math.floor(xi)) - 1
    else:
        base = int(math.floor(xi))
    return base, xi - real(base)


@pointwise
def quadratic(real, f):
    r"""The quadratic B-spline's weights and slopes (Steffen et al. 2008 §3) as tuples:
    :math:`\tfrac12(\tfrac32 - f)^2,\ \tfrac34 - (f - 1)^2,\ \tfrac12(f - \tfrac12)^2` and
    :math:`f - \tfrac32,\ -2(f - 1),\ f - \tfrac12`."""
    a, b, c = real(1.5) - f, f - real(1.0), f - real(0.5)
    return ((real(0.5) * (a * a), real(0.75) - b * b, real(0.5) * (c * c)),
            (f - real(1.5), -real(2.0) * b, f - real(0.5)))


@pointwise
def cubic(real, f):
    r"""The cubic B-spline's weights and slopes as tuples, with :math:`s = f - 1`, :math:`t = 2 - f`:
    :math:`t^3/6,\ \tfrac12 s^3 - s^2 + \tfrac23,\ \tfrac12 t^3 - t^2 + \tfrac23,\ s^3/6` and
    :math:`-\tfrac12 t^2,\ \tfrac32 s^2 - 2s,\ -\tfrac32 t^2 + 2t,\ \tfrac12 s^2` (cubes as products, as the
    reference's :meth:`~mpmref.physics.kernels.CubicBSpline.weights`)."""
    s, t = f - real(1.0), real(2.0) - f
    s2, t2 = s * s, t * t
    s3, t3 = s2 * s, t2 * t
    third2, half, three_halves, two = real(2.0 / 3.0), real(0.5), real(1.5), real(2.0)
    return ((t3 / real(6.0), half * s3 - s2 + third2, half * t3 - t2 + third2, s3 / real(6.0)),
            (-half * t2, three_halves * s2 - two * s, -three_halves * t2 + two * t, half * s2))


@pointwise
def linear(real, f):
    r"""The linear hat's weights :math:`1 - f,\ f` and slopes :math:`-1,\ 1` as tuples."""
    return (real(1.0) - f, f), (-real(1.0), real(1.0))


#: each kernel's weights and slopes by its name (what a device kernel, compiled for one kernel, calls)
AXIS = {"linear": linear, "quadratic": quadratic, "cubic": cubic}


@pointwise(inline=True)
def weights_and_slopes(kernel, real, f):
    """The weights :math:`N_k(f)` and slopes :math:`N'_k(f)` (grid units) of the kernel coded ``kernel``, as two
    tuples (:func:`quadratic`, :func:`cubic`, :func:`linear`)."""
    if kernel == 1:
        return quadratic(real, f)
    if kernel == 2:
        return cubic(real, f)
    return linear(real, f)


@pointwise(inline=True)
def kernel_axis(kernel, real, xi):
    """The stencil of one axis: ``(b, f, weights, slopes)`` (:func:`fraction`, :func:`weights_and_slopes`)."""
    base, f = fraction(kernel, real, xi)
    w, dw = weights_and_slopes(kernel, real, f)
    return base, f, w, dw


@pointwise
def axis_basis(w, f, dx, q, norm):
    r"""PolyPIC's orthogonal polynomials of one axis at its stencil nodes (:func:`mpmref.physics.polypic.axis_basis`):
    ``q[j, k]`` = :math:`q_j(\delta_k)`, ``norm[j]`` = :math:`\langle q_j, q_j\rangle`, from the weights ``w[k]`` and
    the fraction ``f``, in the dtype of ``q``.

    :math:`q_0 = 1,\ q_{j+1} = (\delta - \alpha_j) q_j - \beta_j q_{j-1}` with
    :math:`\alpha_j = \langle \delta q_j, q_j\rangle / \langle q_j, q_j\rangle`,
    :math:`\beta_j = \langle q_j, q_j\rangle / \langle q_{j-1}, q_{j-1}\rangle`,
    :math:`\langle f, g\rangle = \sum_k N_k f_k g_k`, :math:`\delta_k = (k - f)\Delta x` (Gautschi 2004 §2.2.3;
    Fu et al. 2017 §4 for their use in PolyPIC); the top one in closed form (:func:`top_polynomial`).
    """
    real = q.dtype.type
    S = w.shape[0]
    total = real(0.0)
    for k in range(S):
        q[0, k] = real(1.0)
        total += w[k]
    norm[0] = total
    for j in range(S - 2):
        num = real(0.0)
        for k in range(S):
            num += w[k] * ((real(k) - f) * dx) * q[j, k] * q[j, k]
        alpha = num / norm[j] if norm[j] > real(0.0) else real(0.0)
        beta = real(0.0)
        if j > 0 and norm[j - 1] > real(0.0):
            beta = norm[j] / norm[j - 1]
        total = real(0.0)
        for k in range(S):
            nxt = (((real(k) - f) * dx) - alpha) * q[j, k]
            if j > 0:
                nxt -= beta * q[j - 1, k]
            q[j + 1, k] = nxt
            total += w[k] * nxt * nxt
        norm[j + 1] = total
    top_polynomial(w, dx, q, norm)


@pointwise
def top_polynomial(w, dx, q, norm):
    r"""The top polynomial of one axis in closed form (:func:`mpmref.physics.polypic.top_polynomial`):
    :math:`q_{S-1}(\delta_k) = \lambda d_k / N_k`, :math:`\lambda = L / \sum_k d_k^2 / N_k`, norm :math:`\lambda L`,
    :math:`L = (S-1)!\,\Delta x^{S-1}`, :math:`d_k = (-1)^{S-1-k}\binom{S-1}{k}`; all zero where a weight of the axis
    is exactly 0 (the tie rule).

    Docs: docs/transfers.md#conditioning-of-the-top-modes
    """
    real = q.dtype.type
    S = w.shape[0]
    top = S - 1
    L = real(1.0)
    for j in range(top):
        L *= real(j + 1)
    power = real(1.0)
    for _ in range(top):
        power *= dx
    L = L * power
    inside = True
    for k in range(S):
        inside = inside and w[k] > real(0.0)
    if not inside:
        for k in range(S):
            q[top, k] = real(0.0)
        norm[top] = real(0.0)
        return
    total = real(0.0)
    for k in range(S):
        dk = difference_coefficient(real, top, k)
        total += dk * dk / w[k]
    lam = L / total
    for k in range(S):
        q[top, k] = lam * difference_coefficient(real, top, k) / w[k]
    norm[top] = lam * L


@pointwise
def difference_coefficient(real, order, k):
    r""":math:`(-1)^{order-k}\binom{order}{k}`, the ``k``-th coefficient of the ``order``-th forward difference."""
    c = real(1.0)
    for j in range(k):
        c = c * real(order - j) / real(j + 1)
    return c if (order - k) % 2 == 0 else -c
