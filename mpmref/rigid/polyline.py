r"""Rigid-body geometry for CPIC (compatible PIC): 2D polylines, their validation and surface samples.

A 2D rigid body is a polyline: ``vertices`` of shape ``(n, 2)`` and ``segments`` of shape ``(m, 2)``, each
row a pair of vertex indices ``(a, b)``. Segment ``k`` runs from :math:`\mathbf a_k` to :math:`\mathbf b_k`.
Its frame is the unit tangent :math:`\mathbf t_k = (\mathbf b_k - \mathbf a_k)/\ell_k` and the *left* unit
normal :math:`\mathbf n_k = (-t_{k,y},\ t_{k,x})` (the tangent turned by +90°). A point
:math:`\mathbf x` has edge parameter :math:`s = (\mathbf x - \mathbf a_k)\cdot \mathbf t_k / \ell_k` and
signed normal offset :math:`h = (\mathbf x - \mathbf a_k)\cdot \mathbf n_k`; the side with :math:`h < 0`
is side 1 (the colored distance field's ``T`` bit), the side with :math:`h \ge 0` is side 0.

Source: Hu et al. 2018, SIGGRAPH, "A Moving Least Squares Material Point Method with Displacement
Discontinuity and Two-Way Rigid Body Coupling", §4 (rigid bodies as boundary elements sampled for the
colored distance field); the sampling rule is the one of the authors' reference implementation (docs/cpic.md). 3D
triangle meshes are in :mod:`mpmref.rigid.trimesh`.
"""

from dataclasses import dataclass

import numpy as np

from ..errors import SceneError


@dataclass(frozen=True)
class Polyline:
    """A validated 2D polyline body.

    Attributes
    ----------
    vertices : (n, 2) float array   vertex positions
    segments : (m, 2) int array     vertex-index pairs ``(a, b)``; the segment runs from ``a`` to ``b``
    closed : bool                   a closed (solid) body: every vertex is used by exactly two segments
    """

    vertices: np.ndarray
    segments: np.ndarray
    closed: bool = False

    @property
    def starts(self):
        """Segment start points :math:`\\mathbf a_k`, shape (m, 2)."""
        return self.vertices[self.segments[:, 0]]

    @property
    def ends(self):
        """Segment end points :math:`\\mathbf b_k`, shape (m, 2)."""
        return self.vertices[self.segments[:, 1]]

    @property
    def lengths(self):
        r"""Segment lengths :math:`\ell_k = |\mathbf b_k - \mathbf a_k|`, shape (m,)."""
        return np.linalg.norm(self.ends - self.starts, axis=1)


def validate_polyline(vertices, segments, closed=False, index=0):
    """Check a 2D polyline and return it as a :class:`Polyline`.

    Parameters
    ----------
    vertices : array-like (n, 2)    finite vertex coordinates
    segments : array-like (m, 2)    integer vertex-index pairs, ``m >= 1``
    closed : bool                   the body is declared closed (solid)
    index : int                     the body's position in ``rigid_bodies``, used in error field names

    Raises
    ------
    SceneError
        naming ``rigid_bodies[index].vertices`` (wrong shape, not finite), ``rigid_bodies[index].segments``
        (wrong shape, not integers, an index out of range, a zero-length segment) or
        ``rigid_bodies[index].closed`` (declared closed, but some vertex is not used by exactly two segments).
    """
    where = f"rigid_bodies[{index}]"
    try:
        v = np.asarray(vertices, dtype=np.float64)
    except (TypeError, ValueError):
        raise SceneError(f"{where}.vertices", vertices, "an (n, 2) array of numbers") from None
    if v.ndim != 2 or v.shape[1] != 2 or v.shape[0] < 2:
        raise SceneError(f"{where}.vertices", vertices, "an (n, 2) array of numbers with n >= 2")
    if not np.all(np.isfinite(v)):
        raise SceneError(f"{where}.vertices", vertices, "finite coordinates")
    s = np.asarray(segments)
    if s.ndim != 2 or s.shape[1] != 2 or s.shape[0] < 1 or not (s.size == 0 or np.issubdtype(s.dtype, np.integer)):
        raise SceneError(f"{where}.segments", segments, "an (m, 2) array of integer vertex indices with m >= 1")
    s = s.astype(np.int64)
    bad = np.nonzero(np.any((s < 0) | (s >= len(v)), axis=1))[0]
    if bad.size:
        k = int(bad[0])
        raise SceneError(f"{where}.segments", segments,
                         f"vertex indices in [0, {len(v) - 1}] (segment {k} is {s[k].tolist()})")
    lengths = np.linalg.norm(v[s[:, 1]] - v[s[:, 0]], axis=1)
    extent = float(np.max(np.ptp(v, axis=0))) or 1.0
    bad = np.nonzero(lengths <= 1e-12 * extent)[0]
    if bad.size:
        k = int(bad[0])
        raise SceneError(f"{where}.segments", segments,
                         f"segments of nonzero length (segment {k} = {s[k].tolist()} is degenerate)")
    if closed:
        uses = np.bincount(s.ravel(), minlength=len(v))
        bad = np.nonzero(uses != 2)[0]
        if bad.size:
            k = int(bad[0])
            raise SceneError(f"{where}.closed", closed,
                             f"false, or a closed polyline in which every vertex is used by exactly two segments "
                             f"(vertex {k} is used by {int(uses[k])})")
    return Polyline(vertices=v, segments=s, closed=bool(closed))


def surface_samples(body, dx):
    r"""Sample each segment of ``body`` with points at most ``dx`` apart.

    Segment :math:`k` of length :math:`\ell_k` is cut into :math:`n_k = \max(\lceil \ell_k/\Delta x\rceil, 2)`
    equal pieces and sampled at their midpoints,

    .. math:: \mathbf x_{kj} = \mathbf a_k + \frac{j + 1/2}{n_k} (\mathbf b_k - \mathbf a_k),
              \quad j = 0, \dots, n_k - 1 .

    Source: the authors' reference implementation (Hu et al. 2018 §4 samples the rigid elements
    to rasterise the colored distance field but does not give the rule).

    Parameters
    ----------
    body : Polyline
    dx : float                      grid spacing :math:`\Delta x`

    Returns
    -------
    x : (k, 2) float array          sample positions
    segment : (k,) int array        index of the segment each sample lies on
    """
    lengths = body.lengths
    n = np.maximum(np.ceil(lengths / dx).astype(np.int64), 2)
    segment = np.repeat(np.arange(len(n)), n)
    first = np.concatenate([[0], np.cumsum(n)[:-1]])
    j = np.arange(segment.size) - first[segment]
    u = (j + 0.5) / n[segment]
    a, b = body.starts[segment], body.ends[segment]
    return a + u[:, None] * (b - a), segment


def segment_frame(body, segment, x):
    r"""Edge parameter :math:`s` and signed normal offset :math:`h` of points ``x`` in segments' frames.

    .. math:: s = \frac{(\mathbf x - \mathbf a_k)\cdot(\mathbf b_k - \mathbf a_k)}{\ell_k^2}, \qquad
              h = (\mathbf x - \mathbf a_k)\cdot \mathbf n_k, \quad \mathbf n_k = (-t_{k,y}, t_{k,x}),

    with :math:`\mathbf t_k` the unit tangent. :math:`s \in [0, 1]` means the projection of
    :math:`\mathbf x` lies on the segment; :math:`|h|` is then the distance to it.

    Source: Hu et al. 2018 §4 (distance and side of a node with respect to a boundary element), as the authors'
    reference implementation does (docs/cpic.md).

    Parameters
    ----------
    body : Polyline
    segment : (k,) int array        segment index per point
    x : (k, 2) float array          points

    Returns
    -------
    s, h : (k,) float arrays
    """
    a, b = body.starts[segment], body.ends[segment]
    e = b - a
    length2 = np.einsum("ij,ij->i", e, e)
    r = x - a
    s = np.einsum("ij,ij->i", r, e) / length2
    h = (r[:, 1] * e[:, 0] - r[:, 0] * e[:, 1]) / np.sqrt(length2)  # r · (-e_y, e_x) / |e|
    return s, h


#: the geometry of Hu et al. 2018's 2D sand wheel (the authors' reference scene), for :func:`wheel`
SAND_WHEEL = {"center": [0.5, 0.35], "ring_radius": 0.16, "ring_segments": 60, "blade_inner": 0.136,
              "blade_outer": 0.24, "blades": 18}


def wheel(center, ring_radius, ring_segments, blade_inner, blade_outer, blades):
    r"""The sand wheel of Hu et al. 2018 (§7, the 2D sand wheel): a ring and slanted blades, as two polylines.

    The ring is a regular polygon of ``ring_segments`` segments on the circle of radius ``ring_radius``,
    traversed clockwise, so that its side 0 (left of each segment) is outside and side 1 inside. Blade
    :math:`i` runs from radius ``blade_inner`` at angle :math:`-i\alpha` to radius ``blade_outer`` at angle
    :math:`-(i+1)\alpha`, :math:`\alpha = 2\pi/` ``blades`` (slanted by one blade spacing, as in the authors'
    reference scene).

    Returns ``((ring_vertices, ring_segments), (blade_vertices, blade_segments))`` as lists (TOML-ready).
    """
    c = np.asarray(center, dtype=np.float64)
    phi = -2.0 * np.pi * np.arange(ring_segments) / ring_segments
    ring = c + ring_radius * np.stack([np.cos(phi), np.sin(phi)], axis=1)
    ring_segs = np.stack([np.arange(ring_segments), (np.arange(ring_segments) + 1) % ring_segments], axis=1)
    alpha = 2.0 * np.pi / blades
    start, end = -alpha * np.arange(blades), -alpha * (np.arange(blades) + 1)
    inner = c + blade_inner * np.stack([np.cos(start), np.sin(start)], axis=1)
    outer = c + blade_outer * np.stack([np.cos(end), np.sin(end)], axis=1)
    blade_vertices = np.stack([inner, outer], axis=1).reshape(-1, 2)
    blade_segs = np.arange(2 * blades).reshape(blades, 2)
    return (ring.tolist(), ring_segs.tolist()), (blade_vertices.tolist(), blade_segs.tolist())


def inside_closed(shape, x):
    """Whether each point of ``x`` (n, 2) is inside the closed polyline ``shape`` (the even-odd rule: a ray from
    the point towards +x crosses the polyline an odd number of times)."""
    a, b = shape.starts, shape.ends
    y = x[:, 1:2]
    spans = (a[:, 1] > y) != (b[:, 1] > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        x_cross = a[:, 0] + (y - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
    return np.count_nonzero(spans & (x[:, 0:1] < x_cross), axis=1) % 2 == 1


def distance_to_polyline(shape, x):
    r"""Euclidean distance from each point of ``x`` (n, 2) to the nearest segment of ``shape``:
    :math:`\min_k |\mathbf x - \mathbf a_k - \mathrm{clamp}(s_k, 0, 1)(\mathbf b_k - \mathbf a_k)|`
    (:func:`segment_frame`'s edge parameter :math:`s_k`)."""
    a, b = shape.starts[None], shape.ends[None]
    e = b - a
    s = np.clip(np.einsum("nkd,nkd->nk", x[:, None] - a, e) / np.einsum("nkd,nkd->nk", e, e), 0.0, 1.0)
    return np.linalg.norm(x[:, None] - a - s[..., None] * e, axis=2).min(axis=1)
