"""CPIC foundations (docs/cpic.md): rigid polylines, the colored distance field, particle tags with sticky side
memory, compatibility and the least-squares distance/normal — the CPIC acceptance tests 1–3 and properties
around them."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from mpmref.errors import SceneError
from mpmref.physics.cdf import build_cdf, compatible, reconstruct, update_tags
from mpmref.rigid.polyline import segment_frame, surface_samples, validate_polyline

DX = 1.0 / 64
SHAPE = (65, 65)  # nodes of a 64 x 64 grid on the unit square
ORIGIN = (0.0, 0.0)


def horizontal_segment(x0=0.25, x1=0.75, y=0.5):
    return validate_polyline([[x0, y], [x1, y]], [[0, 1]])


@pytest.fixture(scope="module")
def field():
    return build_cdf([horizontal_segment()], SHAPE, ORIGIN, DX)


def tags_for(field, x):
    """Tags of fresh particles (no previous tags)."""
    none = np.zeros((len(x), 1), dtype=bool)
    return update_tags(field, np.asarray(x, dtype=float), none, none)


# ----------------------------------------------------------------------------------------- geometry
def test_surface_samples_are_midpoints_of_equal_pieces():
    body = validate_polyline([[0.0, 0.0], [0.1, 0.0], [0.1, 0.005]], [[0, 1], [1, 2]])
    x, seg = surface_samples(body, dx=0.01)
    # segment 0: len 0.1 -> 10 pieces; segment 1: len 0.005 -> max(1, 2) = 2 pieces
    assert np.array_equal(seg, [0] * 10 + [1] * 2)
    assert np.allclose(x[:10, 0], (np.arange(10) + 0.5) * 0.01) and np.allclose(x[:10, 1], 0.0)
    assert np.allclose(x[10:], [[0.1, 0.00125], [0.1, 0.00375]])
    s, h = segment_frame(body, seg, x)
    assert np.allclose(h, 0.0, atol=1e-15) and np.all((s > 0) & (s < 1))


@pytest.mark.parametrize("vertices, segments, closed, field_name", [
    ([[0, 0], [1, 0]], [[0, 0]], False, "rigid_bodies[3].segments"),                      # zero length (self-loop)
    ([[0, 0], [1, 0], [0, 0]], [[0, 1], [1, 2], [0, 2]], False, "rigid_bodies[3].segments"),  # coincident vertices
    ([[0, 0], [1, 0]], [[0, 2]], False, "rigid_bodies[3].segments"),                      # index out of range
    ([[0, 0], [1, 0]], [[-1, 1]], False, "rigid_bodies[3].segments"),                     # negative index
    ([[0, 0], [1, 0]], [[0.0, 1.0]], False, "rigid_bodies[3].segments"),                  # not integers
    ([[0, 0], [1, 0], [1, 1]], [[0, 1], [1, 2]], True, "rigid_bodies[3].closed"),         # open, declared closed
    ([[0, 0], [1, 0, 2]], [[0, 1]], False, "rigid_bodies[3].vertices"),                   # ragged
    ([[0, 0], [np.nan, 0]], [[0, 1]], False, "rigid_bodies[3].vertices"),                 # not finite
])
def test_validation_errors_name_the_field(vertices, segments, closed, field_name):
    with pytest.raises(SceneError) as info:
        validate_polyline(vertices, segments, closed=closed, index=3)
    assert info.value.field == field_name
    assert field_name in str(info.value)


def test_a_closed_polyline_is_accepted():
    body = validate_polyline([[0, 0], [1, 0], [1, 1], [0, 1]], [[0, 1], [1, 2], [2, 3], [3, 0]], closed=True)
    assert body.closed and body.segments.shape == (4, 2)


# -------------------------------------------------------------------------------- acceptance test 1
def test_cdf_of_a_segment(field):
    """CPIC acceptance test 1: in the band inside the segment's x-range A = 1, d = |y - 0.5|, T = [y < 0.5];
    nodes more than 2 dx away have A = 0."""
    xi = field.node_positions()
    dist = np.abs(xi[:, 1] - 0.5)
    band = (dist <= 1.0 * DX + 1e-12) & (xi[:, 0] >= 0.25 - 1e-12) & (xi[:, 0] <= 0.75 + 1e-12)
    assert band.sum() == 3 * 33
    assert np.all(field.A[band, 0])
    assert np.allclose(field.d[band], dist[band], rtol=0, atol=1e-6)
    assert np.array_equal(field.T[band, 0], xi[band, 1] < 0.5)
    assert np.all(field.body[band] == 0)
    far = dist > 2 * DX
    assert not field.A[far, 0].any()
    # and nodes beyond the ends (further than 2 dx along x) are untouched too
    assert not field.A[(xi[:, 0] < 0.25 - 2 * DX) | (xi[:, 0] > 0.75 + 2 * DX), 0].any()


@given(ax=st.floats(0.2, 0.8), ay=st.floats(0.2, 0.8), angle=st.floats(0.0, 2 * np.pi),
       length=st.floats(0.05, 0.3))
def test_cdf_distance_is_the_point_segment_distance(ax, ay, angle, length):
    """For every banded node whose projection lies on the segment, d equals the analytic point-segment distance
    and T says whether the node lies to the right of a -> b."""
    a = np.array([ax, ay])
    b = a + length * np.array([np.cos(angle), np.sin(angle)])
    f = build_cdf([validate_polyline([a, b], [[0, 1]])], SHAPE, ORIGIN, DX)
    xi = f.node_positions()
    e = b - a
    s = (xi - a) @ e / (e @ e)
    on = f.A[:, 0] & (s >= 0) & (s <= 1)
    foot = a + np.clip(s, 0, 1)[:, None] * e
    exact = np.linalg.norm(xi - foot, axis=1)
    assert on.sum() > 0
    assert np.allclose(f.d[on], exact[on], rtol=0, atol=1e-12)
    cross = e[0] * (xi[:, 1] - a[1]) - e[1] * (xi[:, 0] - a[0])  # > 0: left of a -> b
    assert np.array_equal(f.T[on, 0], cross[on] < 0)
    # the band: stencil nodes of samples, at most 1.5 dx per axis from a sample on the segment
    assert np.all(f.d[f.A[:, 0]] <= 1.5 * np.sqrt(2) * DX + 1e-12)


# -------------------------------------------------------------------------------- acceptance test 2
def test_reconstruction_above_the_segment(field):
    """CPIC acceptance test 2: a particle 0.3 dx above gets T = 0, |phi - 0.3 dx| < 0.05 dx, n within 2° of +y."""
    x = np.array([[0.5 + 0.37 * DX, 0.5 + 0.3 * DX]])
    A_p, T_p = tags_for(field, x)
    assert A_p[0, 0] and not T_p[0, 0]
    phi, normal, near = reconstruct(field, x, A_p, T_p)
    assert near[0]
    assert abs(phi[0] - 0.3 * DX) < 0.05 * DX
    angle = np.degrees(np.arccos(np.clip(normal[0] @ [0.0, 1.0], -1, 1)))
    assert angle < 2.0


# -------------------------------------------------------------------------------- acceptance test 3
def test_tag_persists_when_forced_below(field):
    """CPIC acceptance test 3: forced to 0.3 dx below without re-tagging, the particle keeps T = 0 and gets
    phi < 0 (the penalty would engage)."""
    above = np.array([[0.5 + 0.37 * DX, 0.5 + 0.3 * DX]])
    A_p, T_p = tags_for(field, above)
    below = above - [0.0, 0.6 * DX]
    phi, normal, near = reconstruct(field, below, A_p, T_p)
    assert not T_p[0, 0] and near[0]
    assert phi[0] < 0
    assert abs(phi[0] + 0.3 * DX) < 0.05 * DX
    # the normal still points to the particle's own side (+y)
    assert normal[0] @ [0.0, 1.0] > np.cos(np.radians(2.0))
    # update_tags (the sticky rule) does not change the tag either
    A_q, T_q = update_tags(field, below, A_p, T_p)
    assert A_q[0, 0] and not T_q[0, 0]


# ------------------------------------------------------------------------------------- sticky tags
def test_tags_are_sticky_while_recomputing_them_would_flip_the_side(field):
    """A particle walks down through the segment in 0.1 dx steps. The sticky rule keeps T = 0 all the way (its
    distance turns negative: it is seen as having penetrated); recomputing the tag from scratch each step (the
    broken variant) flips it to T = 1 once below, so the particle would be treated as belonging there."""
    ys = 0.5 + DX * np.arange(0.9, -0.95, -0.1)
    x = np.stack([np.full_like(ys, 0.5 + 0.21 * DX), ys], axis=1)
    A_s, T_s = tags_for(field, x[:1])
    sticky_T, fresh_T, sticky_phi = [], [], []
    for xp in x:
        A_s, T_s = update_tags(field, xp[None], A_s, T_s)
        sticky_T.append(T_s[0, 0])
        sticky_phi.append(reconstruct(field, xp[None], A_s, T_s)[0][0])
        A_f, T_f = tags_for(field, xp[None])
        fresh_T.append(T_f[0, 0])
    assert not any(sticky_T)
    assert any(fresh_T) and fresh_T[-1]
    below = ys < 0.5 - 0.05 * DX
    assert np.all(np.array(sticky_phi)[below] < 0)


def test_tags_clear_when_the_body_is_left_and_are_recomputed_on_return(field):
    x = np.array([[0.5, 0.5 + 0.3 * DX]])
    A_p, T_p = tags_for(field, x)
    assert A_p[0, 0] and not T_p[0, 0]
    far_below = np.array([[0.5, 0.5 - 4 * DX]])
    A_p, T_p = update_tags(field, far_below, A_p, T_p)
    assert not A_p[0, 0] and not T_p[0, 0]
    phi, normal, near = reconstruct(field, far_below, A_p, T_p)
    assert not near[0] and phi[0] == 0 and np.all(normal[0] == 0)
    back_below = np.array([[0.5, 0.5 - 0.3 * DX]])
    A_p, T_p = update_tags(field, back_below, A_p, T_p)
    assert A_p[0, 0] and T_p[0, 0]  # approached from below this time: side 1


def test_two_bodies_tag_independently():
    bodies = [horizontal_segment(y=0.5), validate_polyline([[0.5 + 0.5 * DX, 0.3], [0.5 + 0.5 * DX, 0.7]], [[1, 0]])]
    f = build_cdf(bodies, SHAPE, ORIGIN, DX)
    # near the crossing, in the quadrant above the horizontal one and left of the vertical one (pointing -y,
    # whose left normal is +x, so "left" in x is h < 0: T = 1)
    x = np.array([[0.5 + 0.1 * DX, 0.5 + 0.3 * DX]])
    A_p, T_p = tags_for(f, x)
    assert A_p[0].tolist() == [True, True]
    assert T_p[0].tolist() == [False, True]


# -------------------------------------------------------------------------------------- compatibility
def test_compatibility_cases():
    t, f = True, False
    # no shared body: compatible whatever the sides
    assert compatible([t, f], [t, f], [f, t], [f, t])
    assert compatible([f, f], [f, f], [f, f], [f, f])
    # shared body, same side / other side
    assert compatible([t], [t], [t], [t]) and compatible([t], [f], [t], [f])
    assert not compatible([t], [t], [t], [f]) and not compatible([t], [f], [t], [t])
    # two shared bodies: one differing side is enough to be incompatible
    assert not compatible([t, t], [f, t], [t, t], [f, f])
    # a side bit of a body the other record is not near does not count
    assert compatible([t, t], [f, t], [t, f], [f, f])


bits = st.lists(st.booleans(), min_size=4, max_size=4)


@given(A_i=bits, T_i=bits, A_p=bits, T_p=bits)
def test_compatibility_is_symmetric_and_ignores_unshared_sides(A_i, T_i, A_p, T_p):
    A_i, T_i, A_p, T_p = map(np.array, (A_i, T_i, A_p, T_p))
    c = compatible(A_i, T_i, A_p, T_p)
    assert c == compatible(A_p, T_p, A_i, T_i)
    shared = A_i & A_p
    assert c == compatible(A_i, np.where(shared, T_i, ~T_i), A_p, T_p)  # unshared side bits are irrelevant
    assert c == bool(np.all(T_i[shared] == T_p[shared]))


def test_compatibility_broadcasts_over_nodes_and_particles(field):
    x = np.array([[0.5, 0.5 + 0.3 * DX], [0.5, 0.5 - 0.3 * DX]])
    A_p, T_p = tags_for(field, x)
    c = compatible(field.A[:, None, :], field.T[:, None, :], A_p[None], T_p[None])
    assert c.shape == (len(field.d), 2)
    xi = field.node_positions()
    banded = field.A[:, 0]
    # particle 0 (above) is compatible with banded nodes at y >= 0.5, particle 1 (below) with those at y < 0.5
    assert np.array_equal(c[banded, 0], xi[banded, 1] >= 0.5)
    assert np.array_equal(c[banded, 1], xi[banded, 1] < 0.5)
    assert np.all(c[~banded])


# ------------------------------------------------------------------------------ reconstruction rules
def synthetic_field(T_node):
    """A 2-body field on an 8 x 8 unit grid where every node is near both bodies with d_i = y_i + 1 (a linear
    field) and the side bits ``T_node`` everywhere except node (3, 4), which gets the bits given per call."""
    from mpmref.physics.cdf import ColoredDistanceField

    shape = (8, 8)
    idx = np.indices(shape).reshape(2, -1).T
    A = np.ones((64, 2), dtype=bool)
    T = np.zeros((64, 2), dtype=bool)
    T[np.ravel_multi_index((3, 4), shape)] = T_node
    return ColoredDistanceField(d=idx[:, 1] + 1.0, body=np.zeros(64, dtype=np.int64), A=A, T=T, shape=shape,
                                origin=np.zeros(2), dx=1.0)


def test_reconstruction_targets_compatible_one_differing_and_skipped_nodes():
    x = np.array([[3.2, 3.9]])
    A_p, T_p = np.ones((1, 2), dtype=bool), np.zeros((1, 2), dtype=bool)
    # all compatible: the linear field d = y + 1 is fitted exactly
    phi, normal, near = reconstruct(synthetic_field([False, False]), x, A_p, T_p)
    assert near[0] and np.isclose(phi[0], 4.9) and np.allclose(normal[0], [0.0, 1.0])
    # both shared sides differ at node (3, 4): skipped, the rest is still linear, same fit
    phi2, normal2, _ = reconstruct(synthetic_field([True, True]), x, A_p, T_p)
    assert np.isclose(phi2[0], 4.9) and np.allclose(normal2[0], [0.0, 1.0])
    # exactly one differs: the node's target becomes -d, which changes the fit
    phi1, _, _ = reconstruct(synthetic_field([True, False]), x, A_p, T_p)
    assert phi1[0] < 4.9 - 0.1
    # untagged particles are not fitted
    phi0, normal0, near0 = reconstruct(synthetic_field([False, False]), x, np.zeros((1, 2), bool), T_p)
    assert not near0[0] and phi0[0] == 0 and np.all(normal0 == 0)


def test_nearest_body_id():
    bodies = [horizontal_segment(y=0.5), horizontal_segment(y=0.5 + 2 * DX)]
    f = build_cdf(bodies, SHAPE, ORIGIN, DX)
    xi = f.node_positions()
    mid = np.isclose(xi[:, 0], 0.5)
    for y, body in ((0.5 - DX, 0), (0.5, 0), (0.5 + 2 * DX, 1), (0.5 + 3 * DX, 1)):
        i = np.nonzero(mid & np.isclose(xi[:, 1], y))[0][0]
        assert f.body[i] == body
    i = np.nonzero(mid & np.isclose(xi[:, 1], 0.5 + DX))[0][0]  # equally near both: the lower id
    assert f.body[i] == 0 and f.A[i].all() and f.T[i].tolist() == [False, True]
