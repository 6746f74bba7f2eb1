"""CPIC in 3D on the Numba backend: the 3D conformance cases (non-trivial, and failing for a broken stage on the
reference; these default tests compile nothing), and, in the slow set, the compiled 3D stages against the
reference at 1e-12, a coupled trajectory and bitwise thread-count independence."""

import numba
import numpy as np
import pytest
from test_cpic_numba import AllCompatible, ForgetfulTags, assert_state_follows

from mpmref import Scene, Simulation
from mpmref.backends.numba import threads as numba_threads
from mpmref.conformance import CPIC_CONFORMANCE_STAGES, check, make_cases

CASES_3D = make_cases(dims=(3,), stages=CPIC_CONFORMANCE_STAGES)
QUICK_3D = [c for c in CASES_3D if c.variant in ("bodies", "pic-mls-quadratic")]


def _reference(stage, variant="pic-mls-quadratic"):
    case = next(c for c in CASES_3D if c.stage == stage and c.variant in (variant, "bodies"))
    inputs = case.inputs()
    return inputs, case.reference(inputs)


def test_3d_cpic_cases_cover_every_stage_and_method():
    from mpmref.conformance.cases import cpic_methods

    assert {c.stage for c in CASES_3D} == set(CPIC_CONFORMANCE_STAGES) and all(c.dim == 3 for c in CASES_3D)
    labels = {f"{m['scheme']}-{m['force']}-{m['kernel']}" for m in cpic_methods()}
    for stage in ("cpic_p2g", "cpic_g2p", "cpic_step"):
        assert labels <= {c.variant for c in CASES_3D if c.stage == stage}


def test_3d_cpic_cases_exercise_every_branch():
    """Every body bands nodes on both sides; near and far particles, penetrated ones (phi < 0), incompatible
    nodes, new and dropped tags, impulses on every body and the penalty all occur."""
    _, field = _reference("cpic_field")
    assert field["cdf_A"].sum(axis=0).min() >= 5 and field["cdf_T"].sum(axis=0).min() >= 3
    assert set(np.unique(field["cdf_body"])) == {-1, 0, 1, 2}
    inputs, tags = _reference("cpic_tags")
    n = len(inputs["x"])
    assert n / 2 < tags["near"].sum() < n
    assert (tags["phi"][tags["near"]] < 0).sum() >= 10 and (tags["phi"][tags["near"]] > 0).sum() >= 10
    assert (~tags["compatible"]).sum() > 100
    assert (tags["tag_A"] & ~inputs["tag_A"]).any() and (inputs["tag_A"] & ~tags["tag_A"]).any()
    _, p2g = _reference("cpic_p2g")
    assert np.all(np.abs(p2g["impulse_J"]).max(axis=1) > 1e-4) and p2g["impulse_L"].shape == (3, 3)
    _, g2p = _reference("cpic_g2p")
    assert np.abs(g2p["penalty_J"]).max() > 1e-3


@pytest.mark.parametrize("candidate, failing", [(ForgetfulTags, set(CPIC_CONFORMANCE_STAGES) - {"cpic_field"}),
                                                (AllCompatible, {"cpic_tags", "cpic_p2g", "cpic_g2p", "cpic_step"})])
def test_broken_3d_cpic_fails_at_the_stages_it_breaks(candidate, failing):
    report = check(candidate, QUICK_3D)
    assert report.failed_stages() == failing
    assert check("numpy", QUICK_3D).worst().error == 0.0


def test_exported_3d_cpic_vectors_are_the_references(tmp_path):
    """3D CPIC cases export like the 2D ones: the reference's outputs bit for bit, and the meshes with their
    inertia tensors in the manifest's resolved scene."""
    import json

    from mpmref.conformance import export, load_vectors

    cases = [c for c in QUICK_3D if c.stage in ("cpic_field", "cpic_p2g")]
    export(tmp_path, cases)
    manifest = json.loads((tmp_path / "manifest.json").read_text())
    for case, entry in zip(cases, manifest["cases"]):
        inputs, outputs = load_vectors(tmp_path / entry["file"])
        reference = case.reference(inputs)
        assert outputs.keys() == reference.keys() and all(np.array_equal(outputs[k], reference[k]) for k in outputs)
    bodies = manifest["cases"][0]["resolved"]["rigid_bodies"]
    assert [len(b["triangles"]) for b in bodies] == [4, 4, 2]
    inertia = np.array(bodies[0]["inertia"])
    assert inertia.shape == (3, 3) and np.allclose(inertia, inertia.T) and bodies[1]["inertia"] == "inf"


@pytest.mark.slow
def test_numba_3d_cpic_stages_conform_at_1e_12():
    report = check("numba", CASES_3D, rtol=1e-12)
    assert report.passed, report.table()
    assert not report.skipped and len(report.results) == len(CASES_3D)


def box_scene(steps=30):
    """A jelly ball thrown onto a free V-shaped sheet next to a scripted, turning blade (every CPIC branch acts)."""
    return Scene.from_dict({
        "dim": 3, "name": "plate3d", "grid": {"size": 1.0, "cells": 16},
        "method": {"scheme": "apic", "coupling": "cpic", "penalty": 1e3, "pushing_force": 2e4},
        "materials": {"j": {"type": "fixed_corotated", "E": 1e3, "rho": 1.0}},
        "bodies": [{"shape": "sphere", "material": "j", "center": [0.5, 0.52, 0.5], "radius": 0.12,
                    "velocity": [0.3, -3.0, 0.2]}],
        "boundary": {"type": "open"}, "time": {"dt": 5e-4, "steps": steps},
        "rigid_bodies": [{"vertices": [[0.25, 0.4, 0.25], [0.5, 0.36, 0.25], [0.75, 0.41, 0.25], [0.25, 0.4, 0.75],
                                       [0.5, 0.36, 0.75], [0.75, 0.41, 0.75]],
                          "triangles": [[0, 1, 4], [0, 4, 3], [1, 2, 5], [1, 5, 4]], "motion": "dynamic",
                          "density": 1.0},
                         {"vertices": [[0.45, 0.45, 0.4], [0.55, 0.7, 0.4], [0.5, 0.6, 0.62]],
                          "triangles": [[0, 1, 2]], "motion": "scripted", "velocity": [0.0, -1.0, 0.0],
                          "angular_velocity": [0.0, 2.0, 1.0], "type": "sticky"}]})


@pytest.mark.slow
def test_numba_3d_trajectory_with_bodies_follows_the_reference(candidate):
    """30 coupled 3D steps: every particle and body field within 1e-12 of the reference, tags identical."""
    scene = box_scene()
    sims = {b: Simulation(scene, backend=b) for b in ("numpy", candidate)}
    for sim in sims.values():
        sim.run()
    ref, got = sims["numpy"].state, sims[candidate].state
    assert ref.particles.near.sum() > 20 and np.abs(ref.rigid.impulse).max() > 0
    assert_state_follows(ref, got)


@pytest.mark.slow
def test_3d_cpic_steps_are_bitwise_identical_for_one_and_two_threads(monkeypatch, parallel_builds):
    monkeypatch.setattr(numba_threads, "SERIAL_BELOW", 0)  # small scenes would otherwise run on one thread
    states = []
    for threads in (1, 2):
        before = numba.get_num_threads()
        numba.set_num_threads(threads)
        try:
            sim = Simulation(box_scene(), backend="numba")
            sim.run()
            states.append(sim.state)
        finally:
            numba.set_num_threads(before)
    one, two = states
    for name, array in one.particles.arrays().items():
        assert np.array_equal(array, two.particles.arrays()[name]), name
    for name, array in one.rigid.arrays().items():
        assert np.array_equal(array, two.rigid.arrays()[name]), name


@pytest.mark.slow
def test_cut3d_example_writes_the_blades_and_four_pieces(tmp_path):
    """examples/cut3d.toml with `mpmref run --backend numba`: the two crossed blades cut the block into 4 pieces, and
    the series holds the blades as polygon cells."""
    import glob

    from mpmref.cli import main
    from verification.cpic import components

    pv = pytest.importorskip("pyvista")
    assert main(["run", "examples/cut3d.toml", "--out", str(tmp_path), "--backend", "numba", "--no-progress"]) == 0
    last = sorted(glob.glob(str(tmp_path / "particles_*.vtu")))[-1]
    assert components(np.asarray(pv.read(last).points), 1.0 / 32) == 4
    blades = pv.read(sorted(glob.glob(str(tmp_path / "rigid_bodies_*.vtp")))[-1])
    assert blades.n_cells == 8 and set(blades.cell_data["body"]) == {0, 1}
    assert (tmp_path / "rigid_bodies.pvd").exists()
