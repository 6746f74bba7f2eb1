r"""The per-node scatter that the P2G kernels of both dimensions share (:mod:`.transfers2d`, :mod:`.transfers3d`;
the equations of :func:`mpmref.backends.numpy.transfers.p2g`)."""

from numba import njit

from .tuple_math import fma


@njit(cache=True, inline="always")
def p2g_node(grid, idx, w, d, fw, ks, m, mv, mC, Q, p, modes, q, mode_index, affine, poly, fused, mls_force):
    r"""P2G scatter of one particle to one node ``idx`` of ``grid`` (rows: mass, momentum, force):
    :math:`w_{ip} m_p`, :math:`w_{ip} (m_p v_p + m_p C_p (x_i - x_p) + m_p \sum_r c_{pr} s_r(x_i))` and
    :math:`Q_p\, \mathrm{fw}` (``d`` = :math:`x_i - x_p`; ``fw`` = :math:`w_{ip}(x_i - x_p)` with the MLS
    force matrix :math:`Q_p = -V_p^0\tau_p D_p^{-1}`, or :math:`\nabla w_{ip}` with the classic
    :math:`Q_p = -V_p^0\tau_p`; ``ks`` the node's per-axis stencil index; ``mv``, ``mC``, ``Q`` are the
    particle's values as tuples). ``fused`` (rows: mass, momentum after the force): ``mC`` holds
    :math:`A_p = m_p C_p + \Delta t Q_p` with the MLS force, and with the classic force ``Q`` holds
    :math:`\Delta t Q_p`, added to the momentum instead of a force column."""
    dim = len(d)
    grid[idx, 0] = fma(w, m, grid[idx, 0])
    for a in range(dim):
        mom = mv[a]
        if affine:
            for b in range(dim):
                mom = fma(mC[a][b], d[b], mom)
        if poly:
            for r in range(mode_index.shape[0]):
                s = m
                for c in range(dim):
                    s *= q[c, mode_index[r, c], ks[c]]
                mom = fma(s, modes[p, r, a], mom)
        if fused and not mls_force:
            grid[idx, 1 + a] += fma(w, mom, force_row(Q, fw, a, dim))
        else:
            grid[idx, 1 + a] = fma(w, mom, grid[idx, 1 + a])
            if not fused:
                grid[idx, 1 + dim + a] += force_row(Q, fw, a, dim)


@njit(cache=True, inline="always")
def force_row(Q, fw, a, dim):
    r""":math:`\sum_b Q_{ab}\,\mathrm{fw}_b`, the node force's component ``a`` (fused multiply-adds, in order)."""
    f = Q[a][0] * fw[0]
    for b in range(1, dim):
        f = fma(Q[a][b], fw[b], f)
    return f
