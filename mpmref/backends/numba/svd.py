r"""Fast signed SVD and polar decomposition for the Numba material kernels, one particle at a time.

The algorithms, conventions and sources are those of :mod:`mpmref.physics.svd` (read its docstrings):
the closed-form 2×2 polar decomposition and SVD of the talk's 88-line program, and for 3×3 one-sided
Jacobi sweeps to a fixed tolerance, sorting, and a QR by Givens rotations after McAdams et al. 2011.
The result is the *signed* SVD :math:`F = U\Sigma V^T` with :math:`U, V` rotations and
:math:`\sigma_1 \ge \dots \ge |\sigma_d|`, :math:`\sigma_d < 0` where :math:`\det F < 0`, as
:func:`mpmref.physics.materials.signed_svd` returns it.

Every function writes into arrays the caller provides, so a kernel can allocate them once per chunk of
particles rather than once per particle, and computes in the dtype of ``F`` (float32 or float64: every
constant is converted with ``F.dtype.type``, the tolerance is that dtype's round-off). Outputs must not
alias ``F``.
"""

import numpy as np
from numba import njit

from ...physics.svd import MAX_SWEEPS, TOL_ULPS


@njit(cache=True, inline="always")
def polar_2d_into(F, R):
    r"""Rotation :math:`R` of the 2×2 polar decomposition :math:`F = RS`, closed form, into ``R``.

    :math:`\theta = \operatorname{atan2}(F_{10} - F_{01}, F_{00} + F_{11})`, :math:`R = R(\theta)`
    (:func:`mpmref.physics.svd.polar_2d`); :math:`R = I` where :math:`F_{00}+F_{11} = F_{10}-F_{01} = 0`.
    Returns :math:`(\cos\theta, \sin\theta)`.
    """
    T = F.dtype.type
    x = F[0, 0] + F[1, 1]
    y = F[1, 0] - F[0, 1]
    h = np.hypot(x, y)
    if h > 0:
        c, s = x / h, y / h
    else:
        c, s = T(1.0), T(0.0)
    R[0, 0], R[0, 1], R[1, 0], R[1, 1] = c, -s, s, c
    return c, s


@njit(cache=True, inline="always")
def svd_2d_into(F, U, sigma, Vt):
    r"""Closed-form signed SVD of a 2×2 ``F`` into ``U``, ``sigma``, ``Vt`` (:func:`mpmref.physics.svd.svd_2d`).

    :math:`F = RS` (:func:`polar_2d_into`), :math:`\phi = \tfrac12\operatorname{atan2}(2S_{01}, S_{00} -
    S_{11})`, :math:`V = R(\phi)`, :math:`\sigma_1 = \tfrac{S_{00}+S_{11}}{2} + \sqrt{(\tfrac{S_{00}-S_{11}}{2})^2
    + S_{01}^2}`, :math:`\sigma_2 = \det F/\sigma_1`, :math:`U = RV`.
    """
    T = F.dtype.type
    half = T(0.5)
    c, s = polar_2d_into(F, U)
    a = c * F[0, 0] + s * F[1, 0]
    d = c * F[1, 1] - s * F[0, 1]
    b = half * ((c * F[0, 1] + s * F[1, 1]) + (c * F[1, 0] - s * F[0, 0]))
    phi = half * np.arctan2(T(2.0) * b, a - d)
    cp, sp = np.cos(phi), np.sin(phi)
    Vt[0, 0], Vt[0, 1], Vt[1, 0], Vt[1, 1] = cp, sp, -sp, cp
    s1 = half * (a + d) + np.hypot(half * (a - d), b)
    sigma[0] = s1
    sigma[1] = (F[0, 0] * F[1, 1] - F[0, 1] * F[1, 0]) / s1 if s1 > 0 else T(0.0)
    # U = R V, V = [[cp, -sp], [sp, cp]]
    U[0, 0], U[0, 1], U[1, 0], U[1, 1] = c * cp - s * sp, -c * sp - s * cp, s * cp + c * sp, c * cp - s * sp


@njit(cache=True, inline="always")
def _jacobi_pair(x0, x1, x2, y0, y1, y2, v0, v1, v2, w0, w1, w2, tol2):
    r"""One one-sided Jacobi rotation of a column pair: ``x``, ``y`` columns ``p, q`` of :math:`B`, ``v``, ``w``
    columns ``p, q`` of :math:`V`. Returns whether it rotated and the 12 new entries.

    No rotation where the columns are orthogonal to the tolerance, :math:`\gamma^2 \le \tau^2\alpha\beta`
    (``tol2`` :math:`= \tau^2`; :math:`\alpha, \beta, \gamma = x\cdot x, y\cdot y, x\cdot y`). The rotation
    is that of :func:`mpmref.physics.svd.jacobi_rotation`, written without dividing by :math:`\gamma`
    (fewer dependent divisions and square roots on the critical path): with :math:`u = \beta - \alpha`,
    :math:`w = 2\gamma`, the tangent :math:`t = \operatorname{sign}(u)\,w/(|u| + \sqrt{u^2 + w^2})` and
    :math:`(c, s) = (|u| + \sqrt{u^2+w^2},\ \operatorname{sign}(u)\,w)\,/\,\|\cdot\|`;
    :math:`x \leftarrow c\,x - s\,y`, :math:`y \leftarrow s\,x + c\,y` (and :math:`v, w` alike)."""
    alpha = x0 * x0 + x1 * x1 + x2 * x2
    beta = y0 * y0 + y1 * y1 + y2 * y2
    gamma = x0 * y0 + x1 * y1 + x2 * y2
    if gamma * gamma <= tol2 * alpha * beta:
        return False, x0, x1, x2, y0, y1, y2, v0, v1, v2, w0, w1, w2
    u = beta - alpha
    two_gamma = gamma + gamma
    den = abs(u) + np.hypot(u, two_gamma)
    num = two_gamma if u >= 0 else -two_gamma
    norm = np.hypot(den, num)
    c, s = den / norm, num / norm
    return (True, c * x0 - s * y0, c * x1 - s * y1, c * x2 - s * y2, s * x0 + c * y0, s * x1 + c * y1, s * x2 + c * y2,
            c * v0 - s * w0, c * v1 - s * w1, c * v2 - s * w2, s * v0 + c * w0, s * v1 + c * w1, s * v2 + c * w2)


@njit(cache=True, inline="always")
def _sort_pair(x0, x1, x2, y0, y1, y2, v0, v1, v2, w0, w1, w2):
    r"""Columns ``x, y`` of :math:`B` (``v, w`` of :math:`V`) in order of decreasing length: where
    :math:`\|x\| < \|y\|` they swap and the new second column is negated, so that :math:`\det V` is unchanged
    (as in McAdams et al. 2011)."""
    if x0 * x0 + x1 * x1 + x2 * x2 < y0 * y0 + y1 * y1 + y2 * y2:
        return y0, y1, y2, -x0, -x1, -x2, w0, w1, w2, -v0, -v1, -v2
    return x0, x1, x2, y0, y1, y2, v0, v1, v2, w0, w1, w2


@njit(cache=True, inline="always")
def _givens(a, b, one, zero):
    r""":math:`(c, s)` with :math:`c\,a + s\,b = \sqrt{a^2+b^2}`, :math:`c\,b - s\,a = 0`
    (:func:`mpmref.physics.svd.givens`; :math:`(1, 0)` where :math:`a = b = 0`). ``one``, ``zero``: 1 and 0
    in the dtype (an integer literal would promote float32 to float64)."""
    r = np.sqrt(a * a + b * b)
    if r > 0:
        return a / r, b / r
    return one, zero


@njit(cache=True, inline="always")
def _rotate(x, y, c, s):
    r""":math:`(c\,x + s\,y,\ c\,y - s\,x)`: the plane rotation of a Givens step."""
    return c * x + s * y, c * y - s * x


@njit(cache=True)
def svd_3d_into(F, U, sigma, Vt):
    r"""Signed SVD of a 3×3 ``F`` into ``U``, ``sigma``, ``Vt``.

    :func:`mpmref.physics.svd.svd_3d`, per particle and in local variables (``bij`` = :math:`B_{ij}`,
    ``vij`` = :math:`V_{ij}`, ``uij`` = :math:`U_{ij}`): one-sided Jacobi sweeps over the column pairs
    (0,1), (0,2), (1,2) of :math:`B = FV` until a sweep rotates none (at most ``MAX_SWEEPS``), sorting by
    column length with sign-preserving swaps, then :math:`B = QR` by Givens rotations that zero
    :math:`B_{10}, B_{20}, B_{21}`, :math:`U = Q`, :math:`\sigma_i = R_{ii}` (after McAdams et al. 2011).
    """
    T = F.dtype.type
    tol2 = T((TOL_ULPS * np.finfo(F.dtype).eps) ** 2)
    one, zero = T(1.0), T(0.0)
    b00, b01, b02 = F[0, 0], F[0, 1], F[0, 2]
    b10, b11, b12 = F[1, 0], F[1, 1], F[1, 2]
    b20, b21, b22 = F[2, 0], F[2, 1], F[2, 2]
    v00, v01, v02 = one, zero, zero
    v10, v11, v12 = zero, one, zero
    v20, v21, v22 = zero, zero, one
    for _ in range(MAX_SWEEPS):
        r01, b00, b10, b20, b01, b11, b21, v00, v10, v20, v01, v11, v21 = _jacobi_pair(
            b00, b10, b20, b01, b11, b21, v00, v10, v20, v01, v11, v21, tol2)
        r02, b00, b10, b20, b02, b12, b22, v00, v10, v20, v02, v12, v22 = _jacobi_pair(
            b00, b10, b20, b02, b12, b22, v00, v10, v20, v02, v12, v22, tol2)
        r12, b01, b11, b21, b02, b12, b22, v01, v11, v21, v02, v12, v22 = _jacobi_pair(
            b01, b11, b21, b02, b12, b22, v01, v11, v21, v02, v12, v22, tol2)
        if not (r01 or r02 or r12):
            break
    b00, b10, b20, b01, b11, b21, v00, v10, v20, v01, v11, v21 = _sort_pair(
        b00, b10, b20, b01, b11, b21, v00, v10, v20, v01, v11, v21)
    b00, b10, b20, b02, b12, b22, v00, v10, v20, v02, v12, v22 = _sort_pair(
        b00, b10, b20, b02, b12, b22, v00, v10, v20, v02, v12, v22)
    b01, b11, b21, b02, b12, b22, v01, v11, v21, v02, v12, v22 = _sort_pair(
        b01, b11, b21, b02, b12, b22, v01, v11, v21, v02, v12, v22)
    # QR: rows (0, 1) zero B10; U = G1^T
    c, s = _givens(b00, b10, one, zero)
    b00, b10 = _rotate(b00, b10, c, s)
    b01, b11 = _rotate(b01, b11, c, s)
    b02, b12 = _rotate(b02, b12, c, s)
    u00, u01, u02 = c, -s, zero
    u10, u11, u12 = s, c, zero
    u20, u21, u22 = zero, zero, one
    # rows (0, 2) zero B20; U <- U G2^T acts on columns 0, 2
    c, s = _givens(b00, b20, one, zero)
    b00, b20 = _rotate(b00, b20, c, s)
    b01, b21 = _rotate(b01, b21, c, s)
    b02, b22 = _rotate(b02, b22, c, s)
    u00, u02 = _rotate(u00, u02, c, s)
    u10, u12 = _rotate(u10, u12, c, s)
    u20, u22 = _rotate(u20, u22, c, s)
    # rows (1, 2) zero B21; U <- U G3^T acts on columns 1, 2
    c, s = _givens(b11, b21, one, zero)
    b11, b21 = _rotate(b11, b21, c, s)
    b12, b22 = _rotate(b12, b22, c, s)
    u01, u02 = _rotate(u01, u02, c, s)
    u11, u12 = _rotate(u11, u12, c, s)
    u21, u22 = _rotate(u21, u22, c, s)
    U[0, 0], U[0, 1], U[0, 2] = u00, u01, u02
    U[1, 0], U[1, 1], U[1, 2] = u10, u11, u12
    U[2, 0], U[2, 1], U[2, 2] = u20, u21, u22
    sigma[0], sigma[1], sigma[2] = b00, b11, b22
    Vt[0, 0], Vt[0, 1], Vt[0, 2] = v00, v10, v20
    Vt[1, 0], Vt[1, 1], Vt[1, 2] = v01, v11, v21
    Vt[2, 0], Vt[2, 1], Vt[2, 2] = v02, v12, v22


@njit(cache=True, inline="always")
def signed_svd_into(F, U, sigma, Vt):
    r"""Signed SVD :math:`F = U\Sigma V^T` of a 2×2 or 3×3 ``F`` (closed form or Jacobi) into ``U``, ``sigma``,
    ``Vt``."""
    if F.shape[0] == 2:
        svd_2d_into(F, U, sigma, Vt)
    else:
        svd_3d_into(F, U, sigma, Vt)


@njit(cache=True)
def signed_svd(F):
    r"""Signed SVD of one (d, d) ``F``, allocating: returns ``U``, ``sigma``, ``Vt`` (as
    :func:`mpmref.physics.materials.signed_svd` for one matrix)."""
    d = F.shape[0]
    U = np.empty((d, d), F.dtype)
    sigma = np.empty(d, F.dtype)
    Vt = np.empty((d, d), F.dtype)
    signed_svd_into(F, U, sigma, Vt)
    return U, sigma, Vt


@njit(cache=True, inline="always")
def polar_rotation_into(F, R, U, sigma, Vt):
    r"""Rotation :math:`R = UV^T` of the polar decomposition of a 2×2 or 3×3 ``F`` into ``R``.

    2D: the closed form of :func:`polar_2d_into` (no eigen-decomposition). 3D: :math:`UV^T` of
    :func:`svd_3d_into`; ``U``, ``sigma``, ``Vt`` are (d, d), (d,), (d, d) work arrays (they hold the SVD
    afterwards in 3D).
    """
    d = F.shape[0]
    if d == 2:
        polar_2d_into(F, R)
        return
    svd_3d_into(F, U, sigma, Vt)
    T = F.dtype.type
    for i in range(3):
        for j in range(3):
            acc = T(0.0)
            for k in range(3):
                acc += U[i, k] * Vt[k, j]
            R[i, j] = acc


@njit(cache=True)
def polar_rotation(F):
    r"""Rotation :math:`R` of the polar decomposition of one (d, d) ``F``, allocating."""
    d = F.shape[0]
    R = np.empty((d, d), F.dtype)
    U = np.empty((d, d), F.dtype)
    sigma = np.empty(d, F.dtype)
    Vt = np.empty((d, d), F.dtype)
    polar_rotation_into(F, R, U, sigma, Vt)
    return R
