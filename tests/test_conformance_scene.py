"""Conformance cases drawn from a user's scene (``mpmref conformance check|export --scene``), the stages of
asynchronous stepping, and Δt drawn per case in the CPIC cases.

* Every stage a scene's steps call has cases; each case keeps the scene's physics (method, materials with their
  parameters, walls, gravity, dtype), in its own small box at the scene's cell size, with its own Δt inside the stable
  range and its own time; colliders are placed in the box where the scene has them, relative to its walls.
* The states are drawn at the scene's scales; the reference reproduces itself on every example scene; the Numba
  backend passes the example scenes at 1e-12.
* The export records the scene, the scales and the resolved parameters.
"""

import json
from pathlib import Path

import numpy as np
import pytest

from mpmref.backends.numpy import NumpyBackend
from mpmref.cli import main
from mpmref.conformance import ASYNC_CONFORMANCE_STAGES, CPIC_CONFORMANCE_STAGES, check, make_cases, scene_cases
from mpmref.conformance.scenes import CASES_PER_STAGE, Compression, scene_scales, scene_stages
from mpmref.conformance.states import CFL_RANGE, cfl_number
from mpmref.conformance.vectors import load_vectors
from mpmref.scene import Scene

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = sorted((ROOT / "examples").glob("*.toml"))

#: a 2D scene with a moving disk, a plane and a box collider, two materials and mixed walls
COLLIDER_SCENE = {
    "name": "colliders", "dim": 2, "gravity": [0.0, -9.8], "grid": {"size": [2.0, 1.0], "cells": 64},
    "method": {"scheme": "apic"},
    "materials": {"jelly": {"type": "neo_hookean", "E": 2.0e4, "rho": 2.0}, "water": {"type": "fluid", "K": 1e3}},
    "bodies": [{"shape": "box", "material": "jelly", "lower": [0.4, 0.3], "upper": [0.8, 0.6],
                "velocity": [3.0, 0.0]}],
    "boundary": {"type": "slip", "walls": {"y_min": {"type": "separate", "friction": 0.4}}},
    "colliders": [{"shape": "disk", "center": [1.2, 0.4], "radius": 0.2, "velocity": [-1.0, 0.0],
                   "type": "separate", "friction": 0.2},
                  {"shape": "plane", "point": [0.0, 0.1], "normal": [0.1, 1.0], "type": "sticky"},
                  {"shape": "box", "lower": [1.6, 0.0], "upper": [1.9, 0.3], "type": "slip"}],
    "time": {"cfl": 0.4, "t_end": 1.0},
}


# ------------------------------------------------------------------------------------------- what is drawn
@pytest.mark.parametrize("path", EXAMPLES, ids=[p.stem for p in EXAMPLES])
def test_every_stage_a_scene_calls_has_its_cases_on_the_scenes_physics(path):
    scene = Scene.from_toml(path)
    cases = scene_cases(path)
    stages = scene_stages(scene)
    assert [c.stage for c in cases if c.extreme is None] == [s for s in stages for _ in range(CASES_PER_STAGE)]
    assert [c.stage for c in cases] == [s for s in stages for c in cases if c.stage == s]  # each stage's together
    if scene.rigid_bodies:
        assert set(CPIC_CONFORMANCE_STAGES) <= set(stages) and "step" not in stages
    if scene.time.stepping == "async":
        assert set(ASYNC_CONFORMANCE_STAGES) <= set(stages)  # conservative interfaces, the default
    assert ("return_map" in stages) == scene.tracks("Jp")
    for case in cases:
        own = case.scene()
        assert case.source == scene.name and own.dtype == scene.dtype and own.dim == scene.dim
        assert own.method == scene.method and own.cpic == scene.cpic and own.materials == scene.materials
        assert np.array_equal(own.gravity, scene.gravity) and own.boundary == scene.boundary
        assert own.time.stepping == scene.time.stepping and own.grid.dx == scene.grid.dx
        cells = np.array(own.grid.cells)
        assert len(set(cells)) > 1 and cells.min() >= max(8, 2 * (scene.boundary.width + 1))
        assert cells.max() <= cells.min() + 16


@pytest.mark.parametrize("name", ["mpm88", "stork2d", "cut2d", "fluid3d"])
def test_scene_cases_vary_box_origin_dt_and_time_inside_the_stable_range(name):
    cases = scene_cases(ROOT / "examples" / f"{name}.toml")
    scales = cases[0].scales
    for stage in dict.fromkeys(c.stage for c in cases):
        own = [c for c in cases if c.stage == stage and c.extreme is None]  # the extremes set their own Δt
        inputs = [c.inputs() for c in own]
        origins = {tuple(c.scene().grid.origin) for c in own}
        assert len(origins) == len(own)
        dts = [float(i["dt"]) for i in inputs if "dt" in i]
        if dts:
            assert len(set(dts)) == len(dts) == len(own)
            cfl = np.array([cfl_number(c.scene(), dt, scales.speed) for c, dt in zip(own, dts, strict=True)])
            assert cfl.max() <= CFL_RANGE[1] * (1 + 1e-12) and cfl.min() >= CFL_RANGE[0] * (1 - 1e-12)
        times = [float(i["time"]) for i in inputs if "time" in i]
        assert len(set(times)) == len(times)


def test_states_are_drawn_at_the_scenes_scales():
    """mpm88: the free fall across its unit box (√(2 g L) = 4.43 m/s) beats its bodies' 1 m/s; C is that over two
    cells; node masses are its density's; Δt spans its CFL range at its wave speed √(γ K / ρ) = 20 m/s."""
    path = ROOT / "examples" / "mpm88.toml"
    scales = scene_scales(Scene.from_toml(path))
    dx = 1.0 / 128
    assert scales.speed == pytest.approx(np.sqrt(2 * 9.8), rel=1e-12)
    assert scales.affine == pytest.approx(scales.speed / (2 * dx), rel=1e-12) and scales.density == 1.0
    assert scales.force_per_speed * scales.speed == pytest.approx(0.01 * 400.0 / dx, rel=1e-12)  # 0.01 c² / dx
    velocities = np.concatenate([c.inputs()["v"] for c in scene_cases(path, stages=("g2p",))])
    assert velocities.std() == pytest.approx(scales.speed, rel=0.1)
    grid = scene_cases(path, stages=("grid_update",))[0].inputs()
    filled = grid["grid_mass"][grid["grid_mass"] > 0]
    assert 0.2 * dx**2 <= filled.min() and filled.max() <= 1.5 * dx**2


def test_colliders_are_placed_in_each_box_as_in_the_scene():
    """The domain is mapped into each case's box by one scale and shift: every collider keeps its place relative to
    the walls, its shape and velocity, acts on some of the box's nodes, and moves less than two cells by the case's
    time; the scene's physics is kept (two materials, mixed walls)."""
    scene = Scene.from_dict(COLLIDER_SCENE)
    cases = scene_cases(COLLIDER_SCENE, stages=("grid_update", "step"))
    for case in cases:
        own = case.scene()
        box = {"origin": own.grid.origin, "size": np.array(own.grid.cells) * own.grid.dx}
        compression = Compression.between(scene.grid, box)
        disk = own.colliders[0]
        assert np.allclose(disk.shape.center, compression.point(scene.colliders[0].shape.center))
        assert disk.shape.radius == pytest.approx(compression.scale * 0.2)
        assert np.array_equal(disk.velocity, scene.colliders[0].velocity)
        nodes = own.grid.origin + own.grid.node_indices() * own.grid.dx
        for collider in own.colliders:
            assert (collider.shape.sdf(nodes) < 0).any(), (case.name, collider)
        time = float(case.inputs()["time"])
        assert time * np.linalg.norm(disk.velocity) < 2 * own.grid.dx
    report = check("numpy", cases)
    assert report.passed and len(report.results) == len(cases)


def test_the_reference_reproduces_itself_on_every_example_scene():
    """Bit for bit, but the fused P2G (the unfused one plus Δt times its force: round-off); two cases per stage."""
    for path in EXAMPLES:
        report = check("numpy", scene_cases(path, count=2))
        assert report.passed and not report.not_applicable, path.stem
        assert max(r.error for r in report.results if r.case.stage != "p2g_fused") == 0.0, path.stem
        assert max((r.error for r in report.results if r.case.stage == "p2g_fused"), default=0.0) < 2e-15


def test_a_backend_that_does_not_implement_the_scene_has_no_applicable_case():
    import sys

    sys.path.insert(0, str(ROOT / "examples"))
    try:
        report = check("mpm88_backend:factory", scene_cases(ROOT / "examples" / "jelly.toml"))
    finally:
        sys.path.remove(str(ROOT / "examples"))
    assert not report.results and not report.passed
    assert {n.reasons for n in report.not_applicable} == {
        ("needs the material fixed_corotated", "compares F: this backend evolves C, J only",
         "needs friction (Coulomb, talk Eq. 25)")}
    assert "no case applies to this candidate: nothing was checked" in report.table()


# ------------------------------------------------------------------------------------------------ the export
def test_export_scene_records_the_scene_its_scales_and_the_resolved_parameters(tmp_path, capsys):
    path = ROOT / "examples" / "mpm88.toml"
    assert main(["conformance", "export", str(tmp_path), "--scene", str(path)]) == 0
    assert "wrote 50 cases" in capsys.readouterr().out  # 35 drawn, 15 at the extremes
    manifest = json.loads((tmp_path / "manifest.json").read_text())
    assert manifest["version"] == 5 and manifest["scene"]["name"] == "mpm88"
    assert manifest["scene"]["declared"]["materials"]["water"]["gamma"] == 1.0
    assert manifest["scene"]["resolved"]["grid"]["cells"] == [128, 128]
    assert manifest["scene"]["resolved"]["boundary"]["walls"]["y_min"] == {"type": "separate", "friction": 0.0}
    assert manifest["scene"]["stages"] == scene_stages(Scene.from_toml(path))
    assert manifest["scene"]["scales"]["speed"] == pytest.approx(np.sqrt(2 * 9.8))
    for entry in manifest["cases"]:
        assert entry["source"] == "mpm88" and entry["resolved"]["materials"][0]["gamma"] == 1.0
        assert entry["resolved"]["boundary"]["width"] == 3 and entry["resolved"]["grid"]["dx"] == 1.0 / 128
        inputs, outputs = load_vectors(tmp_path / entry["file"])
        assert set(outputs) and all(a.dtype.kind != "f" or a.dtype == np.float64 for a in inputs.values())
    fused = next(e for e in manifest["cases"] if e["stage"] == "p2g_fused")
    assert "in_tau" in fused["arrays"]


# ------------------------------------------------------------------------------------------------- numba
@pytest.mark.parametrize("name", [pytest.param("jelly"), *[pytest.param(n, marks=pytest.mark.slow)
                                                          for n in ("snow88", "sand", "stork2d", "cut2d")]])
def test_numba_conforms_on_example_scenes_at_1e_12(name):
    """A compiled backend on the example scenes (jelly in the default run; the others compile more kernels, about a
    minute on a fresh cache with CPIC's: the slow set)."""
    cases = scene_cases(ROOT / "examples" / f"{name}.toml")
    report = check("numba", cases, rtol=1e-12)
    assert report.passed and len(report.results) == len(cases), report.table()


# ----------------------------------------------------------------------------------- asynchronous stepping
ASYNC_CASES = make_cases(dims=(2,), stages=ASYNC_CONFORMANCE_STAGES)


class KicksWithoutFlipShare(NumpyBackend):
    """Node kicks with κ = 1 whatever the scheme (FLIP's G2P returns only the share 1 - α of the exchange)."""

    def interface_kicks(self, grid_state, dt, kappa):
        return super().interface_kicks(grid_state, dt, 1.0)


class G2pWithoutKicks(NumpyBackend):
    """A G2P that ignores the node kicks: no impulse, no moment."""

    def g2p(self, particles, v_grid, v_tilde, dt, prepared=None, kicks=None):
        new = super().g2p(particles, v_grid, v_tilde, dt, prepared)
        if kicks is None:
            return new
        n, d = particles.x.shape
        return new, (np.zeros((n, d)), np.zeros((n, 1 if d == 2 else 3)))


def test_the_stages_of_asynchronous_stepping_are_checked_and_catch_their_bugs():
    """The reference reproduces itself; the kicks' κ is seen only with FLIP; a G2P that drops the kicks fails every
    kick case on the impulses (their states exchange momentum across classes)."""
    assert {c.stage for c in ASYNC_CASES} == set(ASYNC_CONFORMANCE_STAGES)
    assert all(c.scene().time.stepping == "async" and c.dt > 0 for c in ASYNC_CASES)
    reference = check("numpy", ASYNC_CASES)
    assert reference.passed and reference.worst().error == 0.0
    kappa = check(KicksWithoutFlipShare, ASYNC_CASES)
    assert {r.case.name for r in kappa.failures()} == {"interface_kicks-2d-flip-mls-quadratic"}
    dropped = check(G2pWithoutKicks, ASYNC_CASES)
    assert {r.case.stage for r in dropped.failures()} == {"g2p_kicks"}
    assert len(dropped.failures()) == len([c for c in ASYNC_CASES if c.stage == "g2p_kicks"])
    assert all(r.worst_output in ("impulse_P", "impulse_L") for r in dropped.failures())


def test_a_synchronous_backend_is_not_applicable_to_the_stages_of_asynchronous_stepping():
    import sys

    sys.path.insert(0, str(ROOT / "examples"))
    try:
        report = check("mpm88_backend:factory", ASYNC_CASES)
    finally:
        sys.path.remove(str(ROOT / "examples"))
    assert not report.results
    assert all("needs asynchronous time stepping" in n.reasons for n in report.not_applicable)


# ------------------------------------------------------------------------------------------ CPIC's Δt and time
def test_cpic_cases_draw_dt_and_time_per_case_inside_the_stable_range():
    """Five or more Δt per CPIC stage (one per case), CFL numbers over decades, none past the
    penalty's bound k Δt <= 1, and the time varies too."""
    for stage in ("cpic_p2g", "cpic_g2p", "cpic_step"):
        cases = make_cases(dims=(2, 3), stages=(stage,))
        inputs = [c.inputs() for c in cases]
        dts = np.array([float(i["dt"]) for i in inputs])
        assert len(set(dts)) == len(dts) >= 5
        assert all(float(i["dt"]) == c.scene().time.dt for c, i in zip(cases, inputs, strict=True))
        penalty = np.array([c.scene().cpic.penalty for c in cases])
        assert np.all(penalty * dts <= 1.0 + 1e-12)
        cfl = np.array([cfl_number(c.scene()) for c in cases])
        assert cfl.max() <= CFL_RANGE[1] and np.log10(cfl.max() / cfl.min()) > 2
        times = [float(i["time"]) for i in inputs]
        assert len(set(times)) == len(times)
