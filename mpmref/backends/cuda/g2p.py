r"""G2P of the GPU backend, one particle per thread (:func:`mpmref.backends.numpy.transfers.g2p` for the equations).

Each thread gathers the node velocities of its particle's stencil, in its registers and local arrays:
:math:`v^{PIC}_p = \sum_i w_{ip} v_i`, :math:`B_p = \sum_i w_{ip} v_i (x_i - x_p)^T` (affine schemes and the MLS
velocity gradient), :math:`\sum_i v_i \nabla w_{ip}^T` (the classic one), :math:`\sum_i w_{ip}(v_i - \tilde v_i)`
(FLIP) and PolyPIC's projections :math:`\sum_i w_{ip} s_r(x_i) v_i`; then writes the particle's new position,
velocity, :math:`C_p = B_p D_p^{-1}`, modes, :math:`F_p \leftarrow F_p + \Delta t\,\nabla v_p F_p` and
:math:`J_p \leftarrow J_p(1 + \Delta t \operatorname{tr}\nabla v_p)`. A gather writes only its own particle: no atomics,
the same bits on every run.
"""

from functools import lru_cache

import numpy as np
from numba import types

from ...physics.kernels import KERNELS
from ..pointwise.stencil import AXIS, KERNEL_CODES, axis_basis, fraction
from .launch import array, device, kernel_set, real_types, scalar
from .runtime import cuda, load


@lru_cache(maxsize=None)
def g2p_kernel(dtype, dim, kernel, affine, poly, flip, mls_gradient, tracks_F, tracks_J):
    """The G2P kernel of one configuration (a namespace with the :class:`~.launch.DeviceKernel` ``g2p``): particles of
    ``dtype`` in ``dim`` dimensions, the kernel named ``kernel``, an ``affine`` scheme, PolyPIC's modes (``poly``),
    FLIP, the MLS or classic velocity gradient, and the tracked deformation (F, J or both)."""
    load()
    T, nb = real_types(dtype)
    D = dim
    KERNEL, S = KERNEL_CODES[kernel], KERNELS[kernel].support
    st_fraction, st_weights, st_axis_basis = device(fraction), device(AXIS[kernel]), device(axis_basis)
    K = S**D
    M = max(K - 1 - D, 1)
    NEED_B = affine or mls_gradient
    one, zero = T(1.0), T(0.0)

    def g2p(x, v, F, J, origin, dx, inertia, dt, flip_alpha, mode_index, node_shape, v_grid, v_tilde, x_new, v_new,
            C_new, F_new, J_new, modes_new):
        """Particle ``p``'s new state from the node velocities ``v_grid`` (and ``v_tilde``, FLIP) of its stencil."""
        p = cuda.grid(1)
        if p >= x.shape[0]:
            return
        h, step = T(dx), T(dt)
        base = cuda.local.array(D, types.int64)
        f = cuda.local.array(D, nb)
        w = cuda.local.array((D, S), nb)
        at = cuda.local.array(D, types.int64)
        for a in range(D):
            b, f[a] = st_fraction(KERNEL, T, (x[p, a] - origin[a]) / h)
            base[a] = min(max(b, 0), node_shape[a] - S)  # a particle outside the valid region reads no other memory
            weights = st_weights(T, f[a])[0]
            for k in range(S):
                w[a, k] = weights[k]
        q = cuda.local.array((D, S, S), nb)
        norm = cuda.local.array((D, S), nb)
        if poly:
            for a in range(D):
                st_axis_basis(w[a], f[a], h, q[a], norm[a])
        v_pic = cuda.local.array(D, nb)
        dv_flip = cuda.local.array(D, nb)
        B = cuda.local.array((D, D), nb)
        grad = cuda.local.array((D, D), nb)
        acc = cuda.local.array((M, D), nb)
        g = cuda.local.array(D, nb)
        for a in range(D):
            v_pic[a] = zero
            dv_flip[a] = zero
            for b in range(D):
                B[a, b] = zero
                grad[a, b] = zero
            for r in range(M):
                acc[r, a] = zero
        for o in range(K):
            rest = o
            for a in range(D - 1, -1, -1):
                at[a] = rest % S
                rest //= S
            node = 0
            weight = one
            for a in range(D):
                node = node * node_shape[a] + base[a] + at[a]
                weight *= w[a, at[a]]
            for a in range(D):
                vi = v_grid[node, a]
                v_pic[a] += weight * vi
                if NEED_B:
                    for b in range(D):
                        B[a, b] += (weight * vi) * ((T(at[b]) - f[b]) * h)
                if flip:
                    dv_flip[a] += weight * (vi - v_tilde[node, a])
            if not mls_gradient:
                for b in range(D):
                    g[b] = st_weights(T, f[b])[1][at[b]] / h
                    for c in range(D):
                        if c != b:
                            g[b] = g[b] * w[c, at[c]]
                for a in range(D):
                    for b in range(D):
                        grad[a, b] += v_grid[node, a] * g[b]
            if poly:
                for r in range(mode_index.shape[0]):
                    s = weight
                    for c in range(D):
                        s *= q[c, mode_index[r, c], at[c]]
                    for a in range(D):
                        acc[r, a] += s * v_grid[node, a]
        if NEED_B:
            for a in range(D):
                for b in range(D):
                    B[a, b] = B[a, b] / T(inertia)  # B becomes C = B D^-1
        if mls_gradient:
            for a in range(D):
                for b in range(D):
                    grad[a, b] = B[a, b]
        for a in range(D):
            x_new[p, a] = x[p, a] + step * v_pic[a]
            if flip:
                alpha = T(flip_alpha)
                v_new[p, a] = alpha * (v[p, a] + dv_flip[a]) + (one - alpha) * v_pic[a]
            else:
                v_new[p, a] = v_pic[a]
            if affine:
                for b in range(D):
                    C_new[p, a, b] = B[a, b]
        if poly:
            for r in range(mode_index.shape[0]):
                n_r = one
                for c in range(D):
                    n_r *= norm[c, mode_index[r, c]]
                for a in range(D):
                    modes_new[p, r, a] = acc[r, a] / n_r if n_r > zero else zero
        if tracks_F:
            for a in range(D):
                for b in range(D):
                    s = zero
                    for c in range(D):
                        s += (step * grad[a, c]) * F[p, c, b]
                    F_new[p, a, b] = F[p, a, b] + s
        if tracks_J:
            trace = zero
            for a in range(D):
                trace += grad[a, a]
            J_new[p] = J[p] * (one + step * trace)

    real1, real2, real3, f64 = array(dtype, 1), array(dtype, 2), array(dtype, 3), scalar(np.float64)
    return kernel_set(g2p=(g2p, (real2, real2, real3, real1, real1, f64, f64, f64, f64, array(np.int64, 2),
                                 array(np.int64, 1), real2, real2, real2, real2, real3, real3, real1, real3)))
