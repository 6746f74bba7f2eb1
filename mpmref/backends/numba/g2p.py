r"""What the G2P kernels of both dimensions share (:mod:`.transfers2d`, :mod:`.transfers3d`; the equations of
:func:`mpmref.backends.numpy.transfers.g2p`): the parallel loop's task size, PolyPIC's per-node mode projections
and the per-particle update from the gathered sums."""

from numba import njit


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
            acc[r, a] += (w * s) * v_grid[idx, a]


@njit(cache=True, inline="always")
def finish_particle(p, x, v, F, J, dt, inertia, flip_alpha, v_pic, dv_flip, B, grad_v, acc, qnorm, mode_index, out,
                    affine, poly, flip, mls_gradient):
    r"""G2P's per-particle update from the gathered sums (see :func:`mpmref.backends.numpy.transfers.g2p`) into
    ``out`` (a :class:`~.kernel_args.G2POutput`; ``F`` or ``J`` only where the state tracks it, ``out.F`` or
    ``out.J`` empty otherwise).

    The sums are tuples (``B`` and ``grad_v`` flat, row-major; separate arguments: Numba's parallel array
    analysis cannot follow tuples of tuples of different lengths). :math:`C_p = B_p D_p^{-1}`; :math:`\nabla v_p = C_p` (MLS, ``mls_gradient``) or the gathered
    :math:`\sum_i v_i \nabla w_{ip}^T`;
    :math:`x_p \leftarrow x_p + \Delta t\, v^{PIC}_p`; the FLIP blend (``dv_flip`` holds
    :math:`\sum_i w_{ip}(v_i - \tilde v_i)` less :math:`v^{PIC}_p`, added back here); :math:`F_p \leftarrow
    F_p + \Delta t\, \nabla v_p F_p`; :math:`J_p \leftarrow J_p (1 + \Delta t \operatorname{tr} \nabla v_p)`;
    PolyPIC modes :math:`c_{pr} = \sum_i w_{ip} s_r v_i / \prod_a \langle q_{r_a}, q_{r_a}\rangle_a`.
    """
    x_new, v_new, C_new, F_new, J_new, modes_new = out
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
    if F_new.shape[0] > 0:  # the state tracks F
        for a in range(d):
            for b in range(d):
                s = 0.0
                for c in range(d):
                    s += dt * (B[a * d + c] / inertia if mls_gradient else grad_v[a * d + c]) * F[p, c, b]
                F_new[p, a, b] = F[p, a, b] + s
    if J_new.shape[0] > 0:  # the state tracks J
        trace = 0.0
        for a in range(d):
            trace += B[a * d + a] / inertia if mls_gradient else grad_v[a * d + a]
        J_new[p] = J[p] * (1.0 + dt * trace)
