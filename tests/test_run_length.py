"""The length of a run, said before it starts: ``mpmref run --t-end T`` and ``mpmref study`` print one line
with the steps, the particles and the rate measured on a few steps here; past an hour, a warning that says how
Ctrl-C stops it. The estimate is checked against a fixed-Δt scene, whose step count is known."""

import re

import numpy as np
import pytest

from mpmref import Scene, Simulation
from mpmref.cli import LONG_RUN_S, duration, length_line, main, run_length
from verification.framework.executor import Executor

DT = 1.0e-3
#: a 2D elastic block on an 8-cell grid stepped at a fixed Δt
SCENE = f"""name = "tiny"
dim = 2
gravity = [0.0, -9.8]
[grid]
size = [1.0, 1.0]
cells = 8
[materials.jelly]
type = "fixed_corotated"
E = 1000.0
nu = 0.3
rho = 1.0
[[bodies]]
shape = "box"
material = "jelly"
lower = [0.3, 0.4]
upper = [0.7, 0.7]
ppc = 4
[time]
dt = {DT}
t_end = 1.0
"""


@pytest.fixture
def scene_file(tmp_path):
    path = tmp_path / "tiny.toml"
    path.write_text(SCENE)
    return path


def particles(scene_file):
    return Simulation(Scene.from_toml(scene_file)).n_particles


def test_the_estimate_counts_the_steps_to_the_end_time_and_leaves_the_run_alone(scene_file):
    sim = Simulation(Scene.from_toml(scene_file))
    sim.run(steps=3)
    before = {k: a.copy() for k, a in sim.particles.arrays().items()}
    length = run_length(sim.scene, "numpy", 1.0e6 * DT, sim.state)
    assert length.steps == pytest.approx(1.0e6 - 3, rel=1e-9) and length.particles == sim.n_particles
    assert 1 <= length.probed <= 20 and length.rate > 0
    assert length.seconds == pytest.approx(length.steps * length.particles / length.rate, rel=1e-9)
    assert sim.step_count == 3
    for k, a in before.items():
        np.testing.assert_array_equal(getattr(sim.particles, k), a)


def test_a_probe_that_cannot_step_gives_no_estimate(scene_file):
    sim = Simulation(Scene.from_toml(scene_file))
    sim.run(steps=2)
    assert run_length(sim.scene, "numpy", DT, sim.state) is None  # the end time is past: the run says so itself


@pytest.mark.parametrize("seconds, text", [(0.1411, "0.14 s"), (40, "40 s"), (725, "12 min"), (3.5 * 3600, "3.5 h"),
                                           (9.1 * 86400, "9.1 days"), (1220 * 365.25 * 86400, "1220 years"),
                                           (3.2e4 * 365.25 * 86400, "3.2e+04 years")])
def test_durations_read_in_their_unit(seconds, text):
    assert duration(seconds) == text


def interrupt_at_start(monkeypatch, target, name):
    """Ctrl-C as soon as ``target.name`` is called (the run, or the study's runs, starting)."""
    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(target, name, interrupted)


def test_run_to_a_far_end_time_warns_before_it_starts(scene_file, tmp_path, monkeypatch, capsys):
    interrupt_at_start(monkeypatch, Simulation, "run")
    assert main(["run", str(scene_file), "--t-end", "1e9", "--out", str(tmp_path / "o"), "--no-progress"]) == 130
    warning, stop = capsys.readouterr().err.splitlines()
    assert warning.startswith("mpmref: warning: this will take about ")
    assert f" years (1e+12 steps of {particles(scene_file)} particles at " in warning
    assert warning.endswith("Ctrl-C stops it with a checkpoint that --resume continues")
    assert stop.startswith("mpmref: interrupted at step 0")


def test_run_to_a_near_end_time_says_how_long_its_steps_take(scene_file, tmp_path, capsys):
    assert main(["run", str(scene_file), "--t-end", str(5 * DT), "--out", str(tmp_path / "o"), "--no-progress"]) == 0
    line = capsys.readouterr().err.strip()
    assert line.startswith("mpmref: the steps will take about ")
    assert f"(5 steps of {particles(scene_file)} particles at " in line
    assert "warning" not in line


def test_a_study_to_a_far_end_time_warns_before_its_runs_start(scene_file, tmp_path, monkeypatch, capsys):
    interrupt_at_start(monkeypatch, Executor, "map")
    args = ["study", str(scene_file), "--vary", "grid.cells=8,16", "--t-end", "1e9", "--out", str(tmp_path / "s"),
            "--workers", "2", "--no-progress"]
    assert main(args) == 130
    warning, stop = capsys.readouterr().err.splitlines()
    assert re.fullmatch(r"mpmref study: warning: this will take about \S+ years \(2 runs, \S+ particle-steps at \S+ "
                        r"particle-steps/s measured on each run's first steps here, 2 at a time\); Ctrl-C stops it and "
                        r"keeps the finished runs, which the same command reuses", warning), warning
    assert stop.startswith("mpmref study: interrupted; 0 of 2 runs finished")


@pytest.mark.parametrize("seconds, warned", [(LONG_RUN_S - 1, False), (LONG_RUN_S + 1, True)])
def test_past_an_hour_the_line_is_a_warning_that_says_how_to_stop(seconds, warned):
    line = length_line("mpmref", seconds, "how", "what Ctrl-C does")
    assert line.startswith("mpmref: warning: this will take about") == warned
    assert line.endswith("(how); what Ctrl-C does" if warned else "(how)")


def test_a_study_on_a_compiled_backend_says_it_compiles_before_its_runs(scene_file, tmp_path, monkeypatch, capsys):
    pytest.importorskip("numba")
    interrupt_at_start(monkeypatch, Executor, "map")
    args = ["study", str(scene_file), "--vary", "grid.cells=8,16", "--t-end", "1e9", "--out", str(tmp_path / "s"),
            "--backend", "numba", "--workers", "2", "--no-progress"]
    assert main(args) == 130
    first = capsys.readouterr().err.splitlines()[0]
    assert re.fullmatch(r"mpmref study: compiling kernels for this scene \(the first run only: they are cached in "
                        r".+\)… done in \d+\.\d s", first), first
