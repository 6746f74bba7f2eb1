r"""What the G2P kernels of both dimensions share (:mod:`.transfers2d`, :mod:`.transfers3d`; the equations of
:func:`mpmref.backends.numpy.transfers.g2p`): the parallel loop's task size, PolyPIC's per-node mode projections
and the per-particle update from the gathered sums (its motion, then its deformation)."""

from numba import njit

from .tuple_math import fma, matrix

#: particles per task of G2P's parallel loop
G2P_CHUNK = 256


@njit(cache=True, inline="always")
def gather_modes(acc, idx, w, ks, v_grid, q, mode_index):
    r"""PolyPIC's mode projections of one node: ``acc[r] += w s_r(x_i) v_i`` (``ks`` the node's per-axis stencil
    index; :math:`s_r = \prod_a q_{a, r_a}`)."""
    d = v_grid.shape[1]
    for r in range(mode_index.shape[0]):
        s = 1.0
        for c in range(d):
            s *= q[c, mode_index[r, c], ks[c]]
        for a in range(d):
            acc[r, a] = fma(w * s, v_grid[idx, a], acc[r, a])


@njit(cache=True, inline="always")
def move_particle(p, x, v, dt, inertia, flip_alpha, v_pic, dv_flip, B, acc, qnorm, mode_index, x_new, v_new, C_new,
                  modes_new, affine, poly, flip):
    r"""G2P's update of particle ``p``'s motion from the gathered sums (see
    :func:`mpmref.backends.numpy.transfers.g2p`), the sums as tuples (``B`` flat, row-major).

    :math:`x_p \leftarrow x_p + \Delta t\, v^{PIC}_p`; the FLIP blend (``dv_flip`` holds
    :math:`\sum_i w_{ip}(v_i - \tilde v_i)` less :math:`v^{PIC}_p`, added back here); :math:`C_p = B_p D_p^{-1}`;
    PolyPIC modes :math:`c_{pr} = \sum_i w_{ip} s_r v_i / \prod_a \langle q_{r_a}, q_{r_a}\rangle_a`.
    """
    d = x.shape[1]
    for a in range(d):
        x_new[p, a] = x[p, a] + dt * v_pic[a]
        if flip:
            v_new[p, a] = flip_alpha * (v[p, a] + (v_pic[a] + dv_flip[a])) + (1.0 - flip_alpha) * v_pic[a]
        else:
            v_new[p, a] = v_pic[a]
        if affine:
            for b in range(d):
                C_new[p, a, b] = B[a * d + b] / inertia
    if poly:
        for r in range(mode_index.shape[0]):
            norm = 1.0
            for a in range(d):
                norm *= qnorm[a, mode_index[r, a]]
            for a in range(d):
                modes_new[p, r, a] = acc[r, a] / norm if norm > 0 else 0.0


@njit(cache=True, inline="always")
def deform_particle(p, dim, F, J, dt, inertia, B, grad_v, F_new, J_new, mls_gradient, tracks_F, tracks_J):
    r"""G2P's update of particle ``p``'s deformation (see :func:`mpmref.backends.numpy.transfers.g2p`), after
    :func:`move_particle`: :math:`\nabla v_p = C_p = B_p D_p^{-1}` (MLS, ``mls_gradient``) or the gathered
    :math:`\sum_i v_i \nabla w_{ip}^T` (``grad_v``; both flat, row-major tuples); :math:`F_p \leftarrow
    F_p + \Delta t\, \nabla v_p F_p` if ``tracks_F``; :math:`J_p \leftarrow J_p (1 + \Delta t \operatorname{tr}
    \nabla v_p)` if ``tracks_J``. ``dim`` is the dimension (a compile-time constant). The particle's :math:`F_p` is
    read whole before any entry is written, so ``F_new`` may be ``F`` (a G2P in place, :meth:`g2p_rows
    <mpmref.backends.base.RowBackend.g2p_rows>`).
    """
    if tracks_F:
        Fp = matrix(F[p], F.dtype.type(1.0), dim)
        for a in range(dim):
            for b in range(dim):
                s = 0.0
                for c in range(dim):
                    s += dt * (B[a * dim + c] / inertia if mls_gradient else grad_v[a * dim + c]) * Fp[c][b]
                F_new[p, a, b] = Fp[a][b] + s
    if tracks_J:
        trace = 0.0
        for a in range(dim):
            trace += B[a * dim + a] / inertia if mls_gradient else grad_v[a * dim + a]
        J_new[p] = J[p] * (1.0 + dt * trace)
