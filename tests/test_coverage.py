"""What a run exercised (verification/framework/coverage.py): a comparison along a run sees a wrong field only where
the run makes it matter, and the verdict says which fields and features it did not exercise."""

import numpy as np

from mpmref import Scene, SceneBuilder, Simulation
from verification.framework.coverage import FLOOR, exercised, not_exercised


def falling_block(walls="sticky"):
    """A jelly block in free fall in the middle of a large box, far from its walls for the steps run."""
    return (SceneBuilder(dim=2, name="falling").grid(size=1.0, cells=32).material("m", "fixed_corotated", E=1e3)
            .box("m", lower=[0.4, 0.5], upper=[0.6, 0.7]).gravity([0.0, -9.8]).walls(walls).time(dt=1e-4).build())


def states_of(scene, steps, every):
    sim = Simulation(scene)
    kept = [sim.state]
    for n in range(steps):
        sim.step()
        if (n + 1) % every == 0:
            kept.append(sim.state)
    return kept


def by_name(items):
    return {i.name: i for i in items}


def test_free_fall_exercises_neither_c_nor_f_nor_the_walls():
    """Every particle falls with g t: the affine matrix and the deformation stay at round-off, and no particle comes
    near a wall, so a wrong C, a wrong F update or a wrong wall would not show along this run."""
    scene = falling_block()
    items = by_name(exercised(scene, states_of(scene, 20, 10)))
    assert not items["C"].exercised and items["C"].figure < 1e-10
    assert not items["F"].exercised and items["F"].figure < 1e-10
    assert not items["walls"].exercised and items["walls"].figure == 0
    assert not_exercised(items.values()) == (f"C stayed below {FLOOR:g} of its scale; F stayed below {FLOOR:g} of "
                                             "its scale; walls never touched")


def test_a_block_that_lands_exercises_c_f_and_the_floor():
    """The same block dropped just above the floor: once it lands, it shears and squashes (C and F) and its lowest
    particles reach the floor's band; seen at every step, since it bounces off again."""
    scene = (SceneBuilder(dim=2, name="landing").grid(size=1.0, cells=32).material("m", "fixed_corotated", E=1e3)
             .box("m", lower=[0.4, 0.14], upper=[0.6, 0.3]).gravity([0.0, -9.8]).walls("sticky").time(dt=1e-4)
             .build())
    items = by_name(exercised(scene, states_of(scene, 1200, 1)))
    assert items["C"].exercised and items["F"].exercised and items["walls"].exercised
    assert not_exercised(items.values()) == ""


def test_open_walls_are_no_item_and_a_plastic_material_reports_its_flow():
    scene = Scene.from_toml("examples/snow88.toml")
    sim = Simulation(scene)
    before = by_name(exercised(scene, [sim.state]))
    assert not before["plastic flow"].exercised and before["plastic flow"].figure == 0.0
    assert "walls" not in by_name(exercised(falling_block("open"), [Simulation(falling_block("open")).state]))
    sim.particles.Jp[:] = np.linspace(0.9, 1.1, sim.n_particles)
    assert by_name(exercised(scene, [sim.particles]))["plastic flow"].exercised
