"""Level-set colliders: signed distances, normals, and their effect in a run."""

import numpy as np
import pytest

from mpmref import SceneBuilder, SceneError, Simulation
from mpmref.physics.colliders import Ball, Box, Cylinder, Plane

SHAPES = [
    Plane(point=np.array([0.1, 0.2, 0.0]), normal=np.array([0.0, 2.0, 0.0])),
    Ball(center=np.array([0.5, 0.5, 0.5]), radius=0.2),
    Box(lower=np.array([0.2, 0.3, 0.4]), upper=np.array([0.6, 0.5, 0.7])),
    Cylinder(point=np.array([0.5, 0.5, 0.0]), axis=np.array([0.0, 0.0, 3.0]), radius=0.1),
]


def test_signed_distances_at_hand_computed_points():
    plane, ball, box, cyl = SHAPES
    x = np.array([[0.3, 0.5, 0.9], [0.5, 0.5, 0.5], [0.4, 0.4, 0.5], [0.9, 0.5, 0.5]])
    np.testing.assert_allclose(plane.sdf(x), [0.3, 0.3, 0.2, 0.3])
    np.testing.assert_allclose(ball.sdf(x), [np.sqrt(0.04 + 0.16) - 0.2, -0.2, np.sqrt(0.02) - 0.2, 0.2])
    # box: (0.4, 0.4, 0.5) is inside, 0.1 from the y faces and x faces -> -0.1; (0.9, .5, .5) 0.3 beyond x = 0.6
    np.testing.assert_allclose(box.sdf(x[2:]), [-0.1, 0.3])
    np.testing.assert_allclose(cyl.sdf(x), [np.sqrt(0.04) - 0.1, -0.1, np.sqrt(0.02) - 0.1, 0.3])


@pytest.mark.parametrize("shape", SHAPES, ids=lambda s: type(s).__name__)
def test_gradient_is_the_unit_normal_of_the_distance(shape, rng):
    x = rng.random((200, 3))
    phi = shape.sdf(x)
    g = shape.gradient(x)
    h = 1e-6
    fd = np.stack([(shape.sdf(x + h * e) - shape.sdf(x - h * e)) / (2 * h) for e in np.eye(3)], axis=1)
    # away from the medial axis (box edges and corners inside), the sdf is differentiable
    ok = np.all(np.abs(fd - g) < 1e-5, axis=1)
    assert ok.mean() > 0.9
    np.testing.assert_allclose(np.linalg.norm(g[ok], axis=1), 1.0, rtol=1e-12)
    assert np.all(np.isfinite(phi))


def falling_block(collider=True, t_end=0.3):
    b = (SceneBuilder(dim=2, name="drop").grid(size=1.0, cells=32).method("mls")
         .material("jelly", "neo_hookean", E=2e3, nu=0.3, rho=1.0)
         .box("jelly", lower=[0.4, 0.6], upper=[0.6, 0.75]).gravity([0.0, -9.8])
         .walls("separate").time(cfl=0.4, t_end=t_end))
    if collider:
        b.collider("disk", type="separate", friction=0.0, center=[0.5, 0.3], radius=0.15)
    return Simulation(b.build())


def test_disk_collider_stops_a_falling_block():
    """Without the collider the block falls 0.44 m in 0.3 s (½ g t²) past the disk's top at y = 0.45;
    with it, no particle ends inside the disk by more than a cell."""
    free, held = falling_block(False), falling_block(True)
    free.run()
    held.run()
    disk = Ball(center=np.array([0.5, 0.3]), radius=0.15)
    assert disk.sdf(free.x).min() < -0.1
    assert disk.sdf(held.x).min() > -held.scene.grid.dx


def test_moving_sticky_piston_carries_the_block():
    """A sticky plane rising at 0.5 m/s from 0.05 below a free block (no gravity) meets it after
    about 0.1 s (grid contact begins a cell earlier) and then carries it: after 0.3 s the block moves
    with the piston (mean velocity within 10 %), has risen by at least the piston's travel after
    contact (0.15 - 0.05 m), and no particle is behind the plane."""
    scene = (SceneBuilder(dim=2, name="piston").grid(size=1.0, cells=32).method("apic")
             .material("jelly", "fixed_corotated", E=2e3, nu=0.3, rho=1.0)
             .box("jelly", lower=[0.3, 0.25], upper=[0.7, 0.45]).walls("open")
             .collider("plane", type="sticky", point=[0.0, 0.2], normal=[0.0, 1.0], velocity=[0.0, 0.5])
             .time(cfl=0.3, t_end=0.3).build())
    sim = Simulation(scene)
    y0 = sim.x[:, 1].mean()
    sim.run()
    assert sim.v[:, 1].mean() == pytest.approx(0.5, rel=0.1)
    assert 0.1 <= sim.x[:, 1].mean() - y0 <= 0.15
    assert sim.x[:, 1].min() > 0.2 + 0.5 * sim.time


def test_collider_validation():
    base = (SceneBuilder(dim=2, name="c").grid(size=1.0, cells=16).material("m", "fluid", K=10.0)
            .box("m", lower=[0.3, 0.3], upper=[0.6, 0.6]).time(dt=1e-3, steps=1))
    with pytest.raises(SceneError, match=r"colliders\[0\].shape.*'cylinder' only in 3D"):
        base.collider("cylinder", point=[0.5, 0.5], axis=[0.0, 1.0], radius=0.1).build()
    base._data["colliders"] = []
    with pytest.raises(SceneError, match=r"colliders\[0\].normal"):
        base.collider("plane", point=[0.5, 0.5], normal=[0.0, 0.0]).build()
    base._data["colliders"] = []
    with pytest.raises(SceneError, match=r"colliders\[0\].type"):
        base.collider("disk", type="bouncy", center=[0.5, 0.5], radius=0.1).build()
