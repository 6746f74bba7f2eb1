"""CPIC on the Numba backend: stage-by-stage conformance with the NumPy reference (the CPIC conformance cases
are non-trivial and catch a broken stage), bitwise thread-count independence, and `mpmref run` of a CPIC scene."""

import importlib

import numba
import numpy as np
import pytest

from mpmref import Scene, Simulation
from mpmref.backends.numba import threads as numba_threads
from mpmref.backends.numpy import NumpyBackend
from mpmref.cli import main
from mpmref.conformance import CPIC_CONFORMANCE_STAGES, check, make_cases
from mpmref.physics.cdf import update_tags

CPIC_CASES = make_cases(dims=(2,), stages=CPIC_CONFORMANCE_STAGES)
#: the default run checks every stage on three methods (one per kernel, affine and not, both forces) and the step's
#: variants; the slow run checks all of them, the per-body fit included (a fresh Numba cache compiles two kernels per
#: method, and the per-body fit's kernels took 19 s of one core)
QUICK_VARIANTS = {"bodies", "mls-mls-quadratic", "pic-classic-linear", "apic-classic-cubic", "pic-mls-quadratic",
                  "pic-mls-quadratic-exact", "mls-mls-quadratic-no-ghost-force"}
QUICK_CASES = [c for c in CPIC_CASES if c.variant in QUICK_VARIANTS]


def test_cpic_cases_cover_every_stage_and_cpic_method():
    from mpmref.conformance.cases import cpic_methods

    assert {c.stage for c in CPIC_CASES} == set(CPIC_CONFORMANCE_STAGES)
    labels = {f"{m['scheme']}-{m['force']}-{m['kernel']}" for m in cpic_methods()}
    for stage in ("cpic_p2g", "cpic_g2p", "cpic_step"):
        assert labels <= {c.variant for c in CPIC_CASES if c.stage == stage}
    assert {c.scene().kernel.name for c in CPIC_CASES if c.stage == "cpic_tags"} == {"linear", "quadratic", "cubic"}
    assert {c.stage for c in QUICK_CASES} == set(CPIC_CONFORMANCE_STAGES)
    assert make_cases(stages=CPIC_CONFORMANCE_STAGES, dtype="float32") == []


def _reference(stage, variant="pic-mls-quadratic"):
    case = next(c for c in CPIC_CASES if c.stage == stage and c.variant in (variant, "bodies"))
    inputs = case.inputs()
    return inputs, case.reference(inputs)


def test_cpic_cases_exercise_every_branch():
    """The random states put particles near every body, on both sides, some of them penetrated (their sticky
    tag disagrees with the geometry): incompatible nodes, rejected momentum, impulses on every body and the
    penalty all occur, so the conformance cases can fail where any of them is wrong."""
    _, field = _reference("cpic_field")
    assert field["cdf_A"].sum(axis=0).min() >= 5 and field["cdf_T"].sum(axis=0).min() >= 3
    assert set(np.unique(field["cdf_body"])) == {-1, 0, 1, 2}
    inputs, tags = _reference("cpic_tags")
    n = len(inputs["x"])
    assert n / 2 < tags["near"].sum() < n  # near and far particles
    assert (tags["phi"][tags["near"]] < 0).sum() >= 10 and (tags["phi"][tags["near"]] > 0).sum() >= 10
    assert (~tags["compatible"]).sum() > 100
    assert (tags["tag_A"] & ~inputs["tag_A"]).any() and (inputs["tag_A"] & ~tags["tag_A"]).any()  # new and dropped
    _, p2g = _reference("cpic_p2g")
    assert np.all(np.abs(p2g["impulse_J"]).max(axis=1) > 1e-3)
    assert np.any(p2g["grid_rejected_momentum"] != 0) and np.any(p2g["grid_rejected_force"] != 0)
    _, g2p = _reference("cpic_g2p")
    assert np.abs(g2p["penalty_J"]).max() > 1e-2


@pytest.mark.parametrize("cases", [pytest.param(QUICK_CASES, id="quick"),
                                   pytest.param([c for c in CPIC_CASES if c not in QUICK_CASES], id="all",
                                                marks=pytest.mark.slow)])
def test_numba_cpic_stages_conform_at_1e_12(cases):
    report = check("numba", cases, rtol=1e-12)
    assert report.passed, report.table()
    assert not report.skipped and len(report.results) == len(cases)


def test_reference_cpic_stages_reproduce_themselves_exactly():
    report = check("numpy", QUICK_CASES)
    assert report.passed and report.worst().error == 0.0


class ForgetfulTags(NumpyBackend):
    """The reference with tags recomputed every step (no sticky side memory): the broken variant of CPIC."""

    def cpic_contact(self, particles, prepared, rigid, dt):
        n, nb = particles.tag_A.shape
        cleared = particles.with_(tag_A=np.zeros((n, nb), dtype=bool), tag_T=np.zeros((n, nb), dtype=bool))
        return super().cpic_contact(cleared, prepared, rigid, dt)


class AllCompatible(NumpyBackend):
    """The reference that lets every node take every particle (no compatibility, i.e. plain MPM)."""

    def cpic_contact(self, particles, prepared, rigid, dt):
        particles, contact = super().cpic_contact(particles, prepared, rigid, dt)
        contact.compatible[:] = True
        return particles, contact


@pytest.mark.parametrize("candidate, failing", [(ForgetfulTags, set(CPIC_CONFORMANCE_STAGES) - {"cpic_field"}),
                                                (AllCompatible, {"cpic_tags", "cpic_p2g", "cpic_g2p", "cpic_step"})])
def test_broken_cpic_fails_at_the_stages_it_breaks(candidate, failing):
    report = check(candidate, QUICK_CASES)
    assert report.failed_stages() == failing
    assert all(r.passed for r in report.results if r.case.stage == "cpic_field")


def test_forgetful_tags_differ_from_sticky_ones():
    """Sanity of the broken variant above: clearing the tags changes some particle's side."""
    inputs, tags = _reference("cpic_tags")
    case = next(c for c in CPIC_CASES if c.stage == "cpic_tags")
    from mpmref.backends.numba.cpic.field2d import build_cdf
    from mpmref.conformance.cpic import rigid_from

    scene = case.scene()
    cdf = build_cdf(scene.rigid_bodies, rigid_from(inputs), np.array(scene.grid.node_shape), scene.grid.origin,
                    scene.grid.dx)
    fresh_A, fresh_T = update_tags(cdf, inputs["x"], np.zeros_like(inputs["tag_A"]), np.zeros_like(inputs["tag_T"]))
    assert np.any(fresh_T != tags["tag_T"])


# -------------------------------------------------------------------------------------------- threads
def plate_scene(cells=64, steps=20, scheme="apic"):
    """A jelly disk thrown onto a free plate, with pushing force and penalty (every CPIC branch acts)."""
    return Scene.from_dict({
        "dim": 2, "name": "plate", "grid": {"size": 1.0, "cells": cells},
        "method": {"scheme": scheme, "coupling": "cpic", "penalty": 1e3, "pushing_force": 2e4},
        "materials": {"j": {"type": "fixed_corotated", "E": 1e3, "rho": 1.0}},
        "bodies": [{"shape": "disk", "material": "j", "center": [0.5, 0.5], "radius": 0.12, "velocity": [0.3, -3.0]}],
        "boundary": {"type": "open"}, "time": {"dt": 2e-4, "steps": steps},
        "rigid_bodies": [{"vertices": [[0.25, 0.4], [0.5, 0.38], [0.75, 0.41]], "segments": [[0, 1], [1, 2]],
                          "motion": "dynamic", "density": 1.0},
                         {"vertices": [[0.45, 0.45], [0.55, 0.7]], "segments": [[0, 1]], "motion": "scripted",
                          "velocity": [0.0, -1.0], "angular_velocity": 2.0, "type": "sticky"}]})


def run_with_threads(threads, scene, steps):
    before = numba.get_num_threads()
    numba.set_num_threads(threads)
    try:
        sim = Simulation(scene, backend="numba")
        sim.run(steps=steps)
        return sim.state
    finally:
        numba.set_num_threads(before)


def test_cpic_steps_are_bitwise_identical_for_one_and_two_threads(monkeypatch, parallel_builds):
    monkeypatch.setattr(numba_threads, "SERIAL_BELOW", 0)  # small scenes would otherwise run on one thread
    scene = plate_scene()
    one, two = run_with_threads(1, scene, 40), run_with_threads(2, scene, 40)
    assert one.particles.near.sum() > 20 and np.abs(one.rigid.impulse).max() > 0  # the coupling acted
    for name, array in one.particles.arrays().items():
        assert np.array_equal(array, two.particles.arrays()[name]), name
    for name, array in one.rigid.arrays().items():
        assert np.array_equal(array, two.rigid.arrays()[name]), name


def test_numba_trajectory_with_bodies_follows_the_reference(candidate):
    """40 coupled steps: every particle and body field within 1e-12 of the reference (relative to its
    largest entry), tags identical."""
    scene = plate_scene(cells=32)
    sims = {b: Simulation(scene, backend=b) for b in ("numpy", candidate)}
    for sim in sims.values():
        sim.run(steps=40)
    ref, got = sims["numpy"].state, sims[candidate].state
    assert ref.particles.near.sum() > 5
    assert_state_follows(ref, got)


def assert_state_follows(ref, got, rtol=1e-12):
    """Every particle and body field of ``got`` within ``rtol`` of ``ref`` (relative to its largest entry);
    boolean fields (the tags, ``near``) identical."""
    for name, array in ref.particles.arrays().items():
        other = got.particles.arrays()[name]
        if array.dtype == bool:
            assert np.array_equal(array, other), name
        else:
            assert np.abs(other - array).max() <= rtol * max(np.abs(array).max(), 1e-300), name
    for name, array in ref.rigid.arrays().items():
        assert np.abs(got.rigid.arrays()[name] - array).max() <= rtol * max(np.abs(array).max(), 1e-300), name


def test_mpmref_run_of_a_cpic_scene_with_numba(tmp_path, capsys):
    scene = tmp_path / "plate.toml"
    scene.write_text("""dim = 2
name = "plate"
[grid]
size = 1.0
cells = 32
[method]
scheme = "mls"
coupling = "cpic"
[materials.j]
type = "fixed_corotated"
E = 1000.0
rho = 1.0
[[bodies]]
shape = "disk"
material = "j"
center = [0.5, 0.47]
radius = 0.06
velocity = [0.0, -3.0]
[boundary]
type = "open"
[time]
dt = 0.0002
steps = 20
[[rigid_bodies]]
vertices = [[0.3, 0.4], [0.7, 0.4]]
segments = [[0, 1]]
motion = "dynamic"
density = 1.0
""")
    out = tmp_path / "out"
    assert main(["run", str(scene), "--out", str(out), "--backend", "numba", "--no-progress"]) == 0
    assert "outputs" in capsys.readouterr().out
    rows = (out / "diagnostics.csv").read_text().splitlines()
    header, last = rows[0].split(","), rows[-1].split(",")
    assert float(last[header.index("rigid0_impulse_y")]) < 0  # the disk pushed the plate down


def test_exported_cpic_vectors_are_the_references(tmp_path):
    """The CPIC cases export like the others: inputs, the reference's outputs bit for bit, and the bodies in
    the manifest's resolved scene."""
    import json

    from mpmref.conformance import export, load_vectors

    cases = [c for c in QUICK_CASES if c.variant in ("bodies", "pic-mls-quadratic")]
    export(tmp_path, cases)
    manifest = json.loads((tmp_path / "manifest.json").read_text())
    assert "cpic" in manifest["conventions"]
    for case, entry in zip(cases, manifest["cases"]):
        inputs, outputs = load_vectors(tmp_path / entry["file"])
        expected = case.inputs()
        assert inputs.keys() == expected.keys() and all(np.array_equal(inputs[k], expected[k]) for k in inputs)
        reference = case.reference(inputs)
        assert outputs.keys() == reference.keys()
        assert all(np.array_equal(outputs[k], reference[k]) for k in outputs)
        bodies = entry["resolved"]["rigid_bodies"]
        assert [b["motion"] for b in bodies] == ["dynamic", "scripted", "fixed"]
        assert bodies[1]["mass"] == "inf" and bodies[1]["friction"] == [-1.0, -1.0]


def test_impulses_go_to_each_node_s_nearest_body(backend):
    """Momentum accounting (docs/cpic.md), reference and compiled reduction: with two bodies near, an
    incompatible node's impulse goes to the nearer one, with its torque about that body's reference point."""
    from types import SimpleNamespace

    from mpmref.physics.cdf import build_cdf
    from mpmref.rigid.dynamics import RigidState
    from mpmref.rigid.polyline import validate_polyline

    dx = 1.0 / 32
    lower = validate_polyline([[0.2, 0.5 - 0.4 * dx], [0.8, 0.5 - 0.4 * dx]], [[0, 1]])
    upper = validate_polyline([[0.2, 0.5 + 0.7 * dx], [0.8, 0.5 + 0.7 * dx]], [[0, 1]])
    cdf = build_cdf([lower, upper], (33, 33), (0.0, 0.0), dx)
    node = np.ravel_multi_index((16, 16), (33, 33))  # (0.5, 0.5): 0.4 dx from the lower, 0.7 dx from the upper
    rejected = np.zeros((33 * 33, 2))
    rejected[node] = [1.0, -2.0]
    grid_state = SimpleNamespace(rejected_momentum=rejected, rejected_force=np.zeros_like(rejected))
    rigid = RigidState(position=np.array([[0.5, 0.49], [0.5, 0.52]]), angle=np.zeros(2), velocity=np.zeros((2, 2)),
                       angular_velocity=np.zeros(2), impulse=np.zeros((2, 2)), angular_impulse=np.zeros(2))
    from mpmref.backends.numba.cpic.stages import CPIC_KERNELS_BY_DIM

    impulses = importlib.import_module(f"mpmref.backends.{backend}.cpic").impulses
    # the Numba stages call the kernels the contact chose
    contact = SimpleNamespace(cdf=cdf, kernels=CPIC_KERNELS_BY_DIM[2])
    J, L = impulses(grid_state, contact, rigid, dt=1e-3)
    assert np.array_equal(J, [[1.0, -2.0], [0.0, 0.0]])
    assert L[0] == pytest.approx(-0.01 * 1.0) and L[1] == 0.0  # (x - c) = (0, 0.01): L = -0.01 * J_x


@pytest.mark.slow
def test_cut2d_example_on_numba_ends_in_two_pieces_like_the_reference(candidate):
    """examples/cut2d.toml (2510 steps) on Numba: the blade cuts the jelly into 2 pieces, and every particle ends
    where the reference puts it. Measured: 1.8e-12 dx apart; the bound 1e-9 dx leaves room for another
    machine's rounding over the 2510 steps while still catching any difference in the coupling."""
    from pathlib import Path

    from verification.cpic import components

    scene = Scene.from_toml(Path(__file__).resolve().parent.parent / "examples" / "cut2d.toml")
    states = {}
    for backend in ("numpy", candidate):
        sim = Simulation(scene, backend=backend)
        sim.run(t_end=0.8)
        states[backend] = sim.particles
    ref, got = states["numpy"], states[candidate]
    assert components(got.x, scene.grid.dx) == 2
    assert np.array_equal(ref.id, got.id) and np.array_equal(ref.tag_T, got.tag_T)
    assert np.abs(got.x - ref.x).max() <= 1e-9 * scene.grid.dx
