r"""CPIC kernels of the Numba backend in 2D, the transfers: ghost velocities, P2G to compatible nodes with the
rejected momentum and force, the bodies' impulses from the incompatible nodes, and G2P with ghost velocities
and the penalty (:mod:`mpmref.backends.numpy.cpic`; Hu et al. 2018, SIGGRAPH, §4–5; docs/cpic.md)."""

from functools import lru_cache

import numpy as np
from numba import njit, prange

from ....physics.cdf import PENALTY_WINDOW
from ...pointwise.stencil import kernel_axis
from ..source_digest import SOURCE_DIGEST
from ..twin import parallel_kernel
from .common import crossed_body, tagged_by_several


@njit(cache=True, inline="always")
def ghost_velocity(v0, v1, node_x0, node_x1, r, position, velocity, omega, n0, n1, mu):
    r"""The friction projection :math:`\Pi(\mathbf v; \mathbf v_r(\mathbf x_i), \mathbf n, \mu)` against body ``r``.

    :math:`\mathbf v_r(\mathbf x) = \mathbf v_r + \omega_r\hat{\mathbf z}\times(\mathbf x - \mathbf c_r)`;
    :math:`\mathbf u = \mathbf v - \mathbf v_r(\mathbf x_i)`, :math:`u_n = \mathbf n\cdot\mathbf u`,
    :math:`\mathbf u_t = \mathbf u - u_n\mathbf n`; sticky (:math:`\mu = -1`): :math:`\mathbf v_r(\mathbf x_i)`;
    otherwise :math:`\mathbf v_r(\mathbf x_i) + \max(|\mathbf u_t| + \mu'\min(u_n, 0), 0)\,\mathbf u_t/|\mathbf u_t|`
    plus :math:`\max(u_n, 0)\mathbf n` if :math:`\mu \ge 0` (:math:`\mu' = \mu`; slip: :math:`\mu' = -\mu - 2`).
    The talk's Eq. 25 (Hu et al. 2018 §5; docs/cpic.md); see :func:`mpmref.rigid.dynamics.friction_projection`.
    """
    rel0 = node_x0 - position[r, 0]
    rel1 = node_x1 - position[r, 1]
    vb0 = velocity[r, 0] + omega[r] * -rel1
    vb1 = velocity[r, 1] + omega[r] * rel0
    if mu == -1.0:
        return vb0, vb1
    u0, u1 = v0 - vb0, v1 - vb1
    un = n0 * u0 + n1 * u1
    ut0, ut1 = u0 - un * n0, u1 - un * n1
    ut_norm = np.sqrt(ut0 * ut0 + ut1 * ut1)
    coeff = mu if mu >= 0.0 else -mu - 2.0
    scale = max(ut_norm + coeff * min(un, 0.0), 0.0) / (ut_norm if ut_norm > 0.0 else 1.0)
    g0, g1 = vb0 + scale * ut0, vb1 + scale * ut1
    if mu >= 0.0:
        g0 += max(un, 0.0) * n0
        g1 += max(un, 0.0) * n1
    return g0, g1


@njit(cache=True, inline="always")
def ghost_frame(p, idx, c, node_body, near, normal, tag_T, friction, fit_normal):
    r"""What the ghost velocity of incompatible node ``idx`` for particle ``p`` projects against
    (:func:`mpmref.backends.numpy.cpic.ghost_frames`): ``(project, r, n0, n1, mu)``.

    Single fit: the node's nearest body :math:`r`, the particle's normal :math:`\mathbf n_p`, the friction of its
    side, ``project`` = ``near[p]``. With the per-body fit, a crossed body ``c >= 0``
    (:func:`~mpmref.backends.numba.cpic.common.crossed_body`; -1 if none, or without the per-body fit) with its
    own normal :math:`\mathbf n_{pc}` (``fit_normal[p, c]``)."""
    if c >= 0:
        mu = friction[c, 1] if tag_T[p, c] else friction[c, 0]
        return True, c, fit_normal[p, c, 0], fit_normal[p, c, 1], mu
    r = max(node_body[idx], 0)
    mu = friction[r, 1] if tag_T[p, r] else friction[r, 0]
    return near[p], r, normal[p, 0], normal[p, 1], mu


@njit(cache=True, inline="always")
def node_ghost(p, idx, c, nx0, nx1, node_body, near, normal, tag_T, friction, fit_normal, v0, v1, a0, a1, position,
               velocity, omega):
    r"""Ghost velocity of incompatible node ``idx`` for particle ``p`` (see
    :func:`mpmref.backends.numpy.cpic.ghost_velocities`): if :func:`ghost_frame` projects, the friction
    projection of :math:`\mathbf v^*_p + \mathbf a_{ip}` (``(v0 + a0, v1 + a1)``, the load with the particle's
    own internal force) against its body and normal; otherwise :math:`\mathbf v^*_p` = ``(v0, v1)``."""
    project, r, n0, n1, mu = ghost_frame(p, idx, c, node_body, near, normal, tag_T, friction, fit_normal)
    if not project:
        return v0, v1
    return ghost_velocity(v0 + a0, v1 + a1, nx0, nx1, r, position, velocity, omega, n0, n1, mu)


@njit(cache=True, inline="always")
def force_velocity(ghost_force, dt, f0, f1, w, m):
    r""":math:`\mathbf a_{ip} = \Delta t\, \mathbf f_{ip} / (m_p w_{ip})`, :math:`\mathbf f_{ip} = -V_p^0\tau_p g_{ip}`
    given as ``(f0, f1)`` = :math:`V_p^0\tau_p g_{ip}` (0 where :math:`w_{ip} = 0`, or without ``ghost_force``);
    see :func:`mpmref.backends.numpy.cpic.force_velocity`."""
    if not ghost_force or not w > 0.0:
        return 0.0, 0.0
    return (-dt * f0) / (w * m), (-dt * f1) / (w * m)


@njit(cache=True, inline="always")
def gradient_weight(mls_force, w, d0, d1, wa0, wa1, dwa0, dwa1, dx, inertia):
    r"""The force's gradient weight :math:`g_{ip}` of a node (2D): MLS :math:`w_{ip}(\mathbf x_i - \mathbf x_p)/D`
    (``d0, d1`` = :math:`\mathbf x_i - \mathbf x_p`, ``inertia`` = :math:`D`), or the kernel gradient
    :math:`(N'_0 N_1, N_0 N'_1)/\Delta x` from the per-axis weights ``wa`` and derivatives ``dwa`` (see
    :func:`mpmref.backends.numpy.transfers.mls_gradient_weight` and ``classic_gradient_weight``)."""
    if mls_force:
        return w * d0 / inertia, w * d1 / inertia
    return dwa0 / dx * wa1, dwa1 / dx * wa0


@lru_cache(maxsize=None)
def p2g_kernel(KERNEL, S, AFFINE, MLS_FORCE, PER_BODY):
    r"""CPIC P2G kernel (2D): mass, momentum and force to compatible nodes; rejected momentum and force at
    the others (see :func:`mpmref.backends.numpy.transfers.p2g` with a contact).

    At compatible nodes as plain P2G; at an incompatible node :math:`i`

    .. math:: \mathbf J^m_i \mathrel{+}= m_p w_{ip}(\mathbf v^*_p - \tilde{\mathbf v}_i), \qquad
              \mathbf J^f_i \mathrel{-}= V_p^0 \tau_p g_{ip}

    with the ghost velocity :math:`\tilde{\mathbf v}_i` (:func:`node_ghost`). Block-parallel by colour.
    """
    SOURCES = SOURCE_DIGEST

    @parallel_kernel(cache=True)
    def p2g(x, v, C, mass, vol0, tau, layout, groups, contact, bodies, gravity_dv, ghost_force, dt, grid_mass,
            grid_momentum, grid_force, rejected_momentum, rejected_force, fits):
        SOURCES  # noqa: B018 - a closure constant: part of the cache key (see source_digest)
        origin, dx, inertia, strides = layout
        order, block_start, colour_blocks, colour_start = groups
        incompatible, node_body, node_d, near, phi, normal, tag_T = contact
        position, velocity, omega, friction = bodies
        for colour in range(colour_start.shape[0] - 1):
            first = colour_start[colour]
            for bi in prange(colour_start[colour + 1] - first):
                block = colour_blocks[first + bi]
                for q in range(block_start[block], block_start[block + 1]):
                    p = order[q]
                    m = mass[p]
                    s00, s01 = vol0[p] * tau[p, 0, 0], vol0[p] * tau[p, 0, 1]
                    s10, s11 = vol0[p] * tau[p, 1, 0], vol0[p] * tau[p, 1, 1]
                    b0, f0, w0, dw0 = kernel_axis(KERNEL, np.float64, (x[p, 0] - origin[0]) / dx)
                    b1, f1, w1, dw1 = kernel_axis(KERNEL, np.float64, (x[p, 1] - origin[1]) / dx)
                    base = b0 * strides[0] + b1 * strides[1]
                    inc = incompatible[p]
                    for i in range(S):
                        d0 = (i - f0) * dx
                        for j in range(S):
                            d1 = (j - f1) * dx
                            w = w0[i] * w1[j]
                            g0, g1 = gradient_weight(MLS_FORCE, w, d0, d1, w0[i], w1[j], dw0[i], dw1[j], dx, inertia)
                            idx = base + i * strides[0] + j * strides[1]
                            f_0 = s00 * g0 + s01 * g1
                            f_1 = s10 * g0 + s11 * g1
                            if inc == 0 or not (inc >> (i * S + j)) & 1:
                                wm = w * m
                                mom0, mom1 = v[p, 0], v[p, 1]
                                if AFFINE:
                                    mom0 += C[p, 0, 0] * d0 + C[p, 0, 1] * d1
                                    mom1 += C[p, 1, 0] * d0 + C[p, 1, 1] * d1
                                grid_mass[idx] += wm
                                grid_momentum[idx, 0] += wm * mom0
                                grid_momentum[idx, 1] += wm * mom1
                                grid_force[idx, 0] -= f_0
                                grid_force[idx, 1] -= f_1
                            else:
                                nx0 = origin[0] + (b0 + i) * dx
                                nx1 = origin[1] + (b1 + j) * dx
                                vs0, vs1 = v[p, 0] + gravity_dv[0], v[p, 1] + gravity_dv[1]
                                a0, a1 = force_velocity(ghost_force, dt, f_0, f_1, w, m)
                                c = crossed_body(p, idx, tag_T, fits) if PER_BODY else -1
                                gh0, gh1 = node_ghost(p, idx, c, nx0, nx1, node_body, near, normal, tag_T, friction,
                                                      fits.normal, vs0, vs1, a0, a1, position, velocity, omega)
                                wm = w * m
                                rejected_momentum[idx, 0] += wm * (vs0 - gh0)
                                rejected_momentum[idx, 1] += wm * (vs1 - gh1)
                                rejected_force[idx, 0] -= f_0
                                rejected_force[idx, 1] -= f_1

    return p2g


@njit(cache=True, inline="always")
def nearest_body(base, S, strides, node_body, node_d):
    """The nearest body of the stencil node at ``base`` closest to a body (the first such node in stencil
    order), or 0 if no node has a body: the body that receives a particle's penalty impulse."""
    best_d, best_body = np.inf, 0
    for i in range(S):
        for j in range(S):
            idx = base + i * strides[0] + j * strides[1]
            if node_body[idx] >= 0 and node_d[idx] < best_d:
                best_d, best_body = node_d[idx], node_body[idx]
    return best_body


@njit(cache=True, inline="always")
def add_impulse(block_impulse, bi, r, j0, j1, x0, x1, position):
    r"""Add the impulse :math:`\mathbf J = (j_0, j_1)` at :math:`\mathbf x` on body ``r`` to block ``bi``'s sums:
    :math:`\mathbf J` and :math:`(\mathbf x - \mathbf c_r)\times\mathbf J`."""
    block_impulse[bi, r, 0] += j0
    block_impulse[bi, r, 1] += j1
    block_impulse[bi, r, 2] += (x0 - position[r, 0]) * j1 - (x1 - position[r, 1]) * j0


@njit(cache=True)
def node_impulses(rejected_momentum, rejected_force, dt, node_body, node_shape, origin, dx, position, J, L):
    r"""Impulses on the bodies from the incompatible nodes, summed node by node in node order.

    :math:`\mathbf J_i = \mathbf J^m_i + \Delta t\,\mathbf J^f_i` at node :math:`i`; its nearest body
    :math:`r` receives :math:`\mathbf J_i` and :math:`(\mathbf x_i - \mathbf c_r)\times\mathbf J_i` (docs/cpic.md,
    "after all particles"). ``J`` (nb, 2) and ``L`` (nb,) are accumulated into.
    """
    for i in range(rejected_momentum.shape[0]):
        j0 = rejected_momentum[i, 0] + dt * rejected_force[i, 0]
        j1 = rejected_momentum[i, 1] + dt * rejected_force[i, 1]
        if j0 == 0.0 and j1 == 0.0:
            continue
        r = node_body[i]
        rel0 = (origin[0] + (i // node_shape[1]) * dx) - position[r, 0]
        rel1 = (origin[1] + (i % node_shape[1]) * dx) - position[r, 1]
        J[r, 0] += j0
        J[r, 1] += j1
        L[r] += rel0 * j1 - rel1 * j0


@lru_cache(maxsize=None)
def g2p_kernel(KERNEL, S, AFFINE, MLS_FORCE, MLS_GRADIENT, TRACKS_F, TRACKS_J, PER_BODY):
    r"""CPIC G2P kernel (2D): G2P with ghost velocities, ``C_p := 0`` for near particles, and the penalty
    (see :func:`mpmref.backends.numpy.cpic.g2p`).

    At an incompatible node the particle sees :math:`\tilde{\mathbf v}_i + \mathbf n_p\Delta t\,\Delta x\,f_{push}`
    (the push for near particles only) instead of :math:`\mathbf v_i`; then :math:`\mathbf v_p = \sum_i w_{ip}
    \tilde{\mathbf v}_i`, :math:`C_p`, :math:`F_p` or :math:`J_p`, :math:`\mathbf x_p` as plain G2P. A near
    particle with :math:`-0.3\Delta x < \phi_p < -0.05\Delta x` loses :math:`\Delta\mathbf v = k\phi_p\mathbf n_p`;
    its nearest body :math:`r` (the body of its stencil node closest to a body, first in stencil order; body 0
    if none) receives :math:`m_p\Delta\mathbf v` at :math:`\mathbf x_p` (after the move):
    ``block_impulse[bi, r]`` (zero on entry) accumulates :math:`(J_x, J_y, (\mathbf x_p - \mathbf c_r)\times
    \mathbf J)` over the particles of block ``bi`` in their order. Block-parallel gather; every particle
    writes only its own rows, every block its own impulses. ``MLS_FORCE``: the force's gradient weight
    is MLS's (it enters :math:`\mathbf a_{ip}`, :func:`force_velocity`); ``MLS_GRADIENT``: the velocity gradient
    is :math:`C_p` (``transfer.mls_gradient``). The new particle arrays go to ``out`` (a
    :class:`~mpmref.backends.numba.kernel_args.G2POutput`); ``fits`` is the step's
    :class:`~mpmref.backends.numba.kernel_args.BodyFits` (the per-body fit, read only with ``PER_BODY``).
    """
    NEED_B = AFFINE or MLS_GRADIENT
    SOURCES = SOURCE_DIGEST
    LO, HI = PENALTY_WINDOW

    @parallel_kernel(cache=True)
    def g2p(x, v, gravity_dv, F, J, mass, vol0, tau, ghost_force, layout, dt, groups, v_grid, contact, bodies, push,
            penalty, out, block_impulse, fits):
        SOURCES  # noqa: B018 - a closure constant: part of the cache key (see source_digest)
        origin, dx, inertia, strides = layout
        x_new, v_new, C_new, F_new, J_new = out.x, out.v, out.C, out.F, out.J
        order, block_start, blocks, colour_start = groups
        incompatible, node_body, node_d, near, phi, normal, tag_T = contact
        position, velocity, omega, friction = bodies
        for bi in prange(blocks.shape[0]):
            block = blocks[bi]
            for q in range(block_start[block], block_start[block + 1]):
                p = order[q]
                b0, f0, w0, dw0 = kernel_axis(KERNEL, np.float64, (x[p, 0] - origin[0]) / dx)
                b1, f1, w1, dw1 = kernel_axis(KERNEL, np.float64, (x[p, 1] - origin[1]) / dx)
                base = b0 * strides[0] + b1 * strides[1]
                inc = incompatible[p]
                vp0, vp1 = 0.0, 0.0
                B00, B01, B10, B11 = 0.0, 0.0, 0.0, 0.0
                G00, G01, G10, G11 = 0.0, 0.0, 0.0, 0.0
                for i in range(S):
                    d0 = (i - f0) * dx
                    for j in range(S):
                        d1 = (j - f1) * dx
                        w = w0[i] * w1[j]
                        idx = base + i * strides[0] + j * strides[1]
                        if inc == 0 or not (inc >> (i * S + j)) & 1:
                            vi0, vi1 = v_grid[idx, 0], v_grid[idx, 1]
                        else:
                            nx0 = origin[0] + (b0 + i) * dx
                            nx1 = origin[1] + (b1 + j) * dx
                            c = crossed_body(p, idx, tag_T, fits) if PER_BODY else -1
                            project, r, n0, n1, mu = ghost_frame(p, idx, c, node_body, near, normal, tag_T, friction,
                                                                 fits.normal)
                            a0, a1 = 0.0, 0.0
                            if project and ghost_force:
                                g0, g1 = gradient_weight(MLS_FORCE, w, d0, d1, w0[i], w1[j], dw0[i], dw1[j], dx,
                                                         inertia)
                                s00, s01 = vol0[p] * tau[p, 0, 0], vol0[p] * tau[p, 0, 1]
                                s10, s11 = vol0[p] * tau[p, 1, 0], vol0[p] * tau[p, 1, 1]
                                a0, a1 = force_velocity(True, dt, s00 * g0 + s01 * g1, s10 * g0 + s11 * g1, w, mass[p])
                            vi0, vi1 = v[p, 0] + gravity_dv[0], v[p, 1] + gravity_dv[1]
                            if project:
                                vi0, vi1 = ghost_velocity(vi0 + a0, vi1 + a1, nx0, nx1, r, position, velocity, omega,
                                                          n0, n1, mu)
                                vi0 += n0 * (dt * dx * push)
                                vi1 += n1 * (dt * dx * push)
                        vp0 += w * vi0
                        vp1 += w * vi1
                        if NEED_B:
                            B00 += (w * vi0) * d0
                            B01 += (w * vi0) * d1
                            B10 += (w * vi1) * d0
                            B11 += (w * vi1) * d1
                        if not MLS_GRADIENT:
                            g0, g1 = gradient_weight(False, w, d0, d1, w0[i], w1[j], dw0[i], dw1[j], dx, inertia)
                            G00 += vi0 * g0
                            G01 += vi0 * g1
                            G10 += vi1 * g0
                            G11 += vi1 * g1
                if MLS_GRADIENT:
                    G00, G01, G10, G11 = B00 / inertia, B01 / inertia, B10 / inertia, B11 / inertia
                x_new[p, 0] = x[p, 0] + dt * vp0
                x_new[p, 1] = x[p, 1] + dt * vp1
                dv0, dv1 = 0.0, 0.0
                if PER_BODY and tagged_by_several(p, fits.tag_A):  # PER_BODY: a closure constant
                    tag_A, fit_phi, fit_normal, fit_near = fits.tag_A, fits.phi, fits.normal, fits.near
                    for r in range(tag_A.shape[1]):
                        if fit_near[p, r] and fit_phi[p, r] > LO * dx and fit_phi[p, r] < HI * dx and penalty > 0.0:
                            kphi = penalty * fit_phi[p, r]
                            dvr0, dvr1 = kphi * fit_normal[p, r, 0], kphi * fit_normal[p, r, 1]
                            dv0 += dvr0
                            dv1 += dvr1
                            add_impulse(block_impulse, bi, r, mass[p] * dvr0, mass[p] * dvr1, x_new[p, 0],
                                        x_new[p, 1], position)
                elif near[p] and phi[p] > LO * dx and phi[p] < HI * dx and penalty > 0.0:
                    dv0, dv1 = penalty * phi[p] * normal[p, 0], penalty * phi[p] * normal[p, 1]
                    r = nearest_body(base, S, strides, node_body, node_d)
                    add_impulse(block_impulse, bi, r, mass[p] * dv0, mass[p] * dv1, x_new[p, 0], x_new[p, 1], position)
                v_new[p, 0] = vp0 - dv0
                v_new[p, 1] = vp1 - dv1
                if AFFINE:
                    if near[p]:
                        C_new[p, 0, 0], C_new[p, 0, 1], C_new[p, 1, 0], C_new[p, 1, 1] = 0.0, 0.0, 0.0, 0.0
                    else:
                        C_new[p, 0, 0], C_new[p, 0, 1] = B00 / inertia, B01 / inertia
                        C_new[p, 1, 0], C_new[p, 1, 1] = B10 / inertia, B11 / inertia
                if TRACKS_F:
                    F_new[p, 0, 0] = F[p, 0, 0] + (dt * G00 * F[p, 0, 0] + dt * G01 * F[p, 1, 0])
                    F_new[p, 0, 1] = F[p, 0, 1] + (dt * G00 * F[p, 0, 1] + dt * G01 * F[p, 1, 1])
                    F_new[p, 1, 0] = F[p, 1, 0] + (dt * G10 * F[p, 0, 0] + dt * G11 * F[p, 1, 0])
                    F_new[p, 1, 1] = F[p, 1, 1] + (dt * G10 * F[p, 0, 1] + dt * G11 * F[p, 1, 1])
                if TRACKS_J:
                    J_new[p] = J[p] * (1.0 + dt * (G00 + G11))

    return g2p
