"""Grid-node velocity projection at walls and colliders (mpmref.physics.boundary, talk Eq. 25).

All expected velocities are worked out by hand in each test (numbers, not calls to the module).
Notation: n is the unit normal pointing into the material, v_n = (v - v_co).n, v_t = (v - v_co) - v_n n.
"""

import numpy as np
import pytest

from mpmref.physics.boundary import BOUNDARY_TYPES, project_velocity

ATOL = 1e-14

# floor wall in 2D, normal +y (material above). Approaching means v_y < 0.
N_UP = np.array([[0.0, 1.0]])
# a slanted 3D wall, normal (0.6, 0, 0.8) (unit length)
N_SLANT = np.array([[0.6, 0.0, 0.8]])


def _proj(v, n, kind, **kw):
    return project_velocity(np.atleast_2d(np.asarray(v, dtype=float)), np.atleast_2d(n), kind, **kw)


def test_boundary_types_listed():
    assert set(BOUNDARY_TYPES) == {"sticky", "slip", "separate"}


# ------------------------------------------------------------------------------------------ sticky


@pytest.mark.parametrize("v", [[3.0, -2.0], [3.0, 2.0], [0.0, 0.0]], ids=["approaching", "separating", "rest"])
def test_sticky_static_wall_gives_zero(v):
    out = _proj(v, N_UP, "sticky", friction=0.7)
    np.testing.assert_allclose(out, [[0.0, 0.0]], atol=ATOL)


@pytest.mark.parametrize("v", [[3.0, -2.0], [3.0, 2.0]], ids=["approaching", "separating"])
def test_sticky_moving_collider_gives_collider_velocity(v):
    out = _proj(v, N_UP, "sticky", v_collider=np.array([0.5, -0.25]))
    np.testing.assert_allclose(out, [[0.5, -0.25]], atol=ATOL)


# -------------------------------------------------------------------------------------------- slip


def test_slip_approaching_2d():
    # v = (3, -2): v_n = -2, v_t = (3, 0)
    out = _proj([3.0, -2.0], N_UP, "slip", friction=0.5)
    np.testing.assert_allclose(out, [[3.0, 0.0]], atol=ATOL)


def test_slip_separating_2d_also_removes_normal():
    # slip removes the normal component for BOTH signs: v = (3, 2) -> (3, 0)
    out = _proj([3.0, 2.0], N_UP, "slip")
    np.testing.assert_allclose(out, [[3.0, 0.0]], atol=ATOL)


@pytest.mark.parametrize("sign", [-1.0, 1.0], ids=["approaching", "separating"])
def test_slip_slanted_3d(sign):
    # v = t + sign*2 n with tangential t = (0.8, 1.5, -0.6) (t.n = 0.48 - 0.48 = 0)
    n = N_SLANT[0]
    t = np.array([0.8, 1.5, -0.6])
    assert abs(t @ n) < 1e-15
    v = t + sign * 2.0 * n  # = (0.8 +- 1.2, 1.5, -0.6 +- 1.6)
    out = _proj(v, N_SLANT, "slip")
    np.testing.assert_allclose(out, [[0.8, 1.5, -0.6]], atol=1e-14)


# ---------------------------------------------------------------------------------------- separate


@pytest.mark.parametrize("mu", [0.0, 0.3, 10.0])
def test_separate_separating_unchanged(mu):
    out = _proj([3.0, 2.0], N_UP, "separate", friction=mu)
    np.testing.assert_allclose(out, [[3.0, 2.0]], atol=ATOL)


def test_separate_tangential_motion_exactly_along_wall_unchanged():
    # v_n = 0 is not approaching: nothing changes even with friction
    out = _proj([3.0, 0.0], N_UP, "separate", friction=0.5)
    np.testing.assert_allclose(out, [[3.0, 0.0]], atol=ATOL)


def test_separate_frictionless_approaching_keeps_tangential():
    out = _proj([3.0, -2.0], N_UP, "separate", friction=0.0)
    np.testing.assert_allclose(out, [[3.0, 0.0]], atol=ATOL)


def test_separate_frictionless_head_on_gives_zero():
    out = _proj([0.0, -2.0], N_UP, "separate", friction=0.0)
    np.testing.assert_allclose(out, [[0.0, 0.0]], atol=ATOL)


def test_separate_friction_sliding_2d():
    # v = (3, -2), mu = 0.5: |v_t| = 3 > -mu v_n = 1 -> slides; v_t + mu v_n v_t/|v_t| = (3 - 1, 0) = (2, 0)
    out = _proj([3.0, -2.0], N_UP, "separate", friction=0.5)
    np.testing.assert_allclose(out, [[2.0, 0.0]], atol=ATOL)
    # tangential speed reduced by exactly mu |v_n| = 1
    assert np.linalg.norm(out[0]) == pytest.approx(3.0 - 0.5 * 2.0, abs=ATOL)


def test_separate_friction_sticking_2d():
    # v = (3, -2), mu = 2: |v_t| = 3 <= -mu v_n = 4 -> sticks -> 0
    out = _proj([3.0, -2.0], N_UP, "separate", friction=2.0)
    np.testing.assert_allclose(out, [[0.0, 0.0]], atol=ATOL)


def test_separate_friction_boundary_case_sticks():
    # |v_t| = 3 == -mu v_n = 1.5 * 2 exactly (all representable): the <= rule sticks -> 0
    out = _proj([3.0, -2.0], N_UP, "separate", friction=1.5)
    np.testing.assert_allclose(out, [[0.0, 0.0]], atol=ATOL)


def test_separate_friction_sliding_slanted_3d():
    # n = (0.6, 0, 0.8); v = t - 2 n with t = (0.8, 1.5, -0.6), |t| = sqrt(0.64 + 2.25 + 0.36) = sqrt(3.25)
    n = N_SLANT[0]
    t = np.array([0.8, 1.5, -0.6])
    v = t - 2.0 * n
    mu = 0.25  # -mu v_n = 0.5 < |t| ~ 1.803 -> slides
    out = _proj(v, N_SLANT, "separate", friction=mu)
    t_norm = np.sqrt(3.25)
    expected = t * (t_norm - 0.5) / t_norm
    np.testing.assert_allclose(out, [expected], atol=1e-14)
    # no normal component left, direction of t kept, speed reduced by mu |v_n| = 0.5
    assert out[0] @ n == pytest.approx(0.0, abs=1e-14)
    assert np.linalg.norm(out[0]) == pytest.approx(t_norm - 0.5, abs=1e-14)
    np.testing.assert_allclose(np.cross(out[0], t), 0.0, atol=1e-14)


# --------------------------------------------------------------------------------- moving collider


def test_moving_collider_separate_sliding_uses_relative_velocity():
    # collider v_co = (1, 0.5); v = (5, -1.5): v_rel = (4, -2), v_n = -2, v_t = (4, 0)
    # mu = 0.5: |v_t| = 4 > 1 -> v_rel' = (4 - 1, 0) = (3, 0); result = v_rel' + v_co = (4, 0.5)
    out = _proj([5.0, -1.5], N_UP, "separate", friction=0.5, v_collider=np.array([1.0, 0.5]))
    np.testing.assert_allclose(out, [[4.0, 0.5]], atol=ATOL)


def test_moving_collider_separate_sticking_gives_collider_velocity():
    # v_rel = (4, -2), mu = 3: |v_t| = 4 <= 6 -> v_rel' = 0 -> result = v_co
    out = _proj([5.0, -1.5], N_UP, "separate", friction=3.0, v_collider=np.array([1.0, 0.5]))
    np.testing.assert_allclose(out, [[1.0, 0.5]], atol=ATOL)


def test_moving_collider_separating_relative_unchanged_even_if_absolute_approaches():
    # absolute v_y = -0.5 < 0 but the wall moves down faster: v_co = (0, -1) -> v_rel = (2, 0.5) separating
    out = _proj([2.0, -0.5], N_UP, "separate", friction=0.9, v_collider=np.array([0.0, -1.0]))
    np.testing.assert_allclose(out, [[2.0, -0.5]], atol=ATOL)


def test_moving_collider_approaching_relative_even_if_absolute_separates():
    # absolute v_y = +0.5 > 0 but the wall moves up faster: v_co = (0, 2) -> v_rel = (3, -1.5)
    # frictionless separate -> v_rel' = (3, 0) -> result = (3, 2)
    out = _proj([3.0, 0.5], N_UP, "separate", friction=0.0, v_collider=np.array([0.0, 2.0]))
    np.testing.assert_allclose(out, [[3.0, 2.0]], atol=ATOL)


def test_moving_collider_slip():
    # v_co = (1, 0.5), v = (5, 3): v_rel = (4, 2.5) -> v_t = (4, 0) -> result (5, 0.5)
    out = _proj([5.0, 3.0], N_UP, "slip", v_collider=np.array([1.0, 0.5]))
    np.testing.assert_allclose(out, [[5.0, 0.5]], atol=ATOL)


# ------------------------------------------------------------------------------------- vectorised


def test_vectorised_separate_mixed_cases():
    # four walls in 2D with different normals, one node each, mixed situations, mu = 0.5
    normals = np.array(
        [
            [0.0, 1.0],  # floor
            [-1.0, 0.0],  # right wall (material to the left)
            [0.0, -1.0],  # ceiling
            [1.0, 0.0],  # left wall
            [0.0, 1.0],  # floor
        ]
    )
    v = np.array(
        [
            [3.0, -2.0],  # floor, v_n = -2, |v_t| = 3 > 1 -> slides to (2, 0)
            [4.0, 0.5],  # right wall, v_n = -4, |v_t| = 0.5 <= 2 -> sticks -> 0
            [1.0, -7.0],  # ceiling, v_n = +7 separating -> unchanged
            [-1.0, -3.0],  # left wall, v_n = -1, |v_t| = 3 > 0.5 -> (0, -2.5)
            [0.0, 0.0],  # at rest: v_n = 0 -> unchanged
        ]
    )
    expected = np.array([[2.0, 0.0], [0.0, 0.0], [1.0, -7.0], [0.0, -2.5], [0.0, 0.0]])
    out = project_velocity(v.copy(), normals, "separate", friction=0.5)
    np.testing.assert_allclose(out, expected, atol=ATOL)


def test_vectorised_slip_and_sticky_mixed_signs():
    normals = np.array([[0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])
    v = np.array([[3.0, -2.0], [4.0, 0.5], [1.0, -7.0]])
    np.testing.assert_allclose(
        project_velocity(v, normals, "slip"), [[3.0, 0.0], [0.0, 0.5], [1.0, 0.0]], atol=ATOL
    )
    v_co = np.array([[0.1, 0.2], [0.3, 0.4], [0.5, 0.6]])
    np.testing.assert_allclose(project_velocity(v, normals, "sticky", v_collider=v_co), v_co, atol=ATOL)


def test_vectorised_moving_collider_broadcast_3d():
    # one collider velocity (d,) broadcast over several nodes on a floor z = const (normal +z)
    normals = np.tile([0.0, 0.0, 1.0], (3, 1))
    v_co = np.array([0.0, 1.0, 0.0])
    v = np.array(
        [
            [3.0, 1.0, -4.0],  # v_rel = (3, 0, -4): mu = 0.5, |v_t| = 3 > 2 -> (1, 0, 0) -> + v_co = (1, 1, 0)
            [0.5, 1.0, -4.0],  # v_rel = (0.5, 0, -4): 0.5 <= 2 -> sticks -> v_co = (0, 1, 0)
            [3.0, 5.0, 2.0],  # v_rel = (3, 4, 2): separating -> unchanged
        ]
    )
    expected = np.array([[1.0, 1.0, 0.0], [0.0, 1.0, 0.0], [3.0, 5.0, 2.0]])
    out = project_velocity(v, normals, "separate", friction=0.5, v_collider=v_co)
    np.testing.assert_allclose(out, expected, atol=ATOL)


def test_input_not_modified_and_new_array_returned():
    v = np.array([[3.0, -2.0], [4.0, 0.5]])
    normals = np.array([[0.0, 1.0], [-1.0, 0.0]])
    v0 = v.copy()
    for kind in BOUNDARY_TYPES:
        out = project_velocity(v, normals, kind, friction=0.5)
        assert out is not v
        np.testing.assert_array_equal(v, v0)


# ------------------------------------------------------------------------------------------ errors


@pytest.mark.parametrize("kind", ["sticky ", "Slip", "free", "", "separating"])
def test_unknown_kind_raises(kind):
    with pytest.raises(ValueError):
        project_velocity(np.zeros((2, 2)), np.tile([0.0, 1.0], (2, 1)), kind)
