r"""P2G, grid update and G2P of the Numba backend: the equations of
:mod:`mpmref.backends.numpy.transfers`, one particle at a time with the stencil inside.

Each kernel is built for one scene configuration (a :class:`~mpmref.physics.scheme.TransferSpec`): dimension, kernel, scheme
features (affine matrix, PolyPIC modes, FLIP), force discretisation and the tracked deformation (F or J).
These are closure constants, so Numba compiles only the branches the scene uses, and each configuration is
cached on disk like any other ``cache=True`` function: Numba keys a closure's cache entry on the pickled
values of its constants, which is why they are plain ints, bools and a string and never other compiled
functions (a dispatcher pickles differently in every process, which would defeat the cache).

P2G runs block-parallel over the colour classes of :mod:`.blocks` (no atomics, bitwise the same for any
thread count); G2P gathers, so it runs block-parallel over all blocks at once.
"""

import hashlib
from functools import lru_cache
from pathlib import Path

import numpy as np
from numba import njit, prange

from .stencil import KERNEL_CODES, kernel_axis, polypic_axis_basis


def _source_digest():
    """Hash of this backend's source files.

    Numba's on-disk cache of a function is invalidated only when *its own* file changes, not when a jitted
    function it calls from another file does. Each transfer kernel carries this digest as a closure
    constant, which Numba's cache key includes, so editing any file of the backend recompiles them.
    """
    h = hashlib.sha256()
    for path in sorted(Path(__file__).parent.glob("*.py")):
        h.update(path.read_bytes())
    return h.hexdigest()


SOURCE_DIGEST = _source_digest()


def make_p2g(spec):
    """P2G kernel for a :class:`~mpmref.physics.scheme.TransferSpec` (FLIP and the tracked deformation are
    invisible to P2G, so those variants share one compiled kernel); see :func:`p2g_kernel`."""
    return p2g_kernel(spec.dim, KERNEL_CODES[spec.kernel], spec.support, spec.affine, spec.polypic, spec.mls)


def make_g2p(spec):
    """G2P kernel for a :class:`~mpmref.physics.scheme.TransferSpec`; see :func:`g2p_kernel`."""
    return g2p_kernel(spec.dim, KERNEL_CODES[spec.kernel], spec.support, spec.affine, spec.polypic, spec.flip,
                      spec.mls_gradient, spec.tracks_F, spec.tracks_J)


@lru_cache(maxsize=None)
def p2g_kernel(DIM, KERNEL, S, AFFINE, POLY, MLS):
    r"""P2G kernel: node mass, momentum and internal force (Hu et al. 2018 Eq. 18; see
    :func:`mpmref.backends.numpy.transfers.p2g` for the equations).

    The returned function ``p2g(x, v, C, modes, mass, vol0, tau, origin, dx, inertia, strides, mode_index,
    order, block_start, colour_blocks, colour_start, grid_mass, grid_momentum, grid_force)`` accumulates
    into the zeroed grid arrays. Per particle the stencil is a nest of ``S`` x ``S`` (x ``S``) loops with
    the per-axis weights in registers; :math:`x_i - x_p`, :math:`w_{ip}` and the gradient weight
    :math:`g_{ip}` are formed per node and handed to :func:`p2g_node`, which scatters.
    """
    SOURCES = SOURCE_DIGEST

    @njit(parallel=True, cache=True)
    def p2g(x, v, C, modes, mass, vol0, tau, origin, dx, inertia, strides, mode_index,
            order, block_start, colour_blocks, colour_start, grid_mass, grid_momentum, grid_force):
        SOURCES  # noqa: B018 - a closure constant: part of the cache key (see _source_digest)
        n_modes = mode_index.shape[0]
        for colour in range(colour_start.shape[0] - 1):
            first = colour_start[colour]
            for bi in prange(colour_start[colour + 1] - first):
                block = colour_blocks[first + bi]
                q = np.empty((DIM, S, S))
                qnorm = np.empty((DIM, S))
                w_arr = np.empty((DIM, S))
                fx_arr = np.empty(DIM)
                for k in range(block_start[block], block_start[block + 1]):
                    p = order[k]
                    m, vel, stress_volume = mass[p], row(v, p, DIM), matrix(tau, p, DIM, vol0[p])
                    if AFFINE:
                        Cp = matrix(C, p, DIM, 1.0)
                    else:
                        Cp = stress_volume  # unused
                    b0, f0, w0, dw0 = kernel_axis(KERNEL, (x[p, 0] - origin[0]) / dx)
                    b1, f1, w1, dw1 = kernel_axis(KERNEL, (x[p, 1] - origin[1]) / dx)
                    if DIM == 2:
                        base = b0 * strides[0] + b1 * strides[1]
                        if POLY:
                            for j in range(S):
                                w_arr[0, j], w_arr[1, j] = w0[j], w1[j]
                            fx_arr[0], fx_arr[1] = f0, f1
                            polypic_axis_basis(w_arr, fx_arr, dx, q, qnorm)
                        for i in range(S):
                            d0 = (i - f0) * dx
                            for j in range(S):
                                d1 = (j - f1) * dx
                                w = w0[i] * w1[j]
                                if MLS:
                                    g = (w * d0 / inertia, w * d1 / inertia)
                                else:
                                    g = (dw0[i] / dx * w1[j], dw1[j] / dx * w0[i])
                                p2g_node(base + i * strides[0] + j * strides[1], w, (d0, d1), g, (i, j), m, vel, Cp,
                                         stress_volume, p, modes, q, mode_index, grid_mass, grid_momentum,
                                         grid_force, AFFINE, POLY)
                    else:
                        b2, f2, w2, dw2 = kernel_axis(KERNEL, (x[p, 2] - origin[2]) / dx)
                        base = b0 * strides[0] + b1 * strides[1] + b2 * strides[2]
                        if POLY:
                            for j in range(S):
                                w_arr[0, j], w_arr[1, j], w_arr[2, j] = w0[j], w1[j], w2[j]
                            fx_arr[0], fx_arr[1], fx_arr[2] = f0, f1, f2
                            polypic_axis_basis(w_arr, fx_arr, dx, q, qnorm)
                        for i in range(S):
                            d0 = (i - f0) * dx
                            for j in range(S):
                                d1 = (j - f1) * dx
                                for l in range(S):
                                    d2 = (l - f2) * dx
                                    w = w0[i] * w1[j] * w2[l]
                                    if MLS:
                                        g = (w * d0 / inertia, w * d1 / inertia, w * d2 / inertia)
                                    else:
                                        g = (dw0[i] / dx * w1[j] * w2[l], dw1[j] / dx * w0[i] * w2[l],
                                             dw2[l] / dx * w0[i] * w1[j])
                                    p2g_node(base + i * strides[0] + j * strides[1] + l * strides[2], w,
                                             (d0, d1, d2), g, (i, j, l), m, vel, Cp, stress_volume, p, modes,
                                             q, mode_index, grid_mass, grid_momentum, grid_force, AFFINE, POLY)

    return p2g


@njit(cache=True, inline="always")
def row(a, p, dim):
    """``a[p]`` of an (n, d) array as a d-tuple (held in registers by the compiled loop)."""
    if dim == 2:
        return (a[p, 0], a[p, 1])
    return (a[p, 0], a[p, 1], a[p, 2])


@njit(cache=True, inline="always")
def matrix(a, p, dim, scale):
    """``scale * a[p]`` of an (n, d, d) array as a d-tuple of d-tuples."""
    if dim == 2:
        return ((scale * a[p, 0, 0], scale * a[p, 0, 1]), (scale * a[p, 1, 0], scale * a[p, 1, 1]))
    return ((scale * a[p, 0, 0], scale * a[p, 0, 1], scale * a[p, 0, 2]),
            (scale * a[p, 1, 0], scale * a[p, 1, 1], scale * a[p, 1, 2]),
            (scale * a[p, 2, 0], scale * a[p, 2, 1], scale * a[p, 2, 2]))


@njit(cache=True, inline="always")
def p2g_node(idx, w, d, g, ks, m, vel, Cp, stress_volume, p, modes, q, mode_index, grid_mass, grid_momentum,
             grid_force, affine, poly):
    r"""P2G scatter of one particle to one node: :math:`w_{ip} m_p`, :math:`w_{ip} m_p (v_p + C_p (x_i - x_p)
    + \sum_r c_{pr} s_r(x_i))` and :math:`-V_p^0 \tau_p g_{ip}` (``d`` = :math:`x_i - x_p`, ``g`` = :math:`g_{ip}`,
    ``ks`` the node's per-axis stencil index; ``vel``, ``Cp``, ``stress_volume`` = :math:`V_p^0\tau_p` are the
    particle's values as tuples)."""
    dim = len(d)
    wm = w * m
    grid_mass[idx] += wm
    for a in range(dim):
        mom = vel[a]
        if affine:
            for b in range(dim):
                mom += Cp[a][b] * d[b]
        if poly:
            for r in range(mode_index.shape[0]):
                s = 1.0
                for c in range(dim):
                    s *= q[c, mode_index[r, c], ks[c]]
                mom += s * modes[p, r, a]
        grid_momentum[idx, a] += wm * mom
        f = 0.0
        for b in range(dim):
            f += stress_volume[a][b] * g[b]
        grid_force[idx, a] -= f


@lru_cache(maxsize=None)
def g2p_kernel(DIM, KERNEL, S, AFFINE, POLY, FLIP, MLS, TRACKS_F, TRACKS_J):
    r"""G2P kernel: PIC velocity, affine matrix, PolyPIC modes, FLIP blend, F or J and position
    (Jiang et al. 2015 §5; Hu et al. 2018 §4; see :func:`mpmref.backends.numpy.transfers.g2p`).

    The returned ``g2p(x, v, F, J, origin, dx, inertia, dt, flip_alpha, strides, mode_index, order,
    block_start, blocks, v_grid, v_tilde, x_new, v_new, C_new, F_new, J_new, modes_new)`` writes the new
    particle arrays. The stencil loops are those of :func:`make_p2g`; :func:`g2p_node` gathers. ``MLS`` here is
    the MLS velocity gradient :math:`\nabla v_p = C_p` (``spec.mls_gradient``), chosen apart from the force.
    """
    NEED_B = AFFINE or MLS
    SOURCES = SOURCE_DIGEST

    @njit(parallel=True, cache=True)
    def g2p(x, v, F, J, origin, dx, inertia, dt, flip_alpha, strides, mode_index, order, block_start, blocks,
            v_grid, v_tilde, x_new, v_new, C_new, F_new, J_new, modes_new):
        SOURCES  # noqa: B018 - a closure constant: part of the cache key (see _source_digest)
        n_modes = mode_index.shape[0]
        for bi in prange(blocks.shape[0]):
            block = blocks[bi]
            v_pic = np.empty(DIM)
            dv_flip = np.empty(DIM)
            B = np.empty((DIM, DIM))
            grad_v = np.empty((DIM, DIM))
            q = np.empty((DIM, S, S))
            qnorm = np.empty((DIM, S))
            w_arr = np.empty((DIM, S))
            fx_arr = np.empty(DIM)
            acc = np.empty((max(n_modes, 1), DIM))

            for k in range(block_start[block], block_start[block + 1]):
                p = order[k]
                for a in range(DIM):
                    v_pic[a] = 0.0
                    dv_flip[a] = 0.0
                    for b in range(DIM):
                        B[a, b] = 0.0
                        grad_v[a, b] = 0.0
                if POLY:
                    acc[:] = 0.0
                b0, f0, w0, dw0 = kernel_axis(KERNEL, (x[p, 0] - origin[0]) / dx)
                b1, f1, w1, dw1 = kernel_axis(KERNEL, (x[p, 1] - origin[1]) / dx)
                if DIM == 2:
                    base = b0 * strides[0] + b1 * strides[1]
                    if POLY:
                        for j in range(S):
                            w_arr[0, j], w_arr[1, j] = w0[j], w1[j]
                        fx_arr[0], fx_arr[1] = f0, f1
                        polypic_axis_basis(w_arr, fx_arr, dx, q, qnorm)
                    for i in range(S):
                        d0 = (i - f0) * dx
                        for j in range(S):
                            d1 = (j - f1) * dx
                            w = w0[i] * w1[j]
                            g = (dw0[i] / dx * w1[j], dw1[j] / dx * w0[i])
                            g2p_node(base + i * strides[0] + j * strides[1], w, (d0, d1), g, (i, j), v_grid, v_tilde, v_pic,
                                     B, grad_v, dv_flip, acc, q, mode_index, NEED_B, MLS, FLIP, POLY)
                else:
                    b2, f2, w2, dw2 = kernel_axis(KERNEL, (x[p, 2] - origin[2]) / dx)
                    base = b0 * strides[0] + b1 * strides[1] + b2 * strides[2]
                    if POLY:
                        for j in range(S):
                            w_arr[0, j], w_arr[1, j], w_arr[2, j] = w0[j], w1[j], w2[j]
                        fx_arr[0], fx_arr[1], fx_arr[2] = f0, f1, f2
                        polypic_axis_basis(w_arr, fx_arr, dx, q, qnorm)
                    for i in range(S):
                        d0 = (i - f0) * dx
                        for j in range(S):
                            d1 = (j - f1) * dx
                            for l in range(S):
                                d2 = (l - f2) * dx
                                w = w0[i] * w1[j] * w2[l]
                                g = (dw0[i] / dx * w1[j] * w2[l], dw1[j] / dx * w0[i] * w2[l],
                                     dw2[l] / dx * w0[i] * w1[j])
                                g2p_node(base + i * strides[0] + j * strides[1] + l * strides[2], w, (d0, d1, d2),
                                         g, (i, j, l), v_grid, v_tilde, v_pic, B, grad_v, dv_flip, acc, q,
                                         mode_index, NEED_B, MLS, FLIP, POLY)
                finish_particle(p, x, v, F, J, dt, inertia, flip_alpha, v_pic, dv_flip, B, grad_v, acc, qnorm,
                                mode_index, x_new, v_new, C_new, F_new, J_new, modes_new,
                                AFFINE, POLY, FLIP, MLS, TRACKS_F, TRACKS_J)

    return g2p


@njit(cache=True, inline="always")
def g2p_node(idx, w, d, g, ks, v_grid, v_tilde, v_pic, B, grad_v, dv_flip, acc, q, mode_index, need_B, mls, flip,
             poly):
    r"""G2P gathers of one node: :math:`\sum_i w_{ip} v_i`, :math:`B_p = \sum_i w_{ip} v_i (x_i - x_p)^T`,
    :math:`\sum_i v_i \nabla w_{ip}^T` (classic force), the FLIP increment and PolyPIC's mode projections."""
    dim = len(d)
    for a in range(dim):
        vi = v_grid[idx, a]
        v_pic[a] += w * vi
        if need_B:
            for b in range(dim):
                B[a, b] += (w * vi) * d[b]
        if not mls:
            for b in range(dim):
                grad_v[a, b] += vi * g[b]
        if flip:
            dv_flip[a] += w * (vi - v_tilde[idx, a])
    if poly:
        for r in range(mode_index.shape[0]):
            s = 1.0
            for c in range(dim):
                s *= q[c, mode_index[r, c], ks[c]]
            for a in range(dim):
                acc[r, a] += (w * s) * v_grid[idx, a]


@njit(cache=True, inline="always")
def finish_particle(p, x, v, F, J, dt, inertia, flip_alpha, v_pic, dv_flip, B, grad_v, acc, qnorm, mode_index,
                    x_new, v_new, C_new, F_new, J_new, modes_new, affine, poly, flip, mls, tracks_F, tracks_J):
    r"""G2P's per-particle update from the gathered sums (see :func:`mpmref.backends.numpy.transfers.g2p`).

    :math:`C_p = B_p D_p^{-1}`; :math:`\nabla v_p = C_p` (MLS) or the gathered :math:`\sum_i v_i \nabla w_{ip}^T`;
    :math:`x_p \leftarrow x_p + \Delta t\, v^{PIC}_p`; the FLIP blend; :math:`F_p \leftarrow F_p + \Delta t\,
    \nabla v_p F_p`; :math:`J_p \leftarrow J_p (1 + \Delta t \operatorname{tr} \nabla v_p)`; PolyPIC modes
    :math:`c_{pr} = \sum_i w_{ip} s_r v_i / \prod_a \langle q_{r_a}, q_{r_a}\rangle_a`.
    """
    d = x.shape[1]
    if mls:
        for a in range(d):
            for b in range(d):
                grad_v[a, b] = B[a, b] / inertia
    for a in range(d):
        x_new[p, a] = x[p, a] + dt * v_pic[a]
        if flip:
            v_new[p, a] = flip_alpha * (v[p, a] + dv_flip[a]) + (1.0 - flip_alpha) * v_pic[a]
        else:
            v_new[p, a] = v_pic[a]
        if affine:
            for b in range(d):
                C_new[p, a, b] = B[a, b] / inertia
    if poly:
        for r in range(mode_index.shape[0]):
            norm = 1.0
            for a in range(d):
                norm *= qnorm[a, mode_index[r, a]]
            for a in range(d):
                modes_new[p, r, a] = acc[r, a] / norm if norm > 0 else 0.0
    if tracks_F:
        for a in range(d):
            for b in range(d):
                s = 0.0
                for c in range(d):
                    s += dt * grad_v[a, c] * F[p, c, b]
                F_new[p, a, b] = F[p, a, b] + s
    if tracks_J:
        trace = 0.0
        for a in range(d):
            trace += grad_v[a, a]
        J_new[p] = J[p] * (1.0 + dt * trace)


@njit(parallel=True, cache=True)
def grid_velocity(mass, momentum, force, dt, gravity, node_shape, strides, wall_width, wall_type, wall_friction,
                  v, v_tilde):
    r"""Grid update with Eq. 25 walls (see :func:`mpmref.backends.numpy.transfers.grid_update`).

    .. math:: \tilde v_i = (mv)_i / m_i, \qquad v_i = \tilde v_i + \Delta t\,(f_i / m_i + g)

    then, wall by wall in the order x_min, x_max, y_min, … (the reference's order; a corner node is
    projected by both of its walls in turn), the talk's Eq. 25 projection at every node of the wall's band
    (index within ``wall_width`` cells of the wall), with the wall's inward normal. ``wall_type[2a + side]``:
    0 open, 1 sticky, 2 slip, 3 separate; ``wall_friction`` the Coulomb μ. Nodes without mass get zero
    velocity.
    """
    N, d = momentum.shape
    for i in prange(N):
        if mass[i] <= 0:
            for a in range(d):
                v[i, a] = 0.0
                v_tilde[i, a] = 0.0
            continue
        inv_m = 1.0 / mass[i]
        for a in range(d):
            v_tilde[i, a] = momentum[i, a] * inv_m
            v[i, a] = (momentum[i, a] + dt * force[i, a]) * inv_m + dt * gravity[a]
        for a in range(d):
            index = (i // strides[a]) % node_shape[a]
            if index < wall_width:
                project_at_wall(v, i, a, 1.0, wall_type[2 * a], wall_friction[2 * a])
            if index > node_shape[a] - 1 - wall_width:
                project_at_wall(v, i, a, -1.0, wall_type[2 * a + 1], wall_friction[2 * a + 1])


@njit(cache=True)
def project_at_wall(v, i, axis, sign, kind, friction):
    r"""Talk Eq. 25 at an axis-aligned wall with inward normal ``sign * e_axis`` (see
    :func:`mpmref.physics.boundary.project_velocity`)."""
    d = v.shape[1]
    if kind == 0:
        return
    if kind == 1:
        for a in range(d):
            v[i, a] = 0.0
        return
    vn = v[i, axis] * sign
    if kind == 2:
        v[i, axis] -= vn * sign
        return
    if vn >= 0.0:
        return
    vt_norm2 = 0.0
    for a in range(d):
        if a != axis:
            vt_norm2 += v[i, a] ** 2
    vt_norm = np.sqrt(vt_norm2)
    if vt_norm <= -friction * vn:
        for a in range(d):
            v[i, a] = 0.0
        return
    scale = 1.0 + friction * vn / vt_norm
    v[i, axis] = 0.0
    for a in range(d):
        if a != axis:
            v[i, a] *= scale
