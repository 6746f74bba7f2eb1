r"""The colored distance field (CDF), particle tags, compatibility and the particle distance/normal fit.

CPIC (compatible PIC) lets a particle exchange momentum only with grid nodes on its own side of every
nearby thin rigid body. This module builds the pieces that decide *which side*, in 2D (polylines,
:mod:`mpmref.rigid.polyline`) and 3D (triangle meshes, :mod:`mpmref.rigid.trimesh`), NumPy reference:

* :func:`build_cdf` — per grid node :math:`i`: the unsigned distance :math:`d_i` to the nearest body, that
  body's id, and per body :math:`r` an affinity bit :math:`A_{ir}` (the node is near body :math:`r`) and a
  side bit :math:`T_{ir}` (the node is on side 1 of it);
* :func:`update_tags` — per particle :math:`p` and body :math:`r`: the tags :math:`A_{pr}, T_{pr}`, with
  sticky side memory (an existing tag is never recomputed while the body stays near);
* :func:`compatible` — the rule that a node and a particle agree on the side of every body both are near;
* :func:`reconstruct` — the weighted least-squares signed distance :math:`\phi_p` and normal
  :math:`\mathbf n_p` of each tagged particle, and its ``near`` flag.

Representation. The reference code packs, per node and per particle, 2 bits per body and the nearest-body
id into one 32-bit word (for memory, up to 12 bodies). Here the bits are boolean arrays of shape
``(n_nodes, n_bodies)`` and ``(n_particles, n_bodies)``, and the nearest-body id is its own int array:
this is a reference to read against the equations, so readability wins over memory. Nodes are numbered
in C order over the grid's node shape (``np.ravel_multi_index``).

Source: Hu et al. 2018, SIGGRAPH, "A Moving Least Squares Material Point Method with Displacement
Discontinuity and Two-Way Rigid Body Coupling", §4 (compatible particle-in-cell, the colored distance
field, particle tags and the reconstruction). Where the paper does not give a constant or an ordering
(the edge-parameter margin 0.02, the tag threshold 1e-7, the determinant thresholds 3e-3 in 2D and 1e-4
in 3D) this module does as the authors' reference implementation does (docs/cpic.md).
"""

from dataclasses import dataclass

import numpy as np

from ..rigid.polyline import segment_frame, surface_samples
from ..rigid.trimesh import TriMesh, triangle_frame
from ..rigid.trimesh import surface_samples as triangle_samples
from .kernels import compute_stencil, get_kernel

#: the penalty acts on near particles with -0.3 dx < phi < -0.05 dx (docs/cpic.md)
PENALTY_WINDOW = (-0.3, -0.05)
#: a node is rasterised only if its edge parameter lies in [-EDGE_MARGIN, 1 + EDGE_MARGIN] (docs/cpic.md)
EDGE_MARGIN = 0.02
#: a node is rasterised only if all barycentric coordinates of its projection are >= -this (docs/cpic.md, 3D:
#: inside the triangle; the tolerance only keeps nodes whose projection is on an edge up to round-off)
BARYCENTRIC_TOLERANCE = 1e-10
#: a newly near body tags a particle only if the weighted distance sum exceeds this (docs/cpic.md)
TAG_THRESHOLD = 1e-7
#: the least-squares fit is accepted (``near``) if abs(det) of its normal matrix exceeds this in 2D (docs/cpic.md)
DET_THRESHOLD_2D = 3e-3
#: the same in 3D (docs/cpic.md)
DET_THRESHOLD_3D = 1e-4
#: the fitted normal is normalised only if its squared length exceeds this (docs/cpic.md)
NORMAL_THRESHOLD = 1e-4


@dataclass
class ColoredDistanceField:
    """The colored distance field on the nodes of a grid.

    Attributes
    ----------
    d : (n_nodes,) float array          unsigned distance :math:`d_i` to the nearest body (``inf`` if none)
    body : (n_nodes,) int array         id of the nearest body (``-1`` if none)
    A : (n_nodes, n_bodies) bool array  affinity :math:`A_{ir}`: node i is in the band of body r
    T : (n_nodes, n_bodies) bool array  side :math:`T_{ir} = [h < 0]`: node i is on side 1 of body r
    shape : tuple                       nodes per axis (C order numbering)
    origin : (d,) float array           position of node 0
    dx : float                          grid spacing
    d_body : (n_nodes, n_bodies) float array or None
                                        unsigned distance :math:`d_{ir}` to each body (``inf`` outside its band;
                                        d_i is the least over r), for the per-body fit (None where not built)
    """

    d: np.ndarray
    body: np.ndarray
    A: np.ndarray
    T: np.ndarray
    shape: tuple
    origin: np.ndarray
    dx: float
    d_body: np.ndarray = None

    def node_positions(self):
        """Positions of all nodes, shape (n_nodes, d), in node order."""
        idx = np.indices(self.shape).reshape(len(self.shape), -1).T
        return self.origin + idx * self.dx


def _stencil_nodes(shape, base, offsets):
    """Flat node index of ``base + offset`` for every offset (K, d) and point (n, d), shape (K, n), and a mask
    of those inside the grid (0 where outside)."""
    node = base[None, :, :] + offsets[:, None, :]
    inside = np.all((node >= 0) & (node < np.asarray(shape)), axis=-1)
    flat = np.zeros(inside.shape, dtype=np.int64)
    if inside.any():
        flat[inside] = np.ravel_multi_index(tuple(node[inside].T), shape)
    return flat, inside


def _element_samples(body, dx):
    """Surface samples of a body and the element each lies on (docs/cpic.md): segments in 2D, triangles in 3D."""
    return triangle_samples(body, dx) if isinstance(body, TriMesh) else surface_samples(body, dx)


def _project_on_element(body, element, x):
    r"""Signed normal offset :math:`h` of points ``x`` in their elements' frames, and whether to rasterise them.

    A point is kept if its projection lies on the element (docs/cpic.md): a segment's edge parameter in
    :math:`[-0.02, 1.02]`, or all barycentric coordinates in a triangle :math:`\ge 0` (up to round-off).
    """
    if isinstance(body, TriMesh):
        bary, h = triangle_frame(body, element, x)
        return np.all(bary >= -BARYCENTRIC_TOLERANCE, axis=1), h
    s, h = segment_frame(body, element, x)
    return (s >= -EDGE_MARGIN) & (s <= 1.0 + EDGE_MARGIN), h


def build_cdf(bodies, shape, origin, dx):
    r"""Rasterise the colored distance field of ``bodies`` onto the grid nodes.

    For every surface sample :math:`s` of body :math:`r` (:func:`mpmref.rigid.polyline.surface_samples` in
    2D, :func:`mpmref.rigid.trimesh.surface_samples` in 3D) and every node :math:`i` of its
    quadratic-B-spline stencil (:math:`3^d` nodes), with the node's signed normal offset :math:`h` in the
    frame of the sample's element, if the node's projection lies on the element — in 2D its edge parameter
    :math:`-0.02 \le \sigma \le 1.02` (:func:`mpmref.rigid.polyline.segment_frame`), in 3D all its
    barycentric coordinates :math:`\lambda \ge 0` (:func:`mpmref.rigid.trimesh.triangle_frame`):

    .. math::

        d_i \leftarrow \min(d_i, |h|), \qquad \text{body}_i \leftarrow r \text{ if } |h| \text{ is the new minimum},
        \qquad A_{ir} \leftarrow 1, \qquad T_{ir} \leftarrow [h < 0].

    Only stencil nodes of samples are touched, so the band is the nodes within about 1.5 Δx of a body.

    Deterministic choices where the reference writes in parallel (last writer wins): when several
    elements of one body reach a node, :math:`T_{ir}` is taken from the one with the smallest
    :math:`|h|`; when two bodies are equally near, the lower body id is the nearest.

    Source: Hu et al. 2018 §4 (colored distance field), as the authors' reference implementation does (docs/cpic.md).

    Parameters
    ----------
    bodies : sequence of Polyline (2D) or of TriMesh (3D)   the rigid bodies, id = position in the sequence
    shape : (d,) ints                   nodes per axis
    origin : (d,) floats                position of node 0
    dx : float                          grid spacing :math:`\Delta x`

    Returns
    -------
    ColoredDistanceField
    """
    shape = tuple(int(n) for n in shape)
    origin = np.asarray(origin, dtype=np.float64)
    n_nodes, n_bodies = int(np.prod(shape)), len(bodies)
    d = np.full(n_nodes, np.inf)
    d_body = np.full((n_nodes, n_bodies), np.inf)
    nearest = np.full(n_nodes, -1, dtype=np.int64)
    A = np.zeros((n_nodes, n_bodies), dtype=bool)
    T = np.zeros((n_nodes, n_bodies), dtype=bool)
    kernel = get_kernel("quadratic")
    for r, body in enumerate(bodies):
        xs, element = _element_samples(body, dx)
        stencil = compute_stencil(kernel, xs, origin, dx)
        flat, inside = _stencil_nodes(shape, stencil.base, stencil.offsets)  # (K, samples): offset by offset
        xi = origin + (stencil.base[None, :, :] + stencil.offsets[:, None, :])[inside] * dx
        keep, h = _project_on_element(body, np.broadcast_to(element, inside.shape)[inside], xi)
        flat, h = flat[inside][keep], h[keep]
        dist = np.abs(h)
        d_r = np.full(n_nodes, np.inf)
        np.minimum.at(d_r, flat, dist)
        d_body[:, r] = d_r
        A[flat, r] = True
        # T from the element nearest to the node (the pairs at the body's minimum distance)
        at_min = dist == d_r[flat]
        T[flat[at_min], r] = h[at_min] < 0.0
        closer = d_r < d
        d[closer] = d_r[closer]
        nearest[closer] = r
    return ColoredDistanceField(d=d, body=nearest, A=A, T=T, shape=shape, origin=origin, dx=float(dx), d_body=d_body)


def _particle_stencil(cdf, x):
    """Quadratic stencil of the particles ``x`` on the field's grid."""
    return compute_stencil(get_kernel("quadratic"), np.asarray(x, dtype=np.float64), cdf.origin, cdf.dx)


def update_tags(cdf, x, A_p, T_p):
    r"""Update the particles' tags :math:`A_{pr}, T_{pr}` from the field (sticky side memory).

    1. :math:`N_{pr} = \bigvee_{i \in \text{stencil}(p)} A_{ir}`; clear :math:`A_{pr}, T_{pr}` where
       :math:`N_{pr} = 0` (the body is no longer near).
    2. For each body with :math:`N_{pr} = 1` and :math:`A_{pr} = 0` (newly near), with the quadratic
       B-spline weights :math:`w_{ip}`,

       .. math:: S_s = \sum_{i:\ A_{ir} = 1,\ T_{ir} = s} w_{ip}\, d_i \quad (s = 0, 1);

       if :math:`S_0 + S_1 > 10^{-7}` set :math:`A_{pr} = 1` and :math:`T_{pr} = [S_1 > S_0]`.

    Existing tags (:math:`A_{pr} = 1` and the body still near) are **never recomputed**: a particle pushed
    across a body keeps the side it came from, which is what lets CPIC stop it crossing.

    Source: Hu et al. 2018 §4 (particle tags carried from step to step), as the authors' reference implementation
    does for the weighting and the threshold (docs/cpic.md steps 1–2).

    Parameters
    ----------
    cdf : ColoredDistanceField
    x : (n, d) float array                  particle positions
    A_p, T_p : (n, n_bodies) bool arrays    the particles' tags from the previous step (not modified)

    Returns
    -------
    A_p, T_p : (n, n_bodies) bool arrays    the new tags
    """
    stencil = _particle_stencil(cdf, x)
    flat, inside = _stencil_nodes(cdf.shape, stencil.base, stencil.offsets)  # every array: (K nodes, n, bodies)
    A_i = cdf.A[flat] & inside[:, :, None]
    near = A_i.any(axis=0)
    wd = stencil.node_weights()[:, :, None] * np.where(A_i, cdf.d[flat][:, :, None], 0.0)  # w_ip d_i, A_ir = 1
    T_i = cdf.T[flat]
    S = np.sum(np.where(T_i, 0.0, wd), axis=0, initial=0.0), np.sum(np.where(T_i, wd, 0.0), axis=0, initial=0.0)
    A_new = np.asarray(A_p, dtype=bool) & near
    T_new = np.asarray(T_p, dtype=bool) & A_new
    fresh = near & ~A_new & (S[0] + S[1] > TAG_THRESHOLD)
    A_new = A_new | fresh
    T_new = np.where(fresh, S[1] > S[0], T_new)
    return A_new, T_new


def compatible(A_i, T_i, A_p, T_p):
    r"""Whether node and particle records are compatible (broadcast over leading axes; bodies on the last).

    With :math:`R = \{r : A_{ir} = A_{pr} = 1\}`, node :math:`i` and particle :math:`p` are compatible iff

    .. math:: T_{ir} = T_{pr} \quad \forall r \in R

    (and always if :math:`R` is empty). The rule is symmetric in node and particle.

    Source: Hu et al. 2018 §4 (compatibility of a particle and a grid node), docs/cpic.md.

    Parameters
    ----------
    A_i, T_i : (..., n_bodies) bool arrays  the node's affinity and side bits
    A_p, T_p : (..., n_bodies) bool arrays  the particle's tags

    Returns
    -------
    (...) bool array
    """
    shared = np.asarray(A_i, dtype=bool) & np.asarray(A_p, dtype=bool)
    return ~np.any(shared & (np.asarray(T_i, dtype=bool) != np.asarray(T_p, dtype=bool)), axis=-1)


def reconstruct(cdf, x, A_p, T_p):
    r"""Weighted least-squares signed distance :math:`\phi_p`, normal :math:`\mathbf n_p` and ``near`` flag.

    For a tagged particle, every stencil node :math:`i` that carries a body gives a sample at
    :math:`\mathbf z_i = (\mathbf x_i - \mathbf x_p)/\Delta x` with target

    .. math::

        y_i = \begin{cases} +d_i/\Delta x & i \text{ compatible with } p \text{ (see } \texttt{compatible}) \\
                            -d_i/\Delta x & \text{exactly one shared body's side bit differs} \\
                            \text{(skipped)} & \text{otherwise,} \end{cases}

    and the fit minimises over :math:`(\mathbf n, c)`

    .. math:: \sum_i w_{ip} (\mathbf n \cdot \mathbf z_i + c - y_i)^2 ,

    i.e. solves :math:`M (\mathbf n, c) = \sum_i w_{ip} y_i (\mathbf z_i, 1)` with the normal matrix
    :math:`M = \sum_i w_{ip} (\mathbf z_i, 1)(\mathbf z_i, 1)^T`. If :math:`|\det M|` exceeds
    :math:`3\cdot 10^{-3}` (2D) or :math:`10^{-4}` (3D): ``near`` is true, :math:`\phi_p = c\,\Delta x`
    (positive on the particle's own side, negative once it has penetrated) and
    :math:`\mathbf n_p = \mathbf n/|\mathbf n|` if :math:`|\mathbf n|^2 > 10^{-4}`, else 0.
    Otherwise ``near`` is false and :math:`\phi_p = 0`, :math:`\mathbf n_p = 0`.

    Source: Hu et al. 2018 §4 (particle distance and normal reconstructed from the colored distance
    field by moving least squares), as the authors' reference implementation does for the targets and thresholds
    (docs/cpic.md).

    Parameters
    ----------
    cdf : ColoredDistanceField
    x : (n, d) float array                  particle positions
    A_p, T_p : (n, n_bodies) bool arrays    the particles' tags (from :func:`update_tags`)

    Returns
    -------
    phi : (n,) float array      signed distance :math:`\phi_p`
    normal : (n, d) float array unit normal :math:`\mathbf n_p` (or 0)
    near : (n,) bool array
    """
    A_p, T_p = np.asarray(A_p, dtype=bool), np.asarray(T_p, dtype=bool)
    stencil = _particle_stencil(cdf, x)
    flat, inside = _stencil_nodes(cdf.shape, stencil.base, stencil.offsets)  # every array: (K nodes, n, ...)
    A_i, T_i = cdf.A[flat], cdf.T[flat]
    has_body = inside & A_i.any(axis=2)
    differing = np.count_nonzero(A_i & A_p & (T_i != T_p), axis=2)
    d = np.where(has_body, cdf.d[flat], 0.0) / cdf.dx
    y = np.where(differing == 0, d, -d)
    use = A_p.any(axis=1) & has_body & (differing <= 1)
    w = np.where(use, stencil.node_weights(), 0.0)
    z1 = _fit_basis(stencil, cdf.dx)
    M = np.sum(w[:, :, None, None] * z1[:, :, :, None] * z1[:, :, None, :], axis=0, initial=0.0)
    rhs = np.sum((w * y)[:, :, None] * z1, axis=0, initial=0.0)
    return _solve_fit(M, rhs, cdf.dx)


def _fit_basis(stencil, dx):
    r"""The fit's basis :math:`(\mathbf z_i, 1)`, :math:`\mathbf z_i = (\mathbf x_i - \mathbf x_p)/\Delta x`, for
    every stencil node and particle: shape (K, n, d + 1)."""
    z = stencil.node_offset_vectors() / dx
    return np.concatenate([z, np.ones(z.shape[:2] + (1,))], axis=2)


def _solve_fit(M, rhs, dx):
    r"""Solve the fits :math:`M (\mathbf n, c) = \mathbf b` (M (n, d+1, d+1), ``rhs`` (n, d+1)) of :func:`reconstruct`.

    Accepted (``near``) where :math:`|\det M|` exceeds :data:`DET_THRESHOLD_2D` (2D) or :data:`DET_THRESHOLD_3D`
    (3D); then :math:`\phi = c\,\Delta x` and :math:`\mathbf n/|\mathbf n|` (0 if :math:`|\mathbf n|^2 \le 10^{-4}`).
    Returns ``(phi (n,), normal (n, d), near (n,))``, zero where not accepted.
    """
    n, dim = len(M), M.shape[1] - 1
    det = np.linalg.det(M)
    near = np.abs(det) > (DET_THRESHOLD_2D if dim == 2 else DET_THRESHOLD_3D)
    phi = np.zeros(n)
    normal = np.zeros((n, dim))
    if near.any():
        sol = np.linalg.solve(M[near], rhs[near][:, :, None])[:, :, 0]
        nvec, c = sol[:, :dim], sol[:, dim]
        phi[near] = c * dx
        norm2 = np.einsum("ij,ij->i", nvec, nvec)
        unit = np.where((norm2 > NORMAL_THRESHOLD)[:, None], nvec / np.sqrt(np.maximum(norm2, 1e-300))[:, None], 0.0)
        normal[near] = unit
    return phi, normal, near


def reconstruct_per_body(cdf, x, A_p, T_p):
    r"""Per-body least-squares distance :math:`\phi_{pr}`, normal :math:`\mathbf n_{pr}` and ``near`` flag of each
    particle tagged by two or more bodies (the per-body fit, ``method.cpic_fit = "per_body"``; docs/cpic.md).

    For such a particle and each body :math:`r` it is tagged by, the fit of :func:`reconstruct` is made with only
    the stencil nodes in body :math:`r`'s band (:math:`A_{ir} = 1`) and body :math:`r`'s own distance
    :math:`d_{ir}` (``cdf.d_body``):

    .. math::

        y_{ir} = \begin{cases} +d_{ir}/\Delta x & T_{ir} = T_{pr} \\ -d_{ir}/\Delta x & T_{ir} \ne T_{pr},
        \end{cases} \qquad \min_{\mathbf n, c} \sum_{i:\ A_{ir} = 1} w_{ip}(\mathbf n\cdot\mathbf z_i + c - y_{ir})^2,

    with the same acceptance threshold on :math:`|\det M|` and the same normalisation. A particle in the wedge
    where two bodies meet thus gets each body's own signed distance and normal, where the single fit mixes both.
    Particles tagged by fewer than two bodies get nothing here (all zero, ``near`` false): they keep the single
    fit. This is mpmref's extension, not the paper's: Hu et al. 2018 §4 reconstruct one :math:`(\phi_p,
    \mathbf n_p)` per particle.

    Parameters
    ----------
    cdf : ColoredDistanceField              with ``d_body``
    x : (n, d) float array                  particle positions
    A_p, T_p : (n, n_bodies) bool arrays    the particles' tags (from :func:`update_tags`)

    Returns
    -------
    phi : (n, n_bodies) float array         :math:`\phi_{pr}`
    normal : (n, n_bodies, d) float array   :math:`\mathbf n_{pr}`
    near : (n, n_bodies) bool array         the fit of body r is accepted (only for particles tagged by >= 2 bodies)
    """
    A_p, T_p = np.asarray(A_p, dtype=bool), np.asarray(T_p, dtype=bool)
    stencil = _particle_stencil(cdf, x)
    (n, dim), n_bodies = stencil.base.shape, A_p.shape[1]
    M = np.zeros((n_bodies, n, dim + 1, dim + 1))
    rhs = np.zeros((n_bodies, n, dim + 1))
    several = A_p.sum(axis=1) >= 2
    flat, inside = _stencil_nodes(cdf.shape, stencil.base, stencil.offsets)  # (K nodes, n)
    z1, weights = _fit_basis(stencil, cdf.dx), stencil.node_weights()
    for r in range(n_bodies):
        use = several & A_p[:, r] & inside & cdf.A[flat, r]
        d = np.where(use, cdf.d_body[flat, r], 0.0) / cdf.dx
        y = np.where(cdf.T[flat, r] == T_p[:, r], d, -d)
        w = np.where(use, weights, 0.0)
        M[r] = np.sum(w[:, :, None, None] * z1[:, :, :, None] * z1[:, :, None, :], axis=0, initial=0.0)
        rhs[r] = np.sum((w * y)[:, :, None] * z1, axis=0, initial=0.0)
    fits = [_solve_fit(M[r], rhs[r], cdf.dx) for r in range(n_bodies)]
    phi = np.stack([f[0] for f in fits], axis=1).reshape(n, n_bodies)
    normal = np.stack([f[1] for f in fits], axis=1).reshape(n, n_bodies, dim)
    near = np.stack([f[2] for f in fits], axis=1).reshape(n, n_bodies) & several[:, None]
    return phi, normal, near
