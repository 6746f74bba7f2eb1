"""CPIC in 3D: triangle-mesh rigid bodies (validation, mass properties, surface samples, element frame, meshio)
and the colored distance field, tags and reconstruction of a triangle — the CPIC acceptance tests 1–3 in 3D."""

import meshio
import numpy as np
import pytest

from mpmref.errors import SceneError
from mpmref.physics.cdf import build_cdf, compatible, reconstruct, update_tags
from mpmref.rigid.trimesh import (
    box,
    crossed_blades,
    mass_properties,
    read_trimesh,
    rectangle,
    shell_mass_properties,
    signed_volume,
    solid_mass_properties,
    surface_samples,
    triangle_frame,
    validate_trimesh,
)

DX = 1.0 / 32
SHAPE = (33, 33, 33)  # nodes of a 32^3 grid on the unit cube
ORIGIN = (0.0, 0.0, 0.0)
# an oblique triangle (no edge or normal along a grid axis)
OBLIQUE = np.array([[0.27, 0.31, 0.42], [0.71, 0.44, 0.58], [0.38, 0.69, 0.36]])


@pytest.fixture(scope="module")
def oblique():
    return validate_trimesh(OBLIQUE, [[0, 1, 2]])


@pytest.fixture(scope="module")
def oblique_field(oblique):
    return build_cdf([oblique], SHAPE, ORIGIN, DX)


def tags_for(field, x):
    """Tags of fresh particles (no previous tags)."""
    none = np.zeros((len(x), len(field.A[0])), dtype=bool)
    return update_tags(field, np.asarray(x, dtype=float), none, none)


def plane_offset(points, corners):
    """Signed distance to the plane of a triangle, normal by the right-hand rule (computed independently)."""
    n = np.cross(corners[1] - corners[0], corners[2] - corners[0])
    return (points - corners[0]) @ (n / np.linalg.norm(n))


def projection_inside(points, corners):
    """Whether the projection of each point onto the triangle's plane lies in the triangle (same-side test)."""
    n = np.cross(corners[1] - corners[0], corners[2] - corners[0])
    signs = [np.cross(corners[(k + 1) % 3] - corners[k], points - corners[k]) @ n for k in range(3)]
    return np.all(np.array(signs) >= 0, axis=0)


# ------------------------------------------------------------------------------------------ element frame
def test_triangle_frame_of_corners_centroid_and_offsets(oblique):
    n = oblique.normals[0]
    centroid = OBLIQUE.mean(axis=0)
    x = np.vstack([OBLIQUE, centroid + 0.7 * n, centroid - 0.2 * n])
    bary, h = triangle_frame(oblique, np.zeros(len(x), dtype=np.int64), x)
    assert np.allclose(bary[:3], np.eye(3), atol=1e-14)
    assert np.allclose(bary[3:], 1 / 3, atol=1e-14)
    assert np.allclose(h, [0, 0, 0, 0.7, -0.2], atol=1e-14)
    # the barycentric coordinates rebuild the projected point
    assert np.allclose(bary @ OBLIQUE, x - h[:, None] * n, atol=1e-14)


def test_surface_samples_are_a_lattice_that_covers_the_triangle(oblique):
    dx = 0.05
    x, tri = surface_samples(oblique, dx)
    longest = max(np.linalg.norm(OBLIQUE[k] - OBLIQUE[k - 1]) for k in range(3))
    n = int(np.ceil(longest / dx))
    assert len(x) == (n + 1) * (n + 2) // 2 and np.all(tri == 0)
    bary, h = triangle_frame(oblique, tri, x)
    assert np.allclose(h, 0, atol=1e-14) and np.all(bary >= -1e-14)
    # lattice in the edge frame: barycentric coordinates are multiples of 1/n, spacing <= dx along each edge
    assert np.allclose(bary * n, np.round(bary * n), atol=1e-9)
    assert longest / n <= dx
    # every point of the triangle is within longest/(sqrt(3) n) of a sample
    w = np.random.default_rng(0).dirichlet([1, 1, 1], 4000)
    gap = np.min(np.linalg.norm((w @ OBLIQUE)[:, None] - x[None], axis=2), axis=1)
    assert gap.max() <= longest / (np.sqrt(3) * n) + 1e-12


# -------------------------------------------------------------------------------- acceptance test 1 (3D)
def test_cdf_of_a_horizontal_triangle():
    """CPIC acceptance test 1 in 3D: a triangle in the plane y = 0.5 (normal +y). Nodes within 1 dx of the plane
    whose projection is in the triangle have A = 1, d = |y - 0.5|, T = [y < 0.5]; nodes more than 2 dx away or
    whose projection is outside have A = 0."""
    corners = np.array([[0.25, 0.5, 0.25], [0.25, 0.5, 0.75], [0.75, 0.5, 0.25]])
    field = build_cdf([validate_trimesh(corners, [[0, 1, 2]])], SHAPE, ORIGIN, DX)
    xi = field.node_positions()
    dist = np.abs(xi[:, 1] - 0.5)
    inside = (xi[:, 0] >= 0.25 - 1e-12) & (xi[:, 2] >= 0.25 - 1e-12) & (xi[:, 0] + xi[:, 2] <= 1.0 + 1e-12)
    band = inside & (dist <= DX + 1e-12)
    assert band.sum() == 3 * 17 * 18 // 2  # 3 node layers of the 17-node-sided triangle
    assert np.all(field.A[band, 0])
    assert np.allclose(field.d[band], dist[band], rtol=0, atol=1e-6)
    assert np.array_equal(field.T[band, 0], xi[band, 1] < 0.5)
    assert np.all(field.body[band] == 0)
    assert not np.any(field.A[dist > 2 * DX, 0]) and not np.any(field.A[~inside, 0])


def test_cdf_of_an_oblique_triangle_is_the_distance_to_its_plane(oblique_field):
    """Every rasterised node projects into the triangle, with d = its analytic distance to the plane and
    T = [below the plane]; every node within 0.9 dx of the plane that projects into the triangle is rasterised
    (a sample lies within dx/sqrt(3) of its projection, so the node is within 1.5 dx of it along each axis)."""
    xi = oblique_field.node_positions()
    offset = plane_offset(xi, OBLIQUE)
    inside = projection_inside(xi, OBLIQUE)
    A = oblique_field.A[:, 0]
    assert A.sum() > 100
    assert np.all(inside[A])
    assert np.allclose(oblique_field.d[A], np.abs(offset[A]), rtol=0, atol=1e-12)
    assert np.array_equal(oblique_field.T[A, 0], offset[A] < 0)
    assert np.all(A[inside & (np.abs(offset) <= 0.9 * DX)])
    assert np.all(np.abs(offset[A]) <= 1.5 * np.sqrt(3) * DX)
    assert np.all(np.isinf(oblique_field.d[~A])) and np.all(oblique_field.body[~A] == -1)


# -------------------------------------------------------------------------------- acceptance test 2 (3D)
@pytest.mark.parametrize("weights", [(1 / 3, 1 / 3, 1 / 3), (0.6, 0.25, 0.15), (0.2, 0.2, 0.6)])
def test_reconstruction_above_the_triangle(oblique, oblique_field, weights):
    """CPIC acceptance test 2 in 3D: a particle 0.3 dx above the triangle gets T = 0, |phi - 0.3 dx| < 0.05 dx
    and a normal within 2 degrees of the triangle's."""
    n = oblique.normals[0]
    x = (np.array(weights) @ OBLIQUE + 0.3 * DX * n)[None]
    A_p, T_p = tags_for(oblique_field, x)
    assert A_p[0, 0] and not T_p[0, 0]
    phi, normal, near = reconstruct(oblique_field, x, A_p, T_p)
    assert near[0]
    assert abs(phi[0] - 0.3 * DX) < 0.05 * DX
    assert np.degrees(np.arccos(np.clip(normal[0] @ n, -1, 1))) < 2.0


# -------------------------------------------------------------------------------- acceptance test 3 (3D)
def test_tag_persists_when_forced_below_the_triangle(oblique, oblique_field):
    """CPIC acceptance test 3 in 3D: forced to 0.3 dx below without re-tagging, the particle keeps T = 0, gets
    phi < 0 (the penalty would engage) and a normal still pointing to its own side; the sticky update keeps it."""
    n = oblique.normals[0]
    above = (OBLIQUE.mean(axis=0) + 0.3 * DX * n)[None]
    A_p, T_p = tags_for(oblique_field, above)
    below = above - 0.6 * DX * n
    phi, normal, near = reconstruct(oblique_field, below, A_p, T_p)
    assert not T_p[0, 0] and near[0]
    assert phi[0] < 0 and abs(phi[0] + 0.3 * DX) < 0.05 * DX
    assert normal[0] @ n > np.cos(np.radians(2.0))
    A_q, T_q = update_tags(oblique_field, below, A_p, T_p)
    assert A_q[0, 0] and not T_q[0, 0]
    # recomputing the tag from scratch (the broken variant) would put it on side 1
    assert tags_for(oblique_field, below)[1][0, 0]


# -------------------------------------------------------------------------------------- crossed blades
def test_crossed_blades_separate_four_quadrants():
    """The 3D cut geometry: two upright blades crossing on the line x = z = 0.5. Particles in the four
    quadrants next to the crossing get four different tag pairs, and a particle is compatible only with the
    nodes of its own quadrant among those near both blades."""
    blades = crossed_blades([0.5, 0.5, 0.5], half_width=0.25, half_height=0.2, up=1, domain=([0] * 3, [1] * 3))
    assert [b.closed for b in blades] == [False, False] and [len(b.triangles) for b in blades] == [2, 2]
    assert np.allclose(blades[0].normals, [1, 0, 0]) and np.allclose(blades[1].normals, [0, 0, 1])
    assert np.allclose(blades[0].vertices[:, 0], 0.5) and np.allclose(blades[1].vertices[:, 2], 0.5)
    assert np.allclose(np.ptp(blades[0].vertices, axis=0), [0, 0.4, 0.5])
    field = build_cdf(blades, SHAPE, ORIGIN, DX)
    signs = np.array([[1, 1], [1, -1], [-1, 1], [-1, -1]])
    x = np.stack([0.5 + 0.4 * DX * signs[:, 0], np.full(4, 0.5 + 0.13 * DX), 0.5 + 0.4 * DX * signs[:, 1]], axis=1)
    A_p, T_p = tags_for(field, x)
    assert A_p.all()
    assert np.array_equal(T_p, signs < 0)  # side 1 is below each blade's normal
    xi = field.node_positions()
    both = field.A.all(axis=1)
    c = compatible(field.A[both][:, None], field.T[both][:, None], A_p[None], T_p[None])
    quadrant = np.stack([xi[both, 0] < 0.5, xi[both, 2] < 0.5], axis=1)
    assert np.array_equal(c, np.all(quadrant[:, None] == T_p[None], axis=2))


# ---------------------------------------------------------------------------------------- mass properties
def rotation(axis, angle):
    """Rotation matrix about a unit axis (Rodrigues)."""
    k = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def test_unit_cube_solid_and_shell():
    """Solid unit cube of density rho: m = rho, I = m/6 * 1 about its centre. Thin-walled unit cube (area
    density rho): m = 6 rho, I = 5/18 m * 1 (each face's plate inertia plus the parallel-axis terms)."""
    cube = box([0, 0, 0], [1, 1, 1])
    assert cube.closed and signed_volume(cube) == pytest.approx(1.0, rel=1e-14)
    solid = mass_properties(cube, 3.0)
    assert solid.mass == pytest.approx(3.0, rel=1e-14)
    assert np.allclose(solid.center, 0.5, atol=1e-14)
    assert np.allclose(solid.inertia, 3.0 / 6 * np.eye(3), atol=1e-13)
    shell = shell_mass_properties(cube, 3.0)
    assert shell.mass == pytest.approx(18.0, rel=1e-14)
    assert np.allclose(shell.inertia, 5 / 18 * 18.0 * np.eye(3), atol=1e-13)


def test_rotated_translated_box_inertia():
    """A box a x b x c of density rho: I = m/12 diag(b² + c², a² + c², a² + b²) in its frame; rotated by R and
    moved, the centre moves with it and the tensor becomes R I Rᵀ."""
    a, b, c, rho = 0.3, 0.5, 0.8, 7.0
    body = box([0, 0, 0], [a, b, c])
    R = rotation([1, 2, 3], 0.7)
    shift = np.array([0.2, -0.1, 0.4])
    moved = validate_trimesh(body.vertices @ R.T + shift, body.triangles, closed=True)
    props = solid_mass_properties(moved, rho)
    m = rho * a * b * c
    assert props.mass == pytest.approx(m, rel=1e-13)
    assert np.allclose(props.center, R @ [a / 2, b / 2, c / 2] + shift, atol=1e-14)
    expected = R @ np.diag([b * b + c * c, a * a + c * c, a * a + b * b]) * m / 12 @ R.T
    assert np.allclose(props.inertia, expected, rtol=0, atol=1e-13 * m)


def test_tetrahedron_solid():
    """Solid tetrahedron (0, e_x, e_y, e_z): V = 1/6, centre (1/4, 1/4, 1/4), and about the centre
    I_xx = 3m/40, I_xy = +m/80 (Tonon 2004's closed forms for this tetrahedron)."""
    vertices = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]
    tet = validate_trimesh(vertices, [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]], closed=True)
    rho = 2.5
    mass, center, inertia = mass_properties(tet, rho)
    m = rho / 6
    assert mass == pytest.approx(m, rel=1e-14)
    assert np.allclose(center, 0.25, atol=1e-15)
    expected = m * (3 / 40 * np.eye(3) + (1 - np.eye(3)) / 80)
    assert np.allclose(inertia, expected, rtol=0, atol=1e-15)


def test_thin_rectangular_plate():
    """An open rectangle a x b (two triangles) of area density rho in the xy plane: m = rho a b and
    I = m/12 diag(b², a², a² + b²) (thin-plate formulas)."""
    a, b, rho = 0.6, 0.2, 4.0
    plate = rectangle([0.1, 0.2, 0.3], [a / 2, 0, 0], [0, b / 2, 0])
    props = mass_properties(plate, rho)
    m = rho * a * b
    assert props.mass == pytest.approx(m, rel=1e-14)
    assert np.allclose(props.center, [0.1, 0.2, 0.3], atol=1e-15)
    assert np.allclose(props.inertia, m / 12 * np.diag([b * b, a * a, a * a + b * b]), rtol=0, atol=1e-15)
    with pytest.raises(ValueError, match="closed"):
        solid_mass_properties(plate, rho)


# ---------------------------------------------------------------------------------------------- refusals
CUBE = box([0, 0, 0], [1, 1, 1])


@pytest.mark.parametrize("vertices, triangles, closed, field_name, words", [
    ([[0, 0, 0], [1, 0, 0], [0.5, 0, 0]], [[0, 1, 2]], False, "triangles", "degenerate"),     # collinear
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 1]], False, "triangles", "degenerate"),       # repeated vertex
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 3]], False, "triangles", "vertex indices"),   # out of range
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0.0, 1.0, 2.0]], False, "triangles", "integer"),    # not integers
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], [[0, 1, 2], [1, 2, 3]], False,             # flipped neighbour
     "triangles", "consistently oriented"),
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], [[0, 2, 1], [0, 1, 3], [0, 3, 2]], True,   # open, declared closed
     "closed", "watertight"),
    (CUBE.vertices, CUBE.triangles[:, ::-1], True, "triangles", "oriented outward"),        # inward
    ([[0, 0], [1, 0], [0, 1]], [[0, 1, 2]], False, "vertices", "(n, 3)"),                   # 2D vertices
    ([[0, 0, 0], [np.inf, 0, 0], [0, 1, 0]], [[0, 1, 2]], False, "vertices", "finite"),
    ([[0, 0, 0], [1, 0, 0], [0, 1.5, 0]], [[0, 1, 2]], False, "vertices", "inside the domain"),  # outside
])
def test_validation_errors_name_the_field(vertices, triangles, closed, field_name, words):
    with pytest.raises(SceneError) as info:
        validate_trimesh(vertices, triangles, closed=closed, index=4, domain=([-0.1] * 3, [1.1] * 3))
    assert info.value.field == f"rigid_bodies[4].{field_name}"
    assert words in str(info.value)


def test_an_open_mesh_and_a_mesh_without_a_domain_are_accepted():
    open_tet = validate_trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], [[0, 2, 1], [0, 1, 3], [0, 3, 2]])
    assert not open_tet.closed
    far = validate_trimesh([[5, 0, 0], [6, 0, 0], [5, 1, 0]], [[0, 1, 2]])
    assert np.allclose(far.normals, [0, 0, 1])


# ---------------------------------------------------------------------------------------------- meshio
@pytest.mark.parametrize("name, options", [("cube.obj", {}), ("cube.stl", {"binary": True})])
def test_meshio_round_trip(tmp_path, name, options):
    """A closed box written with meshio and read back (relative to base_dir) is the same watertight,
    outward body: same volume and mass properties."""
    body = box([0.1, 0.2, 0.3], [0.4, 0.6, 0.9])
    meshio.write_points_cells(tmp_path / name, body.vertices, [("triangle", body.triangles)], **options)
    read = read_trimesh(name, closed=True, index=2, domain=([0] * 3, [1] * 3), base_dir=tmp_path)
    assert read.closed and len(read.triangles) == 12 and len(read.vertices) == 8
    assert signed_volume(read) == pytest.approx(0.3 * 0.4 * 0.6, rel=1e-6)
    p, q = mass_properties(read, 2.0), mass_properties(body, 2.0)
    assert p.mass == pytest.approx(q.mass, rel=1e-6)
    assert np.allclose(p.center, q.center, atol=1e-7) and np.allclose(p.inertia, q.inertia, atol=1e-7)


def test_meshio_refusals_name_the_mesh_field(tmp_path):
    with pytest.raises(SceneError) as info:
        read_trimesh(tmp_path / "missing.obj", index=1)
    assert info.value.field == "rigid_bodies[1].mesh"
    points = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
    meshio.write_points_cells(tmp_path / "tet.vtk", points, [("tetra", np.array([[0, 1, 2, 3]]))])
    with pytest.raises(SceneError, match="tetra cells") as info:
        read_trimesh(tmp_path / "tet.vtk", index=1)
    assert info.value.field == "rigid_bodies[1].mesh"
    quads = np.array([[0, 1, 2, 3]])
    meshio.write_points_cells(tmp_path / "quad.obj", points, [("triangle", np.array([[0, 2, 1]])), ("quad", quads)])
    with pytest.raises(SceneError, match="quad cells; triangulate") as info:
        read_trimesh(tmp_path / "quad.obj", index=1)
    meshio.write_points_cells(tmp_path / "open.obj", points, [("triangle", np.array([[0, 2, 1], [0, 1, 3]]))])
    with pytest.raises(SceneError, match="watertight") as info:
        read_trimesh(tmp_path / "open.obj", closed=True, index=1)
    assert info.value.field == "rigid_bodies[1].mesh" and "rigid_bodies[1].closed" in str(info.value)
