"""CPIC in 3D: [[rigid_bodies]] triangle meshes in scenes and their refusals, 3D rigid dynamics (inertia tensor,
orientation that stays orthonormal, angular momentum), and the coupled step on the NumPy reference."""

import numpy as np
import pytest
from test_cpic_coupling import assert_refused

from mpmref import Scene, SceneBuilder, Simulation
from mpmref.errors import SceneError
from mpmref.rigid import dynamics as rigid_dynamics
from mpmref.rigid import dynamics3d as rigid_dynamics3d
from mpmref.rigid.trimesh import box, rectangle

PLATE = rectangle([0.5, 0.4, 0.5], [0.2, 0.0, 0.0], [0.0, 0.0, -0.2])  # normal +y
PLATE_ENTRY = {"vertices": PLATE.vertices.tolist(), "triangles": PLATE.triangles.tolist()}
CUBE = box([0.4, 0.3, 0.4], [0.6, 0.4, 0.6])
CUBE_ENTRY = {"vertices": CUBE.vertices.tolist(), "triangles": CUBE.triangles.tolist(), "closed": True}


def builder(method=None, steps=4, **body):
    b = (SceneBuilder(dim=3, name="c3").grid(size=1.0, cells=16).method("pic", **(method or {"coupling": "cpic"}))
         .material("j", "fixed_corotated", E=1e3, rho=1.0).ball("j", center=[0.5, 0.56, 0.5], radius=0.1,
                                                                   velocity=[0.0, -1.0, 0.0]).walls("open")
         .time(dt=1e-3, steps=steps))
    b._data.setdefault("rigid_bodies", []).append({**PLATE_ENTRY, **body})
    return b


# ------------------------------------------------------------------------------------------- the scene
@pytest.mark.parametrize("body, field, words", [
    ({"vertices": [[0.3, 0.4, 0.3], [0.7, 0.4, 0.3], [0.5, 0.4, 0.3]], "triangles": [[0, 1, 2]]},
     "rigid_bodies[0].triangles", "degenerate"),
    ({"closed": True}, "rigid_bodies[0].closed", "watertight"),
    ({"motion": "fixed", "velocity": [1.0, 0.0, 0.0]}, "rigid_bodies[0].velocity", "known keys"),
    ({"motion": "scripted", "density": 1.0}, "rigid_bodies[0].density", "known keys"),
    ({"motion": "scripted", "keyframes": [{"time": 0.0}, {"time": 1.0, "angle": 0.5}]},
     "rigid_bodies[0].keyframes[1].angle", "known keys"),
    ({"motion": "dynamic"}, "rigid_bodies[0].density", "required"),
    ({"motion": "scripted", "angular_velocity": 1.0, "center": [0.5, 0.5]}, "rigid_bodies[0].center",
     "3 finite numbers"),
    ({"vertices": (PLATE.vertices + [0.0, 0.0, 0.35]).tolist()}, "rigid_bodies[0].vertices", "inside the domain"),
    ({"segments": [[0, 1]]}, "rigid_bodies[0].segments", "known keys"),
    ({"mesh": "blade.stl"}, "rigid_bodies[0].triangles", "absent when mesh"),
    ({"friction": [0.3, -1.0]}, "rigid_bodies[0].friction", ">= 0"),
    ({"motion": "dynamic", "density": 1.0, "pinned": True}, "rigid_bodies[0].pinned", "2D only"),
    ({"motion": "dynamic", "density": 1.0, "angular_damping": 1.0}, "rigid_bodies[0].angular_damping", "2D only"),
])
def test_3d_rigid_body_refusals_name_the_field(body, field, words):
    assert_refused(builder(**body).as_dict(), field, words)


def test_a_mesh_file_is_read_relative_to_the_scene(tmp_path):
    meshio = pytest.importorskip("meshio")
    meshio.write_points_cells(tmp_path / "cube.stl", CUBE.vertices, [("triangle", CUBE.triangles)], binary=True)
    data = builder().as_dict()
    data["rigid_bodies"] = [{"mesh": "cube.stl", "closed": True, "motion": "dynamic", "density": 2.0}]
    body = Scene.from_dict(data, base_dir=tmp_path).rigid_bodies[0]
    assert body.mass == pytest.approx(2.0 * 0.2 * 0.1 * 0.2)  # rho V
    data["rigid_bodies"] = [{"mesh": "missing.stl"}]
    with pytest.raises(SceneError) as info:
        Scene.from_dict(data, base_dir=tmp_path)
    assert info.value.field == "rigid_bodies[0].mesh"


def test_dynamic_mass_and_inertia_from_volume_or_area():
    solid = builder(**{**CUBE_ENTRY, "motion": "dynamic", "density": 10.0}).build().rigid_bodies[0]
    m = 10.0 * 0.2 * 0.1 * 0.2
    assert solid.mass == pytest.approx(m)
    assert np.allclose(solid.center, [0.5, 0.35, 0.5])
    # solid box of sides (a, b, c): I_xx = m (b^2 + c^2) / 12, ...
    assert np.allclose(solid.inertia, m / 12 * np.diag([0.1**2 + 0.2**2, 0.2**2 + 0.2**2, 0.2**2 + 0.1**2]))
    shell = builder(motion="dynamic", density=3.0).build().rigid_bodies[0]
    m = 3.0 * 0.4 * 0.4  # rho * area of a 0.4 x 0.4 plate in y = 0.4
    assert shell.mass == pytest.approx(m)
    # thin square plate of side s about its in-plane axes m s^2 / 12, about its normal m s^2 / 6
    assert np.allclose(shell.inertia, m * 0.4**2 * np.diag([1 / 12, 1 / 6, 1 / 12]))


# ---------------------------------------------------------------------------------- rigid dynamics in 3D
def test_quaternions_rotate_like_the_rotation_vector():
    phi = np.array([0.3, -1.1, 0.7])
    R = rigid_dynamics3d.rotation_matrix(rigid_dynamics3d.quaternion_from_rotation_vector(phi))
    axis, angle = phi / np.linalg.norm(phi), np.linalg.norm(phi)
    K = np.cross(np.eye(3), axis)  # the cross-product matrix [axis]_x
    rodrigues = np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * (K @ K)
    assert np.allclose(R, rodrigues, atol=1e-14)
    back = rigid_dynamics3d.rotation_vector_from_quaternion(rigid_dynamics3d.quaternion_from_rotation_vector(phi))
    assert np.allclose(back, phi, atol=1e-14)


def free_box(omega, steps, dt=1e-3):
    body = builder(**{**CUBE_ENTRY, "motion": "dynamic", "density": 10.0, "gravity": False,
                      "angular_velocity": list(map(float, omega))}).build().rigid_bodies[0]
    state = rigid_dynamics.initial_state([body])
    for k in range(steps):
        state = rigid_dynamics.end_step([body], state, k * dt, dt, np.zeros(3))
    return body, state


def test_free_rotation_stays_orthonormal_and_keeps_angular_momentum():
    omega0 = np.array([3.0, 20.0, -5.0])  # not along a principal axis: the box tumbles
    body, state = free_box(omega0, 5000)
    R = rigid_dynamics3d.rotation_matrix(state.angle[0])
    assert np.abs(R @ R.T - np.eye(3)).max() < 1e-13
    L = R @ body.inertia @ R.T @ state.angular_velocity[0]
    assert np.abs(L - body.inertia @ omega0).max() < 1e-11 * np.abs(body.inertia @ omega0).max()
    assert not np.allclose(state.angular_velocity[0], omega0, atol=1e-2)  # it precesses


def test_rotation_about_a_principal_axis_turns_by_omega_t():
    body, state = free_box([0.0, 2.0, 0.0], 1000)  # 2 rad/s about y for 1 s
    q = state.angle[0]
    assert np.allclose(rigid_dynamics3d.rotation_vector_from_quaternion(q), [0.0, 2.0, 0.0], atol=1e-12)


def test_scripted_rotation_velocity_and_keyframes():
    body = builder(motion="scripted", angular_velocity=[0.0, 1.5, 0.0], velocity=[0.1, 0.0, 0.0]
                   ).build().rigid_bodies[0]
    state = rigid_dynamics.begin_step([body], rigid_dynamics.initial_state([body]), 0.2, 1e-3)
    assert np.allclose(state.angular_velocity[0], [0.0, 1.5, 0.0], atol=1e-12)
    x = np.array([[0.7, 0.4, 0.5]])
    v = rigid_dynamics.point_velocity(state, np.array([0]), x)
    assert np.allclose(v, [0.1, 0.0, 0.0] + np.cross([0.0, 1.5, 0.0], x[0] - body.center))
    keyed = builder(motion="scripted", keyframes=[{"time": 0.0}, {"time": 1.0, "offset": [0.0, 0.1, 0.0],
                                                                   "rotation": [0.0, 0.0, 0.4]}]).build()
    offset, phi = rigid_dynamics3d.scripted_pose(keyed.rigid_bodies[0], 0.25)
    assert np.allclose(offset, [0.0, 0.025, 0.0]) and np.allclose(phi, [0.0, 0.0, 0.1])


def test_impulses_give_linear_and_angular_impulse():
    x = np.array([[1.0, 0.0, 0.0], [0.0, 2.0, 0.0]])
    J = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 3.0]])
    lin, ang = rigid_dynamics3d.body_impulses(2, np.array([0, 1]), x, J, np.zeros((2, 3)))
    assert np.allclose(lin, J) and np.allclose(ang, [[0.0, 0.0, 1.0], [6.0, 0.0, 0.0]])


# ------------------------------------------------------------------------------ the coupled step in 3D
def total_momentum(sim):
    return (sim.mass[:, None] * sim.v).sum(axis=0) + rigid_dynamics.momentum(sim.scene.rigid_bodies, sim.state.rigid)


def test_exact_variant_keeps_momentum_in_3d_and_pushes_the_plate():
    sim = Simulation(builder({"coupling": "cpic", "momentum_exact": True}, motion="dynamic", density=0.05,
                             gravity=False).build())
    p0 = total_momentum(sim)
    sim.run(steps=90)  # the ball (bottom at 0.46) meets the plate at y = 0.4 after about 0.05 s
    drift = np.abs(total_momentum(sim) - p0).max() / np.abs(p0).max()
    assert drift < 1e-12, drift
    assert sim.state.rigid.velocity[0, 1] < -0.05  # the plate moves along the ball's velocity


def test_restart_and_outputs_with_a_3d_body(tmp_path):
    pv = pytest.importorskip("pyvista")
    scene = builder(motion="scripted", velocity=[0.0, 0.5, 0.0], angular_velocity=[0.0, 1.0, 0.0], steps=4
                    ).output(every=2).build()
    full = Simulation(scene, out_dir=tmp_path / "full")
    full.run()
    half = Simulation(scene, out_dir=tmp_path / "half")
    half.run(steps=2)
    resumed = Simulation.resume(scene, tmp_path / "half")
    resumed.run()
    for name, arr in full.state.rigid.arrays().items():
        assert np.array_equal(arr, getattr(resumed.state.rigid, name)), name
    for name, arr in full.particles.arrays().items():
        assert np.array_equal(arr, getattr(resumed.particles, name)), name
    mesh = pv.read(tmp_path / "full" / "rigid_bodies_000004.vtp")
    assert mesh.n_cells == 2 and np.allclose(mesh.points[:, 1], 0.4 + 0.5 * 4e-3)
    assert "rigid0_omega_y" in (tmp_path / "full" / "diagnostics.csv").read_text().splitlines()[0]

