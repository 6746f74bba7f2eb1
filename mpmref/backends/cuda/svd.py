r"""Signed SVD and polar decomposition of one small matrix per thread, as numba-cuda device functions.

The algorithms of :mod:`mpmref.physics.svd` (read its docstrings for the method, its sources and its accuracy):
the closed-form 2×2 polar decomposition and SVD of the talk's 88-line program (Hu et al. 2018), and for 3×3
one-sided Jacobi sweeps to a fixed tolerance, sorting by column length, and a QR by Givens rotations after
McAdams et al. 2011. The result is the *signed* SVD :math:`F = U\Sigma V^T` with :math:`U, V` rotations,
:math:`\sigma_1 \ge \dots \ge |\sigma_d|` and :math:`\sigma_d < 0` where :math:`\det F < 0`.

The functions work on per-thread local arrays (``cuda.local.array``) of the dtype :func:`make_svd` is made for:
every constant is of that dtype, so a float32 run computes in float32, and the Jacobi tolerance is that dtype's
round-off (:data:`mpmref.physics.svd.TOL_ULPS` ulps). All are inlined into their callers by NVVM
(:func:`~mpmref.backends.cuda.launch.device_function`).
"""

import math
from functools import lru_cache
from types import SimpleNamespace

import numpy as np

from ...physics.svd import MAX_SWEEPS, PAIRS_3D, TOL_ULPS
from .launch import device_function, real_types
from .runtime import cuda, load


@lru_cache(maxsize=None)
def make_svd(dtype, dim):
    """The device functions of the decompositions of ``dim`` × ``dim`` matrices in ``dtype``: a namespace with
    ``signed_svd(F, U, sigma, Vt)`` and ``polar_rotation(F, R, U, sigma, Vt)``."""
    load()
    T, nb = real_types(dtype)
    one, zero, half, two = T(1.0), T(0.0), T(0.5), T(2.0)
    tol2 = T((TOL_ULPS * np.finfo(T).eps) ** 2)
    first, second = tuple(p for p, _ in PAIRS_3D), tuple(q for _, q in PAIRS_3D)

    @device_function
    def polar_2d(F, R):
        r"""Rotation of :math:`F = RS` into ``R``: :math:`\theta = \operatorname{atan2}(F_{10} - F_{01}, F_{00} +
        F_{11})` (:func:`mpmref.physics.svd.polar_2d`), :math:`R = I` where both are 0; returns
        :math:`(\cos\theta, \sin\theta)`."""
        x = F[0, 0] + F[1, 1]
        y = F[1, 0] - F[0, 1]
        h = math.hypot(x, y)
        c, s = one, zero
        if h > zero:
            c, s = x / h, y / h
        R[0, 0], R[0, 1], R[1, 0], R[1, 1] = c, -s, s, c
        return c, s

    @device_function
    def svd_2d(F, U, sigma, Vt):
        r"""Closed-form signed SVD of a 2×2 ``F`` (:func:`mpmref.physics.svd.svd_2d`): :math:`S = R^TF`,
        :math:`\phi = \tfrac12\operatorname{atan2}(2S_{01}, S_{00} - S_{11})`, :math:`V = R(\phi)`,
        :math:`\sigma_1 = \tfrac{S_{00}+S_{11}}2 + \operatorname{hypot}(\tfrac{S_{00}-S_{11}}2, S_{01})`,
        :math:`\sigma_2 = \det F / \sigma_1`, :math:`U = RV`."""
        c, s = polar_2d(F, U)
        a = c * F[0, 0] + s * F[1, 0]
        d = c * F[1, 1] - s * F[0, 1]
        b = half * ((c * F[0, 1] + s * F[1, 1]) + (c * F[1, 0] - s * F[0, 0]))
        phi = half * math.atan2(two * b, a - d)
        cp, sp = math.cos(phi), math.sin(phi)
        Vt[0, 0], Vt[0, 1], Vt[1, 0], Vt[1, 1] = cp, sp, -sp, cp
        s1 = half * (a + d) + math.hypot(half * (a - d), b)
        sigma[0] = s1
        sigma[1] = zero
        if s1 > zero:
            sigma[1] = (F[0, 0] * F[1, 1] - F[0, 1] * F[1, 0]) / s1
        U[0, 0], U[0, 1] = c * cp - s * sp, -(c * sp + s * cp)
        U[1, 0], U[1, 1] = s * cp + c * sp, c * cp - s * sp

    @device_function
    def rotate_columns(A, p, q, c, s):
        r"""Columns :math:`a_p \leftarrow c\,a_p - s\,a_q`, :math:`a_q \leftarrow s\,a_p + c\,a_q` of a 3×3 ``A``."""
        for i in range(3):
            ap, aq = A[i, p], A[i, q]
            A[i, p] = c * ap - s * aq
            A[i, q] = s * ap + c * aq

    @device_function
    def column_dot(A, p, q):
        """The dot product of columns ``p`` and ``q`` of a 3×3 ``A``."""
        return A[0, p] * A[0, q] + A[1, p] * A[1, q] + A[2, p] * A[2, q]

    @device_function
    def jacobi_rotation(alpha, beta, gamma):
        r""":math:`(c, s)` of the one-sided Jacobi rotation (:func:`mpmref.physics.svd.jacobi_rotation`):
        :math:`u = \beta - \alpha`, :math:`w = 2\gamma`, :math:`(c, s) \propto (|u| + \operatorname{hypot}(u, w),
        \operatorname{sign}(u) w)`."""
        u = beta - alpha
        w = gamma + gamma
        den = abs(u) + math.hypot(u, w)
        num = w if u >= zero else -w
        norm = math.hypot(den, num)
        return den / norm, num / norm

    @device_function
    def givens(a, b):
        r""":math:`(c, s) = (a, b)/\operatorname{hypot}(a, b)`, :math:`(1, 0)` where both are 0
        (:func:`mpmref.physics.svd.givens`)."""
        r = math.hypot(a, b)
        if r > zero:
            return a / r, b / r
        return one, zero

    @device_function
    def svd_3d(F, U, sigma, Vt):
        r"""Signed SVD of a 3×3 ``F`` into ``U``, ``sigma``, ``Vt`` (:func:`mpmref.physics.svd.svd_3d`): Jacobi sweeps
        over the column pairs of :math:`B = FV` until none rotates (at most ``MAX_SWEEPS``), the columns sorted by
        decreasing length (a swap negates the new second column, keeping :math:`\det V = 1`), then :math:`B = QR`
        by Givens rotations, :math:`U = Q`, :math:`\sigma_i = R_{ii}`."""
        B = cuda.local.array((3, 3), nb)
        V = cuda.local.array((3, 3), nb)
        for i in range(3):
            for j in range(3):
                B[i, j] = F[i, j]
                V[i, j] = one if i == j else zero
                U[i, j] = one if i == j else zero
        for _ in range(MAX_SWEEPS):
            rotated = False
            for k in range(3):
                p, q = first[k], second[k]
                alpha, beta, gamma = column_dot(B, p, p), column_dot(B, q, q), column_dot(B, p, q)
                if gamma * gamma > tol2 * alpha * beta:
                    rotated = True
                    c, s = jacobi_rotation(alpha, beta, gamma)
                    rotate_columns(B, p, q, c, s)
                    rotate_columns(V, p, q, c, s)
            if not rotated:
                break
        for k in range(3):
            p, q = first[k], second[k]
            if column_dot(B, p, p) < column_dot(B, q, q):
                for A in (B, V):
                    for i in range(3):
                        A[i, p], A[i, q] = A[i, q], -A[i, p]
        for k in range(3):  # rows (p, q) zero B[q, col], col = 0, 0, 1
            p, q = first[k], second[k]
            col = p
            c, s = givens(B[p, col], B[q, col])
            for j in range(3):
                bp, bq = B[p, j], B[q, j]
                B[p, j] = c * bp + s * bq
                B[q, j] = c * bq - s * bp
            rotate_columns(U, p, q, c, -s)
        for i in range(3):
            sigma[i] = B[i, i]
            for j in range(3):
                Vt[i, j] = V[j, i]

    @device_function
    def polar_from_svd(F, R, U, sigma, Vt):
        r"""Rotation :math:`R = UV^T` of :math:`F = RS` into ``R`` from :func:`svd_3d` (``U``, ``sigma``, ``Vt`` are
        work arrays and hold the SVD afterwards)."""
        svd_3d(F, U, sigma, Vt)
        for i in range(3):
            for j in range(3):
                R[i, j] = U[i, 0] * Vt[0, j] + U[i, 1] * Vt[1, j] + U[i, 2] * Vt[2, j]

    @device_function
    def polar_closed_form(F, R, U, sigma, Vt):
        r"""Rotation :math:`R` of :math:`F = RS` into ``R`` by :func:`polar_2d` (the work arrays are unused)."""
        polar_2d(F, R)

    if dim == 2:
        return SimpleNamespace(signed_svd=svd_2d, polar_rotation=polar_closed_form)
    return SimpleNamespace(signed_svd=svd_3d, polar_rotation=polar_from_svd)

