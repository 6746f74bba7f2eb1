"""CPIC in the step: the [[rigid_bodies]] scene keys and their refusals, rigid motion, the friction projection,
momentum exchange with a body, restart bit-identity with bodies, and the rigid-body outputs."""

import numpy as np
import pytest
from helpers import full_and_resumed_runs

from mpmref import Scene, SceneBuilder, Simulation
from mpmref.errors import SceneError
from mpmref.rigid.dynamics import area_mass_properties, encode_friction, friction_projection, line_mass_properties
from mpmref.rigid.dynamics2d import scripted_pose
from mpmref.rigid.polyline import validate_polyline

PLATE = {"vertices": [[0.3, 0.4], [0.7, 0.4]], "segments": [[0, 1]]}


def builder(scheme="pic", coupling=None, **body):
    method = {"coupling": "cpic"} if coupling is None else coupling
    b = (SceneBuilder(dim=2, name="c").grid(size=1.0, cells=32).method(scheme, **method)
         .material("j", "fixed_corotated", E=1e3, rho=1.0).ball("j", center=[0.5, 0.55], radius=0.06,
                                                                   velocity=[0.0, -1.0]).walls("open")
         .time(dt=2e-4, steps=4))
    if body is not None:
        b.rigid_body(**{**PLATE, **body})
    return b


def assert_refused(data, field, words):
    with pytest.raises(SceneError) as info:
        Scene.from_dict(data)
    assert info.value.field == field, str(info.value)
    assert words in str(info.value)


# ------------------------------------------------------------------------------------------- the scene
@pytest.mark.parametrize("body, field, words", [
    ({"vertices": [[0.3, 0.4], [0.3, 0.4]]}, "rigid_bodies[0].segments", "degenerate"),
    ({"vertices": [[0.3, 0.4], [0.7, 0.4], [0.5, 0.5]], "segments": [[0, 1], [1, 2]], "closed": True},
     "rigid_bodies[0].closed", "exactly two segments"),
    ({"motion": "fixed", "velocity": [1.0, 0.0]}, "rigid_bodies[0].velocity", "known keys"),
    ({"motion": "scripted", "density": 1.0}, "rigid_bodies[0].density", "known keys"),
    ({"motion": "dynamic"}, "rigid_bodies[0].density", "required"),
    ({"motion": "rolling"}, "rigid_bodies[0].motion", "'scripted'"),
    ({"vertices": [[0.3, 0.4], [1.2, 0.4]]}, "rigid_bodies[0].vertices", "inside the domain"),
    ({"type": "glue"}, "rigid_bodies[0].type", "sticky"),
    ({"friction": [0.3, -1.0]}, "rigid_bodies[0].friction", ">= 0"),
    ({"motion": "scripted", "keyframes": [{"time": 0.0}, {"time": 0.0}]}, "rigid_bodies[0].keyframes[1].time",
     "greater than"),
])
def test_rigid_body_refusals_name_the_field(body, field, words):
    assert_refused(builder(**body).as_dict(), field, words)


def test_method_refusals_say_why():
    assert_refused(builder("flip").as_dict(), "method.scheme", "FLIP's increment")
    assert_refused(builder("polypic").as_dict(), "method.scheme", "PolyPIC")
    assert_refused(builder("mls", {"coupling": "cpic", "momentum_exact": True}).as_dict(), "method.momentum_exact",
            "needs PIC")
    assert_refused(builder("pic", {"coupling": "cpic", "momentum_exact": True, "pushing_force": 1.0}).as_dict(),
            "method.pushing_force", "no body receives")
    assert_refused(builder("pic", {}).as_dict(), "method.coupling", "'cpic' when the scene has")
    no_bodies = builder().as_dict()
    del no_bodies["rigid_bodies"]
    assert_refused(no_bodies, "method.coupling", "without [[rigid_bodies]]")
    assert_refused(builder("pic", {"penalty": 1.0}).as_dict(), "method.penalty", "only with method.coupling")


def test_cpic_settings_are_the_scene_s_cpic_spec():
    """The ``[method]`` CPIC keys stay where they are in the file and land in ``Scene.cpic`` (None without)."""
    from mpmref.scene import CpicSpec

    assert builder().build().cpic == CpicSpec(pushing_force=2e4, penalty=0.0, momentum_exact=False,
                                              ghost_force=True, fit="single")
    exact = builder("pic", {"coupling": "cpic", "momentum_exact": True, "penalty": 5.0, "ghost_force": False,
                            "cpic_fit": "per_body"}).build()
    assert exact.cpic == CpicSpec(pushing_force=0.0, penalty=5.0, momentum_exact=True, ghost_force=False,
                                  fit="per_body")
    plain = builder("pic", {}).as_dict()
    del plain["rigid_bodies"]
    scene = Scene.from_dict(plain)
    assert scene.cpic is None and not hasattr(scene.method, "coupling")


def test_no_cpic_state_without_bodies():
    plain = builder("pic", {}).as_dict()
    del plain["rigid_bodies"]
    sim = Simulation(Scene.from_dict(plain))
    assert sim.state.rigid is None and sim.particles.tag_A is None
    sim.run(steps=1)
    assert sim.state.rigid is None and "rigid0_x" not in sim.diagnostics()


def test_mass_properties_of_a_rod_and_a_square():
    rod = validate_polyline([[0.0, 0.0], [2.0, 0.0]], [[0, 1]])
    m, c, i = line_mass_properties(rod, density=3.0)
    assert m == pytest.approx(6.0) and np.allclose(c, [1.0, 0.0]) and i == pytest.approx(6.0 * 4 / 12)
    square = validate_polyline([[0, 0], [1, 0], [1, 1], [0, 1]], [[0, 1], [1, 2], [2, 3], [3, 0]], closed=True)
    m, c, i = area_mass_properties(square, density=2.0)
    assert m == pytest.approx(2.0) and np.allclose(c, [0.5, 0.5]) and i == pytest.approx(2.0 * 2 / 12)


def test_scripted_keyframes_interpolate_and_hold():
    scene = builder(motion="scripted", keyframes=[{"time": 0.0}, {"time": 1.0, "offset": [0.1, 0.0], "angle": 0.5}]
                    ).build()
    body = scene.rigid_bodies[0]
    offset, angle = scripted_pose(body, 0.25)
    assert np.allclose(offset, [0.025, 0.0]) and angle == pytest.approx(0.125)
    offset, angle = scripted_pose(body, 3.0)
    assert np.allclose(offset, [0.1, 0.0]) and angle == pytest.approx(0.5)


# ------------------------------------------------------------------------------ the friction projection
def test_friction_projection_cases():
    n = np.array([0.0, 1.0])
    vb = np.array([0.5, 0.0])
    v = np.array([2.0, -1.0])  # approaching: u = (1.5, -1)
    assert np.allclose(friction_projection(v, vb, n, np.float64(encode_friction("sticky", 0.0))), vb)
    # separate, mu = 0.3: tangential 1.5 - 0.3 * 1 = 1.2, normal removed
    assert np.allclose(friction_projection(v, vb, n, np.float64(0.3)), [0.5 + 1.2, 0.0])
    # enough friction to stop the tangential motion
    assert np.allclose(friction_projection(v, vb, n, np.float64(2.0)), vb)
    # separating: separate keeps the normal part, slip removes it
    away = np.array([2.0, 1.0])
    assert np.allclose(friction_projection(away, vb, n, np.float64(0.3)), away)
    assert np.allclose(friction_projection(away, vb, n, np.float64(encode_friction("slip", 0.3))), [2.0, 0.0])


# ---------------------------------------------------------------------------------- exchange and restart
def collision(exact, steps):
    method = {"coupling": "cpic", "momentum_exact": True} if exact else {"coupling": "cpic", "pushing_force": 0.0}
    scene = builder("pic", method, motion="dynamic", density=0.1, gravity=False).time(dt=2e-4, steps=steps).build()
    return Simulation(scene)


def total_momentum(sim):
    d = sim.diagnostics()
    return (sim.mass[:, None] * sim.v).sum(axis=0) + [d["rigid_momentum_x"], d["rigid_momentum_y"]]


def test_exact_variant_keeps_particles_plus_plate_momentum_and_pushes_the_plate():
    sim = collision(exact=True, steps=0)
    p0 = total_momentum(sim)
    sim.run(steps=450)  # the ball reaches the plate after about 0.07 s
    drift = np.abs(total_momentum(sim) - p0).max() / np.abs(p0).max()
    assert drift < 1e-12, drift
    assert sim.diagnostics()["rigid0_vy"] < -0.1  # the plate moves along the ball's velocity
    assert sim.diagnostics()["rigid0_impulse_y"] < 0.0


def test_restart_with_bodies_is_bit_identical(tmp_path):
    scene = builder("mls", {"coupling": "cpic", "penalty": 100.0}, motion="dynamic", density=0.1,
                    vertices=[[0.3, 0.465], [0.7, 0.465]]).time(
        dt=2e-4, steps=6).gravity([0.0, -10.0]).build()
    full, resumed = full_and_resumed_runs(scene, tmp_path, steps=6, stop_at=3)
    for name, arr in full.state.rigid.arrays().items():
        assert np.array_equal(arr, getattr(resumed.state.rigid, name)), name
    assert full.particles.tag_A.any()  # the tags that were carried over are not trivial


def test_outputs_write_the_bodies_and_the_tags(tmp_path):
    pv = pytest.importorskip("pyvista")
    scene = builder(motion="scripted", velocity=[0.0, 0.5]).time(dt=2e-4, steps=4).output(every=2).build()
    sim = Simulation(scene, out_dir=tmp_path)
    sim.run()
    series = (tmp_path / "rigid_bodies.pvd").read_text()
    assert series.count("<DataSet") == 3 and "rigid_bodies_000004.vtp" in series
    lines = pv.read(tmp_path / "rigid_bodies_000004.vtp")
    assert np.allclose(lines.points[:, 1], 0.4 + 0.5 * 4 * 2e-4) and lines.n_lines == 1
    particles = pv.read(tmp_path / "particles_000004.vtu")
    assert {"side", "distance", "near"} <= set(particles.point_data.keys())
    header = (tmp_path / "diagnostics.csv").read_text().splitlines()[0]
    for column in ("rigid0_x", "rigid0_vy", "rigid0_omega", "rigid0_impulse_y"):
        assert column in header


@pytest.mark.slow
def test_cut2d_example_writes_the_blade_and_two_pieces(tmp_path):
    from mpmref.cli import main
    from verification.cpic import components

    pv = pytest.importorskip("pyvista")
    assert main(["run", "examples/cut2d.toml", "--out", str(tmp_path), "--no-progress"]) == 0
    last = sorted(tmp_path.glob("particles_*.vtu"))[-1]
    x = np.asarray(pv.read(last).points)[:, :2]
    assert components(x, 1.0 / 64) == 2
    blade = pv.read(sorted(tmp_path.glob("rigid_bodies_*.vtp"))[-1])
    assert blade.n_lines == 2 and (tmp_path / "rigid_bodies.pvd").exists()
