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


@njit(cache=True)
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


@njit(cache=True)
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


@njit(cache=True)
def _rotate_columns(A, p, q, c, s):
    r"""Columns :math:`a_p \leftarrow c\,a_p - s\,a_q`, :math:`a_q \leftarrow s\,a_p + c\,a_q` of a 3×3 ``A``."""
    for i in range(3):
        ap, aq = A[i, p], A[i, q]
        A[i, p] = c * ap - s * aq
        A[i, q] = s * ap + c * aq


@njit(cache=True)
def _jacobi_pair(B, V, p, q, tol):
    r"""One one-sided Jacobi rotation of columns ``p, q`` of ``B`` and ``V``, unless they are already orthogonal
    to ``tol`` (:func:`mpmref.physics.svd.jacobi_rotation`). Returns whether it rotated."""
    T = B.dtype.type
    one = T(1.0)
    alpha, beta, gamma = T(0.0), T(0.0), T(0.0)
    for i in range(3):
        alpha += B[i, p] * B[i, p]
        beta += B[i, q] * B[i, q]
        gamma += B[i, p] * B[i, q]
    if abs(gamma) <= tol * (np.sqrt(alpha) * np.sqrt(beta)):
        return False
    zeta = (beta - alpha) / (T(2.0) * gamma)
    t = (one if zeta >= 0 else -one) / (abs(zeta) + np.hypot(one, zeta))
    c = one / np.sqrt(one + t * t)
    s = c * t
    _rotate_columns(B, p, q, c, s)
    _rotate_columns(V, p, q, c, s)
    return True


@njit(cache=True)
def _sort_pair(B, V, p, q):
    r"""Swap columns ``p, q`` of ``B`` and ``V`` if :math:`\|b_p\| < \|b_q\|`, negating the new column ``q`` so
    that :math:`\det V` is unchanged (McAdams et al. 2011 §3)."""
    T = B.dtype.type
    np_, nq = T(0.0), T(0.0)
    for i in range(3):
        np_ += B[i, p] * B[i, p]
        nq += B[i, q] * B[i, q]
    if np_ < nq:
        for i in range(3):
            B[i, p], B[i, q] = B[i, q], -B[i, p]
            V[i, p], V[i, q] = V[i, q], -V[i, p]


@njit(cache=True)
def _givens_step(B, U, p, q, col):
    r"""Zero ``B[q, col]`` against ``B[p, col]`` by a Givens rotation of rows ``p, q`` (:math:`B \leftarrow GB`)
    and accumulate :math:`U \leftarrow UG^T` (:func:`mpmref.physics.svd.givens`)."""
    T = B.dtype.type
    a, b = B[p, col], B[q, col]
    r = np.hypot(a, b)
    if r > 0:
        c, s = a / r, b / r
    else:
        c, s = T(1.0), T(0.0)
    for j in range(3):
        bp, bq = B[p, j], B[q, j]
        B[p, j] = c * bp + s * bq
        B[q, j] = c * bq - s * bp
    _rotate_columns(U, p, q, c, -s)


@njit(cache=True)
def svd_3d_into(F, U, sigma, Vt, B):
    r"""Signed SVD of a 3×3 ``F`` into ``U``, ``sigma``, ``Vt``; ``B`` is a 3×3 scratch array.

    :func:`mpmref.physics.svd.svd_3d`, per particle: one-sided Jacobi sweeps over the column pairs
    (0,1), (0,2), (1,2) of :math:`B = FV` until a sweep rotates none (at most ``MAX_SWEEPS``), sorting by
    column length with sign-preserving swaps, then :math:`B = QR` by Givens rotations, :math:`U = Q`,
    :math:`\sigma_i = R_{ii}` (McAdams et al. 2011 §2–§4). :math:`V` is built in ``Vt`` and transposed in
    place at the end.
    """
    T = F.dtype.type
    tol = T(TOL_ULPS * np.finfo(F.dtype).eps)
    V = Vt
    for i in range(3):
        for j in range(3):
            B[i, j] = F[i, j]
            V[i, j] = T(1.0) if i == j else T(0.0)
            U[i, j] = T(1.0) if i == j else T(0.0)
    for _ in range(MAX_SWEEPS):
        r01 = _jacobi_pair(B, V, 0, 1, tol)
        r02 = _jacobi_pair(B, V, 0, 2, tol)
        r12 = _jacobi_pair(B, V, 1, 2, tol)
        if not (r01 or r02 or r12):
            break
    _sort_pair(B, V, 0, 1)
    _sort_pair(B, V, 0, 2)
    _sort_pair(B, V, 1, 2)
    _givens_step(B, U, 0, 1, 0)
    _givens_step(B, U, 0, 2, 0)
    _givens_step(B, U, 1, 2, 1)
    for i in range(3):
        sigma[i] = B[i, i]
    for i in range(3):  # V -> V^T in place
        for j in range(i + 1, 3):
            Vt[i, j], Vt[j, i] = Vt[j, i], Vt[i, j]


@njit(cache=True)
def signed_svd_into(F, U, sigma, Vt, work):
    r"""Signed SVD :math:`F = U\Sigma V^T` of a 2×2 or 3×3 ``F`` (closed form or Jacobi) into ``U``, ``sigma``,
    ``Vt``; ``work`` is a (d, d) scratch array (unused in 2D)."""
    if F.shape[0] == 2:
        svd_2d_into(F, U, sigma, Vt)
    else:
        svd_3d_into(F, U, sigma, Vt, work)


@njit(cache=True)
def signed_svd(F):
    r"""Signed SVD of one (d, d) ``F``, allocating: returns ``U``, ``sigma``, ``Vt`` (as
    :func:`mpmref.physics.materials.signed_svd` for one matrix)."""
    d = F.shape[0]
    U = np.empty((d, d), F.dtype)
    sigma = np.empty(d, F.dtype)
    Vt = np.empty((d, d), F.dtype)
    work = np.empty((d, d), F.dtype)
    signed_svd_into(F, U, sigma, Vt, work)
    return U, sigma, Vt


@njit(cache=True)
def polar_rotation_into(F, R, U, sigma, Vt, work):
    r"""Rotation :math:`R = UV^T` of the polar decomposition of a 2×2 or 3×3 ``F`` into ``R``.

    2D: the closed form of :func:`polar_2d_into` (no eigen-decomposition). 3D: :math:`UV^T` of
    :func:`svd_3d_into`; ``U``, ``sigma``, ``Vt`` and ``work`` are (d, d), (d,), (d, d), (d, d) scratch
    arrays (they hold the SVD afterwards in 3D).
    """
    d = F.shape[0]
    if d == 2:
        polar_2d_into(F, R)
        return
    svd_3d_into(F, U, sigma, Vt, work)
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
    work = np.empty((d, d), F.dtype)
    polar_rotation_into(F, R, U, sigma, Vt, work)
    return R
