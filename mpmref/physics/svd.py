r"""Fast signed SVD and polar decomposition of small matrices, vectorised over particles.

The constitutive models need, per particle, the *signed* singular value decomposition

.. math:: F = U\,\Sigma\,V^T,\qquad \det U = \det V = +1,\qquad
          \sigma_1 \ge \dots \ge \sigma_{d-1} \ge |\sigma_d|,

whose last singular value is negative exactly where :math:`\det F < 0` (Irving et al. 2004 §4), and the
rotation :math:`R = UV^T` of the polar decomposition :math:`F = RS` (Stomakhin et al. 2012 §4). This is the
convention of :func:`mpmref.physics.materials.signed_svd`, which obtains it from LAPACK
(``np.linalg.svd``) and then flips a sign. This module obtains it without LAPACK:

* **2D, closed form** (as in the talk's 88-line MLS-MPM program, Hu et al. 2018): the rotation of the polar
  decomposition comes from the angle of the antisymmetric against the symmetric part of :math:`F`
  (:func:`polar_2d`), and the symmetric factor :math:`S = R^TF` is diagonalised by one Jacobi rotation
  (:func:`svd_2d`).
* **3D, Jacobi** (after McAdams et al. 2011, "Computing the singular value decomposition of 3×3 matrices
  with minimal branching and elementary floating point operations": Jacobi eigenanalysis, sorting, QR by
  Givens rotations): cyclic Jacobi sweeps build a
  rotation :math:`V` that orthogonalises the columns of :math:`B = FV`; the columns are sorted by length
  (a swap negates one column so that :math:`\det V` stays +1); a QR factorisation of :math:`B` by three
  Givens rotations gives :math:`U = Q` and :math:`\Sigma = \operatorname{diag}(R)` (:func:`svd_3d`). Where
  McAdams et al. diagonalise :math:`F^TF` with a fixed number of sweeps of *approximate* rotations (single
  precision), the sweeps here use exact rotations computed from the current columns of :math:`B`
  (one-sided Jacobi, Hestenes 1958; Demmel & Veselić 1992) and stop at a fixed tolerance: :math:`F^TF`
  squares the condition number, and a matrix with two singular values below
  :math:`\sqrt{\varepsilon}\,\sigma_1` would lose them entirely.

Both are backward stable: the computed factors are exact for a matrix :math:`F + \delta F` with
:math:`\|\delta F\| \le c\,\varepsilon\,\|F\|` (:math:`\varepsilon` the machine epsilon of the dtype).
``tests/test_svd.py`` checks this, and the agreement with LAPACK, by hypothesis.

The NumPy reference backend does **not** use this module: its materials keep ``np.linalg.svd``
(:func:`mpmref.physics.materials.signed_svd`), an implementation independent of the one the Numba backend
compiles (:mod:`mpmref.backends.pointwise.svd`, the same algorithm as here, per particle). The conformance
harness therefore checks the fast SVD against LAPACK on every stress and return-map case, instead of
checking one algorithm against itself; it holds at :math:`10^{-12}` because both factorisations are
backward stable and the stress and the return maps are well-conditioned functions of :math:`F` even where
:math:`U` and :math:`V` are not unique (see the per-function notes). This module is the readable,
vectorised statement of that algorithm and what ``tests/test_svd.py`` checks it on.
"""

import numpy as np

#: Sweeps after which the 3D Jacobi iteration stops even if a pair is still above the tolerance. One-sided
#: Jacobi converges quadratically; the states of an MPM run (near-rotations) need 2–4 sweeps, random
#: matrices 4–6.
MAX_SWEEPS = 12

#: A column pair is orthogonal enough when :math:`|b_p\cdot b_q| \le` ``TOL_ULPS``
#: :math:`\varepsilon \|b_p\|\|b_q\|` (compared squared): the rounding error of a 3-term dot product is up to
#: :math:`3\varepsilon|b_p||b_q|`, so a smaller threshold would chase round-off; the entry dropped from :math:`R` is
#: then at most ``TOL_ULPS`` :math:`\varepsilon\,\sigma_q`.
TOL_ULPS = 4.0

PAIRS_3D = ((0, 1), (0, 2), (1, 2))


def polar_2d(F):
    r"""Closed-form polar decomposition :math:`F = RS` of a batch of 2×2 matrices.

    .. math::

        \theta = \operatorname{atan2}(F_{10} - F_{01},\; F_{00} + F_{11}),\qquad
        R = \begin{pmatrix}\cos\theta & -\sin\theta\\ \sin\theta & \cos\theta\end{pmatrix},\qquad
        S = R^T F .

    :math:`R^TF` is symmetric exactly when :math:`\tan\theta = (F_{10}-F_{01})/(F_{00}+F_{11})` (the
    antisymmetric part over the symmetric one; Hu et al. 2018, the 88-line program's ``polar_decomp``), and
    ``atan2`` picks the root with :math:`\operatorname{tr}S = \sqrt{(F_{00}+F_{11})^2 + (F_{10}-F_{01})^2}
    \ge 0`. With :math:`\det S = \det F` this makes :math:`S` positive definite where :math:`\det F > 0`
    (the polar decomposition), and gives it one negative eigenvalue, the smaller in magnitude, where
    :math:`\det F < 0` (the signed convention). :math:`\cos\theta, \sin\theta` are computed as
    :math:`x/h, y/h` with :math:`h = \sqrt{x^2+y^2}`; where :math:`h = 0` (:math:`F` a scaled reflection,
    :math:`\sigma_2 = -\sigma_1`, the only case where :math:`R` is not unique) :math:`R = I`.

    Parameters
    ----------
    F : (n, 2, 2) array
        Deformation gradients.

    Returns
    -------
    R : (n, 2, 2) array
        Rotations, :math:`\det R = 1`.
    S : (n, 2, 2) array
        Symmetric factors :math:`R^TF`, symmetrised as :math:`(S + S^T)/2` against round-off.
    """
    x = F[:, 0, 0] + F[:, 1, 1]
    y = F[:, 1, 0] - F[:, 0, 1]
    h = np.hypot(x, y)
    zero = h == 0
    safe = np.where(zero, 1, h)
    c = np.where(zero, 1, x / safe).astype(F.dtype, copy=False)
    s = np.where(zero, 0, y / safe).astype(F.dtype, copy=False)
    R = np.empty_like(F)
    R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1] = c, -s, s, c
    S = np.empty_like(F)
    S[:, 0, 0] = c * F[:, 0, 0] + s * F[:, 1, 0]
    S[:, 1, 1] = c * F[:, 1, 1] - s * F[:, 0, 1]
    S[:, 0, 1] = S[:, 1, 0] = 0.5 * ((c * F[:, 0, 1] + s * F[:, 1, 1]) + (c * F[:, 1, 0] - s * F[:, 0, 0]))
    return R, S


def svd_2d(F):
    r"""Closed-form signed SVD :math:`F = U\Sigma V^T` of a batch of 2×2 matrices.

    From the polar decomposition :math:`F = RS` (:func:`polar_2d`), the symmetric
    :math:`S = \begin{pmatrix}a & b\\ b & c\end{pmatrix}` is diagonalised by the rotation :math:`V(\phi)`:

    .. math::

        \phi = \tfrac12 \operatorname{atan2}(2b,\; a - c),\qquad
        \sigma_1 = \tfrac{a+c}{2} + r,\quad r = \sqrt{\left(\tfrac{a-c}{2}\right)^2 + b^2},\qquad
        \sigma_2 = \det F / \sigma_1,\qquad U = R\,V .

    The first column of :math:`V` is the eigenvector of the larger eigenvalue :math:`\sigma_1` (Golub &
    Van Loan 2013 §8.5.2, the symmetric Schur decomposition of a 2×2 matrix). Since
    :math:`\operatorname{tr}S = a + c \ge 0`, :math:`\sigma_1 \ge |\sigma_2|`, and :math:`\sigma_2 < 0`
    exactly where :math:`\det F < 0`. :math:`\sigma_2` is taken from :math:`\det F = \sigma_1\sigma_2`
    rather than :math:`\tfrac{a+c}{2} - r`, which cancels for a nearly singular :math:`F`
    (:math:`\sigma_2 = 0` where :math:`F = 0`).

    Parameters
    ----------
    F : (n, 2, 2) array

    Returns
    -------
    U : (n, 2, 2) array
        Rotation.
    sigma : (n, 2) array
        Signed singular values, :math:`\sigma_1 \ge |\sigma_2|`.
    Vt : (n, 2, 2) array
        Transposed rotation :math:`V^T`.
    """
    R, S = polar_2d(F)
    a, b, c = S[:, 0, 0], S[:, 0, 1], S[:, 1, 1]
    phi = 0.5 * np.arctan2(2 * b, a - c)
    cp, sp = np.cos(phi).astype(F.dtype, copy=False), np.sin(phi).astype(F.dtype, copy=False)
    Vt = np.empty_like(F)
    Vt[:, 0, 0], Vt[:, 0, 1], Vt[:, 1, 0], Vt[:, 1, 1] = cp, sp, -sp, cp
    sigma = np.empty(F.shape[:2], dtype=F.dtype)
    sigma[:, 0] = 0.5 * (a + c) + np.hypot(0.5 * (a - c), b)
    det = F[:, 0, 0] * F[:, 1, 1] - F[:, 0, 1] * F[:, 1, 0]
    positive = sigma[:, 0] > 0
    sigma[:, 1] = np.where(positive, det / np.where(positive, sigma[:, 0], 1), 0)
    U = R @ Vt.transpose(0, 2, 1)
    return U, sigma, Vt


def _rotate_columns(A, p, q, c, s):
    r"""Columns :math:`a_p \leftarrow c\,a_p - s\,a_q,\; a_q \leftarrow s\,a_p + c\,a_q` of each matrix."""
    ap, aq = A[:, :, p].copy(), A[:, :, q].copy()
    A[:, :, p] = c[:, None] * ap - s[:, None] * aq
    A[:, :, q] = s[:, None] * ap + c[:, None] * aq


def _rotate_rows(A, p, q, c, s):
    r"""Rows :math:`a_p \leftarrow c\,a_p + s\,a_q,\; a_q \leftarrow -s\,a_p + c\,a_q` of each matrix."""
    ap, aq = A[:, p, :].copy(), A[:, q, :].copy()
    A[:, p, :] = c[:, None] * ap + s[:, None] * aq
    A[:, q, :] = c[:, None] * aq - s[:, None] * ap


def jacobi_rotation(alpha, beta, gamma):
    r"""Cosine and sine of the rotation that makes two columns orthogonal (one-sided Jacobi).

    For columns :math:`b_p, b_q` with :math:`\alpha = \|b_p\|^2`, :math:`\beta = \|b_q\|^2`,
    :math:`\gamma = b_p\cdot b_q \ne 0`, the columns :math:`c\,b_p - s\,b_q` and :math:`s\,b_p + c\,b_q` are
    orthogonal for :math:`t = s/c` the smaller root :math:`|t| \le 1` of :math:`t^2 + 2\zeta t - 1 = 0`,
    :math:`\zeta = (\beta - \alpha)/(2\gamma)`, i.e. :math:`t = \operatorname{sign}\zeta/(|\zeta| +
    \sqrt{1+\zeta^2})` (Rutishauser's formula; Golub & Van Loan 2013 §8.5.2, Demmel & Veselić 1992), the
    rotation angle of magnitude at most :math:`\pi/4`. This is the Jacobi rotation that annihilates the entry
    :math:`\gamma` of the Gram matrix :math:`B^TB = V^TF^TFV` (McAdams et al. 2011), computed from the
    columns themselves. Multiplying through by :math:`|2\gamma|` avoids the division by :math:`\gamma` (and
    its overflow) and shortens the chain of dependent divisions and square roots:

    .. math::

        u = \beta - \alpha,\quad w = 2\gamma,\quad
        (c, s) = \frac{\big(|u| + \sqrt{u^2 + w^2},\ \operatorname{sign}(u)\,w\big)}
                      {\sqrt{\big(|u| + \sqrt{u^2 + w^2}\big)^2 + w^2}}

    (:math:`\operatorname{sign}(0) = +1`: equal lengths give the rotation by :math:`\pi/4`). Both square
    roots are taken as ``hypot``: :math:`u, w` are squared lengths already, and squaring them again would
    underflow in float32 for columns below about :math:`10^{-10}`, leaving :math:`c^2 + s^2 \ne 1`.

    Parameters
    ----------
    alpha, beta, gamma : (m,) arrays
        :math:`\|b_p\|^2`, :math:`\|b_q\|^2` and :math:`b_p\cdot b_q` of ``m`` column pairs
        (:math:`\gamma \ne 0`).

    Returns
    -------
    c, s : (m,) arrays
        Cosine and sine, :math:`c > 0`, :math:`|s| \le c`.
    """
    u = beta - alpha
    w = 2 * gamma
    den = np.abs(u) + np.hypot(u, w)
    num = np.where(u >= 0, w, -w)
    norm = np.hypot(den, num)
    return den / norm, num / norm


def givens(a, b):
    r"""Cosine and sine of the Givens rotation that maps :math:`(a, b)` to :math:`(r, 0)`, :math:`r \ge 0`.

    .. math:: r = \sqrt{a^2 + b^2},\qquad c = a / r,\quad s = b / r \qquad (c = 1,\ s = 0 \text{ where } r = 0),

    so that :math:`\begin{pmatrix}c & s\\ -s & c\end{pmatrix}\begin{pmatrix}a\\ b\end{pmatrix} =
    \begin{pmatrix}r\\ 0\end{pmatrix}` (Golub & Van Loan 2013 §5.1.8; as in McAdams et al. 2011).

    Parameters
    ----------
    a, b : (m,) arrays
        The entry kept and the entry zeroed.

    Returns
    -------
    c, s : (m,) arrays
    """
    r = np.hypot(a, b)
    zero = r == 0
    safe = np.where(zero, 1, r)
    return np.where(zero, 1, a / safe).astype(a.dtype, copy=False), np.where(zero, 0, b / safe).astype(a.dtype,
                                                                                                      copy=False)


def svd_3d(F, tol_ulps=TOL_ULPS, max_sweeps=MAX_SWEEPS):
    r"""Signed SVD :math:`F = U\Sigma V^T` of a batch of 3×3 matrices by Jacobi sweeps and a Givens QR.

    After McAdams et al. 2011 (Jacobi eigenanalysis, sorting the singular values, QR by Givens
    rotations), with exact one-sided Jacobi rotations (:func:`jacobi_rotation`) and a fixed tolerance:

    1. :math:`B \leftarrow F`, :math:`V \leftarrow I`. Sweep over the column pairs (0,1), (0,2), (1,2),
       rotating columns :math:`p, q` of :math:`B` and of :math:`V` by the Jacobi rotation of the pair
       unless :math:`(b_p\cdot b_q)^2 \le \tau^2\,\|b_p\|^2\|b_q\|^2`, :math:`\tau` = ``tol_ulps`` × the
       machine epsilon :math:`\varepsilon` of the dtype; stop after a sweep with no rotation, or after
       ``max_sweeps``. Then :math:`B = FV` has orthogonal columns, and :math:`\|b_i\| = |\sigma_i|`.
    2. Sort the columns of :math:`B` (and :math:`V`) by decreasing length; each swap also negates one of
       the two columns, so :math:`\det V` stays +1 (as in McAdams et al. 2011).
    3. :math:`B = QR` by three Givens rotations (:func:`givens`) that zero :math:`B_{10}, B_{20}, B_{21}`;
       :math:`U = Q` is a rotation, :math:`R_{00}, R_{11} \ge 0`, and
       :math:`\operatorname{sign}R_{22} = \operatorname{sign}\det F`. The off-diagonal entries of
       :math:`R` are below :math:`\tau\,\|F\|` and are dropped: :math:`\sigma_i = R_{ii}`.

    :math:`U, V` are not unique where singular values repeat (e.g. :math:`F = I` or a scaled rotation), but
    :math:`U\Sigma V^T`, :math:`UV^T` (where :math:`\sigma_i + \sigma_j \ne 0`, signed) and any
    :math:`U\,g(\Sigma)\,V^T` with :math:`g` acting on each :math:`\sigma_i` alike are, which is all the
    materials use.

    Parameters
    ----------
    F : (n, 3, 3) array
    tol_ulps : float
        :math:`\tau/\varepsilon`, see :data:`TOL_ULPS`.
    max_sweeps : int

    Returns
    -------
    U : (n, 3, 3) array
        Rotation.
    sigma : (n, 3) array
        Signed singular values, :math:`\sigma_1 \ge \sigma_2 \ge |\sigma_3|`, :math:`\sigma_3 < 0` where
        :math:`\det F < 0`.
    Vt : (n, 3, 3) array
        Transposed rotation :math:`V^T`.
    """
    n = F.shape[0]
    dtype = F.dtype
    tol = tol_ulps * np.finfo(dtype).eps
    B = F.copy()
    V = np.broadcast_to(np.eye(3, dtype=dtype), (n, 3, 3)).copy()
    for _ in range(max_sweeps):
        rotated = False
        for p, q in PAIRS_3D:
            alpha = np.einsum("ni,ni->n", B[:, :, p], B[:, :, p])
            beta = np.einsum("ni,ni->n", B[:, :, q], B[:, :, q])
            gamma = np.einsum("ni,ni->n", B[:, :, p], B[:, :, q])
            todo = gamma * gamma > tol * tol * alpha * beta
            if not todo.any():
                continue
            rotated = True
            c, s = jacobi_rotation(alpha[todo], beta[todo], gamma[todo])
            for A in (B, V):
                block = A[todo]
                _rotate_columns(block, p, q, c, s)
                A[todo] = block
        if not rotated:
            break
    # sort by decreasing column length; a swap negates the new column q so that det V stays +1
    for p, q in PAIRS_3D:
        norm2 = np.einsum("nij,nij->nj", B, B)
        swap = norm2[:, p] < norm2[:, q]
        for A in (B, V):
            ap, aq = A[swap, :, p].copy(), A[swap, :, q].copy()
            A[swap, :, p], A[swap, :, q] = aq, -ap
    # QR by Givens rotations: B = Q R, U = Q
    U = np.broadcast_to(np.eye(3, dtype=dtype), (n, 3, 3)).copy()
    for col, (p, q) in zip((0, 0, 1), PAIRS_3D):
        c, s = givens(B[:, p, col], B[:, q, col])
        _rotate_rows(B, p, q, c, s)      # B <- G B
        _rotate_columns(U, p, q, c, -s)  # U <- U G^T
    sigma = np.einsum("nii->ni", B).copy()
    return U, sigma, V.transpose(0, 2, 1).copy()


def signed_svd(F):
    r"""Signed SVD :math:`F = U\Sigma V^T` (:func:`svd_2d` or :func:`svd_3d` by the dimension).

    Same contract as :func:`mpmref.physics.materials.signed_svd`: ``U`` (n, d, d) and ``Vt`` (n, d, d)
    rotations, ``sigma`` (n, d) with :math:`\sigma_1 \ge \dots \ge |\sigma_d|` and :math:`\sigma_d < 0`
    where :math:`\det F < 0`.
    """
    return svd_2d(F) if F.shape[1] == 2 else svd_3d(F)


def polar_rotation(F):
    r"""Rotation :math:`R = UV^T` of the polar decomposition :math:`F = RS` and the signed singular values.

    Same contract as :func:`mpmref.physics.materials.polar_rotation`. In 2D :math:`R` is :func:`polar_2d`'s
    closed form (no eigen-decomposition needed); in 3D it is :math:`UV^T` of :func:`svd_3d`. :math:`R` is
    unique where all signed pair sums :math:`\sigma_i + \sigma_j` (:math:`i < j`) are non-zero; its
    sensitivity to a perturbation :math:`\delta F` is at most :math:`2\|\delta F\|/\min_{i<j}(\sigma_i +
    \sigma_j)` to first order: :math:`\delta R = U\Omega V^T` with :math:`\Omega_{ij} = (M_{ij} -
    M_{ji})/(\sigma_i + \sigma_j)`, :math:`M = U^T\delta F\,V` (differentiate :math:`F = RS`,
    :math:`S = V\Sigma V^T`; with positive :math:`\sigma` this is the bound of Li 1995, "New perturbation
    bounds for the unitary polar factor", and Higham 2008, "Functions of Matrices", Ch. 8).
    """
    if F.shape[1] == 2:
        R, _ = polar_2d(F)
        _, sigma, _ = svd_2d(F)
        return R, sigma
    U, sigma, Vt = svd_3d(F)
    return U @ Vt, sigma
