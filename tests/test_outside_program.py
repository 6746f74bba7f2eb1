"""The outside program (examples/outside_mpm, which never imports mpmref) through the command line: mpmref export, its
own run, mpmref compare; the correct program passes in float64 and float32, each planted bug is caught at the frame
where it starts to act, with the statistics it moves named (docs/comparing_runs.md)."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mpmref import Scene, Simulation
from mpmref.cli import main
from mpmref.exchange import read_frames
from verification.compare.comparison import frame_stops, judged, run_ensemble
from verification.framework.executor import Executor

ROOT = Path(__file__).resolve().parents[1]
PROGRAM = ROOT / "examples" / "outside_mpm" / "outside_mpm.py"
SCENE = ROOT / "examples" / "outside_mpm" / "two_blocks.toml"
MEMBERS = 7
POSITIONS = ("com_", "q05_", "q50_", "q95_", "min_", "max_")


def outside(start, out, *options):
    """Run the outside program in its own Python process (mpmref is not imported there)."""
    subprocess.run([sys.executable, str(PROGRAM), "run", str(start), str(out), *options], check=True,
                   capture_output=True)
    return out


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The exported start and the outside program's runs: correct (from the .npz start and from the CSV one, and in
    float32 for 300 steps) and with each planted bug."""
    folder = tmp_path_factory.mktemp("outside")
    assert main(["export", str(SCENE), str(folder / "start")]) == 0
    options = {"correct": (), "csv": ("--csv",), "float32": ("--dtype", "float32", "--steps", "300"),
               **{bug: ("--bug", bug) for bug in ("stiffness", "wall-gravity", "half-dt-advect", "friction-sign")}}
    return folder, {name: outside(folder / "start", folder / name, *o) for name, o in options.items()}


def first_contact_step(scene):
    """The first step at which a particle's stencil reaches a wall's band of nodes, from the NumPy reference's run:
    where a bug of the walls starts to act (independent of mpmref compare)."""
    sim = Simulation(scene)
    width, cells = scene.boundary.width, np.array(scene.grid.cells)
    while sim.step_count < scene.time.steps:
        base = np.floor((sim.x - scene.grid.origin) / scene.grid.dx - 0.5).astype(int)
        if (base <= width - 1).any() or (base + 2 >= cells - width + 1).any():
            return sim.step_count
        sim.step()
    return None


def test_the_program_starts_from_the_exported_start_bit_for_bit(runs):
    folder, dirs = runs
    scene = Scene.from_toml(SCENE)
    ids = Simulation(scene).id
    npz, csv = (read_frames(dirs[name], 2, ids) for name in ("correct", "csv"))
    assert np.array_equal(npz[0].x, Simulation(scene).x) and npz[0].dtype == np.float64
    assert all(np.array_equal(a.x, b.x) for a, b in zip(npz, csv))  # the CSV start reads back to the same bits
    assert [f.step for f in npz] == list(range(0, 601, 30))


@pytest.mark.parametrize("name, dtype, backend, frames", [("correct", "float64", "numba", 21),
                                                          ("float32", "float32", "numpy", 11)])
def test_compare_passes_the_correct_program(runs, name, dtype, backend, frames, capsys):
    """float32 frames are judged against a float32 ensemble (here of the NumPy reference: the suite does not compile
    the Numba backend's float32 kernels; the measured rates of docs/comparing_runs.md use them)."""
    folder, dirs = runs
    out = folder / f"report_{name}"
    assert main(["compare", str(SCENE), str(dirs[name] / "particles.pvd"), "--members", str(MEMBERS), "--workers",
                 "1", "--backend", backend, "--out", str(out), "--no-progress"]) == 0
    assert capsys.readouterr().out.startswith(f"PASSED: every one of {frames} frames lies in the ensemble")
    result = json.loads((out / "results.json").read_text())
    assert result["passed"] and result["dtype"] == dtype and result["backend"] == backend


def test_a_bug_after_contact_fails_on_the_command_line_naming_frame_and_statistic(runs, capsys):
    folder, dirs = runs
    out = folder / "report_friction"
    assert main(["compare", str(SCENE), str(dirs["friction-sign"]), "--members", str(MEMBERS), "--workers", "1",
                 "--out", str(out), "--no-progress"]) == 1
    contact = first_contact_step(Scene.from_toml(SCENE))
    expected = -(-contact // 30) * 30  # the first frame at or after the contact
    assert capsys.readouterr().out.startswith(f"FAILED: the code leaves the ensemble at step {expected}")
    first = json.loads((out / "results.json").read_text())["first_failure"]
    assert first["step"] == expected and any(s["statistic"].endswith("momentum_x") for s in first["statistics"])
    assert (out / f"deviation_{expected:06d}.vtu").is_file() and len(first["particles"]) == 10


def test_each_planted_bug_is_caught_where_it_starts_to_act(runs):
    folder, dirs = runs
    scene = Scene.from_toml(SCENE)
    frames = {bug: read_frames(dirs[bug], 2, Simulation(scene).id)
              for bug in ("stiffness", "wall-gravity", "half-dt-advect", "friction-sign")}
    ensemble = run_ensemble(scene, frame_stops(scene, frames["stiffness"]), members=MEMBERS,
                            executor=Executor(workers=1))
    failures = {bug: judged(scene, f, ensemble, "numba", MEMBERS, 0).first_failure for bug, f in frames.items()}
    contact = -(-first_contact_step(scene) // 30) * 30
    assert {bug: f.step for bug, f in failures.items()} == {"stiffness": 30, "half-dt-advect": 30,
                                                            "wall-gravity": contact, "friction-sign": contact}
    assert failures["stiffness"].left[0][0].startswith("jelly:")  # material 0, the one made stiffer
    assert failures["half-dt-advect"].left[0][0].split(":")[1].startswith(POSITIONS)
    assert all(f.left and f.phase == "round-off" for f in failures.values())
