"""Every example scene validates, samples and takes a few finite steps on the reference."""

from pathlib import Path

import numpy as np
import pytest

from mpmref import Scene, Simulation

EXAMPLES = sorted((Path(__file__).resolve().parent.parent / "examples").glob("*.toml"))


@pytest.mark.parametrize("path", EXAMPLES, ids=[p.stem for p in EXAMPLES])
def test_example_runs_a_few_steps(path):
    sim = Simulation(Scene.from_toml(path))
    first = sim.diagnostics()
    for _ in range(5):
        sim.step()
    last = sim.diagnostics()
    assert all(np.isfinite(a).all() for a in sim.particles.arrays().values())
    assert last["mass"] == first["mass"]


@pytest.mark.parametrize("path", EXAMPLES, ids=[p.stem for p in EXAMPLES])
def test_every_particle_frame_carries_the_ids_of_its_step(path, tmp_path):
    """``meshio.read`` of each particle frame gives an int64 ``id`` array equal, as a set, to ``sim.id`` at
    that step (and each id once), whatever the example deletes, emits or reorders."""
    import meshio

    src = dict(Scene.from_toml(path).source)
    src["output"] = {**src.get("output", {}), "every": 1}
    sim = Simulation(Scene.from_dict(src), out_dir=tmp_path)
    ids = {}
    for _ in range(3):
        ids[sim.step_count] = sim.id.copy()
        sim.run(steps=1)
    ids[sim.step_count] = sim.id.copy()
    frames = sorted(tmp_path.glob("particles_*.vtu"))
    assert [int(f.stem.split("_")[1]) for f in frames] == sorted(ids)
    for frame in frames:
        written = meshio.read(frame).point_data["id"]
        expected = ids[int(frame.stem.split("_")[1])]
        assert written.dtype == np.int64 and len(np.unique(written)) == len(written)
        assert set(written.tolist()) == set(expected.tolist())
