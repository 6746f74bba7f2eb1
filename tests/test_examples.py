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
