r"""Rigid-body geometry for CPIC in 3D: triangle meshes, their validation, mass properties and surface samples.

A 3D rigid body is a triangle mesh: ``vertices`` of shape ``(n, 3)`` and ``triangles`` of shape ``(m, 3)``,
each row the vertex indices ``(a, b, c)`` of one triangle. Triangle :math:`k` has the edge frame
:math:`\mathbf e_1 = \mathbf b_k - \mathbf a_k`, :math:`\mathbf e_2 = \mathbf c_k - \mathbf a_k` and the unit
normal :math:`\mathbf n_k = \mathbf e_1 \times \mathbf e_2 / |\mathbf e_1 \times \mathbf e_2|` (right-hand rule
on the vertex order). A point :math:`\mathbf x` has the barycentric coordinates
:math:`(\lambda_a, \lambda_b, \lambda_c)` of its projection onto the triangle's plane and the signed normal
offset :math:`h = (\mathbf x - \mathbf a_k)\cdot \mathbf n_k`; the side with :math:`h < 0` is side 1 (the
colored distance field's ``T`` bit), the side with :math:`h \ge 0` is side 0. A closed (solid) mesh must be
oriented outward, so that its outside is side 0 and its inside side 1.

A body is closed (``closed = true``, a solid with an enclosed volume) or open (a zero-thickness shell, such
as a blade). Its mass, centre of mass and inertia tensor come from a density over its volume (closed) or its
area (open).

Source: Hu et al. 2018, SIGGRAPH, "A Moving Least Squares Material Point Method with Displacement
Discontinuity and Two-Way Rigid Body Coupling", §4 (rigid bodies as boundary elements sampled for the colored
distance field; thin shells of zero thickness); the sampling rule and the mass measure are those of the authors'
reference implementation (docs/cpic.md).
"""

from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np

from ..errors import SceneError

#: a triangle is degenerate if its area is at most this times the square of the body's extent
DEGENERATE_AREA = 1e-12


@dataclass(frozen=True)
class TriMesh:
    """A validated 3D triangle-mesh body.

    Attributes
    ----------
    vertices : (n, 3) float array   vertex positions
    triangles : (m, 3) int array    vertex indices ``(a, b, c)``; the normal follows the right-hand rule
    closed : bool                   a closed (solid) body: watertight and oriented outward
    """

    vertices: np.ndarray
    triangles: np.ndarray
    closed: bool = False

    @property
    def corners(self):
        r"""Corner positions :math:`(\mathbf a_k, \mathbf b_k, \mathbf c_k)`, shape (m, 3, 3)."""
        return self.vertices[self.triangles]

    @property
    def area_vectors(self):
        r"""Area vectors :math:`\tfrac12 (\mathbf b_k - \mathbf a_k) \times (\mathbf c_k - \mathbf a_k)`, (m, 3)."""
        c = self.corners
        return 0.5 * np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])

    @property
    def areas(self):
        """Triangle areas, shape (m,)."""
        return np.linalg.norm(self.area_vectors, axis=1)

    @property
    def normals(self):
        r"""Unit normals :math:`\mathbf n_k`, shape (m, 3)."""
        return self.area_vectors / self.areas[:, None]


def _refuse_bad_shape(where, vertices, triangles):
    """Vertices and triangles as float/int arrays, or a SceneError naming the malformed one."""
    try:
        v = np.asarray(vertices, dtype=np.float64)
    except (TypeError, ValueError):
        raise SceneError(f"{where}.vertices", vertices, "an (n, 3) array of numbers") from None
    if v.ndim != 2 or v.shape[1] != 3 or v.shape[0] < 3:
        raise SceneError(f"{where}.vertices", vertices, "an (n, 3) array of numbers with n >= 3")
    if not np.all(np.isfinite(v)):
        raise SceneError(f"{where}.vertices", vertices, "finite coordinates")
    t = np.asarray(triangles)
    if t.ndim != 2 or t.shape[1] != 3 or t.shape[0] < 1 or not np.issubdtype(t.dtype, np.integer):
        raise SceneError(f"{where}.triangles", triangles, "an (m, 3) array of integer vertex indices with m >= 1")
    t = t.astype(np.int64)
    bad = np.nonzero(np.any((t < 0) | (t >= len(v)), axis=1))[0]
    if bad.size:
        k = int(bad[0])
        raise SceneError(f"{where}.triangles", triangles,
                         f"vertex indices in [0, {len(v) - 1}] (triangle {k} is {t[k].tolist()})")
    return v, t


def _directed_edges(triangles):
    """The three directed edges ``(a, b), (b, c), (c, a)`` of every triangle, shape (3m, 2)."""
    return np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])


def _edge_defect(triangles):
    """A sentence about the first edge that breaks a consistently oriented mesh, or ``None``.

    Each directed edge may appear once only: a directed edge used twice means two triangles that share the
    edge with opposite normals (inconsistent orientation) or an edge shared by more than two triangles.
    """
    edges = _directed_edges(triangles)
    unique, counts = np.unique(edges, axis=0, return_counts=True)
    if np.any(counts > 1):
        first = int(np.argmax(counts > 1))
        a, b = unique[first].tolist()
        return (f"edge ({a}, {b}) is traversed in the same direction by {int(counts[first])} triangles "
                f"(inconsistent orientation, or more than two triangles on one edge)")
    return None


def _open_edge(triangles):
    """The first directed edge whose reverse no triangle has (a boundary edge of the mesh), or ``None``."""
    edges = _directed_edges(triangles)
    key = edges[:, 0] * (triangles.max() + 1) + edges[:, 1]
    reverse = edges[:, 1] * (triangles.max() + 1) + edges[:, 0]
    missing = ~np.isin(reverse, key)
    return edges[np.argmax(missing)].tolist() if missing.any() else None


def signed_volume(mesh):
    r"""Volume enclosed by a closed mesh, positive if it is oriented outward (divergence theorem).

    .. math:: V = \frac13 \oint \mathbf x \cdot \mathbf n\, dA
              = \sum_k \frac16\, \mathbf a_k \cdot (\mathbf b_k \times \mathbf c_k),

    the sum of the signed volumes of the tetrahedra from the origin to each triangle.

    Source: the divergence theorem applied to :math:`\nabla\cdot\mathbf x = 3`, as in Eberly, "Polyhedral
    Mass Properties (Revisited)", Geometric Tools (2002).

    Parameters
    ----------
    mesh : TriMesh

    Returns
    -------
    float
    """
    c = mesh.corners - mesh.vertices.mean(axis=0)  # about the vertex mean, for round-off
    return float(np.sum(np.einsum("ij,ij->i", c[:, 0], np.cross(c[:, 1], c[:, 2])))) / 6.0


def validate_trimesh(vertices, triangles, closed=False, index=0, domain=None):
    """Check a 3D triangle mesh and return it as a :class:`TriMesh`.

    Parameters
    ----------
    vertices : array-like (n, 3)    finite vertex coordinates
    triangles : array-like (m, 3)   integer vertex-index triples, ``m >= 1``
    closed : bool                   the body is declared closed (solid)
    index : int                     the body's position in ``rigid_bodies``, used in error field names
    domain : (lo, hi) or None       the box every vertex must lie in (``lo <= x <= hi``), if given

    Raises
    ------
    SceneError
        naming ``rigid_bodies[index].vertices`` (wrong shape, not finite, a vertex outside the domain),
        ``rigid_bodies[index].triangles`` (wrong shape, not integers, an index out of range, a degenerate
        triangle, two triangles on one edge with opposite orientations or an edge of more than two triangles,
        a closed mesh oriented inward) or ``rigid_bodies[index].closed`` (declared closed, but some edge
        belongs to one triangle only: the mesh is not watertight).
    """
    where = f"rigid_bodies[{index}]"
    v, t = _refuse_bad_shape(where, vertices, triangles)
    if domain is not None:
        lo, hi = (np.asarray(b, dtype=np.float64) for b in domain)
        out = np.nonzero(np.any((v < lo) | (v > hi), axis=1))[0]
        if out.size:
            k = int(out[0])
            raise SceneError(f"{where}.vertices", v[k].tolist(),
                             f"vertices inside the domain [{lo.tolist()}, {hi.tolist()}] (vertex {k} is outside)")
    mesh = TriMesh(vertices=v, triangles=t, closed=bool(closed))
    extent = float(np.max(np.ptp(v, axis=0))) or 1.0
    bad = np.nonzero(mesh.areas <= DEGENERATE_AREA * extent**2)[0]
    if bad.size:
        k = int(bad[0])
        raise SceneError(f"{where}.triangles", triangles,
                         f"triangles of nonzero area (triangle {k} = {t[k].tolist()} is degenerate)")
    defect = _edge_defect(t)
    if defect:
        raise SceneError(f"{where}.triangles", triangles, f"a consistently oriented mesh ({defect})")
    if closed:
        edge = _open_edge(t)
        if edge is not None:
            raise SceneError(f"{where}.closed", closed,
                             f"false, or a watertight mesh in which every edge is shared by exactly two "
                             f"triangles (edge {tuple(edge)} belongs to one triangle only)")
        volume = signed_volume(mesh)
        if volume <= 0:
            raise SceneError(f"{where}.triangles", triangles,
                             f"a closed mesh oriented outward (its enclosed volume is {volume:.6g}; "
                             f"reverse the vertex order of every triangle)")
    return mesh


def read_trimesh(path, closed=False, index=0, domain=None, base_dir="."):
    """Read a triangle mesh with meshio (``mesh = "file"``) and validate it (:func:`validate_trimesh`).

    The file's surface must be made of ``triangle`` cells (``vertex`` and ``line`` cells are ignored; quads,
    polygons or volume cells are refused). meshio's STL reader merges coincident points, so a closed STL
    surface reads back watertight.

    Parameters
    ----------
    path : str or Path              the mesh file, relative to ``base_dir`` unless absolute
    closed, index, domain           as in :func:`validate_trimesh`
    base_dir : str or Path          the scene file's folder

    Raises
    ------
    SceneError
        naming ``rigid_bodies[index].mesh`` when the file cannot be read, holds no triangles or cells other
        than triangles (vertices and lines aside), or its mesh is refused by :func:`validate_trimesh` (the
        message then says which check failed).
    """
    import meshio

    where = f"rigid_bodies[{index}].mesh"
    path = Path(path)
    path = path if path.is_absolute() else Path(base_dir) / path
    try:
        mesh = meshio.read(path)
    except Exception as exc:  # meshio raises several types for unreadable files
        raise SceneError(where, str(path), f"a triangle mesh readable by meshio ({exc})") from None
    others = sorted({c.type for c in mesh.cells} - {"triangle", "vertex", "line"})
    blocks = [c.data for c in mesh.cells if c.type == "triangle"]
    if others or not blocks:
        found = f"it has {', '.join(others)} cells; triangulate it" if others else "it has none"
        raise SceneError(where, str(path), f"a surface of triangle cells ({found})")
    points = np.asarray(mesh.points, dtype=np.float64)
    if points.shape[1] != 3:
        raise SceneError(where, str(path), f"a mesh with 3D points (it has {points.shape[1]} coordinates)")
    try:
        return validate_trimesh(points, np.concatenate(blocks), closed=closed, index=index, domain=domain)
    except SceneError as err:
        raise SceneError(where, str(path), f"{err.allowed} (check on {err.field})") from None


# ------------------------------------------------------------------------------------------- mass properties
class MassProperties(NamedTuple):
    """Mass, centre of mass and inertia tensor of a rigid body (unpacks as ``mass, center, inertia``).

    Attributes
    ----------
    mass : float                    :math:`m`
    center : (3,) float array       centre of mass :math:`\\mathbf x_c`
    inertia : (3, 3) float array    inertia tensor about the centre of mass, :math:`\\mathbf I =
                                    \\int \\rho (|\\mathbf r|^2 \\mathbf 1 - \\mathbf r \\mathbf r^T)`,
                                    :math:`\\mathbf r = \\mathbf x - \\mathbf x_c`
    """

    mass: float
    center: np.ndarray
    inertia: np.ndarray


def _from_moments(density, measure, first, second):
    r"""Mass properties from the zeroth, first and second moments of a uniform measure.

    With :math:`M_0 = \int d\mu`, :math:`\mathbf M_1 = \int \mathbf x\, d\mu` and
    :math:`\mathbf M_2 = \int \mathbf x \mathbf x^T d\mu`: :math:`m = \rho M_0`,
    :math:`\mathbf x_c = \mathbf M_1 / M_0`, :math:`\mathbf C = \rho(\mathbf M_2 - M_0 \mathbf x_c \mathbf x_c^T)`
    and :math:`\mathbf I = \operatorname{tr}(\mathbf C)\,\mathbf 1 - \mathbf C` (parallel-axis theorem).
    """
    center = first / measure
    C = density * (second - measure * np.outer(center, center))
    return MassProperties(mass=density * measure, center=center, inertia=np.trace(C) * np.eye(3) - C)


def _simplex_second_moment(corners, measure, n_corners):
    r"""Sum over simplices of their second moments :math:`\int \mathbf x \mathbf x^T`.

    For a simplex of :math:`k+1` corners :math:`\mathbf v_j` (triangle :math:`k = 2`, tetrahedron :math:`k = 3`)
    and measure :math:`M`,

    .. math:: \int \mathbf x \mathbf x^T = \frac{M}{(k+1)(k+2)}
              \Big(\sum_j \mathbf v_j \mathbf v_j^T + \mathbf s \mathbf s^T\Big), \quad \mathbf s = \sum_j \mathbf v_j,

    from :math:`\int \lambda_i \lambda_j = M (1 + \delta_{ij}) / ((k+1)(k+2))` over a simplex.
    """
    s = corners.sum(axis=1)
    outer = np.einsum("kji,kjl->kil", corners, corners) + np.einsum("ki,kl->kil", s, s)
    return np.einsum("k,kil->il", measure, outer) / (n_corners * (n_corners + 1))


def shell_mass_properties(mesh, density):
    r"""Mass properties of the mesh as a zero-thickness shell of area density :math:`\rho` (kg/m²).

    :math:`m = \rho A`, :math:`\mathbf x_c = \frac1A \sum_k A_k \bar{\mathbf x}_k` and
    :math:`\int \mathbf x \mathbf x^T dA = \sum_k \frac{A_k}{12}\big(\sum_j \mathbf v_{kj} \mathbf v_{kj}^T +
    \mathbf s_k \mathbf s_k^T\big)` (:math:`\mathbf v_{kj}` the corners of triangle :math:`k`, :math:`\mathbf s_k`
    their sum, :math:`\bar{\mathbf x}_k = \mathbf s_k/3` its centroid); the tensor is then taken about
    :math:`\mathbf x_c` (see :class:`MassProperties`).

    Source: Hu et al. 2018 and the authors' reference implementation (thin shells: mass :math:`\rho \cdot` area, inertia
    from the same measure); the triangle moments are the exact integrals of the linear (barycentric) parametrisation.

    Parameters
    ----------
    mesh : TriMesh
    density : float     area density :math:`\rho > 0`

    Returns
    -------
    MassProperties
    """
    origin = mesh.vertices.mean(axis=0)  # moments about the vertex mean, for round-off
    corners = mesh.corners - origin
    areas = mesh.areas
    first = np.einsum("k,ki->i", areas, corners.sum(axis=1)) / 3.0
    props = _from_moments(density, float(areas.sum()), first, _simplex_second_moment(corners, areas, 3))
    return MassProperties(props.mass, props.center + origin, props.inertia)


def solid_mass_properties(mesh, density):
    r"""Mass properties of a closed, outward-oriented mesh as a solid of volume density :math:`\rho` (kg/m³).

    By the divergence theorem the enclosed region is the signed sum of the tetrahedra :math:`T_k` from a
    reference point :math:`\mathbf o` to each triangle, of signed volumes
    :math:`V_k = \frac16 (\mathbf a_k - \mathbf o)\cdot((\mathbf b_k - \mathbf o) \times (\mathbf c_k - \mathbf o))`:
    :math:`V = \sum_k V_k`, :math:`\int \mathbf x\, dV = \sum_k V_k \mathbf s_k / 4` and
    :math:`\int \mathbf x \mathbf x^T dV = \sum_k \frac{V_k}{20}\big(\sum_j \mathbf v_{kj} \mathbf v_{kj}^T +
    \mathbf s_k \mathbf s_k^T\big)`, with :math:`\mathbf v_{kj}` the four corners of :math:`T_k` (relative to
    :math:`\mathbf o`, so one is 0) and :math:`\mathbf s_k` their sum.

    Source: Hu et al. 2018 and the authors' reference implementation (solid bodies take mass from the enclosed volume);
    the divergence-theorem decomposition is that of Eberly, "Polyhedral Mass Properties (Revisited)", Geometric Tools
    (2002); the tetrahedron moments are those of Tonon, "Explicit exact formulas for the 3-D tetrahedron inertia tensor
    in terms of its vertex coordinates", J. Math. Stat. 1 (2004).

    Parameters
    ----------
    mesh : TriMesh      closed (``mesh.closed``), as :func:`validate_trimesh` checks
    density : float     volume density :math:`\rho > 0`

    Returns
    -------
    MassProperties
    """
    if not mesh.closed:
        raise ValueError("solid mass properties need a closed mesh (validate it with closed=True)")
    origin = mesh.vertices.mean(axis=0)
    tri = mesh.corners - origin
    corners = np.concatenate([tri, np.zeros((len(tri), 1, 3))], axis=1)  # the apex o at the origin
    volumes = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])) / 6.0
    first = np.einsum("k,ki->i", volumes, corners.sum(axis=1)) / 4.0
    props = _from_moments(density, float(volumes.sum()), first, _simplex_second_moment(corners, volumes, 4))
    return MassProperties(props.mass, props.center + origin, props.inertia)


def mass_properties(mesh, density):
    """Mass properties from a density over the volume (closed mesh) or the area (open mesh, a shell).

    See :func:`solid_mass_properties` and :func:`shell_mass_properties` for the equations and sources.
    """
    return solid_mass_properties(mesh, density) if mesh.closed else shell_mass_properties(mesh, density)


# ------------------------------------------------------------------------------- samples and element frame
def surface_samples(mesh, dx):
    r"""Sample each triangle of ``mesh`` on a lattice of spacing at most ``dx`` in its edge frame.

    Triangle :math:`k` with corners :math:`\mathbf a, \mathbf b, \mathbf c` and longest edge :math:`L_k` is
    split into :math:`n_k^2` copies of itself scaled by :math:`1/n_k`, :math:`n_k = \lceil L_k/\Delta x \rceil`,
    and sampled at their corners,

    .. math:: \mathbf x_{kij} = \mathbf a + \frac{i}{n_k} (\mathbf b - \mathbf a)
              + \frac{j}{n_k} (\mathbf c - \mathbf a), \quad i, j \ge 0,\ i + j \le n_k ,

    so neighbouring samples are at most :math:`\Delta x` apart along each edge direction and every point of the
    triangle lies within :math:`L_k / (\sqrt 3\, n_k) \le \Delta x/\sqrt 3` of a sample.

    Source: Hu et al. 2018 and the authors' reference implementation (3D: a lattice with spacing :math:`\Delta x` in the
    triangle's edge frame; the paper, Hu et al. 2018 §4, samples the rigid elements to rasterise the colored distance
    field but gives no rule).

    Parameters
    ----------
    mesh : TriMesh
    dx : float                      grid spacing :math:`\Delta x`

    Returns
    -------
    x : (s, 3) float array          sample positions
    triangle : (s,) int array       index of the triangle each sample lies on
    """
    corners = mesh.corners
    edges = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2)
    n = np.maximum(np.ceil(edges.max(axis=1) / dx).astype(np.int64), 1)
    xs, owner = [], []
    for k in range(len(n)):  # one lattice per triangle: (n+1)(n+2)/2 points
        i, j = np.nonzero(np.add.outer(np.arange(n[k] + 1), np.arange(n[k] + 1)) <= n[k])
        a, b, c = corners[k]
        xs.append(a + np.outer(i / n[k], b - a) + np.outer(j / n[k], c - a))
        owner.append(np.full(len(i), k, dtype=np.int64))
    return np.concatenate(xs), np.concatenate(owner)


def triangle_frame(mesh, triangle, x):
    r"""Barycentric coordinates of the projection and signed normal offset of points in triangles' frames.

    With :math:`\mathbf r = \mathbf x - \mathbf a_k`, :math:`\mathbf e_1 = \mathbf b_k - \mathbf a_k`,
    :math:`\mathbf e_2 = \mathbf c_k - \mathbf a_k` and the unit normal :math:`\mathbf n_k`,

    .. math:: h = \mathbf r \cdot \mathbf n_k, \qquad
              \begin{pmatrix} \mathbf e_1\cdot\mathbf e_1 & \mathbf e_1\cdot\mathbf e_2 \\
                              \mathbf e_1\cdot\mathbf e_2 & \mathbf e_2\cdot\mathbf e_2 \end{pmatrix}
              \begin{pmatrix} \lambda_b \\ \lambda_c \end{pmatrix} =
              \begin{pmatrix} \mathbf r\cdot\mathbf e_1 \\ \mathbf r\cdot\mathbf e_2 \end{pmatrix}, \qquad
              \lambda_a = 1 - \lambda_b - \lambda_c .

    All three :math:`\lambda \ge 0` means the projection of :math:`\mathbf x` lies on the triangle;
    :math:`|h|` is then the distance to it.

    Source: Hu et al. 2018 §4 (distance and side of a node with respect to a boundary element), as the authors'
    reference implementation does (docs/cpic.md: barycentric coordinates and the signed normal offset).

    Parameters
    ----------
    mesh : TriMesh
    triangle : (s,) int array       triangle index per point
    x : (s, 3) float array          points

    Returns
    -------
    bary : (s, 3) float array       :math:`(\lambda_a, \lambda_b, \lambda_c)`
    h : (s,) float array
    """
    a, b, c = np.moveaxis(mesh.corners[triangle], 1, 0)
    e1, e2, r = b - a, c - a, x - a
    g11, g12, g22 = (np.einsum("ij,ij->i", p, q) for p, q in ((e1, e1), (e1, e2), (e2, e2)))
    r1, r2 = np.einsum("ij,ij->i", r, e1), np.einsum("ij,ij->i", r, e2)
    det = g11 * g22 - g12 * g12
    lam_b = (g22 * r1 - g12 * r2) / det
    lam_c = (g11 * r2 - g12 * r1) / det
    h = np.einsum("ij,ij->i", r, mesh.normals[triangle])
    return np.stack([1.0 - lam_b - lam_c, lam_b, lam_c], axis=1), h


# ------------------------------------------------------------------------------------------------ geometries
def rectangle(center, u, v, index=0, domain=None):
    r"""An open rectangle of two triangles: corners :math:`\mathbf c \pm \mathbf u \pm \mathbf v`.

    The normal is :math:`\mathbf u \times \mathbf v / |\mathbf u \times \mathbf v|` (side 0 is the side it
    points to).

    Parameters
    ----------
    center : (3,) floats            the rectangle's centre :math:`\mathbf c`
    u, v : (3,) floats              half-edge vectors (perpendicular for a rectangle)
    index, domain                   as in :func:`validate_trimesh`

    Returns
    -------
    TriMesh
    """
    c, u, v = (np.asarray(a, dtype=np.float64) for a in (center, u, v))
    vertices = [c - u - v, c + u - v, c + u + v, c - u + v]
    return validate_trimesh(vertices, [[0, 1, 2], [0, 2, 3]], closed=False, index=index, domain=domain)


def box(lower, upper, index=0, domain=None):
    """A closed, outward-oriented box ``[lower, upper]`` of 12 triangles (two per face).

    Parameters
    ----------
    lower, upper : (3,) floats      opposite corners, ``lower < upper``
    index, domain                   as in :func:`validate_trimesh`

    Returns
    -------
    TriMesh
    """
    lower, upper = np.asarray(lower, dtype=np.float64), np.asarray(upper, dtype=np.float64)
    bits = np.array([[(k >> 2) & 1, (k >> 1) & 1, k & 1] for k in range(8)])  # corner k = 4 i + 2 j + l
    vertices = np.where(bits == 1, upper, lower)
    triangles = []
    for a in range(3):
        b, c = (a + 1) % 3, (a + 2) % 3  # e_b x e_c = e_a: counter-clockwise in (b, c) faces +a
        for side in (0, 1):
            quad = []
            for ub, uc in ((0, 0), (1, 0), (1, 1), (0, 1)):
                corner = np.zeros(3, dtype=np.int64)
                corner[[a, b, c]] = side, ub, uc
                quad.append(int(corner @ [4, 2, 1]))
            quad = quad if side == 1 else quad[::-1]
            triangles += [[quad[0], quad[1], quad[2]], [quad[0], quad[2], quad[3]]]
    return validate_trimesh(vertices, triangles, closed=True, index=index, domain=domain)


def crossed_blades(center, half_width, half_height, up=1, domain=None):
    """Two perpendicular zero-thickness blades crossing on the vertical line through ``center`` (3D cut).

    Both blades are upright rectangles ``2 half_width`` wide and ``2 half_height`` tall, each of two
    triangles, centred on ``center``; with ``up = 1`` (the y axis up, gravity along -y), blade 0 lies in the
    plane ``x = center[0]`` (normal +x) and blade 1 in the plane ``z = center[2]`` (normal +z). A body falling
    onto the crossing is cut into four pieces. They are two separate bodies: one body has one side bit per
    node, which cannot tell four quadrants apart.

    Parameters
    ----------
    center : (3,) floats            the crossing's midpoint
    half_width, half_height : float half extents of each blade across and along the ``up`` axis
    up : int                        the vertical axis (0, 1 or 2)
    domain : (lo, hi) or None       the box the blades must lie in, as in :func:`validate_trimesh`

    Returns
    -------
    [TriMesh, TriMesh]              rigid bodies 0 and 1
    """
    axes = [a for a in range(3) if a != up]
    vertical = half_height * np.eye(3)[up]
    blades = []
    for index, normal_axis in enumerate(axes):
        across = [a for a in axes if a != normal_axis][0]
        u = half_width * np.eye(3)[across]
        # u x v must point along +normal_axis: order the two half-edges by the cyclic axis order
        u, v = (u, vertical) if (across - normal_axis) % 3 == 1 else (vertical, u)
        blades.append(rectangle(center, u, v, index=index, domain=domain))
    return blades
