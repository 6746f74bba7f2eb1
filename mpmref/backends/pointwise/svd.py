r"""The signed SVD and the polar decomposition of one small matrix, for both compiled backends.

The algorithms, conventions and sources are those of :mod:`mpmref.physics.svd` (read its docstrings): the closed-form
2×2 polar decomposition and SVD of the talk's 88-line program (Hu et al. 2018), and for 3×3 one-sided Jacobi sweeps
to a fixed tolerance, sorting by column length, and a QR by Givens rotations after McAdams et al. 2011. The result is
the *signed* SVD :math:`F = U\Sigma V^T` with :math:`U, V` rotations, :math:`\sigma_1 \ge \dots \ge |\sigma_d|` and
:math:`\sigma_d < 0` where :math:`\det F < 0`, as :func:`mpmref.physics.materials.signed_svd` returns it.

Every function computes in the dtype of ``F`` (its constants are of that type, the Jacobi tolerance is its round-off)
and writes into arrays the caller provides, which must not alias ``F``.
"""

import math

from ...physics.svd import MAX_SWEEPS, TOL_ULPS
from . import pointwise


@pointwise(inline=True)
def unit_round_off(real):
    r""":math:`\varepsilon` of the floating type ``real``: :math:`2^{-23}` for float32, :math:`2^{-52}` for float64.
    (:math:`1 + 2^{-30}` rounds to 1 in float32 only; a comparison of constants, which the compiler folds.)"""
    if real(1.0) + real(2.0**-30) == real(1.0):
        return real(2.0**-23)
    return real(2.0**-52)


@pointwise(inline=True)
def determinant(F):
    r""":math:`\det F` of a 2×2 or 3×3 ``F`` by cofactors (Laplace expansion along the first row)."""
    if F.shape[0] == 2:
        return F[0, 0] * F[1, 1] - F[0, 1] * F[1, 0]
    return (F[0, 0] * (F[1, 1] * F[2, 2] - F[1, 2] * F[2, 1])
            - F[0, 1] * (F[1, 0] * F[2, 2] - F[1, 2] * F[2, 0])
            + F[0, 2] * (F[1, 0] * F[2, 1] - F[1, 1] * F[2, 0]))


@pointwise(inline=True)
def compose(U, sigma, Vt, out):
    r"""``out`` = :math:`U\operatorname{diag}(\sigma)V^T`."""
    d = out.shape[0]
    for a in range(d):
        for b in range(d):
            s = out.dtype.type(0.0)
            for c in range(d):
                s += U[a, c] * sigma[c] * Vt[c, b]
            out[a, b] = s


@pointwise(inline=True)
def polar_2d(F, R):
    r"""Rotation :math:`R` of the 2×2 polar decomposition :math:`F = RS`, closed form, into ``R``.

    :math:`\theta = \operatorname{atan2}(F_{10} - F_{01}, F_{00} + F_{11})`, :math:`R = R(\theta)`
    (:func:`mpmref.physics.svd.polar_2d`); :math:`R = I` where :math:`F_{00}+F_{11} = F_{10}-F_{01} = 0`.
    Returns :math:`(\cos\theta, \sin\theta)`.
    """
    real = R.dtype.type
    x = F[0, 0] + F[1, 1]
    y = F[1, 0] - F[0, 1]
    h = math.hypot(x, y)
    c, s = real(1.0), real(0.0)
    if h > real(0.0):
        c, s = x / h, y / h
    R[0, 0], R[0, 1], R[1, 0], R[1, 1] = c, -s, s, c
    return c, s


@pointwise(inline=True)
def svd_2d(F, U, sigma, Vt):
    r"""Closed-form signed SVD of a 2×2 ``F`` into ``U``, ``sigma``, ``Vt`` (:func:`mpmref.physics.svd.svd_2d`).

    :math:`F = RS` (:func:`polar_2d`), :math:`\phi = \tfrac12\operatorname{atan2}(2S_{01}, S_{00} - S_{11})`,
    :math:`V = R(\phi)`, :math:`\sigma_1 = \tfrac{S_{00}+S_{11}}{2} + \operatorname{hypot}(\tfrac{S_{00}-S_{11}}{2},
    S_{01})`, :math:`\sigma_2 = \det F/\sigma_1`, :math:`U = RV`.
    """
    real = U.dtype.type
    half = real(0.5)
    c, s = polar_2d(F, U)
    a = c * F[0, 0] + s * F[1, 0]
    d = c * F[1, 1] - s * F[0, 1]
    b = half * ((c * F[0, 1] + s * F[1, 1]) + (c * F[1, 0] - s * F[0, 0]))
    phi = half * math.atan2(real(2.0) * b, a - d)
    cp, sp = math.cos(phi), math.sin(phi)
    Vt[0, 0], Vt[0, 1], Vt[1, 0], Vt[1, 1] = cp, sp, -sp, cp
    s1 = half * (a + d) + math.hypot(half * (a - d), b)
    sigma[0] = s1
    sigma[1] = (F[0, 0] * F[1, 1] - F[0, 1] * F[1, 0]) / s1 if s1 > real(0.0) else real(0.0)
    # U = R V, V = [[cp, -sp], [sp, cp]]
    U[0, 0], U[0, 1], U[1, 0], U[1, 1] = c * cp - s * sp, -c * sp - s * cp, s * cp + c * sp, c * cp - s * sp


@pointwise(inline=True)
def jacobi_pair(x0, x1, x2, y0, y1, y2, v0, v1, v2, w0, w1, w2, tol2, real):
    r"""One one-sided Jacobi rotation of a column pair: ``x``, ``y`` columns ``p, q`` of :math:`B`, ``v``, ``w``
    columns ``p, q`` of :math:`V`. Returns whether it rotated and the 12 new entries.

    No rotation where the columns are orthogonal to the tolerance, :math:`\gamma^2 \le \tau^2\alpha\beta`
    (``tol2`` :math:`= \tau^2`; :math:`\alpha, \beta, \gamma = x\cdot x, y\cdot y, x\cdot y`). The rotation is that of
    :func:`mpmref.physics.svd.jacobi_rotation`, written without dividing by :math:`\gamma`: with
    :math:`u = \beta - \alpha`, :math:`w = 2\gamma`, :math:`(c, s) = (|u| + \operatorname{hypot}(u, w),\
    \operatorname{sign}(u)\,w)\,/\,\|\cdot\|`; :math:`x \leftarrow c\,x - s\,y`, :math:`y \leftarrow s\,x + c\,y`
    (and :math:`v, w` alike)."""
    alpha = x0 * x0 + x1 * x1 + x2 * x2
    beta = y0 * y0 + y1 * y1 + y2 * y2
    gamma = x0 * y0 + x1 * y1 + x2 * y2
    if gamma * gamma <= tol2 * alpha * beta:
        return False, x0, x1, x2, y0, y1, y2, v0, v1, v2, w0, w1, w2
    u = beta - alpha
    two_gamma = gamma + gamma
    den = abs(u) + math.hypot(u, two_gamma)
    num = two_gamma if u >= real(0.0) else -two_gamma
    norm = math.hypot(den, num)
    c, s = den / norm, num / norm
    return (True, c * x0 - s * y0, c * x1 - s * y1, c * x2 - s * y2, s * x0 + c * y0, s * x1 + c * y1, s * x2 + c * y2,
            c * v0 - s * w0, c * v1 - s * w1, c * v2 - s * w2, s * v0 + c * w0, s * v1 + c * w1, s * v2 + c * w2)


@pointwise(inline=True)
def sort_pair(x0, x1, x2, y0, y1, y2, v0, v1, v2, w0, w1, w2):
    r"""Columns ``x, y`` of :math:`B` (``v, w`` of :math:`V`) in order of decreasing length: where
    :math:`\|x\| < \|y\|` they swap and the new second column is negated, so that :math:`\det V` is unchanged (as in
    McAdams et al. 2011)."""
    if x0 * x0 + x1 * x1 + x2 * x2 < y0 * y0 + y1 * y1 + y2 * y2:
        return y0, y1, y2, -x0, -x1, -x2, w0, w1, w2, -v0, -v1, -v2
    return x0, x1, x2, y0, y1, y2, v0, v1, v2, w0, w1, w2


@pointwise(inline=True)
def givens(a, b, real):
    r""":math:`(c, s) = (a, b)/\operatorname{hypot}(a, b)`, so that :math:`c\,a + s\,b = \sqrt{a^2+b^2}` and
    :math:`c\,b - s\,a = 0`; :math:`(1, 0)` where :math:`a = b = 0` (:func:`mpmref.physics.svd.givens`)."""
    r = math.hypot(a, b)
    if r > real(0.0):
        return a / r, b / r
    return real(1.0), real(0.0)


@pointwise(inline=True)
def rotate_pairs(x0, y0, x1, y1, x2, y2, c, s):
    r"""Three pairs :math:`(x, y) \mapsto (c\,x + s\,y,\ c\,y - s\,x)`: the plane rotation of a Givens step, applied to
    two rows of :math:`B` or two columns of :math:`U`."""
    return c * x0 + s * y0, c * y0 - s * x0, c * x1 + s * y1, c * y1 - s * x1, c * x2 + s * y2, c * y2 - s * x2


@pointwise
def svd_3d(F, U, sigma, Vt):
    r"""Signed SVD of a 3×3 ``F`` into ``U``, ``sigma``, ``Vt``.

    :func:`mpmref.physics.svd.svd_3d`, in local variables (``bij`` = :math:`B_{ij}`, ``vij`` = :math:`V_{ij}`,
    ``uij`` = :math:`U_{ij}`): one-sided Jacobi sweeps over the column pairs (0,1), (0,2), (1,2) of :math:`B = FV`
    until a sweep rotates none (at most ``MAX_SWEEPS``), sorting by column length with sign-preserving swaps, then
    :math:`B = QR` by Givens rotations that zero :math:`B_{10}, B_{20}, B_{21}`, :math:`U = Q`,
    :math:`\sigma_i = R_{ii}` (after McAdams et al. 2011).
    """
    real = U.dtype.type
    tol2 = real((TOL_ULPS * float(unit_round_off(real))) ** 2)
    one, zero = real(1.0), real(0.0)
    b00, b01, b02 = F[0, 0], F[0, 1], F[0, 2]
    b10, b11, b12 = F[1, 0], F[1, 1], F[1, 2]
    b20, b21, b22 = F[2, 0], F[2, 1], F[2, 2]
    v00, v01, v02 = one, zero, zero
    v10, v11, v12 = zero, one, zero
    v20, v21, v22 = zero, zero, one
    for _ in range(MAX_SWEEPS):
        r01, b00, b10, b20, b01, b11, b21, v00, v10, v20, v01, v11, v21 = jacobi_pair(
            b00, b10, b20, b01, b11, b21, v00, v10, v20, v01, v11, v21, tol2, real)
        r02, b00, b10, b20, b02, b12, b22, v00, v10, v20, v02, v12, v22 = jacobi_pair(
            b00, b10, b20, b02, b12, b22, v00, v10, v20, v02, v12, v22, tol2, real)
        r12, b01, b11, b21, b02, b12, b22, v01, v11, v21, v02, v12, v22 = jacobi_pair(
            b01, b11, b21, b02, b12, b22, v01, v11, v21, v02, v12, v22, tol2, real)
        if not (r01 or r02 or r12):
            break
    b00, b10, b20, b01, b11, b21, v00, v10, v20, v01, v11, v21 = sort_pair(
        b00, b10, b20, b01, b11, b21, v00, v10, v20, v01, v11, v21)
    b00, b10, b20, b02, b12, b22, v00, v10, v20, v02, v12, v22 = sort_pair(
        b00, b10, b20, b02, b12, b22, v00, v10, v20, v02, v12, v22)
    b01, b11, b21, b02, b12, b22, v01, v11, v21, v02, v12, v22 = sort_pair(
        b01, b11, b21, b02, b12, b22, v01, v11, v21, v02, v12, v22)
    # QR: rows (0, 1) zero B10; U = G1^T
    c, s = givens(b00, b10, real)
    b00, b10, b01, b11, b02, b12 = rotate_pairs(b00, b10, b01, b11, b02, b12, c, s)
    u00, u01, u02 = c, -s, zero
    u10, u11, u12 = s, c, zero
    u20, u21, u22 = zero, zero, one
    # rows (0, 2) zero B20; U <- U G2^T acts on columns 0, 2
    c, s = givens(b00, b20, real)
    b00, b20, b01, b21, b02, b22 = rotate_pairs(b00, b20, b01, b21, b02, b22, c, s)
    u00, u02, u10, u12, u20, u22 = rotate_pairs(u00, u02, u10, u12, u20, u22, c, s)
    # rows (1, 2) zero B21; U <- U G3^T acts on columns 1, 2
    c, s = givens(b11, b21, real)
    b10, b20, b11, b21, b12, b22 = rotate_pairs(b10, b20, b11, b21, b12, b22, c, s)  # column 0 is 0 already
    u01, u02, u11, u12, u21, u22 = rotate_pairs(u01, u02, u11, u12, u21, u22, c, s)
    U[0, 0], U[0, 1], U[0, 2] = u00, u01, u02
    U[1, 0], U[1, 1], U[1, 2] = u10, u11, u12
    U[2, 0], U[2, 1], U[2, 2] = u20, u21, u22
    sigma[0], sigma[1], sigma[2] = b00, b11, b22
    Vt[0, 0], Vt[0, 1], Vt[0, 2] = v00, v10, v20
    Vt[1, 0], Vt[1, 1], Vt[1, 2] = v01, v11, v21
    Vt[2, 0], Vt[2, 1], Vt[2, 2] = v02, v12, v22


@pointwise(inline=True)
def signed_svd(F, U, sigma, Vt):
    r"""Signed SVD :math:`F = U\Sigma V^T` of a 2×2 or 3×3 ``F`` (closed form or Jacobi) into ``U``, ``sigma``,
    ``Vt``."""
    if F.shape[0] == 2:
        svd_2d(F, U, sigma, Vt)
    else:
        svd_3d(F, U, sigma, Vt)


@pointwise(inline=True)
def polar_rotation(F, R, U, sigma, Vt):
    r"""Rotation :math:`R = UV^T` of the polar decomposition of a 2×2 or 3×3 ``F`` into ``R``.

    2D: the closed form of :func:`polar_2d` (no SVD). 3D: :math:`UV^T` of :func:`svd_3d`; ``U``, ``sigma``, ``Vt``
    are (d, d), (d,), (d, d) work arrays (they hold the SVD afterwards in 3D).
    """
    if F.shape[0] == 2:
        polar_2d(F, R)
        return
    svd_3d(F, U, sigma, Vt)
    for i in range(3):
        for j in range(3):
            acc = R.dtype.type(0.0)
            for k in range(3):
                acc += U[i, k] * Vt[k, j]
            R[i, j] = acc
