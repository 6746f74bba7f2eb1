r"""CPIC stages of the Numba backend: the colored distance field, the particles' tags and distance,
P2G to compatible nodes, the bodies' impulses and G2P with ghost velocities, compiled (the 2D kernels here,
the 3D ones in :mod:`.cpic3d`; the stages at the end of this module serve both).

The equations are those of the NumPy reference (:mod:`mpmref.backends.numpy.cpic`,
:mod:`mpmref.physics.cdf`, :func:`mpmref.physics.rigid_dynamics.friction_projection`); Hu et al. 2018,
SIGGRAPH, §4–5, as the authors' reference implementation does (docs/cpic.md). What differs is only how
the work is laid out:

* the field is rasterised body by body, sample by sample, in the reference's order (so that its
  deterministic tie rules — the nearest element decides a node's side, the lower body id wins a tie in
  distance — give the same bits);
* the tagging runs over the particles' blocks and skips a block whose particles' stencils reach no node of
  any body's band (most blocks), and writes only the particles near a body;
* per particle, the contact keeps a bit mask of the incompatible nodes of its transfer stencil instead of
  ``(K, n)`` arrays; ghost velocities are formed inside P2G and G2P from the node's nearest body, the
  particle's normal and friction, and the bodies' velocities of that stage;
* P2G runs block-parallel by colour (:mod:`.blocks`), so each node receives its contributions, the rejected
  momentum and force included, in a fixed order for any thread count;
* impulses are reduced in a fixed order: P2G's serially node by node; the penalty's particle by particle
  within each block by the parallel G2P, then block by block: the same bits for any thread count, no
  atomics.

Only the posing of the bodies' polylines and their surface samples (a few points per body, not per node or
particle) stay in NumPy (:func:`mpmref.physics.rigid_dynamics.current_shapes`,
:func:`mpmref.physics.rigid.surface_samples`).
"""

import sys
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numba import njit, prange

from ...physics.cdf import DET_THRESHOLD_2D, EDGE_MARGIN, NORMAL_THRESHOLD, TAG_THRESHOLD, ColoredDistanceField
from ...physics.rigid import surface_samples
from ...physics.rigid_dynamics import current_shapes, initial_state
from ...state import GridState
from ...physics.cdf import PENALTY_WINDOW
from .stencil import KERNEL_CODES, kernel_axis, quadratic_axis
from .transfers import SOURCE_DIGEST


@dataclass
class Contact:
    r"""What the Numba CPIC transfers of one step need.

    Attributes
    ----------
    cdf : ColoredDistanceField  the field of the bodies at the start of the step
    incompatible : (n,) int64   bit ``k`` set iff node ``base + offset_k`` of the transfer stencil is incompatible
                                with the particle (0 for most particles: those far from every body)
    support : int               nodes per axis of the transfer stencil (``K = support**2`` offsets)
    friction : (nb, 2)          encoded friction of each body's side 0 and side 1
    gravity_dv : (2,)           this step's gravity velocity :math:`\mathbf g\Delta t` (a particle's
                                :math:`\mathbf v^*_p = \mathbf v_p + \mathbf g\Delta t` is formed where needed)
    rigid : RigidState          the bodies as P2G sees them (their velocities give P2G's ghost velocities)
    tau : (n, 2, 2)             the particles' Kirchhoff stress (computed once for the step)
    dt : float                  the step
    ghost_force : bool          ghost velocities include the particle's own internal force (``method.ghost_force``)
    dim : int                   2, or 3 for the 3D stages (:mod:`.cpic3d`; vectors then have 3 components)
    fits : tuple                2D: ``(per_body, A, T, d_body, tag_A, fit_normal, fit_near)``, what
                                :func:`ghost_frame` needs for the per-body fit (``method.cpic_fit``; empty
                                ``fit_*`` arrays with the single fit)
    fit_phi : (n, nb) or (0, nb) the per-body distances :math:`\phi_{pr}` (:func:`per_body_fits`)
    """

    cdf: ColoredDistanceField
    incompatible: np.ndarray
    support: int
    friction: np.ndarray
    gravity_dv: np.ndarray
    rigid: object
    tau: np.ndarray
    dt: float
    ghost_force: bool
    dim: int = 2
    fits: tuple = None
    fit_phi: np.ndarray = None

    @property
    def per_body_fit(self):
        """The per-body fit ``(phi, normal, near)``, each ``(n, nb, ...)``, or None with the single fit."""
        return (self.fit_phi, self.fits[5], self.fits[6]) if self.fits is not None and self.fits[0] else None

    @property
    def compatible(self):
        """``(K, n)`` bool: node ``k`` of particle ``p``'s stencil is compatible (the reference's layout)."""
        k = np.arange(self.support**self.dim, dtype=np.int64)
        return ((self.incompatible[None, :] >> k[:, None]) & 1) == 0


# ------------------------------------------------------------------------------------------ the field
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
    n_nodes = int(shape[0] * shape[1])
    d = np.full(n_nodes, np.inf)
    nearest = np.full(n_nodes, -1, dtype=np.int64)
    A = np.zeros((n_nodes, len(bodies)), dtype=np.bool_)
    T = np.zeros((n_nodes, len(bodies)), dtype=np.bool_)
    d_body = np.full((n_nodes, len(bodies)), np.inf)
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
                b0, f0, w0, dw0 = quadratic_axis((x[s, 0] - origin[0]) / dx)
                b1, f1, w1, dw1 = quadratic_axis((x[s, 1] - origin[1]) / dx)
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
                pair_node[count] = flat
                pair_h[count] = h
                count += 1
                d_r[flat] = min(d_r[flat], abs(h))
                A[flat, r] = True
        for c in range(count):
            d_body[pair_node[c], r] = d_r[pair_node[c]]
        settle_body(r, count, pair_node, pair_h, d_r, d, nearest, T)


@njit(cache=True, inline="always")
def settle_body(r, count, pair_node, pair_h, d_r, d, nearest, T):
    r"""After body ``r``'s ``count`` rasterised (node, :math:`h`) pairs: :math:`T_{ir} = [h < 0]` from the pairs at
    the body's distance :math:`d_{ir}` (the last such pair wins), node :math:`i`'s nearest body is ``r`` if
    :math:`d_{ir} < d_i` (so the first body wins a tie), and ``d_r`` is reset to ``inf`` for the next body."""
    for c in range(count):
        if abs(pair_h[c]) == d_r[pair_node[c]]:
            T[pair_node[c], r] = pair_h[c] < 0.0
    for c in range(count):
        flat = pair_node[c]
        if d_r[flat] < d[flat]:
            d[flat] = d_r[flat]
            nearest[flat] = r
    for c in range(count):
        d_r[pair_node[c]] = np.inf


# -------------------------------------------------------------------- tags, distance and compatibility
@lru_cache(maxsize=None)
def tag_kernel(KERNEL, S):
    r"""Sticky tags, least-squares distance and normal of every particle (2D, quadratic stencil), and the
    mask of the incompatible nodes of its transfer stencil (``S`` nodes per axis, kernel code ``KERNEL``).

    The returned ``tags(x, origin, dx, shape, strides, d, A, T, tag_A, tag_T, A_new, T_new, phi, normal, near,
    incompatible, order, block_start, blocks, block, blocks_per_axis, per_body, d_body, fit_phi, fit_normal,
    fit_near)`` fills the arrays from ``A_new`` to ``incompatible``, and with ``per_body`` the per-body fits
    ``fit_*`` (n, nb) of particles tagged by several bodies (:func:`per_body_fits`), which must be zero on entry:
    only particles near a body are written (:func:`tag_particle`, :func:`incompatibility_mask`). It runs over the
    particles' blocks (``prepare``'s
    sort, :mod:`.blocks`) and skips a block at once when no node its particles' stencils reach is in a band.
    """
    SOURCES = SOURCE_DIGEST

    @njit(parallel=True, cache=True)
    def tags(x, origin, dx, shape, strides, d, A, T, tag_A, tag_T, A_new, T_new, phi, normal, near, incompatible,
             order, block_start, blocks, block, blocks_per_axis, per_body, d_body, fit_phi, fit_normal, fit_near):
        SOURCES  # noqa: B018 - a closure constant: part of the cache key (see transfers._source_digest)
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
                    b0, f0, w0, dw0 = kernel_axis(KERNEL, (x[p, 0] - origin[0]) / dx)
                    b1, f1, w1, dw1 = kernel_axis(KERNEL, (x[p, 1] - origin[1]) / dx)
                    incompatible[p] = incompatibility_mask(p, b0, b1, S, strides, A, T, A_new, T_new)
                    if per_body:
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
        for r in range(A_p.shape[1]):
            if A[idx, r] and A_p[p, r] and T[idx, r] != T_p[p, r]:
                mask |= 1 << k
                break
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
    n_bodies = tag_A.shape[1]
    b0, f0, w0, dw0 = quadratic_axis((x[p, 0] - origin[0]) / dx)
    b1, f1, w1, dw1 = quadratic_axis((x[p, 1] - origin[1]) / dx)
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
        reconstruct_particle(p, b0, f0, w0, b1, f1, w1, dx, shape, d, A, T, A_new, T_new, phi, normal, near, M, rhs)
    return tagged


@njit(cache=True, inline="always")
def sticky_tag(p, r, near_r, S0, S1, tag_A, tag_T, A_new, T_new):
    r"""Particle ``p``'s new tag of body ``r``: kept while the body stays near (``near_r[r]``), cleared otherwise; a
    newly near body tags it if :math:`S_0 + S_1 > 10^{-7}`, on side :math:`[S_1 > S_0]`. Returns :math:`A_{pr}`."""
    a = tag_A[p, r] and near_r[r]
    t = tag_T[p, r] and a
    if near_r[r] and not a and S0[r] + S1[r] > TAG_THRESHOLD:
        a, t = True, S1[r] > S0[r]
    A_new[p, r], T_new[p, r] = a, t
    return a


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
def fit_target(p, flat, dx, d, A, T, A_p, T_p):
    r"""Whether node ``flat`` enters particle ``p``'s least-squares fit, and its target :math:`y_i`: the node carries a
    body and at most one body shared with the particle puts them on different sides; :math:`y_i = +d_i/\Delta x`
    if none does (compatible), :math:`-d_i/\Delta x` if one does (:func:`mpmref.physics.cdf.reconstruct`)."""
    has_body = False
    differing = 0
    for r in range(A_p.shape[1]):
        if A[flat, r]:
            has_body = True
            if A_p[p, r] and T[flat, r] != T_p[p, r]:
                differing += 1
    y = d[flat] / dx
    return has_body and differing <= 1, (-y if differing == 1 else y)


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
    n_bodies = A_p.shape[1]
    tagged = 0
    for r in range(n_bodies):
        tagged += A_p[p, r]
    if tagged < 2:
        return
    b0, f0, w0, dw0 = quadratic_axis((x[p, 0] - origin[0]) / dx)
    b1, f1, w1, dw1 = quadratic_axis((x[p, 1] - origin[1]) / dx)
    for r in range(n_bodies):
        if not A_p[p, r]:
            continue
        M[:] = 0.0
        rhs[:] = 0.0
        for k in range(9):
            flat = stencil_node(b0, b1, k, shape)
            if flat < 0 or not A[flat, r]:
                continue
            y = d_body[flat, r] / dx
            add_fit_sample(M, rhs, w0[k // 3] * w1[k % 3], k, f0, f1, dx, -y if T[flat, r] != T_p[p, r] else y)
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


# ------------------------------------------------------------------------------- ghost velocities
@njit(cache=True, inline="always")
def ghost_velocity(v0, v1, node_x0, node_x1, r, position, velocity, omega, n0, n1, mu):
    r"""The friction projection :math:`\Pi(\mathbf v; \mathbf v_r(\mathbf x_i), \mathbf n, \mu)` against body ``r``.

    :math:`\mathbf v_r(\mathbf x) = \mathbf v_r + \omega_r\hat{\mathbf z}\times(\mathbf x - \mathbf c_r)`;
    :math:`\mathbf u = \mathbf v - \mathbf v_r(\mathbf x_i)`, :math:`u_n = \mathbf n\cdot\mathbf u`,
    :math:`\mathbf u_t = \mathbf u - u_n\mathbf n`; sticky (:math:`\mu = -1`): :math:`\mathbf v_r(\mathbf x_i)`;
    otherwise :math:`\mathbf v_r(\mathbf x_i) + \max(|\mathbf u_t| + \mu'\min(u_n, 0), 0)\,\mathbf u_t/|\mathbf u_t|`
    plus :math:`\max(u_n, 0)\mathbf n` if :math:`\mu \ge 0` (:math:`\mu' = \mu`; slip: :math:`\mu' = -\mu - 2`).
    The talk's Eq. 25 (Hu et al. 2018 §5; docs/cpic.md); see :func:`mpmref.physics.rigid_dynamics.friction_projection`.
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
def ghost_frame(p, idx, node_body, near, normal, tag_T, friction, fits):
    r"""What the ghost velocity of incompatible node ``idx`` for particle ``p`` projects against
    (:func:`mpmref.backends.numpy.cpic.ghost_frames`): ``(project, r, n0, n1, mu)``.

    Single fit: the node's nearest body :math:`r`, the particle's normal :math:`\mathbf n_p`, the friction of its
    side, ``project`` = ``near[p]``. With the per-body fit (``fits = (per_body, A, T, d_body, tag_A, fit_normal,
    fit_near)``, ``per_body`` true): the crossed body :math:`c` — :math:`A_{ic} = A_{pc} = 1`,
    :math:`T_{ic} \ne T_{pc}`, the least :math:`d_{ic}`, the lowest id on a tie — with its own normal
    :math:`\mathbf n_{pc}`, if its per-body fit is accepted."""
    per_body, A, T, d_body, tag_A, fit_normal, fit_near = fits
    if per_body:
        c, best = -1, np.inf
        for r in range(tag_A.shape[1]):
            if A[idx, r] and tag_A[p, r] and T[idx, r] != tag_T[p, r] and d_body[idx, r] < best:
                c, best = r, d_body[idx, r]
        if c >= 0 and fit_near[p, c]:
            mu = friction[c, 1] if tag_T[p, c] else friction[c, 0]
            return True, c, fit_normal[p, c, 0], fit_normal[p, c, 1], mu
    r = max(node_body[idx], 0)
    mu = friction[r, 1] if tag_T[p, r] else friction[r, 0]
    return near[p], r, normal[p, 0], normal[p, 1], mu


@njit(cache=True, inline="always")
def node_ghost(p, idx, nx0, nx1, node_body, near, normal, tag_T, friction, fits, v0, v1, a0, a1, position, velocity,
               omega):
    r"""Ghost velocity of incompatible node ``idx`` for particle ``p`` (see
    :func:`mpmref.backends.numpy.cpic.ghost_velocities`): if :func:`ghost_frame` projects, the friction
    projection of :math:`\mathbf v^*_p + \mathbf a_{ip}` (``(v0 + a0, v1 + a1)``, the load with the particle's
    own internal force) against its body and normal; otherwise :math:`\mathbf v^*_p` = ``(v0, v1)``."""
    project, r, n0, n1, mu = ghost_frame(p, idx, node_body, near, normal, tag_T, friction, fits)
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


# ------------------------------------------------------------------------------------------------ P2G
@njit(cache=True, inline="always")
def gradient_weight(mls, w, d0, d1, wa0, wa1, dwa0, dwa1, dx, inertia):
    r"""The force's gradient weight :math:`g_{ip}` of a node (2D): MLS :math:`w_{ip}(\mathbf x_i - \mathbf x_p)/D`
    (``d0, d1`` = :math:`\mathbf x_i - \mathbf x_p`, ``inertia`` = :math:`D`), or the kernel gradient
    :math:`(N'_0 N_1, N_0 N'_1)/\Delta x` from the per-axis weights ``wa`` and derivatives ``dwa`` (see
    :func:`mpmref.backends.numpy.transfers.mls_gradient_weight` and ``classic_gradient_weight``)."""
    if mls:
        return w * d0 / inertia, w * d1 / inertia
    return dwa0 / dx * wa1, dwa1 / dx * wa0


@lru_cache(maxsize=None)
def p2g_kernel(KERNEL, S, AFFINE, MLS):
    r"""CPIC P2G kernel (2D): mass, momentum and force to compatible nodes; rejected momentum and force at
    the others (see :func:`mpmref.backends.numpy.transfers.p2g` with a contact).

    At compatible nodes as plain P2G; at an incompatible node :math:`i`

    .. math:: \mathbf J^m_i \mathrel{+}= m_p w_{ip}(\mathbf v^*_p - \tilde{\mathbf v}_i), \qquad
              \mathbf J^f_i \mathrel{-}= V_p^0 \tau_p g_{ip}

    with the ghost velocity :math:`\tilde{\mathbf v}_i` (:func:`node_ghost`). Block-parallel by colour.
    """
    SOURCES = SOURCE_DIGEST

    @njit(parallel=True, cache=True)
    def p2g(x, v, C, mass, vol0, tau, origin, dx, inertia, strides, order, block_start, colour_blocks, colour_start,
            incompatible, gravity_dv, node_body, near, normal, tag_T, friction, position, velocity, omega, ghost_force,
            dt, grid_mass, grid_momentum, grid_force, rejected_momentum, rejected_force, fits):
        SOURCES  # noqa: B018 - a closure constant: part of the cache key (see transfers._source_digest)
        for colour in range(colour_start.shape[0] - 1):
            first = colour_start[colour]
            for bi in prange(colour_start[colour + 1] - first):
                block = colour_blocks[first + bi]
                for q in range(block_start[block], block_start[block + 1]):
                    p = order[q]
                    m = mass[p]
                    s00, s01 = vol0[p] * tau[p, 0, 0], vol0[p] * tau[p, 0, 1]
                    s10, s11 = vol0[p] * tau[p, 1, 0], vol0[p] * tau[p, 1, 1]
                    b0, f0, w0, dw0 = kernel_axis(KERNEL, (x[p, 0] - origin[0]) / dx)
                    b1, f1, w1, dw1 = kernel_axis(KERNEL, (x[p, 1] - origin[1]) / dx)
                    base = b0 * strides[0] + b1 * strides[1]
                    inc = incompatible[p]
                    for i in range(S):
                        d0 = (i - f0) * dx
                        for j in range(S):
                            d1 = (j - f1) * dx
                            w = w0[i] * w1[j]
                            g0, g1 = gradient_weight(MLS, w, d0, d1, w0[i], w1[j], dw0[i], dw1[j], dx, inertia)
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
                                gh0, gh1 = node_ghost(p, idx, nx0, nx1, node_body, near, normal, tag_T, friction, fits,
                                                      vs0, vs1, a0, a1, position, velocity, omega)
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
def several_tags(p, fits):
    """Whether the per-body fit is on and two or more bodies tag particle ``p`` (it then has a fit per body)."""
    per_body, A, T, d_body, tag_A, fit_normal, fit_near = fits
    if not per_body:
        return False
    tagged = 0
    for r in range(tag_A.shape[1]):
        tagged += tag_A[p, r]
    return tagged >= 2


@njit(cache=True, inline="always")
def add_impulse(block_impulse, bi, r, j0, j1, x0, x1, position):
    r"""Add the impulse :math:`\mathbf J = (j_0, j_1)` at :math:`\mathbf x` on body ``r`` to block ``bi``'s sums:
    :math:`\mathbf J` and :math:`(\mathbf x - \mathbf c_r)\times\mathbf J`."""
    block_impulse[bi, r, 0] += j0
    block_impulse[bi, r, 1] += j1
    block_impulse[bi, r, 2] += (x0 - position[r, 0]) * j1 - (x1 - position[r, 1]) * j0


# ------------------------------------------------------------------------------------------- impulses
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


# ------------------------------------------------------------------------------------------------ G2P
@lru_cache(maxsize=None)
def g2p_kernel(KERNEL, S, AFFINE, MLS_FORCE, MLS, TRACKS_F, TRACKS_J):
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
    is MLS's (it enters :math:`\mathbf a_{ip}`, :func:`force_velocity`); ``MLS``: the velocity gradient is
    :math:`C_p` (``spec.mls_gradient``).
    """
    NEED_B = AFFINE or MLS
    SOURCES = SOURCE_DIGEST
    LO, HI = PENALTY_WINDOW

    @njit(parallel=True, cache=True)
    def g2p(x, v, gravity_dv, F, J, mass, vol0, tau, ghost_force, origin, dx, inertia, dt, strides, order, block_start,
            blocks, v_grid, incompatible, node_body, node_d, near, phi, normal, tag_T, friction, position, velocity,
            omega, push, penalty, x_new, v_new, C_new, F_new, J_new, block_impulse, fits, fit_phi):
        SOURCES  # noqa: B018 - a closure constant: part of the cache key (see transfers._source_digest)
        for bi in prange(blocks.shape[0]):
            block = blocks[bi]
            for q in range(block_start[block], block_start[block + 1]):
                p = order[q]
                b0, f0, w0, dw0 = kernel_axis(KERNEL, (x[p, 0] - origin[0]) / dx)
                b1, f1, w1, dw1 = kernel_axis(KERNEL, (x[p, 1] - origin[1]) / dx)
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
                            project, r, n0, n1, mu = ghost_frame(p, idx, node_body, near, normal, tag_T, friction, fits)
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
                        if not MLS:
                            g0, g1 = gradient_weight(False, w, d0, d1, w0[i], w1[j], dw0[i], dw1[j], dx, inertia)
                            G00 += vi0 * g0
                            G01 += vi0 * g1
                            G10 += vi1 * g0
                            G11 += vi1 * g1
                if MLS:
                    G00, G01, G10, G11 = B00 / inertia, B01 / inertia, B10 / inertia, B11 / inertia
                x_new[p, 0] = x[p, 0] + dt * vp0
                x_new[p, 1] = x[p, 1] + dt * vp1
                dv0, dv1 = 0.0, 0.0
                if several_tags(p, fits):
                    per_body, A, T, d_body, tag_A, fit_normal, fit_near = fits
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


# --------------------------------------------------------------------------- the stages, for the backend
def kernels(dim):
    """The module whose kernels serve ``dim``: this one in 2D, :mod:`.cpic3d` in 3D (the stages below are shared)."""
    if dim == 3:
        from . import cpic3d

        return cpic3d
    return sys.modules[__name__]


def contact(backend, particles, blocks, rigid, dt):
    """The step's :class:`Contact` and the particles with their new tags, distance, normal and ``near`` flag
    (the stage ``cpic_contact``; see :func:`mpmref.backends.numpy.cpic.contact`)."""
    scene, spec = backend.scene, backend.cfg
    bodies, d = scene.rigid_bodies, particles.dim
    k = kernels(d)
    cdf = k.build_cdf(bodies, rigid, backend.node_shape, backend.origin, backend.dx)
    x = np.ascontiguousarray(particles.x, dtype=np.float64)
    n, nb = particles.n, len(bodies)
    A, T = np.zeros((n, nb), dtype=np.bool_), np.zeros((n, nb), dtype=np.bool_)
    phi, normal, near = np.zeros(n), np.zeros((n, d)), np.zeros(n, dtype=np.bool_)
    incompatible = np.zeros(n, dtype=np.int64)
    args = (x, cdf.origin, cdf.dx, backend.node_shape, backend.strides, cdf.d, cdf.A, cdf.T,
            np.ascontiguousarray(particles.tag_A), np.ascontiguousarray(particles.tag_T), A, T, phi, normal, near,
            incompatible, blocks.order, blocks.block_start, blocks.block_colours[0], backend.block,
            backend.blocks_per_axis)
    fits = fit_phi = None
    if d == 2:
        per_body = scene.method.cpic_fit == "per_body"
        m = n if per_body else 0
        fit_phi, fit_normal, fit_near = np.zeros((m, nb)), np.zeros((m, nb, 2)), np.zeros((m, nb), dtype=np.bool_)
        args += (per_body, cdf.d_body, fit_phi, fit_normal, fit_near)
        fits = (per_body, cdf.A, cdf.T, cdf.d_body, A, fit_normal, fit_near)
    k.tag_kernel(KERNEL_CODES[spec.kernel], spec.support)(*args)
    friction = np.array([b.friction for b in bodies], dtype=np.float64).reshape(nb, 2)
    c = Contact(cdf=cdf, incompatible=incompatible, support=spec.support, friction=friction,
                gravity_dv=dt * backend.gravity.astype(particles.v.dtype), rigid=rigid, tau=backend.stress(particles),
                dt=float(dt), ghost_force=bool(scene.method.ghost_force), dim=d, fits=fits, fit_phi=fit_phi)
    return particles.with_(tag_A=A, tag_T=T, phi=phi, normal=normal, near=near), c


def p2g(backend, particles, blocks, contact):
    """CPIC P2G (:func:`p2g_kernel`): a :class:`~mpmref.state.GridState` with ``rejected_momentum`` and
    ``rejected_force``."""
    spec, N = backend.cfg, backend.scene.grid.n_nodes
    d = particles.dim
    gs = GridState(mass=np.zeros(N, dtype=backend.dtype), momentum=np.zeros((N, d), dtype=backend.dtype),
                   force=np.zeros((N, d), dtype=backend.dtype), rejected_momentum=np.zeros((N, d)),
                   rejected_force=np.zeros((N, d)))
    rigid, cdf = contact.rigid, contact.cdf
    kernel = kernels(d).p2g_kernel(KERNEL_CODES[spec.kernel], spec.support, spec.affine, spec.mls)
    kernel(particles.x, particles.v, backend._or_empty(particles.C, 0, d, d), particles.mass, particles.vol0,
           contact.tau, backend.origin, backend.dx, backend.inertia, backend.strides, blocks.order,
           blocks.block_start, *blocks.block_colours, contact.incompatible, contact.gravity_dv,
           cdf.body, particles.near, particles.normal, particles.tag_T, contact.friction, rigid.position,
           rigid.velocity, rigid.angular_velocity, contact.ghost_force, contact.dt, gs.mass, gs.momentum, gs.force,
           gs.rejected_momentum, gs.rejected_force, *(() if d == 3 else (contact.fits,)))
    return gs


def impulses(grid_state, contact, rigid, dt):
    """Impulses ``(J (nb, 2), L (nb,))`` (3D: ``(nb, 3)`` both) of the incompatible nodes on the bodies
    (:func:`node_impulses`)."""
    nb, d = rigid.position.shape
    J, L = np.zeros((nb, d)), np.zeros((nb,) if d == 2 else (nb, 3))
    cdf = contact.cdf
    kernels(d).node_impulses(grid_state.rejected_momentum, grid_state.rejected_force, dt, cdf.body,
                  np.array(cdf.shape, dtype=np.int64), cdf.origin, cdf.dx, rigid.position, J, L)
    return J, L


def g2p(backend, particles, v_grid, dt, blocks, contact, rigid):
    """CPIC G2P (:func:`g2p_kernel`) with the bodies ``rigid`` as G2P sees them; returns ``(new particles,
    (J, L))``, the penalty's impulses on the bodies, summed per block by the kernel, then over blocks in order."""
    spec, method = backend.cfg, backend.scene.method
    n, d = particles.x.shape

    def empty(*shape):
        return np.empty(shape, dtype=backend.dtype)

    x_new, v_new = empty(n, d), empty(n, d)
    C_new = empty(n, d, d) if particles.C is not None else empty(0, d, d)
    F_new = empty(n, d, d) if particles.F is not None else empty(0, d, d)
    J_new = empty(n) if particles.J is not None else empty(0)
    nb = len(rigid.angle)
    block_impulse = np.zeros((len(blocks.block_colours[0]), nb, 3 if d == 2 else 6))  # J, then L
    kernel = kernels(d).g2p_kernel(KERNEL_CODES[spec.kernel], spec.support, spec.affine, spec.mls, spec.mls_gradient,
                        spec.tracks_F, spec.tracks_J)
    cdf = contact.cdf
    kernel(particles.x, particles.v, contact.gravity_dv, backend._or_empty(particles.F, 0, d, d),
           backend._or_empty(particles.J, 0), particles.mass, particles.vol0, contact.tau, contact.ghost_force,
           backend.origin, backend.dx, backend.inertia, dt, backend.strides, blocks.order,
           blocks.block_start, blocks.block_colours[0], v_grid, contact.incompatible, cdf.body, cdf.d, particles.near,
           particles.phi, particles.normal, particles.tag_T, contact.friction, rigid.position, rigid.velocity,
           rigid.angular_velocity, float(method.pushing_force), float(method.penalty), x_new, v_new, C_new, F_new,
           J_new, block_impulse, *(() if d == 3 else (contact.fits, contact.fit_phi)))
    total = sum_in_order(block_impulse)
    J, L = total[:, :d], (total[:, d] if d == 2 else total[:, d:])
    changes = {"x": x_new, "v": v_new}
    for name, array in (("C", C_new), ("F", F_new), ("J", J_new)):
        if getattr(particles, name) is not None:
            changes[name] = array
    return particles.with_(**changes), (J, L)


@njit(cache=True)
def sum_in_order(per_block):
    """``per_block`` (k, nb, 3) summed over its first axis, block after block (a fixed order)."""
    total = np.zeros(per_block.shape[1:])
    for b in range(per_block.shape[0]):
        total += per_block[b]
    return total


def warm_up(backend, particles):
    """Compile (or load) the CPIC kernels by running the contact, P2G, impulse and G2P stages once on
    ``particles`` with Δt = 0, the bodies where they were declared; nothing is returned or kept."""
    n, nb = particles.n, len(backend.scene.rigid_bodies)
    if particles.tag_A is None:
        particles = particles.with_(tag_A=np.zeros((n, nb), dtype=np.bool_), tag_T=np.zeros((n, nb), dtype=np.bool_))
    rigid = initial_state(backend.scene.rigid_bodies)
    blocks = backend.prepare(particles)
    particles, c = contact(backend, particles, blocks, rigid, 0.0)
    gs = p2g(backend, particles, blocks, c)
    impulses(gs, c, rigid, 0.0)
    g2p(backend, particles, np.zeros_like(gs.momentum), 0.0, blocks, c, rigid)
