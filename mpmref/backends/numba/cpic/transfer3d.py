r"""CPIC kernels of the Numba backend in 3D, the transfers: those of :mod:`.transfer2d` with the :math:`3^3`
stencils and the bodies' angular velocity and angular impulse as vectors (:math:`\boldsymbol\omega\times\mathbf r`,
:math:`\mathbf r\times\mathbf J`; :mod:`mpmref.rigid.dynamics3d`). Hu et al. 2018, SIGGRAPH, §4–5;
docs/cpic.md."""

from functools import lru_cache

import numpy as np
from numba import njit, prange

from ....physics.cdf import PENALTY_WINDOW
from ...pointwise.stencil import kernel_axis
from ..source_digest import SOURCE_DIGEST
from ..twin import parallel_kernel
from .common import crossed_body, tagged_by_several


@njit(cache=True, inline="always")
def ghost_velocity(v, node_x, r, position, velocity, omega, n, mu):
    r"""The friction projection :math:`\Pi(\mathbf v; \mathbf v_r(\mathbf x_i), \mathbf n, \mu)` against body ``r``
    in 3D, :math:`\mathbf v_r(\mathbf x) = \mathbf v_r + \boldsymbol\omega_r\times(\mathbf x - \mathbf c_r)`
    (the 3D :func:`mpmref.backends.numba.cpic.transfer2d.ghost_velocity`; the talk's Eq. 25, Hu et al. 2018 §5). ``v``,
    ``node_x``, ``n``: 3-tuples; returns a 3-tuple."""
    rel0, rel1, rel2 = node_x[0] - position[r, 0], node_x[1] - position[r, 1], node_x[2] - position[r, 2]
    vb0 = velocity[r, 0] + (omega[r, 1] * rel2 - omega[r, 2] * rel1)
    vb1 = velocity[r, 1] + (omega[r, 2] * rel0 - omega[r, 0] * rel2)
    vb2 = velocity[r, 2] + (omega[r, 0] * rel1 - omega[r, 1] * rel0)
    if mu == -1.0:
        return vb0, vb1, vb2
    u0, u1, u2 = v[0] - vb0, v[1] - vb1, v[2] - vb2
    un = n[0] * u0 + n[1] * u1 + n[2] * u2
    ut0, ut1, ut2 = u0 - un * n[0], u1 - un * n[1], u2 - un * n[2]
    ut_norm = np.sqrt(ut0 * ut0 + ut1 * ut1 + ut2 * ut2)
    coeff = mu if mu >= 0.0 else -mu - 2.0
    scale = max(ut_norm + coeff * min(un, 0.0), 0.0) / (ut_norm if ut_norm > 0.0 else 1.0)
    g0, g1, g2 = vb0 + scale * ut0, vb1 + scale * ut1, vb2 + scale * ut2
    if mu >= 0.0:
        keep = max(un, 0.0)
        g0, g1, g2 = g0 + keep * n[0], g1 + keep * n[1], g2 + keep * n[2]
    return g0, g1, g2


@njit(cache=True, inline="always")
def ghost_frame(p, idx, c, node_body, near, normal, tag_T, friction, fit_normal):
    r"""What the ghost velocity of incompatible node ``idx`` for particle ``p`` projects against, in 3D
    (:func:`mpmref.backends.numpy.cpic.ghost_frames`): ``(project, r, n0, n1, n2, mu)``. Single fit:
    the node's nearest body, the particle's normal, the friction of its side, ``project`` = ``near[p]``; with
    the per-body fit, the crossed body (:func:`~mpmref.backends.numba.cpic.common.crossed_body`) with its own
    normal :math:`\mathbf n_{pc}`, if there is one (as the 2D
    :func:`~mpmref.backends.numba.cpic.transfer2d.ghost_frame`)."""
    if c >= 0:
        mu = friction[c, 1] if tag_T[p, c] else friction[c, 0]
        return True, c, fit_normal[p, c, 0], fit_normal[p, c, 1], fit_normal[p, c, 2], mu
    r = max(node_body[idx], 0)
    mu = friction[r, 1] if tag_T[p, r] else friction[r, 0]
    return near[p], r, normal[p, 0], normal[p, 1], normal[p, 2], mu


@njit(cache=True, inline="always")
def node_ghost(p, idx, c, node_x, node_body, near, normal, tag_T, friction, fit_normal, vs, a, position, velocity,
               omega):
    r"""Ghost velocity of incompatible node ``idx`` for particle ``p`` in 3D (as the 2D
    :func:`~mpmref.backends.numba.cpic.transfer2d.node_ghost`): if :func:`ghost_frame` projects, the friction
    projection of :math:`\mathbf v^*_p + \mathbf a_{ip}` against its body and normal, else
    :math:`\mathbf v^*_p` (``vs``)."""
    project, r, n0, n1, n2, mu = ghost_frame(p, idx, c, node_body, near, normal, tag_T, friction, fit_normal)
    if not project:
        return vs
    return ghost_velocity((vs[0] + a[0], vs[1] + a[1], vs[2] + a[2]), node_x, r, position, velocity, omega,
                          (n0, n1, n2), mu)


@njit(cache=True, inline="always")
def add_impulse(block_impulse, bi, r, jv, xp, position):
    r"""Add the impulse :math:`\mathbf J` = ``jv`` at :math:`\mathbf x` = ``xp`` on body ``r`` to block ``bi``'s
    sums: :math:`\mathbf J` and :math:`(\mathbf x - \mathbf c_r)\times\mathbf J` (3D)."""
    rel = (xp[0] - position[r, 0], xp[1] - position[r, 1], xp[2] - position[r, 2])
    for a in range(3):
        block_impulse[bi, r, a] += jv[a]
    block_impulse[bi, r, 3] += rel[1] * jv[2] - rel[2] * jv[1]
    block_impulse[bi, r, 4] += rel[2] * jv[0] - rel[0] * jv[2]
    block_impulse[bi, r, 5] += rel[0] * jv[1] - rel[1] * jv[0]


@njit(cache=True, inline="always")
def force_velocity(ghost_force, dt, f, w, m):
    r""":math:`\mathbf a_{ip} = -\Delta t\,\mathbf f_{ip}/(m_p w_{ip})` with ``f`` = :math:`V_p^0\tau_p g_{ip}`
    (3-tuple), 0 where :math:`w_{ip} = 0` or without ``ghost_force`` (see
    :func:`mpmref.backends.numpy.cpic.force_velocity`)."""
    if not ghost_force or not w > 0.0:
        return 0.0, 0.0, 0.0
    return (-dt * f[0]) / (w * m), (-dt * f[1]) / (w * m), (-dt * f[2]) / (w * m)


@njit(cache=True, inline="always")
def gradient_weight(mls_force, w, dpos, wa, dwa, dx, inertia):
    r"""The force's gradient weight :math:`g_{ip}` in 3D: MLS :math:`w_{ip}(\mathbf x_i - \mathbf x_p)/D`, or the
    kernel gradient :math:`(N'_0 N_1 N_2, N_0 N'_1 N_2, N_0 N_1 N'_2)/\Delta x` from the per-axis weights ``wa``
    and derivatives ``dwa`` (3-tuples of the node's own axis values)."""
    if mls_force:
        return w * dpos[0] / inertia, w * dpos[1] / inertia, w * dpos[2] / inertia
    return dwa[0] / dx * wa[1] * wa[2], wa[0] * (dwa[1] / dx) * wa[2], wa[0] * wa[1] * (dwa[2] / dx)


@njit(cache=True, inline="always")
def stress_force(vol0, tau, p, g):
    """:math:`V_p^0 \\tau_p g_{ip}` (3-tuple)."""
    return (vol0[p] * (tau[p, 0, 0] * g[0] + tau[p, 0, 1] * g[1] + tau[p, 0, 2] * g[2]),
            vol0[p] * (tau[p, 1, 0] * g[0] + tau[p, 1, 1] * g[1] + tau[p, 1, 2] * g[2]),
            vol0[p] * (tau[p, 2, 0] * g[0] + tau[p, 2, 1] * g[1] + tau[p, 2, 2] * g[2]))


@lru_cache(maxsize=None)
def p2g_kernel(KERNEL, S, AFFINE, MLS_FORCE, PER_BODY):
    r"""CPIC P2G kernel (3D): mass, momentum and force to compatible nodes; at an incompatible node
    :math:`\mathbf J^m_i \mathrel{+}= m_p w_{ip}(\mathbf v^*_p - \tilde{\mathbf v}_i)` and
    :math:`\mathbf J^f_i \mathrel{-}= V_p^0\tau_p g_{ip}` (see :func:`mpmref.backends.numpy.transfers.p2g` with a
    contact). Block-parallel by the :math:`2^3` block colours."""
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
                    b0, f0, w0, dw0 = kernel_axis(KERNEL, np.float64, (x[p, 0] - origin[0]) / dx)
                    b1, f1, w1, dw1 = kernel_axis(KERNEL, np.float64, (x[p, 1] - origin[1]) / dx)
                    b2, f2, w2, dw2 = kernel_axis(KERNEL, np.float64, (x[p, 2] - origin[2]) / dx)
                    base = b0 * strides[0] + b1 * strides[1] + b2 * strides[2]
                    inc = incompatible[p]
                    vs = (v[p, 0] + gravity_dv[0], v[p, 1] + gravity_dv[1], v[p, 2] + gravity_dv[2])
                    for i in range(S):
                        for j in range(S):
                            for k in range(S):
                                dpos = ((i - f0) * dx, (j - f1) * dx, (k - f2) * dx)
                                w = w0[i] * w1[j] * w2[k]
                                g = gradient_weight(MLS_FORCE, w, dpos, (w0[i], w1[j], w2[k]), (dw0[i], dw1[j], dw2[k]),
                                                    dx, inertia)
                                f = stress_force(vol0, tau, p, g)
                                idx = base + i * strides[0] + j * strides[1] + k * strides[2]
                                wm = w * m
                                if inc == 0 or not (inc >> ((i * S + j) * S + k)) & 1:
                                    grid_mass[idx] += wm
                                    for a in range(3):
                                        mom = v[p, a]
                                        if AFFINE:
                                            mom += C[p, a, 0] * dpos[0] + C[p, a, 1] * dpos[1] + C[p, a, 2] * dpos[2]
                                        grid_momentum[idx, a] += wm * mom
                                        grid_force[idx, a] -= f[a]
                                else:
                                    node_x = (origin[0] + (b0 + i) * dx, origin[1] + (b1 + j) * dx,
                                              origin[2] + (b2 + k) * dx)
                                    acc = force_velocity(ghost_force, dt, f, w, m)
                                    c = crossed_body(p, idx, tag_T, fits) if PER_BODY else -1
                                    gh = node_ghost(p, idx, c, node_x, node_body, near, normal, tag_T, friction,
                                                    fits.normal, vs, acc, position, velocity, omega)
                                    for a in range(3):
                                        rejected_momentum[idx, a] += wm * (vs[a] - gh[a])
                                        rejected_force[idx, a] -= f[a]

    return p2g


@njit(cache=True, inline="always")
def nearest_body(base, S, strides, node_body, node_d):
    """The nearest body of the transfer-stencil node closest to a body (first in stencil order), or 0: the body
    that receives a particle's penalty impulse (3D :func:`mpmref.backends.numba.cpic.transfer2d.nearest_body`)."""
    best_d, best_body = np.inf, 0
    for i in range(S):
        for j in range(S):
            for k in range(S):
                idx = base + i * strides[0] + j * strides[1] + k * strides[2]
                if node_body[idx] >= 0 and node_d[idx] < best_d:
                    best_d, best_body = node_d[idx], node_body[idx]
    return best_body


@njit(cache=True)
def node_impulses(rejected_momentum, rejected_force, dt, node_body, node_shape, origin, dx, position, J, L):
    r"""Impulses on the bodies from the incompatible nodes, node by node in node order: node :math:`i`'s nearest
    body :math:`r` receives :math:`\mathbf J_i = \mathbf J^m_i + \Delta t\,\mathbf J^f_i` and
    :math:`(\mathbf x_i - \mathbf c_r)\times\mathbf J_i`. ``J``, ``L`` (nb, 3) are accumulated into."""
    for i in range(rejected_momentum.shape[0]):
        j0 = rejected_momentum[i, 0] + dt * rejected_force[i, 0]
        j1 = rejected_momentum[i, 1] + dt * rejected_force[i, 1]
        j2 = rejected_momentum[i, 2] + dt * rejected_force[i, 2]
        if j0 == 0.0 and j1 == 0.0 and j2 == 0.0:
            continue
        r = node_body[i]
        rel0 = (origin[0] + (i // (node_shape[1] * node_shape[2])) * dx) - position[r, 0]
        rel1 = (origin[1] + ((i // node_shape[2]) % node_shape[1]) * dx) - position[r, 1]
        rel2 = (origin[2] + (i % node_shape[2]) * dx) - position[r, 2]
        J[r, 0] += j0
        J[r, 1] += j1
        J[r, 2] += j2
        L[r, 0] += rel1 * j2 - rel2 * j1
        L[r, 1] += rel2 * j0 - rel0 * j2
        L[r, 2] += rel0 * j1 - rel1 * j0


@lru_cache(maxsize=None)
def g2p_kernel(KERNEL, S, AFFINE, MLS_FORCE, MLS_GRADIENT, TRACKS_F, TRACKS_J, PER_BODY):
    r"""CPIC G2P kernel (3D): G2P with ghost velocities (plus the pushing force for near particles),
    ``C_p := 0`` for near particles, and the penalty, whose impulse :math:`m_p\Delta\mathbf v` and its moment
    about the nearest body's centre accumulate per block in ``block_impulse[bi, r]`` (6 components); with the
    per-body fit, a particle tagged by several bodies gets the penalty of each body's own fit instead, each
    body receiving its part (``fits``) — the 3D
    :func:`mpmref.backends.numba.cpic.transfer2d.g2p_kernel` (see :func:`mpmref.backends.numpy.cpic.g2p`)."""
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
            vp, B, G, vi = np.empty(3), np.empty((3, 3)), np.empty((3, 3)), np.empty(3)
            for q in range(block_start[block], block_start[block + 1]):
                p = order[q]
                b0, f0, w0, dw0 = kernel_axis(KERNEL, np.float64, (x[p, 0] - origin[0]) / dx)
                b1, f1, w1, dw1 = kernel_axis(KERNEL, np.float64, (x[p, 1] - origin[1]) / dx)
                b2, f2, w2, dw2 = kernel_axis(KERNEL, np.float64, (x[p, 2] - origin[2]) / dx)
                base = b0 * strides[0] + b1 * strides[1] + b2 * strides[2]
                inc = incompatible[p]
                vs = (v[p, 0] + gravity_dv[0], v[p, 1] + gravity_dv[1], v[p, 2] + gravity_dv[2])
                vp[:] = 0.0
                B[:] = 0.0
                G[:] = 0.0
                for i in range(S):
                    for j in range(S):
                        for k in range(S):
                            dpos = ((i - f0) * dx, (j - f1) * dx, (k - f2) * dx)
                            w = w0[i] * w1[j] * w2[k]
                            idx = base + i * strides[0] + j * strides[1] + k * strides[2]
                            if inc == 0 or not (inc >> ((i * S + j) * S + k)) & 1:
                                for a in range(3):
                                    vi[a] = v_grid[idx, a]
                            else:
                                node_x = (origin[0] + (b0 + i) * dx, origin[1] + (b1 + j) * dx,
                                          origin[2] + (b2 + k) * dx)
                                c = crossed_body(p, idx, tag_T, fits) if PER_BODY else -1
                                project, r, n0, n1, n2, mu = ghost_frame(p, idx, c, node_body, near, normal, tag_T,
                                                                         friction, fits.normal)
                                n = (n0, n1, n2)
                                acc = (0.0, 0.0, 0.0)
                                if project and ghost_force:
                                    g = gradient_weight(MLS_FORCE, w, dpos, (w0[i], w1[j], w2[k]),
                                                        (dw0[i], dw1[j], dw2[k]), dx, inertia)
                                    acc = force_velocity(True, dt, stress_force(vol0, tau, p, g), w, mass[p])
                                for a in range(3):
                                    vi[a] = vs[a]
                                if project:
                                    gh = ghost_velocity((vs[0] + acc[0], vs[1] + acc[1], vs[2] + acc[2]), node_x, r,
                                                        position, velocity, omega, n, mu)
                                    for a in range(3):
                                        vi[a] = gh[a] + n[a] * (dt * dx * push)
                            gw = gradient_weight(False, w, dpos, (w0[i], w1[j], w2[k]), (dw0[i], dw1[j], dw2[k]),
                                                 dx, inertia)
                            for a in range(3):
                                vp[a] += w * vi[a]
                                for c in range(3):
                                    if NEED_B:
                                        B[a, c] += (w * vi[a]) * dpos[c]
                                    if not MLS_GRADIENT:
                                        G[a, c] += vi[a] * gw[c]
                if MLS_GRADIENT:
                    for a in range(3):
                        for c in range(3):
                            G[a, c] = B[a, c] / inertia
                for a in range(3):
                    x_new[p, a] = x[p, a] + dt * vp[a]
                xp = (x_new[p, 0], x_new[p, 1], x_new[p, 2])
                dv = (0.0, 0.0, 0.0)
                if PER_BODY and tagged_by_several(p, fits.tag_A):  # PER_BODY: a closure constant
                    tag_A, fit_phi, fit_normal, fit_near = fits.tag_A, fits.phi, fits.normal, fits.near
                    for r in range(tag_A.shape[1]):
                        if fit_near[p, r] and fit_phi[p, r] > LO * dx and fit_phi[p, r] < HI * dx and penalty > 0.0:
                            kphi = penalty * fit_phi[p, r]
                            dvr = (kphi * fit_normal[p, r, 0], kphi * fit_normal[p, r, 1], kphi * fit_normal[p, r, 2])
                            dv = (dv[0] + dvr[0], dv[1] + dvr[1], dv[2] + dvr[2])
                            add_impulse(block_impulse, bi, r, (mass[p] * dvr[0], mass[p] * dvr[1], mass[p] * dvr[2]),
                                        xp, position)
                elif near[p] and phi[p] > LO * dx and phi[p] < HI * dx and penalty > 0.0:
                    dv = (penalty * phi[p] * normal[p, 0], penalty * phi[p] * normal[p, 1],
                          penalty * phi[p] * normal[p, 2])
                    r = nearest_body(base, S, strides, node_body, node_d)
                    add_impulse(block_impulse, bi, r, (mass[p] * dv[0], mass[p] * dv[1], mass[p] * dv[2]), xp, position)
                for a in range(3):
                    v_new[p, a] = vp[a] - dv[a]
                if AFFINE:
                    for a in range(3):
                        for c in range(3):
                            C_new[p, a, c] = 0.0 if near[p] else B[a, c] / inertia
                if TRACKS_F:
                    for a in range(3):
                        for c in range(3):
                            F_new[p, a, c] = F[p, a, c] + (dt * G[a, 0] * F[p, 0, c] + dt * G[a, 1] * F[p, 1, c]
                                                           + dt * G[a, 2] * F[p, 2, c])
                if TRACKS_J:
                    J_new[p] = J[p] * (1.0 + dt * (G[0, 0] + G[1, 1] + G[2, 2]))

    return g2p
