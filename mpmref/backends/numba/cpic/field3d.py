r"""CPIC kernels of the Numba backend in 3D, the field: the colored distance field of triangle meshes and the
particles' tags, distance and normal (:mod:`mpmref.physics.cdf`). The layout is that of :mod:`.field2d`; what
differs is the geometry (a node's barycentric coordinates and signed offset in a triangle's frame), the
:math:`3^3` stencils and the 4 × 4 least-squares fit. Hu et al. 2018, SIGGRAPH, §4; docs/cpic.md."""

from functools import lru_cache

import numpy as np
from numba import njit, prange

from ....physics.cdf import BARYCENTRIC_TOLERANCE, DET_THRESHOLD_3D, NORMAL_THRESHOLD, ColoredDistanceField
from ....rigid.dynamics import current_shapes
from ....rigid.trimesh import surface_samples
from ...pointwise.stencil import QUADRATIC, kernel_axis
from ..source_digest import SOURCE_DIGEST
from ..twin import parallel_kernel
from .common import (
    add_pair,
    add_side_sums,
    body_target,
    empty_field,
    fit_target,
    node_incompatible,
    settle_body,
    sticky_tags,
    tagged_by_several,
)


def body_samples(bodies, rigid, dx):
    """Surface samples of every body where ``rigid`` puts it, concatenated body by body.

    Returns ``(x (k, 3), triangle (k,) global triangle index, start (nb + 1,) first sample of each body,
    corner_a (m, 3), e1 (m, 3), e2 (m, 3), normal (m, 3))``: each triangle's first corner, edge vectors
    :math:`\\mathbf b - \\mathbf a`, :math:`\\mathbf c - \\mathbf a` and unit normal, as
    :func:`mpmref.rigid.trimesh.triangle_frame` forms them.
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
    """The colored distance field (:func:`mpmref.physics.cdf.build_cdf`) of 3D bodies, rasterised by
    :func:`rasterise`."""
    x, tri, start, a, e1, e2, normal = body_samples(bodies, rigid, dx)
    d, nearest, A, T, d_body = empty_field(int(shape[0] * shape[1] * shape[2]), len(bodies))
    rasterise(x, tri, start, a, e1, e2, normal, origin, float(dx), shape, d, nearest, A, T, d_body)
    return ColoredDistanceField(d=d, body=nearest, A=A, T=T, shape=tuple(int(s) for s in shape), origin=origin,
                               dx=float(dx), d_body=d_body)


@njit(cache=True)
def rasterise(x, tri, start, a, e1, e2, normal, origin, dx, shape, d, nearest, A, T, d_body):
    r"""Write the colored distance field into ``d``, ``nearest``, ``A``, ``T`` and the per-body distance
    ``d_body`` (:func:`mpmref.physics.cdf.build_cdf`).

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
            base[s, axis] = kernel_axis(QUADRATIC, np.float64, (x[s, axis] - origin[axis]) / dx)[0]
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
                count = add_pair(flat, h, r, count, pair_node, pair_h, d_r, A)
        settle_body(r, count, pair_node, pair_h, d_r, d, nearest, T, d_body)


@lru_cache(maxsize=None)
def tag_kernel(KERNEL, S, PER_BODY):
    r"""Sticky tags, least-squares distance and normal of every particle (3D, quadratic stencil), and the mask
    of the incompatible nodes of its transfer stencil (``S`` nodes per axis, kernel code ``KERNEL``); as the
    2D :func:`~mpmref.backends.numba.cpic.field2d.tag_kernel` (with its per-body fits,
    :func:`per_body_fits`), over the particles' blocks, skipping blocks far from every band."""
    SOURCES = SOURCE_DIGEST

    @parallel_kernel(cache=True)
    def tags(x, origin, dx, shape, strides, field, old_tags, new_tags, fit, incompatible, groups, block,
             blocks_per_axis, body_fit):
        SOURCES  # noqa: B018 - a closure constant: part of the cache key (see source_digest)
        d, A, T, d_body = field
        tag_A, tag_T = old_tags
        A_new, T_new = new_tags
        phi, normal, near = fit
        fit_phi, fit_normal, fit_near = body_fit
        order, block_start, blocks = groups.order, groups.start, groups.groups
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
                    b0 = kernel_axis(KERNEL, np.float64, (x[p, 0] - origin[0]) / dx)[0]
                    b1 = kernel_axis(KERNEL, np.float64, (x[p, 1] - origin[1]) / dx)[0]
                    b2 = kernel_axis(KERNEL, np.float64, (x[p, 2] - origin[2]) / dx)[0]
                    incompatible[p] = incompatibility_mask(p, b0, b1, b2, S, strides, A, T, A_new, T_new)
                    if PER_BODY:  # a closure constant: the per-body fits compile only where asked for
                        per_body_fits(p, x, origin, dx, shape, d_body, A, T, A_new, T_new, fit_phi, fit_normal,
                                      fit_near, M, rhs)

    return tags


@njit(cache=True, inline="always")
def block_in_band(c0, c1, c2, block, shape, d):
    """Whether a node that the quadratic stencils of block ``(c0, c1, c2)``'s particles can reach is in a band
    (the 3D :func:`mpmref.backends.numba.cpic.field2d.block_in_band`: per axis ``[c B - 1, c B + B + 2]``)."""
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
        if node_incompatible(p, idx, A, T, A_p, T_p):
            mask |= 1 << k
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
    r"""Tags, distance, normal and ``near`` of particle ``p`` (the 3D
    :func:`mpmref.backends.numba.cpic.field2d.tag_particle`: sticky tags,
    :math:`S_s = \sum_{i: A_{ir} = 1, T_{ir} = s} w_{ip} d_i`, then :func:`reconstruct_particle`); returns whether it is
    tagged. Hu et al. 2018 §4; docs/cpic.md."""
    b0, f0, w0, dw0 = kernel_axis(QUADRATIC, np.float64, (x[p, 0] - origin[0]) / dx)
    b1, f1, w1, dw1 = kernel_axis(QUADRATIC, np.float64, (x[p, 1] - origin[1]) / dx)
    b2, f2, w2, dw2 = kernel_axis(QUADRATIC, np.float64, (x[p, 2] - origin[2]) / dx)
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
        add_side_sums(flat, w, A, T, d, near_r, S0, S1)
    tagged = sticky_tags(p, near_r, S0, S1, tag_A, tag_T, A_new, T_new)
    if tagged:
        reconstruct_particle(p, (b0, b1, b2), (f0, f1, f2), w0, w1, w2, dx, shape, d, A, T, A_new, T_new, phi,
                             normal, near, M, rhs)
    return tagged


@njit(cache=True, inline="always")
def reconstruct_particle(p, base, f, w0, w1, w2, dx, shape, d, A, T, A_p, T_p, phi, normal, near, M, rhs):
    r"""The weighted least-squares fit of :func:`mpmref.physics.cdf.reconstruct` for one tagged particle in 3D:
    minimise :math:`\sum_i w_{ip}(\mathbf n\cdot\mathbf z_i + c - y_i)^2` (a 4 × 4 normal system,
    :func:`add_fit_sample`, :func:`solve_fit`); ``near`` iff :math:`|\det M| > 10^{-4}`. ``M``, ``rhs``: scratch."""
    M[:] = 0.0
    rhs[:] = 0.0
    for k in range(27):
        flat = stencil_node(base[0], base[1], base[2], k, shape)
        if flat < 0:
            continue
        use, y = fit_target(p, flat, dx, d, A, T, A_p, T_p)
        if not use:
            continue
        add_fit_sample(M, rhs, w0[k // 9] * w1[(k // 3) % 3] * w2[k % 3], k, f, dx, y)
    accepted, c, n = solve_fit(M, rhs)
    if accepted:
        phi[p] = c * dx
        for a in range(3):
            normal[p, a] = n[a]
        near[p] = True


@njit(cache=True, inline="always")
def add_fit_sample(M, rhs, w, k, f, dx, y):
    r"""Add node ``k`` of the 3 × 3 × 3 stencil (weight ``w``, target ``y``, particle fractions ``f``) to the
    normal equations :math:`M \mathrel{+}= w (\mathbf z, 1)(\mathbf z, 1)^T`,
    :math:`\mathbf b \mathrel{+}= w y (\mathbf z, 1)`, :math:`\mathbf z = (\mathbf x_i - \mathbf x_p)/\Delta x`
    (:func:`mpmref.physics.cdf.reconstruct`)."""
    # (x_i - x_p) / dx, as the reference forms it, and the constant term
    z = (((k // 9) - f[0]) * dx / dx, (((k // 3) % 3) - f[1]) * dx / dx, ((k % 3) - f[2]) * dx / dx, 1.0)
    for i in range(4):
        wz = w * z[i]
        for j in range(4):
            M[i, j] += wz * z[j]
        rhs[i] += wz * y


@njit(cache=True, inline="always")
def solve_fit(M, rhs):
    r"""Solve the 3D fit's normal equations (overwriting ``M``, ``rhs``): ``(accepted, c, n)``, accepted iff
    :math:`|\det M| > 10^{-4}`, the normal :math:`\mathbf n/|\mathbf n|` (0 if :math:`|\mathbf n|^2 \le
    10^{-4}`) as a 3-tuple (:func:`mpmref.physics.cdf.reconstruct`)."""
    det, sol = lu_solve(M, rhs)
    if not abs(det) > DET_THRESHOLD_3D:
        return False, 0.0, (0.0, 0.0, 0.0)
    norm2 = sol[0] * sol[0] + sol[1] * sol[1] + sol[2] * sol[2]
    if norm2 > NORMAL_THRESHOLD:
        length = np.sqrt(norm2)
        return True, sol[3], (sol[0] / length, sol[1] / length, sol[2] / length)
    return True, sol[3], (0.0, 0.0, 0.0)


@njit(cache=True, inline="always")
def per_body_fits(p, x, origin, dx, shape, d_body, A, T, A_p, T_p, fit_phi, fit_normal, fit_near, M, rhs):
    r"""The per-body fits of particle ``p`` in 3D if two or more bodies tag it, as the 2D
    :func:`~mpmref.backends.numba.cpic.field2d.per_body_fits` (:func:`mpmref.physics.cdf.reconstruct_per_body`):
    for each body :math:`r` tagging it, the fit over the stencil nodes with :math:`A_{ir} = 1` of the targets
    :math:`y_{ir} = \pm d_{ir}/\Delta x` (``+`` iff :math:`T_{ir} = T_{pr}`) gives :math:`\phi_{pr}`,
    :math:`\mathbf n_{pr}` and ``fit_near[p, r]`` (``M``, ``rhs``: scratch)."""
    if not tagged_by_several(p, A_p):
        return
    b0, f0, w0, dw0 = kernel_axis(QUADRATIC, np.float64, (x[p, 0] - origin[0]) / dx)
    b1, f1, w1, dw1 = kernel_axis(QUADRATIC, np.float64, (x[p, 1] - origin[1]) / dx)
    b2, f2, w2, dw2 = kernel_axis(QUADRATIC, np.float64, (x[p, 2] - origin[2]) / dx)
    for r in range(A_p.shape[1]):
        if not A_p[p, r]:
            continue
        M[:] = 0.0
        rhs[:] = 0.0
        for k in range(27):
            flat = stencil_node(b0, b1, b2, k, shape)
            if flat < 0 or not A[flat, r]:
                continue
            add_fit_sample(M, rhs, w0[k // 9] * w1[(k // 3) % 3] * w2[k % 3], k, (f0, f1, f2), dx,
                           body_target(p, flat, r, dx, d_body, T, T_p))
        accepted, c, n = solve_fit(M, rhs)
        if accepted:
            fit_phi[p, r] = c * dx
            for a in range(3):
                fit_normal[p, r, a] = n[a]
            fit_near[p, r] = True


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
