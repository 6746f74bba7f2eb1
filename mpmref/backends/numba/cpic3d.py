r"""CPIC kernels of the Numba backend in 3D: the colored distance field of triangle meshes, the particles' tags
and distance, P2G to compatible nodes, the bodies' impulses and G2P with ghost velocities, compiled. The stages
that call them (``contact``, ``p2g``, ``impulses``, ``g2p``, ``warm_up``) are those of :mod:`mpmref.backends.numba.cpic`, which
picks this module's kernels in 3D (:func:`mpmref.backends.numba.cpic.kernels`).

The equations are those of the NumPy reference (:mod:`mpmref.backends.numpy.cpic`, :mod:`mpmref.physics.cdf`,
:func:`mpmref.physics.rigid_dynamics.friction_projection`, :mod:`mpmref.physics.rigid_dynamics3d`); Hu et al.
2018, SIGGRAPH, §4–5, as the authors' reference implementation does (docs/cpic.md). The layout is that of the
2D kernels (:mod:`mpmref.backends.numba.cpic`): the field rasterised body by body in the reference's order, the tags over the
particles' blocks (skipping blocks far from every band), a bit mask of the incompatible nodes of each
particle's transfer stencil (:math:`S^3 \le 64` bits), P2G block-parallel by the :math:`2^3` block colours,
impulses reduced in a fixed order. What differs from 2D is the geometry (a node's barycentric coordinates
and signed offset in a triangle's frame), the :math:`3^3` stencils, the 4 × 4 least-squares fit, and the
bodies' angular velocity and angular impulse, which are vectors (:math:`\boldsymbol\omega\times\mathbf r`,
:math:`\mathbf r\times\mathbf J`).
"""

from functools import lru_cache

import numpy as np
from numba import njit, prange

from ...physics.cdf import BARYCENTRIC_TOLERANCE, DET_THRESHOLD_3D, NORMAL_THRESHOLD, ColoredDistanceField
from ...physics.rigid_dynamics import current_shapes
from ...physics.trimesh import surface_samples
from ...physics.cdf import PENALTY_WINDOW
from .cpic import fit_target, settle_body, sticky_tag
from .stencil import kernel_axis, quadratic_axis
from .transfers import SOURCE_DIGEST


# ------------------------------------------------------------------------------------------ the field
def body_samples(bodies, rigid, dx):
    """Surface samples of every body where ``rigid`` puts it, concatenated body by body.

    Returns ``(x (k, 3), triangle (k,) global triangle index, start (nb + 1,) first sample of each body,
    corner_a (m, 3), e1 (m, 3), e2 (m, 3), normal (m, 3))``: each triangle's first corner, edge vectors
    :math:`\\mathbf b - \\mathbf a`, :math:`\\mathbf c - \\mathbf a` and unit normal, as
    :func:`mpmref.physics.trimesh.triangle_frame` forms them.
    """
    xs, tris, starts, a, e1, e2, normal = [], [], [0], [], [], [], []
    offset = 0
    for mesh in current_shapes(bodies, rigid):
        x, tri = surface_samples(mesh, dx)
        xs.append(x)
        tris.append(tri + offset)
        starts.append(starts[-1] + len(x))
        corners = mesh.corners
        a.append(corners[:, 0])
        e1.append(corners[:, 1] - corners[:, 0])
        e2.append(corners[:, 2] - corners[:, 0])
        normal.append(mesh.normals)
        offset += len(mesh.triangles)
    return (np.concatenate(xs), np.concatenate(tris), np.array(starts, dtype=np.int64),
            *(np.ascontiguousarray(np.concatenate(v)) for v in (a, e1, e2, normal)))


def build_cdf(bodies, rigid, shape, origin, dx):
    """The colored distance field (:func:`mpmref.physics.cdf.build_cdf`) of 3D bodies, rasterised by :func:`rasterise`."""
    x, tri, start, a, e1, e2, normal = body_samples(bodies, rigid, dx)
    n_nodes = int(shape[0] * shape[1] * shape[2])
    d = np.full(n_nodes, np.inf)
    nearest = np.full(n_nodes, -1, dtype=np.int64)
    A = np.zeros((n_nodes, len(bodies)), dtype=np.bool_)
    T = np.zeros((n_nodes, len(bodies)), dtype=np.bool_)
    rasterise(x, tri, start, a, e1, e2, normal, origin, float(dx), shape, d, nearest, A, T)
    return ColoredDistanceField(d=d, body=nearest, A=A, T=T, shape=tuple(int(s) for s in shape), origin=origin,
                               dx=float(dx))


@njit(cache=True)
def rasterise(x, tri, start, a, e1, e2, normal, origin, dx, shape, d, nearest, A, T):
    r"""Write the colored distance field into ``d``, ``nearest``, ``A``, ``T`` (:func:`mpmref.physics.cdf.build_cdf`).

    For every sample :math:`s` of body :math:`r` and node :math:`i` of its 3 × 3 × 3 quadratic stencil, with
    :math:`\mathbf r = \mathbf x_i - \mathbf a`, the signed offset :math:`h = \mathbf r\cdot\mathbf n` and the
    barycentric coordinates of the node's projection in the sample's triangle,

    .. math:: \lambda_b = \frac{g_{22} r_1 - g_{12} r_2}{g_{11} g_{22} - g_{12}^2}, \quad
              \lambda_c = \frac{g_{11} r_2 - g_{12} r_1}{g_{11} g_{22} - g_{12}^2}, \quad
              \lambda_a = 1 - \lambda_b - \lambda_c

    (:math:`g_{jk} = \mathbf e_j\cdot\mathbf e_k`, :math:`r_j = \mathbf r\cdot\mathbf e_j`), if all three are
    :math:`\ge -10^{-10}`: :math:`d_{ir} = \min(d_{ir}, |h|)`, :math:`A_{ir} = 1`; then :math:`T_{ir} = [h < 0]`
    from the pairs at :math:`d_{ir}` (the last in the reference's order, offsets outer and samples inner,
    wins), and node :math:`i`'s nearest body is the first body with the smallest :math:`d_{ir}`.
    Hu et al. 2018 §4; docs/cpic.md.
    """
    n_nodes = d.shape[0]
    n_bodies = start.shape[0] - 1
    d_r = np.full(n_nodes, np.inf)
    cap = 27 * (start[n_bodies] - start[0])
    pair_node = np.empty(cap, dtype=np.int64)
    pair_h = np.empty(cap)
    base = np.empty((x.shape[0], 3), dtype=np.int64)  # each sample's stencil base node, computed once
    for s in range(x.shape[0]):
        for axis in range(3):
            base[s, axis] = quadratic_axis((x[s, axis] - origin[axis]) / dx)[0]
    gram = np.empty((a.shape[0], 4))  # per triangle: g11, g12, g22 and the determinant g11 g22 - g12^2
    for t in range(a.shape[0]):
        g11 = e1[t, 0] * e1[t, 0] + e1[t, 1] * e1[t, 1] + e1[t, 2] * e1[t, 2]
        g12 = e1[t, 0] * e2[t, 0] + e1[t, 1] * e2[t, 1] + e1[t, 2] * e2[t, 2]
        g22 = e2[t, 0] * e2[t, 0] + e2[t, 1] * e2[t, 1] + e2[t, 2] * e2[t, 2]
        gram[t, 0], gram[t, 1], gram[t, 2], gram[t, 3] = g11, g12, g22, g11 * g22 - g12 * g12
    for r in range(n_bodies):
        count = 0
        for k in range(27):
            oi, oj, ok = k // 9, (k // 3) % 3, k % 3
            for s in range(start[r], start[r + 1]):
                i0, i1, i2 = base[s, 0] + oi, base[s, 1] + oj, base[s, 2] + ok
                if i0 < 0 or i1 < 0 or i2 < 0 or i0 >= shape[0] or i1 >= shape[1] or i2 >= shape[2]:
                    continue
                t = tri[s]
                r0 = (origin[0] + i0 * dx) - a[t, 0]
                r1 = (origin[1] + i1 * dx) - a[t, 1]
                r2 = (origin[2] + i2 * dx) - a[t, 2]
                q1 = r0 * e1[t, 0] + r1 * e1[t, 1] + r2 * e1[t, 2]
                q2 = r0 * e2[t, 0] + r1 * e2[t, 1] + r2 * e2[t, 2]
                lam_b = (gram[t, 2] * q1 - gram[t, 1] * q2) / gram[t, 3]
                lam_c = (gram[t, 0] * q2 - gram[t, 1] * q1) / gram[t, 3]
                if (lam_b < -BARYCENTRIC_TOLERANCE or lam_c < -BARYCENTRIC_TOLERANCE
                        or 1.0 - lam_b - lam_c < -BARYCENTRIC_TOLERANCE):
                    continue
                h = r0 * normal[t, 0] + r1 * normal[t, 1] + r2 * normal[t, 2]
                flat = (i0 * shape[1] + i1) * shape[2] + i2
                pair_node[count] = flat
                pair_h[count] = h
                count += 1
                d_r[flat] = min(d_r[flat], abs(h))
                A[flat, r] = True
        settle_body(r, count, pair_node, pair_h, d_r, d, nearest, T)


# -------------------------------------------------------------------- tags, distance and compatibility
@lru_cache(maxsize=None)
def tag_kernel(KERNEL, S):
    r"""Sticky tags, least-squares distance and normal of every particle (3D, quadratic stencil), and the mask
    of the incompatible nodes of its transfer stencil (``S`` nodes per axis, kernel code ``KERNEL``); as the
    2D :func:`mpmref.backends.numba.cpic.tag_kernel`, over the particles' blocks, skipping blocks far from every band."""
    SOURCES = SOURCE_DIGEST

    @njit(parallel=True, cache=True)
    def tags(x, origin, dx, shape, strides, d, A, T, tag_A, tag_T, A_new, T_new, phi, normal, near, incompatible,
             order, block_start, blocks, block, blocks_per_axis):
        SOURCES  # noqa: B018 - a closure constant: part of the cache key (see transfers._source_digest)
        n_bodies = tag_A.shape[1]
        for bi in prange(blocks.shape[0]):
            b = blocks[bi]
            c0 = b // (blocks_per_axis[1] * blocks_per_axis[2])
            c1 = (b // blocks_per_axis[2]) % blocks_per_axis[1]
            c2 = b % blocks_per_axis[2]
            if not block_in_band(c0, c1, c2, block, shape, d):
                continue
            near_r = np.empty(n_bodies, dtype=np.bool_)  # scratch, one set per block
            S0, S1 = np.empty(n_bodies), np.empty(n_bodies)
            M, rhs = np.empty((4, 4)), np.empty(4)
            for q in range(block_start[b], block_start[b + 1]):
                p = order[q]
                if tag_particle(p, x, origin, dx, shape, d, A, T, tag_A, tag_T, A_new, T_new, phi, normal, near,
                                near_r, S0, S1, M, rhs):
                    b0 = kernel_axis(KERNEL, (x[p, 0] - origin[0]) / dx)[0]
                    b1 = kernel_axis(KERNEL, (x[p, 1] - origin[1]) / dx)[0]
                    b2 = kernel_axis(KERNEL, (x[p, 2] - origin[2]) / dx)[0]
                    incompatible[p] = incompatibility_mask(p, b0, b1, b2, S, strides, A, T, A_new, T_new)

    return tags


@njit(cache=True, inline="always")
def block_in_band(c0, c1, c2, block, shape, d):
    """Whether a node that the quadratic stencils of block ``(c0, c1, c2)``'s particles can reach is in a band
    (the 3D :func:`mpmref.backends.numba.cpic.block_in_band`: per axis ``[c B - 1, c B + B + 2]``)."""
    for i0 in range(max(c0 * block - 1, 0), min(c0 * block + block + 3, shape[0])):
        for i1 in range(max(c1 * block - 1, 0), min(c1 * block + block + 3, shape[1])):
            for i2 in range(max(c2 * block - 1, 0), min(c2 * block + block + 3, shape[2])):
                if d[(i0 * shape[1] + i1) * shape[2] + i2] < np.inf:
                    return True
    return False


@njit(cache=True, inline="always")
def incompatibility_mask(p, b0, b1, b2, S, strides, A, T, A_p, T_p):
    r"""Bit ``k`` set iff node ``k`` (C order) of the ``S``:sup:`3` transfer stencil at ``(b0, b1, b2)`` is
    incompatible with particle ``p``: some body has :math:`A_{ir} = A_{pr} = 1`, :math:`T_{ir} \ne T_{pr}`."""
    mask = 0
    for k in range(S * S * S):
        idx = (b0 + k // (S * S)) * strides[0] + (b1 + (k // S) % S) * strides[1] + (b2 + k % S) * strides[2]
        for r in range(A_p.shape[1]):
            if A[idx, r] and A_p[p, r] and T[idx, r] != T_p[p, r]:
                mask |= 1 << k
                break
    return mask


@njit(cache=True, inline="always")
def stencil_node(b0, b1, b2, k, shape):
    """Flat index of node ``k`` (C order) of the 3 × 3 × 3 stencil at base ``(b0, b1, b2)``, or -1 off the grid."""
    i0, i1, i2 = b0 + k // 9, b1 + (k // 3) % 3, b2 + k % 3
    if i0 < 0 or i1 < 0 or i2 < 0 or i0 >= shape[0] or i1 >= shape[1] or i2 >= shape[2]:
        return -1
    return (i0 * shape[1] + i1) * shape[2] + i2


@njit(cache=True, inline="always")
def tag_particle(p, x, origin, dx, shape, d, A, T, tag_A, tag_T, A_new, T_new, phi, normal, near, near_r, S0, S1, M,
                 rhs):
    r"""Tags, distance, normal and ``near`` of particle ``p`` (the 3D :func:`mpmref.backends.numba.cpic.tag_particle`: sticky tags,
    :math:`S_s = \sum_{i: A_{ir} = 1, T_{ir} = s} w_{ip} d_i`, then :func:`reconstruct_particle`); returns
    whether it is tagged. Hu et al. 2018 §4; docs/cpic.md."""
    n_bodies = tag_A.shape[1]
    b0, f0, w0, dw0 = quadratic_axis((x[p, 0] - origin[0]) / dx)
    b1, f1, w1, dw1 = quadratic_axis((x[p, 1] - origin[1]) / dx)
    b2, f2, w2, dw2 = quadratic_axis((x[p, 2] - origin[2]) / dx)
    band = False
    for k in range(27):
        flat = stencil_node(b0, b1, b2, k, shape)
        if flat >= 0 and d[flat] < np.inf:
            band = True
            break
    if not band:  # far from every body: no tags (the common case, kept cheap)
        return False
    near_r[:] = False
    S0[:] = 0.0
    S1[:] = 0.0
    for k in range(27):
        flat = stencil_node(b0, b1, b2, k, shape)
        if flat < 0:
            continue
        w = w0[k // 9] * w1[(k // 3) % 3] * w2[k % 3]
        for r in range(n_bodies):
            if A[flat, r]:
                near_r[r] = True
                if T[flat, r]:
                    S1[r] += w * d[flat]
                else:
                    S0[r] += w * d[flat]
    tagged = False
    for r in range(n_bodies):
        tagged = sticky_tag(p, r, near_r, S0, S1, tag_A, tag_T, A_new, T_new) or tagged
    if tagged:
        reconstruct_particle(p, (b0, b1, b2), (f0, f1, f2), w0, w1, w2, dx, shape, d, A, T, A_new, T_new, phi,
                             normal, near, M, rhs)
    return tagged


@njit(cache=True, inline="always")
def reconstruct_particle(p, base, f, w0, w1, w2, dx, shape, d, A, T, A_p, T_p, phi, normal, near, M, rhs):
    r"""The weighted least-squares fit of :func:`mpmref.physics.cdf.reconstruct` for one tagged particle in 3D:
    minimise :math:`\sum_i w_{ip}(\mathbf n\cdot\mathbf z_i + c - y_i)^2` (a 4 × 4 normal system); ``near``
    iff :math:`|\det M| > 10^{-4}`. ``M``, ``rhs``: scratch."""
    M[:] = 0.0
    rhs[:] = 0.0
    for k in range(27):
        flat = stencil_node(base[0], base[1], base[2], k, shape)
        if flat < 0:
            continue
        use, y = fit_target(p, flat, dx, d, A, T, A_p, T_p)
        if not use:
            continue
        w = w0[k // 9] * w1[(k // 3) % 3] * w2[k % 3]
        # (x_i - x_p) / dx, as the reference forms it, and the constant term
        z = (((k // 9) - f[0]) * dx / dx, (((k // 3) % 3) - f[1]) * dx / dx, ((k % 3) - f[2]) * dx / dx, 1.0)
        for i in range(4):
            wz = w * z[i]
            for j in range(4):
                M[i, j] += wz * z[j]
            rhs[i] += wz * y
    det, sol = lu_solve(M, rhs)
    if not abs(det) > DET_THRESHOLD_3D:
        return
    phi[p] = sol[3] * dx
    norm2 = sol[0] * sol[0] + sol[1] * sol[1] + sol[2] * sol[2]
    if norm2 > NORMAL_THRESHOLD:
        length = np.sqrt(norm2)
        for a in range(3):
            normal[p, a] = sol[a] / length
    near[p] = True


@njit(cache=True, inline="always")
def lu_solve(M, rhs):
    """Determinant of the n × n matrix ``M`` and the solution of ``M s = rhs``, by Gaussian elimination with partial
    pivoting (LAPACK's getrf/getrs order, as ``np.linalg.det`` and ``np.linalg.solve`` of the reference),
    overwriting ``M`` and ``rhs``; ``(0, rhs)`` if a pivot is exactly zero."""
    n = rhs.shape[0]
    det = 1.0
    for c in range(n):
        piv = c
        for r in range(c + 1, n):
            if abs(M[r, c]) > abs(M[piv, c]):
                piv = r
        if M[piv, c] == 0.0:
            return 0.0, rhs
        if piv != c:
            det = -det
            for j in range(n):
                M[c, j], M[piv, j] = M[piv, j], M[c, j]
            rhs[c], rhs[piv] = rhs[piv], rhs[c]
        det *= M[c, c]
        inv = 1.0 / M[c, c]
        for r in range(c + 1, n):
            factor = M[r, c] * inv
            for j in range(c + 1, n):
                M[r, j] -= factor * M[c, j]
            rhs[r] -= factor * rhs[c]
    for r in range(n - 1, -1, -1):
        acc = rhs[r]
        for j in range(r + 1, n):
            acc -= M[r, j] * rhs[j]
        rhs[r] = acc / M[r, r]
    return det, rhs


# ------------------------------------------------------------------------------- ghost velocities
@njit(cache=True, inline="always")
def ghost_velocity(v, node_x, r, position, velocity, omega, n, mu):
    r"""The friction projection :math:`\Pi(\mathbf v; \mathbf v_r(\mathbf x_i), \mathbf n, \mu)` against body ``r``
    in 3D, :math:`\mathbf v_r(\mathbf x) = \mathbf v_r + \boldsymbol\omega_r\times(\mathbf x - \mathbf c_r)`
    (the 3D :func:`mpmref.backends.numba.cpic.ghost_velocity`; the talk's Eq. 25, Hu et al. 2018 §5). ``v``, ``node_x``, ``n``:
    3-tuples; returns a 3-tuple."""
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
def node_ghost(p, idx, node_x, node_body, near, normal, tag_T, friction, vs, a, position, velocity, omega):
    r"""Ghost velocity of incompatible node ``idx`` for particle ``p`` (3D :func:`mpmref.backends.numba.cpic.node_ghost`): if ``near``,
    the friction projection of :math:`\mathbf v^*_p + \mathbf a_{ip}` against the node's nearest body, else
    :math:`\mathbf v^*_p` (``vs``)."""
    if not near[p]:
        return vs
    r = max(node_body[idx], 0)
    mu = friction[r, 1] if tag_T[p, r] else friction[r, 0]
    return ghost_velocity((vs[0] + a[0], vs[1] + a[1], vs[2] + a[2]), node_x, r, position, velocity, omega,
                          (normal[p, 0], normal[p, 1], normal[p, 2]), mu)


@njit(cache=True, inline="always")
def force_velocity(ghost_force, dt, f, w, m):
    r""":math:`\mathbf a_{ip} = -\Delta t\,\mathbf f_{ip}/(m_p w_{ip})` with ``f`` = :math:`V_p^0\tau_p g_{ip}` (3-tuple),
    0 where :math:`w_{ip} = 0` or without ``ghost_force`` (see :func:`mpmref.backends.numpy.cpic.force_velocity`)."""
    if not ghost_force or not w > 0.0:
        return 0.0, 0.0, 0.0
    return (-dt * f[0]) / (w * m), (-dt * f[1]) / (w * m), (-dt * f[2]) / (w * m)


@njit(cache=True, inline="always")
def gradient_weight(mls, w, dpos, wa, dwa, dx, inertia):
    r"""The force's gradient weight :math:`g_{ip}` in 3D: MLS :math:`w_{ip}(\mathbf x_i - \mathbf x_p)/D`, or the
    kernel gradient :math:`(N'_0 N_1 N_2, N_0 N'_1 N_2, N_0 N_1 N'_2)/\Delta x` from the per-axis weights ``wa``
    and derivatives ``dwa`` (3-tuples of the node's own axis values)."""
    if mls:
        return w * dpos[0] / inertia, w * dpos[1] / inertia, w * dpos[2] / inertia
    return dwa[0] / dx * wa[1] * wa[2], wa[0] * (dwa[1] / dx) * wa[2], wa[0] * wa[1] * (dwa[2] / dx)


@njit(cache=True, inline="always")
def stress_force(vol0, tau, p, g):
    """:math:`V_p^0 \\tau_p g_{ip}` (3-tuple)."""
    return (vol0[p] * (tau[p, 0, 0] * g[0] + tau[p, 0, 1] * g[1] + tau[p, 0, 2] * g[2]),
            vol0[p] * (tau[p, 1, 0] * g[0] + tau[p, 1, 1] * g[1] + tau[p, 1, 2] * g[2]),
            vol0[p] * (tau[p, 2, 0] * g[0] + tau[p, 2, 1] * g[1] + tau[p, 2, 2] * g[2]))


# ------------------------------------------------------------------------------------------------ P2G
@lru_cache(maxsize=None)
def p2g_kernel(KERNEL, S, AFFINE, MLS):
    r"""CPIC P2G kernel (3D): mass, momentum and force to compatible nodes; at an incompatible node
    :math:`\mathbf J^m_i \mathrel{+}= m_p w_{ip}(\mathbf v^*_p - \tilde{\mathbf v}_i)` and
    :math:`\mathbf J^f_i \mathrel{-}= V_p^0\tau_p g_{ip}` (see :func:`mpmref.backends.numpy.transfers.p2g` with a
    contact). Block-parallel by the :math:`2^3` block colours."""
    SOURCES = SOURCE_DIGEST

    @njit(parallel=True, cache=True)
    def p2g(x, v, C, mass, vol0, tau, origin, dx, inertia, strides, order, block_start, colour_blocks, colour_start,
            incompatible, gravity_dv, node_body, near, normal, tag_T, friction, position, velocity, omega, ghost_force,
            dt, grid_mass, grid_momentum, grid_force, rejected_momentum, rejected_force):
        SOURCES  # noqa: B018 - a closure constant: part of the cache key (see transfers._source_digest)
        for colour in range(colour_start.shape[0] - 1):
            first = colour_start[colour]
            for bi in prange(colour_start[colour + 1] - first):
                block = colour_blocks[first + bi]
                for q in range(block_start[block], block_start[block + 1]):
                    p = order[q]
                    m = mass[p]
                    b0, f0, w0, dw0 = kernel_axis(KERNEL, (x[p, 0] - origin[0]) / dx)
                    b1, f1, w1, dw1 = kernel_axis(KERNEL, (x[p, 1] - origin[1]) / dx)
                    b2, f2, w2, dw2 = kernel_axis(KERNEL, (x[p, 2] - origin[2]) / dx)
                    base = b0 * strides[0] + b1 * strides[1] + b2 * strides[2]
                    inc = incompatible[p]
                    vs = (v[p, 0] + gravity_dv[0], v[p, 1] + gravity_dv[1], v[p, 2] + gravity_dv[2])
                    for i in range(S):
                        for j in range(S):
                            for k in range(S):
                                dpos = ((i - f0) * dx, (j - f1) * dx, (k - f2) * dx)
                                w = w0[i] * w1[j] * w2[k]
                                g = gradient_weight(MLS, w, dpos, (w0[i], w1[j], w2[k]), (dw0[i], dw1[j], dw2[k]),
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
                                    gh = node_ghost(p, idx, node_x, node_body, near, normal, tag_T, friction, vs, acc,
                                                    position, velocity, omega)
                                    for a in range(3):
                                        rejected_momentum[idx, a] += wm * (vs[a] - gh[a])
                                        rejected_force[idx, a] -= f[a]

    return p2g


@njit(cache=True, inline="always")
def nearest_body(base, S, strides, node_body, node_d):
    """The nearest body of the transfer-stencil node closest to a body (first in stencil order), or 0: the body
    that receives a particle's penalty impulse (3D :func:`mpmref.backends.numba.cpic.nearest_body`)."""
    best_d, best_body = np.inf, 0
    for i in range(S):
        for j in range(S):
            for k in range(S):
                idx = base + i * strides[0] + j * strides[1] + k * strides[2]
                if node_body[idx] >= 0 and node_d[idx] < best_d:
                    best_d, best_body = node_d[idx], node_body[idx]
    return best_body


# ------------------------------------------------------------------------------------------- impulses
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


# ------------------------------------------------------------------------------------------------ G2P
@lru_cache(maxsize=None)
def g2p_kernel(KERNEL, S, AFFINE, MLS_FORCE, MLS, TRACKS_F, TRACKS_J):
    r"""CPIC G2P kernel (3D): G2P with ghost velocities (plus the pushing force for near particles),
    ``C_p := 0`` for near particles, and the penalty, whose impulse :math:`m_p\Delta\mathbf v` and its moment
    about the nearest body's centre accumulate per block in ``block_impulse[bi, r]`` (6 components) — the 3D
    :func:`mpmref.backends.numba.cpic.g2p_kernel` (see :func:`mpmref.backends.numpy.cpic.g2p`)."""
    NEED_B = AFFINE or MLS
    SOURCES = SOURCE_DIGEST
    LO, HI = PENALTY_WINDOW

    @njit(parallel=True, cache=True)
    def g2p(x, v, gravity_dv, F, J, mass, vol0, tau, ghost_force, origin, dx, inertia, dt, strides, order, block_start,
            blocks, v_grid, incompatible, node_body, node_d, near, phi, normal, tag_T, friction, position, velocity,
            omega, push, penalty, x_new, v_new, C_new, F_new, J_new, block_impulse):
        SOURCES  # noqa: B018 - a closure constant: part of the cache key (see transfers._source_digest)
        for bi in prange(blocks.shape[0]):
            block = blocks[bi]
            vp, B, G, vi = np.empty(3), np.empty((3, 3)), np.empty((3, 3)), np.empty(3)
            for q in range(block_start[block], block_start[block + 1]):
                p = order[q]
                b0, f0, w0, dw0 = kernel_axis(KERNEL, (x[p, 0] - origin[0]) / dx)
                b1, f1, w1, dw1 = kernel_axis(KERNEL, (x[p, 1] - origin[1]) / dx)
                b2, f2, w2, dw2 = kernel_axis(KERNEL, (x[p, 2] - origin[2]) / dx)
                base = b0 * strides[0] + b1 * strides[1] + b2 * strides[2]
                inc = incompatible[p]
                scale = dt * dx * push if near[p] else 0.0
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
                                acc = (0.0, 0.0, 0.0)
                                if near[p] and ghost_force:
                                    g = gradient_weight(MLS_FORCE, w, dpos, (w0[i], w1[j], w2[k]),
                                                        (dw0[i], dw1[j], dw2[k]), dx, inertia)
                                    acc = force_velocity(True, dt, stress_force(vol0, tau, p, g), w, mass[p])
                                gh = node_ghost(p, idx, node_x, node_body, near, normal, tag_T, friction, vs, acc,
                                                position, velocity, omega)
                                for a in range(3):
                                    vi[a] = gh[a] + normal[p, a] * scale
                            gw = gradient_weight(False, w, dpos, (w0[i], w1[j], w2[k]), (dw0[i], dw1[j], dw2[k]),
                                                 dx, inertia)
                            for a in range(3):
                                vp[a] += w * vi[a]
                                for c in range(3):
                                    if NEED_B:
                                        B[a, c] += (w * vi[a]) * dpos[c]
                                    if not MLS:
                                        G[a, c] += vi[a] * gw[c]
                if MLS:
                    for a in range(3):
                        for c in range(3):
                            G[a, c] = B[a, c] / inertia
                for a in range(3):
                    x_new[p, a] = x[p, a] + dt * vp[a]
                pushed = near[p] and phi[p] > LO * dx and phi[p] < HI * dx and penalty > 0.0
                for a in range(3):
                    dv = penalty * phi[p] * normal[p, a] if pushed else 0.0
                    v_new[p, a] = vp[a] - dv
                if pushed:
                    r = nearest_body(base, S, strides, node_body, node_d)
                    jv = (mass[p] * (penalty * phi[p] * normal[p, 0]), mass[p] * (penalty * phi[p] * normal[p, 1]),
                          mass[p] * (penalty * phi[p] * normal[p, 2]))
                    rel = (x_new[p, 0] - position[r, 0], x_new[p, 1] - position[r, 1], x_new[p, 2] - position[r, 2])
                    for a in range(3):
                        block_impulse[bi, r, a] += jv[a]
                    block_impulse[bi, r, 3] += rel[1] * jv[2] - rel[2] * jv[1]
                    block_impulse[bi, r, 4] += rel[2] * jv[0] - rel[0] * jv[2]
                    block_impulse[bi, r, 5] += rel[0] * jv[1] - rel[1] * jv[0]
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
