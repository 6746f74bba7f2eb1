r"""CPIC kernels of the Numba backend in 2D, the field: the colored distance field of the bodies' polylines,
rasterised body by body in the NumPy reference's order (:func:`mpmref.physics.cdf.build_cdf`), and the
particles' tags, distance and normal with the mask of the incompatible nodes of each particle's transfer
stencil (:func:`mpmref.physics.cdf.update_tags`, :func:`~mpmref.physics.cdf.reconstruct`,
:func:`~mpmref.physics.cdf.reconstruct_per_body`). Hu et al. 2018, SIGGRAPH, §4; docs/cpic.md."""

from functools import lru_cache

import numpy as np
from numba import njit, prange

from ....physics.cdf import DET_THRESHOLD_2D, EDGE_MARGIN, NORMAL_THRESHOLD, ColoredDistanceField
from ....rigid.dynamics import current_shapes
from ....rigid.polyline import surface_samples
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

    Returns ``(x (k, 2), segment (k,) global segment index, start (nb + 1,) first sample of each body,
    seg_a (m, 2), seg_b (m, 2))``.
    """
    xs, segs, starts, seg_a, seg_b = [], [], [0], [], []
    offset = 0
    for shape in current_shapes(bodies, rigid):
        x, seg = surface_samples(shape, dx)
        xs.append(x)
        segs.append(seg + offset)
        starts.append(starts[-1] + len(x))
        seg_a.append(shape.starts)
        seg_b.append(shape.ends)
        offset += len(shape.segments)
    return (np.concatenate(xs), np.concatenate(segs), np.array(starts, dtype=np.int64), np.concatenate(seg_a),
            np.concatenate(seg_b))


def build_cdf(bodies, rigid, shape, origin, dx):
    """The colored distance field (:func:`mpmref.physics.cdf.build_cdf`), rasterised by :func:`rasterise`.

    ``shape`` is the grid's node shape (an int64 array), ``origin`` a float64 array.
    """
    x, seg, start, seg_a, seg_b = body_samples(bodies, rigid, dx)
    d, nearest, A, T, d_body = empty_field(int(shape[0] * shape[1]), len(bodies))
    rasterise(x, seg, start, seg_a, seg_b, origin, float(dx), shape, d, nearest, A, T, d_body)
    return ColoredDistanceField(d=d, body=nearest, A=A, T=T, shape=(int(shape[0]), int(shape[1])), origin=origin,
                               dx=float(dx), d_body=d_body)


@njit(cache=True)
def rasterise(x, seg, start, seg_a, seg_b, origin, dx, shape, d, nearest, A, T, d_body):
    r"""Write the colored distance field into ``d``, ``nearest``, ``A``, ``T`` and the per-body distance ``d_body``
    (:func:`mpmref.physics.cdf.build_cdf`).

    For every sample :math:`s` of body :math:`r` and node :math:`i` of its 3 × 3 quadratic stencil, with
    the node's edge parameter :math:`\sigma` and signed offset :math:`h` in the frame of the sample's
    segment :math:`(\mathbf a, \mathbf b)`,

    .. math:: \sigma = \frac{(\mathbf x_i - \mathbf a)\cdot \mathbf e}{|\mathbf e|^2}, \qquad
              h = \frac{(\mathbf x_i - \mathbf a) \times \mathbf e}{|\mathbf e|}\ (\text{i.e. } (\mathbf x_i -
              \mathbf a)\cdot \mathbf n,\ \mathbf n = \hat{\mathbf z}\times\hat{\mathbf e}), \qquad \mathbf e =
              \mathbf b - \mathbf a,

    if :math:`-0.02 \le \sigma \le 1.02`: :math:`d_{ir} = \min(d_{ir}, |h|)`, :math:`A_{ir} = 1`; then
    :math:`T_{ir} = [h < 0]` from the pairs at :math:`d_{ir}` (the last in the reference's order, offsets
    outer and samples inner, wins), and node :math:`i`'s nearest body is the first body with the
    smallest :math:`d_{ir}`. Hu et al. 2018 §4; docs/cpic.md.
    """
    n_nodes = d.shape[0]
    n_bodies = start.shape[0] - 1
    d_r = np.full(n_nodes, np.inf)
    cap = 9 * (start[n_bodies] - start[0])
    pair_node = np.empty(cap, dtype=np.int64)
    pair_h = np.empty(cap)
    for r in range(n_bodies):
        count = 0
        for k in range(9):
            oi, oj = k // 3, k % 3
            for s in range(start[r], start[r + 1]):
                b0, f0, w0, dw0 = kernel_axis(QUADRATIC, np.float64, (x[s, 0] - origin[0]) / dx)
                b1, f1, w1, dw1 = kernel_axis(QUADRATIC, np.float64, (x[s, 1] - origin[1]) / dx)
                i0, i1 = b0 + oi, b1 + oj
                if i0 < 0 or i1 < 0 or i0 >= shape[0] or i1 >= shape[1]:
                    continue
                flat = i0 * shape[1] + i1
                e0 = seg_b[seg[s], 0] - seg_a[seg[s], 0]
                e1 = seg_b[seg[s], 1] - seg_a[seg[s], 1]
                length2 = e0 * e0 + e1 * e1
                r0 = (origin[0] + i0 * dx) - seg_a[seg[s], 0]
                r1 = (origin[1] + i1 * dx) - seg_a[seg[s], 1]
                sigma = (r0 * e0 + r1 * e1) / length2
                if sigma < -EDGE_MARGIN or sigma > 1.0 + EDGE_MARGIN:
                    continue
                h = (r1 * e0 - r0 * e1) / np.sqrt(length2)
                count = add_pair(flat, h, r, count, pair_node, pair_h, d_r, A)
        settle_body(r, count, pair_node, pair_h, d_r, d, nearest, T, d_body)


@lru_cache(maxsize=None)
def tag_kernel(KERNEL, S, PER_BODY):
    r"""Sticky tags, least-squares distance and normal of every particle (2D, quadratic stencil), and the
    mask of the incompatible nodes of its transfer stencil (``S`` nodes per axis, kernel code ``KERNEL``).

    The returned ``tags(x, origin, dx, shape, strides, field, old_tags, new_tags, fit, incompatible, groups, block,
    blocks_per_axis, body_fit)`` reads the field ``field`` (a :class:`~mpmref.backends.numba.kernel_args.NodeField`:
    ``d``, ``A``, ``T``, ``d_body``, in this order) and the particles' tags ``old_tags`` (a
    :class:`~mpmref.backends.numba.kernel_args.SideTags`: ``tag_A``, ``tag_T``); it fills ``new_tags``
    (``A_new``, ``T_new``), ``fit`` (a :class:`~mpmref.backends.numba.kernel_args.DistanceFit`: ``phi``,
    ``normal``, ``near``) and ``incompatible``, and compiled with ``PER_BODY`` the per-body fits ``body_fit``
    (``fit_phi``, ``fit_normal``, ``fit_near``, (n, nb, ...)) of particles tagged by several bodies
    (:func:`per_body_fits`); all must be zero on entry: only particles near a body are written
    (:func:`tag_particle`, :func:`incompatibility_mask`). It runs over the particles' blocks (``groups`` a
    :class:`~mpmref.backends.numba.kernel_args.Groups` of ``prepare``'s sort, :mod:`.blocks`; ``block`` cells
    per block edge, ``blocks_per_axis`` of the grid) and skips a block at once when no node its particles'
    stencils reach is in a band.
    """
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
            if not block_in_band(b // blocks_per_axis[1], b % blocks_per_axis[1], block, shape, d):
                continue
            near_r = np.empty(n_bodies, dtype=np.bool_)  # scratch, one set per block
            S0, S1 = np.empty(n_bodies), np.empty(n_bodies)
            M, rhs = np.empty((3, 3)), np.empty(3)
            for q in range(block_start[b], block_start[b + 1]):
                p = order[q]
                if tag_particle(p, x, origin, dx, shape, d, A, T, tag_A, tag_T, A_new, T_new, phi, normal, near,
                                near_r, S0, S1, M, rhs):
                    b0, f0, w0, dw0 = kernel_axis(KERNEL, np.float64, (x[p, 0] - origin[0]) / dx)
                    b1, f1, w1, dw1 = kernel_axis(KERNEL, np.float64, (x[p, 1] - origin[1]) / dx)
                    incompatible[p] = incompatibility_mask(p, b0, b1, S, strides, A, T, A_new, T_new)
                    if PER_BODY:  # a closure constant: the per-body fits compile only where asked for
                        per_body_fits(p, x, origin, dx, shape, d_body, A, T, A_new, T_new, fit_phi, fit_normal,
                                      fit_near, M, rhs)

    return tags


@njit(cache=True, inline="always")
def block_in_band(c0, c1, block, shape, d):
    """Whether a node that the quadratic stencils of block ``(c0, c1)``'s particles can reach is in a band.

    A particle of the block has its transfer stencil's base node in ``[c B, c B + B - 1]`` per axis (``B`` =
    ``block``); whatever the kernel's base shift (0, 1/2 or 1), its quadratic base node then lies in
    ``[c B - 1, c B + B]`` and its stencil in ``[c B - 1, c B + B + 2]``.
    """
    for i0 in range(max(c0 * block - 1, 0), min(c0 * block + block + 3, shape[0])):
        for i1 in range(max(c1 * block - 1, 0), min(c1 * block + block + 3, shape[1])):
            if d[i0 * shape[1] + i1] < np.inf:
                return True
    return False


@njit(cache=True, inline="always")
def incompatibility_mask(p, b0, b1, S, strides, A, T, A_p, T_p):
    r"""Bit ``k`` set iff node ``(b0 + k // S, b1 + k % S)`` is incompatible with particle ``p``: some body
    :math:`r` has :math:`A_{ir} = A_{pr} = 1` and :math:`T_{ir} \ne T_{pr}` (Hu et al. 2018 §4; docs/cpic.md)."""
    mask = 0
    for k in range(S * S):
        idx = (b0 + k // S) * strides[0] + (b1 + k % S) * strides[1]
        if node_incompatible(p, idx, A, T, A_p, T_p):
            mask |= 1 << k
    return mask


@njit(cache=True, inline="always")
def tag_particle(p, x, origin, dx, shape, d, A, T, tag_A, tag_T, A_new, T_new, phi, normal, near, near_r, S0, S1, M,
                 rhs):
    r"""Tags, distance, normal and ``near`` of particle ``p``; returns whether it is tagged (``near_r``,
    ``S0``, ``S1``, ``M``, ``rhs``: scratch arrays).

    Tags (:func:`mpmref.physics.cdf.update_tags`): :math:`N_{pr} = \bigvee_i A_{ir}`; an existing tag is
    kept while :math:`N_{pr} = 1`; a newly near body tags the particle if :math:`S_0 + S_1 > 10^{-7}`, with
    :math:`S_s = \sum_{i: A_{ir} = 1, T_{ir} = s} w_{ip} d_i`, on side :math:`[S_1 > S_0]`.

    Distance and normal (:func:`mpmref.physics.cdf.reconstruct`): minimise
    :math:`\sum_i w_{ip}(\mathbf n\cdot\mathbf z_i + c - y_i)^2` over the stencil nodes that carry a body,
    :math:`\mathbf z_i = (\mathbf x_i - \mathbf x_p)/\Delta x`, :math:`y_i = \pm d_i/\Delta x` (``+`` if
    compatible, ``-`` if exactly one shared body's side differs, skipped otherwise); ``near`` iff
    :math:`|\det M| > 3\cdot 10^{-3}`, then :math:`\phi_p = c\,\Delta x` and :math:`\mathbf n_p = \mathbf n/|\mathbf n|`
    (0 if :math:`|\mathbf n|^2 \le 10^{-4}`). Hu et al. 2018 §4; docs/cpic.md.
    """
    b0, f0, w0, dw0 = kernel_axis(QUADRATIC, np.float64, (x[p, 0] - origin[0]) / dx)
    b1, f1, w1, dw1 = kernel_axis(QUADRATIC, np.float64, (x[p, 1] - origin[1]) / dx)
    if not in_band(b0, b1, shape, d):  # far from every body: no tags (the common case, kept cheap)
        return False
    near_r[:] = False
    S0[:] = 0.0
    S1[:] = 0.0
    for k in range(9):
        flat = stencil_node(b0, b1, k, shape)
        if flat < 0:
            continue
        w = w0[k // 3] * w1[k % 3]
        add_side_sums(flat, w, A, T, d, near_r, S0, S1)
    tagged = sticky_tags(p, near_r, S0, S1, tag_A, tag_T, A_new, T_new)
    if tagged:
        reconstruct_particle(p, b0, f0, w0, b1, f1, w1, dx, shape, d, A, T, A_new, T_new, phi, normal, near, M, rhs)
    return tagged


@njit(cache=True, inline="always")
def stencil_node(b0, b1, k, shape):
    """Flat index of node ``k`` (C order) of the 3 × 3 stencil at base node ``(b0, b1)``, or -1 off the grid."""
    i0, i1 = b0 + k // 3, b1 + k % 3
    if i0 < 0 or i1 < 0 or i0 >= shape[0] or i1 >= shape[1]:
        return -1
    return i0 * shape[1] + i1


@njit(cache=True, inline="always")
def in_band(b0, b1, shape, d):
    """Whether a node of the 3 × 3 stencil at base node ``(b0, b1)`` is in some body's band (finite ``d``)."""
    for k in range(9):
        flat = stencil_node(b0, b1, k, shape)
        if flat >= 0 and d[flat] < np.inf:
            return True
    return False


@njit(cache=True, inline="always")
def reconstruct_particle(p, b0, f0, w0, b1, f1, w1, dx, shape, d, A, T, A_p, T_p, phi, normal, near, M, rhs):
    """The weighted least-squares fit of :func:`tag_particle` for one tagged particle (``M``, ``rhs``: scratch)."""
    M[:] = 0.0
    rhs[:] = 0.0
    for k in range(9):
        flat = stencil_node(b0, b1, k, shape)
        if flat < 0:
            continue
        use, y = fit_target(p, flat, dx, d, A, T, A_p, T_p)
        if not use:
            continue
        add_fit_sample(M, rhs, w0[k // 3] * w1[k % 3], k, f0, f1, dx, y)
    accepted, c, n0, n1 = solve_fit(M, rhs)
    if not accepted:
        return
    phi[p] = c * dx
    normal[p, 0], normal[p, 1] = n0, n1
    near[p] = True


@njit(cache=True, inline="always")
def add_fit_sample(M, rhs, w, k, f0, f1, dx, y):
    r"""Add node ``k`` of the 3 × 3 stencil (weight ``w``, target ``y``) to the normal equations
    :math:`M \mathrel{+}= w (\mathbf z, 1)(\mathbf z, 1)^T`, :math:`\mathbf b \mathrel{+}= w y (\mathbf z, 1)`,
    :math:`\mathbf z = (\mathbf x_i - \mathbf x_p)/\Delta x` (:func:`mpmref.physics.cdf.reconstruct`)."""
    z0, z1 = ((k // 3) - f0) * dx / dx, ((k % 3) - f1) * dx / dx  # (x_i - x_p) / dx, as the reference forms it
    wz0, wz1, wy = w * z0, w * z1, w * y
    M[0, 0] += wz0 * z0
    M[0, 1] += wz0 * z1
    M[0, 2] += wz0
    M[1, 0] += wz1 * z0
    M[1, 1] += wz1 * z1
    M[1, 2] += wz1
    M[2, 0] += w * z0
    M[2, 1] += w * z1
    M[2, 2] += w
    rhs[0] += wy * z0
    rhs[1] += wy * z1
    rhs[2] += wy


@njit(cache=True, inline="always")
def solve_fit(M, rhs):
    r"""Solve the fit's normal equations (overwriting ``M``, ``rhs``): ``(accepted, c, n0, n1)``, accepted iff
    :math:`|\det M| > 3\cdot 10^{-3}`, the normal :math:`\mathbf n/|\mathbf n|` (0 if :math:`|\mathbf n|^2 \le
    10^{-4}`) (:func:`mpmref.physics.cdf.reconstruct`)."""
    det = (M[0, 0] * (M[1, 1] * M[2, 2] - M[1, 2] * M[2, 1]) - M[0, 1] * (M[1, 0] * M[2, 2] - M[1, 2] * M[2, 0])
           + M[0, 2] * (M[1, 0] * M[2, 1] - M[1, 1] * M[2, 0]))
    if not abs(det) > DET_THRESHOLD_2D:
        return False, 0.0, 0.0, 0.0
    n0, n1, c = solve3(M, rhs)
    norm2 = n0 * n0 + n1 * n1
    if norm2 > NORMAL_THRESHOLD:
        length = np.sqrt(norm2)
        return True, c, n0 / length, n1 / length
    return True, c, 0.0, 0.0


@njit(cache=True, inline="always")
def per_body_fits(p, x, origin, dx, shape, d_body, A, T, A_p, T_p, fit_phi, fit_normal, fit_near, M, rhs):
    r"""The per-body fits of particle ``p`` if two or more bodies tag it
    (:func:`mpmref.physics.cdf.reconstruct_per_body`):
    for each body :math:`r` tagging it, the fit over the stencil nodes with :math:`A_{ir} = 1` of the targets
    :math:`y_{ir} = \pm d_{ir}/\Delta x` (``+`` iff :math:`T_{ir} = T_{pr}`) gives :math:`\phi_{pr}`,
    :math:`\mathbf n_{pr}` and ``fit_near[p, r]`` (``M``, ``rhs``: scratch)."""
    if not tagged_by_several(p, A_p):
        return
    b0, f0, w0, dw0 = kernel_axis(QUADRATIC, np.float64, (x[p, 0] - origin[0]) / dx)
    b1, f1, w1, dw1 = kernel_axis(QUADRATIC, np.float64, (x[p, 1] - origin[1]) / dx)
    for r in range(A_p.shape[1]):
        if not A_p[p, r]:
            continue
        M[:] = 0.0
        rhs[:] = 0.0
        for k in range(9):
            flat = stencil_node(b0, b1, k, shape)
            if flat < 0 or not A[flat, r]:
                continue
            add_fit_sample(M, rhs, w0[k // 3] * w1[k % 3], k, f0, f1, dx, body_target(p, flat, r, dx, d_body, T, T_p))
        accepted, c, n0, n1 = solve_fit(M, rhs)
        if accepted:
            fit_phi[p, r] = c * dx
            fit_normal[p, r, 0], fit_normal[p, r, 1] = n0, n1
            fit_near[p, r] = True


@njit(cache=True, inline="always")
def solve3(M, rhs):
    """Solve the 3 × 3 system ``M s = rhs`` by Gaussian elimination with partial pivoting (LAPACK's getrf/getrs),
    overwriting ``M`` and ``rhs``; returns ``s`` as a tuple."""
    a, b = M, rhs
    for c in range(3):
        piv = c
        for r in range(c + 1, 3):
            if abs(a[r, c]) > abs(a[piv, c]):
                piv = r
        if piv != c:
            for j in range(3):
                a[c, j], a[piv, j] = a[piv, j], a[c, j]
            b[c], b[piv] = b[piv], b[c]
        inv = 1.0 / a[c, c]
        for r in range(c + 1, 3):
            factor = a[r, c] * inv
            for j in range(c + 1, 3):
                a[r, j] -= factor * a[c, j]
            b[r] -= factor * b[c]
    s2 = b[2] / a[2, 2]
    s1 = (b[1] - a[1, 2] * s2) / a[1, 1]
    s0 = ((b[0] - a[0, 1] * s1) - a[0, 2] * s2) / a[0, 0]
    return s0, s1, s2
