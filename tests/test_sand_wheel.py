"""The sand wheel's pieces: [[emitters]] (releases, ids, restart), pinned and welded bodies with angular damping,
their refusals, and examples/sand_wheel2d.toml."""

import tomllib
from pathlib import Path

import numpy as np
import pytest
from helpers import full_and_resumed_runs

from mpmref import Scene, SceneBuilder, Simulation
from mpmref.errors import SceneError
from mpmref.rigid.dynamics import apply_impulses, end_step, initial_state
from mpmref.rigid.polyline import distance_to_polyline, inside_closed, validate_polyline, wheel
from mpmref.run.emitters import emit, release_template

EXAMPLE = Path(__file__).resolve().parent.parent / "examples" / "sand_wheel2d.toml"
EMITTER = {"material": "s", "center": [0.5, 0.7], "radius": 0.05, "velocity": [0.0, -1.0], "until": 0.35}


def emitting(cells=32, dt=2.5e-3, **emitter):
    data = (SceneBuilder(dim=2, name="e").grid(size=1.0, cells=cells).method("pic")
            .material("s", "fixed_corotated", E=10.0, rho=1.0).ball("s", center=[0.5, 0.3], radius=0.05)
            .walls("separate", domain_exit="delete").time(dt=dt, t_end=0.4).as_dict())
    data["emitters"] = [{**EMITTER, **emitter}]
    return data


def test_emitter_releases_a_disk_every_interval_with_new_ids():
    scene = Scene.from_dict(emitting())
    sim = Simulation(scene)
    n0 = sim.n_particles
    per_release = n0  # the initial body is the same disk as a release
    counts = []
    while sim.time < 0.4 - 1e-12:
        sim.step(t_end=0.4)
        counts.append((round(sim.time, 6), sim.n_particles))
    # releases at t = 0, 0.1, 0.2, 0.3 (interval 2 r / |v| = 0.1; none at or after until = 0.35), each joining
    # before the step that starts at its time
    expected = [(round(t, 6), n0 + per_release * (1 + min(int(np.floor((t - 1e-9) / 0.1)), 3))) for t, _ in counts]
    assert counts == expected
    assert np.array_equal(np.sort(sim.id), np.arange(n0 + 4 * per_release))
    fresh = Simulation(scene)
    released = emit(scene, fresh.state, [release_template(scene, e) for e in scene.emitters]).particles
    new = released.id >= n0
    assert np.array_equal(released.id[new], np.arange(n0, n0 + per_release))
    assert np.all(released.v[new] == [0.0, -1.0]) and np.all(released.F[new] == np.eye(2))
    assert np.all(np.linalg.norm(released.x[new] - [0.5, 0.7], axis=1) < 0.05)  # the emitter's disk


def test_a_resumed_run_with_emitters_and_a_turning_wheel_is_bit_identical(tmp_path):
    data = tomllib.loads(EXAMPLE.read_text())
    data["grid"]["cells"] = 32
    data["time"] = {"dt": 2e-3}
    data["method"]["penalty"] = 500.0
    data["output"] = {"every": 40}
    scene = Scene.from_dict(data)
    # stopped at step 80, after the release at 0.1 s; the run goes on past the releases at 0.2 and 0.3 s
    full, resumed = full_and_resumed_runs(scene, tmp_path, steps=160, stop_at=80)
    assert resumed.n_particles == full.n_particles == 4 * Simulation(scene).n_particles
    for name, array in full.state.rigid.arrays().items():
        assert np.array_equal(getattr(resumed.state.rigid, name), array), name
    for name, array in full.state.stepper.items():
        assert np.array_equal(resumed.state.stepper[name], array), name
    assert full.state.rigid.angular_velocity[0] == full.state.rigid.angular_velocity[1] != 0.0


def test_example_is_the_reference_wheel_pinned_welded_and_fed():
    scene = Scene.from_toml(EXAMPLE)
    ring, blades, floor = scene.rigid_bodies
    assert ring.pinned and blades.pinned and blades.welded_to == 0 and floor.motion == "fixed"
    assert ring.angular_damping == blades.angular_damping == 2.7
    np.testing.assert_allclose(ring.center, [0.5, 0.35], atol=1e-12)
    radii = np.linalg.norm(ring.shape.vertices - [0.5, 0.35], axis=1)
    np.testing.assert_allclose(radii, 0.16, rtol=1e-10)
    (emitter,) = scene.emitters
    assert emitter.interval == pytest.approx(0.1) and emitter.until == 2.5
    assert scene.time.dt * scene.cpic.penalty == pytest.approx(1.0, rel=1e-3)
    assert scene.cpic.fit == "per_body"  # sand in the blade–ring corners is near two bodies


def test_a_pinned_body_turns_in_place_and_its_spin_decays_exactly():
    scene = Scene.from_toml(EXAMPLE)
    bodies = scene.rigid_bodies
    state = initial_state(bodies)
    kicked = apply_impulses(bodies, state, np.array([[3.0, -2.0], [0.0, 0.0], [0.0, 0.0]]), np.array([5.0, 0.0, 0.0]))
    # the pin takes the linear impulse; the weld shares the angular one over both inertias
    total = bodies[0].inertia + bodies[1].inertia
    assert np.all(kicked.velocity == 0.0)
    np.testing.assert_allclose(kicked.angular_velocity[:2], 5.0 / total, rtol=1e-14)
    dt, state = 1e-3, kicked
    for _ in range(100):
        state = end_step(bodies, state, 0.0, dt, scene.gravity)
    np.testing.assert_array_equal(state.position, kicked.position)  # gravity moves no pinned centre
    np.testing.assert_allclose(state.angular_velocity[:2], 5.0 / total * np.exp(-2.7 * 0.1), rtol=1e-12)
    np.testing.assert_allclose(state.angle[:2], 5.0 / total * dt * np.sum(np.exp(-2.7 * dt * np.arange(100))),
                               rtol=1e-12)


def wheel_data(changes=None):
    data = tomllib.loads(EXAMPLE.read_text())
    for (table, index, key), value in (changes or {}).items():
        target = data[table][index] if index is not None else data[table]
        if value is None:
            target.pop(key)
        else:
            target[key] = value
    return data


@pytest.mark.parametrize("changes, field, words", [
    ({("rigid_bodies", 0, "pinned"): "yes"}, "rigid_bodies[0].pinned", "true or false"),
    ({("rigid_bodies", 0, "velocity"): [1.0, 0.0]}, "rigid_bodies[0].velocity", "pinned"),
    ({("rigid_bodies", 0, "angular_damping"): -1.0}, "rigid_bodies[0].angular_damping", "[0.0, inf]"),
    ({("rigid_bodies", 1, "welded_to"): 1}, "rigid_bodies[1].welded_to", "earlier dynamic body"),
    ({("rigid_bodies", 0, "pinned"): None}, "rigid_bodies[1].welded_to", "two pinned bodies"),
    ({("rigid_bodies", 1, "angular_velocity"): 1.0}, "rigid_bodies[1].angular_velocity", "welded"),
    ({("rigid_bodies", 2, "pinned"): True}, "rigid_bodies[2].pinned", "known keys"),
    ({("emitters", 0, "interval"): 0.05}, "emitters[0].interval", "2 radius / |velocity| = 0.1"),
    ({("emitters", 0, "velocity"): [0.0, 0.0]}, "emitters[0].velocity", "nonzero"),
    ({("emitters", 0, "center"): [0.02, 0.5]}, "emitters[0].center", "valid region"),
    ({("emitters", 0, "until"): 0.1}, "emitters[0].until", "(0.1, inf]"),
    ({("emitters", 0, "material"): "water"}, "emitters[0].material", "'sand'"),
    ({("emitters", 0, "rate"): 3.0}, "emitters[0].rate", "known keys"),
])
def test_wheel_and_emitter_refusals_name_the_field(changes, field, words):
    with pytest.raises(SceneError) as info:
        Scene.from_dict(wheel_data(changes))
    assert info.value.field == field, str(info.value)
    assert words in str(info.value)


def test_welded_bodies_must_share_their_centre_and_emitters_need_sync_stepping():
    data = wheel_data()
    data["rigid_bodies"][1]["vertices"] = (np.array(data["rigid_bodies"][1]["vertices"]) + [0.01, 0.0]).tolist()
    with pytest.raises(SceneError, match="same centre") as info:
        Scene.from_dict(data)
    assert info.value.field == "rigid_bodies[1].welded_to"
    scene = emitting()
    scene["time"] = {"cfl": 0.5, "stepping": "async", "t_end": 0.1}
    with pytest.raises(SceneError, match="emitters") as info:
        Scene.from_dict(scene)
    assert info.value.field == "time.stepping"
    with pytest.raises(SceneError, match="time.dt") as info:
        Scene.from_dict(emitting(dt=0.2))
    assert info.value.field == "emitters[0].interval"


def test_ring_geometry_inside_test_and_distance():
    (ring_v, ring_s), (blade_v, blade_s) = wheel([0.5, 0.35], 0.16, 60, 0.136, 0.24, 18)
    ring, blades = validate_polyline(ring_v, ring_s), validate_polyline(blade_v, blade_s)
    # clockwise: every segment's left normal points away from the centre (side 0 is outside)
    mid = 0.5 * (ring.starts + ring.ends) - [0.5, 0.35]
    tangent = ring.ends - ring.starts
    assert np.all(mid[:, 0] * -tangent[:, 1] + mid[:, 1] * tangent[:, 0] > 0)
    x = np.array([[0.5, 0.35], [0.5, 0.35 + 0.155], [0.5, 0.35 + 0.165], [0.9, 0.9]])
    assert inside_closed(ring, x).tolist() == [True, True, False, False]
    tips = np.array(blade_v)[1::2]
    np.testing.assert_allclose(np.linalg.norm(tips - [0.5, 0.35], axis=1), 0.24, rtol=1e-12)
    assert np.all(distance_to_polyline(blades, tips) == 0.0)
    np.testing.assert_allclose(distance_to_polyline(ring, np.array([[0.5, 0.35]])), 0.16 * np.cos(np.pi / 60),
                               rtol=1e-12)
