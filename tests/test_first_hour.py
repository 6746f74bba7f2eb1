"""The first hour, the safety half: stability guard, domain-exit policies, CLI refusals and Ctrl-C, Numba warm-up."""

import io
import os
import re
import shlex
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

from mpmref import (
    AllParticlesLeftError,
    DomainExitError,
    InstabilityError,
    NonFiniteError,
    Scene,
    SceneBuilder,
    Simulation,
)
from mpmref.cli import main
from mpmref.io.checkpoint import load_checkpoint
from mpmref.run.domain import apply_domain_exit
from mpmref.run.stability import MEASURED_LIMITS, StabilityWarning, first_unbounded, stable_cfl
from mpmref.state import Particles
from mpmref.steppers.pipeline import substep

ROOT = Path(__file__).resolve().parent.parent
JELLY = ROOT / "examples" / "jelly.toml"


def stiff_jelly(policy="error"):
    """The motivating example: examples/jelly.toml with E = 1e12 and a fixed Δt (CFL number 18 564 at step 1)."""
    src = dict(Scene.from_toml(JELLY).source)
    src["materials"] = {"jelly": dict(src["materials"]["jelly"], E=1e12)}
    src["time"] = {"dt": 2.5e-4, "steps": 20}
    src["boundary"] = dict(src["boundary"], domain_exit=policy)
    return Scene.from_dict(src)


# ------------------------------------------------------------------------------------- stability
@pytest.mark.parametrize("policy", ["error", "clamp", "delete"])
def test_the_issue_example_warns_at_step_1_and_stops_as_an_instability(tmp_path, policy):
    sim = Simulation(stiff_jelly(policy), out_dir=tmp_path)
    with pytest.warns(StabilityWarning, match=r"step 1: the CFL number of time.dt = 0.00025 is 18564"), \
            pytest.raises(InstabilityError) as info:
        sim.run()
    err = info.value
    assert not isinstance(err, DomainExitError)
    assert (err.step, err.particle, err.quantity) == (4, 0, "v") and err.cfl == pytest.approx(18564, rel=1e-4)
    assert "above 1.038" in str(err) and sim.clamped == 0 and sim.deleted == 0
    state, _ = load_checkpoint(err.checkpoint)
    assert state.step == 3 and np.isfinite(state.particles.v).all()
    assert np.abs(state.particles.v).max() * 2.5e-4 < sim.scene.grid.dx  # bounded: less than a cell per step


def test_a_time_step_below_the_measured_limit_is_not_warned():
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", StabilityWarning)
        Simulation(Scene.from_toml(JELLY)).run(steps=2)  # CFL rule 0.5
        src = dict(Scene.from_toml(JELLY).source, time={"dt": 1e-4, "steps": 2})  # CFL 0.55
        Simulation(Scene.from_dict(src)).run()
    assert not [w for w in caught if issubclass(w.category, StabilityWarning)]


def test_the_limits_table_is_the_one_in_docs_stability():
    text = (ROOT / "docs" / "stability.md").read_text(encoding="utf-8")
    rows = re.findall(r"^\| (base|ν = [\d.]+|E = [^|]+|ppc = \d+)[^|]* \| (.+) \|$", text, re.MULTILINE)
    documented = [[float(cell.split()[0]) for cell in cells.split(" | ")] for _, cells in rows]
    assert documented == [list(row.values()) for row in MEASURED_LIMITS.values()]
    assert stable_cfl("pic") == 0.912 and stable_cfl("mls") == 1.038


def test_a_non_finite_state_is_an_instability_with_the_last_good_state(tmp_path):
    sim = Simulation(flying_block("error"), out_dir=tmp_path)
    F = sim.F
    F[0] = np.diag([1.0, -1.0])  # inverted: the Neo-Hookean stress takes the log of det F < 0
    sim.F = F
    with pytest.raises(NonFiniteError) as info, np.errstate(invalid="ignore"):
        sim.step()
    assert isinstance(info.value, InstabilityError) and info.value.step == 1
    state, _ = load_checkpoint(info.value.checkpoint)
    assert state.step == 0 and all(np.isfinite(a).all() for a in state.particles.arrays().values())


def test_the_finite_check_looks_past_a_sum_that_overflows(tmp_path):
    """The finite check sums each array first and looks element by element only when the sum is not finite:
    huge but finite values (their float32 sum overflows) pass, and one inf among them is still found."""
    sim = Simulation(flying_block("error"), out_dir=tmp_path)
    huge = sim.particles.with_(v=np.full_like(sim.particles.v, 3e38, dtype=np.float32))
    assert not np.isfinite(np.sum(huge.v))
    sim._check_finite(huge, 1e-3)  # no error: every element is finite
    v = huge.v.copy()
    v[7, 1] = np.inf
    with pytest.raises(NonFiniteError) as info:
        sim._check_finite(huge.with_(v=v), 1e-3)
    assert info.value.particle == int(sim.id[7]) and info.value.quantity == "v"


def test_velocity_jumps_are_found_past_the_fast_bound():
    """first_unbounded's quick bound (largest component times sqrt(d), half the limit) only skips states far
    from the limit: a jump of 1.2 cells is found, one of 0.9 cells is not flagged."""
    v_old = np.zeros((5, 2), dtype=np.float32)
    for cells, found in ((1.2, True), (0.9, False)):
        v_new = v_old.copy()
        v_new[3] = [cells * 0.6, cells * 0.8]  # |dv| dt / dx = cells with dt = dx = 1
        result = first_unbounded(v_old, v_new, 1.0, 1.0)
        assert (result is not None) == found
        if found:
            assert result[0] == 3 and result[1] == pytest.approx(cells, rel=1e-6)


def test_all_inside_is_found_by_the_bounds_and_the_first_outside_particle_still_counts():
    lo, hi = np.array([0.0, 0.0]), np.array([1.0, 1.0])
    inside = particles_at([[0.1, 0.5], [0.9, 0.99]], [[0.0, 0.0], [0.0, 0.0]])
    assert apply_domain_exit(inside, lo, hi, "error").outside.size == 0
    edge = particles_at([[0.1, 0.5], [0.9, 1.0]], [[0.0, 0.0], [0.0, 0.0]])  # hi is excluded: [lo, hi)
    assert list(apply_domain_exit(edge, lo, hi, "error").outside) == [1]


# ------------------------------------------------------------------------------------ domain exit
def particles_at(x, v):
    x, v = np.array(x, dtype=float), np.array(v, dtype=float)
    n = len(x)
    return Particles(x=x, v=v, mass=np.ones(n), vol0=np.ones(n), material=np.zeros(n, dtype=np.int32))


def test_clamp_moves_back_inside_and_zeroes_only_the_outward_normal_velocity():
    lo, hi = np.array([0.0, 0.0]), np.array([1.0, 1.0])
    p = particles_at([[-0.1, 0.5], [0.5, 1.2], [0.5, 0.5], [1.0, -0.5]],
                     [[-2.0, 3.0], [4.0, 5.0], [-7.0, 8.0], [-1.0, -6.0]])
    out = apply_domain_exit(p, lo, hi, "clamp")
    assert out.clamped == 3 and out.deleted == 0 and list(out.outside) == [0, 1, 3]
    np.testing.assert_array_equal(out.particles.v, [[0.0, 3.0], [4.0, 0.0], [-7.0, 8.0], [-1.0, 0.0]])
    assert np.all((out.particles.x > lo) & (out.particles.x < hi))
    np.testing.assert_array_equal(out.particles.x[2], [0.5, 0.5])


def test_delete_and_error_policies():
    p = particles_at([[0.5, 0.5], [1.5, 0.5]], [[0.0, 0.0], [1.0, 0.0]])
    deleted = apply_domain_exit(p, np.zeros(2), np.ones(2), "delete")
    assert deleted.deleted == 1 and deleted.particles.n == 1
    error = apply_domain_exit(p, np.zeros(2), np.ones(2), "error")
    assert error.particles is p and list(error.outside) == [1]


def flying_block(policy, steps=60):
    return (SceneBuilder(dim=2, name="fly").grid(size=1.0, cells=16)
            .material("jelly", "neo_hookean", E=1e3, nu=0.3, rho=1.0)
            .box("jelly", lower=[0.4, 0.4], upper=[0.6, 0.6], velocity=[5.0, 0.0])
            .walls("open", domain_exit=policy).time(dt=2e-3, steps=steps).output(every=5).build())


def test_delete_stops_cleanly_when_the_last_particle_has_left(tmp_path):
    sim = Simulation(flying_block("delete"), out_dir=tmp_path)
    n0 = sim.n_particles
    with pytest.raises(AllParticlesLeftError) as info:
        sim.run()
    assert info.value.deleted == n0 and f"{n0} deleted" in str(info.value)
    assert sim.n_particles > 0 and sim.step_count == info.value.step - 1
    assert Path(info.value.checkpoint).name == "last_good_all_left.npz"


def test_cli_delete_until_empty_exits_3_with_one_line(tmp_path, capsys):
    scene = tmp_path / "fly.toml"
    scene.write_text('dim = 2\n[grid]\nsize = 1.0\ncells = 16\n[materials.j]\ntype = "neo_hookean"\nE = 1e3\n'
                     'rho = 1.0\n[[bodies]]\nshape = "box"\nmaterial = "j"\nlower = [0.4, 0.4]\nupper = [0.6, 0.6]\n'
                     'velocity = [5.0, 0.0]\n[boundary]\ntype = "open"\ndomain_exit = "delete"\n[time]\ndt = 2e-3\n'
                     'steps = 60\n')
    assert main(["run", str(scene), "--out", str(tmp_path / "o"), "--no-progress"]) == 3
    err = capsys.readouterr().err
    assert "AllParticlesLeftError: all particles have left the domain" in err and "Traceback" not in err


def test_clamp_is_counted_in_summary_and_diagnostics(tmp_path, capsys):
    scene = tmp_path / "fly.toml"
    text = (ROOT / "examples" / "jelly.toml").read_text()
    text = text.replace('type = "separate"', 'type = "open"\ndomain_exit = "clamp"')  # first clamped at step 228
    scene.write_text(text.replace('ppc = 4', 'ppc = 4\nvelocity = [20.0, 0.0]'))
    assert main(["run", str(scene), "--out", str(tmp_path / "o"), "--steps", "300", "--no-progress"]) == 0
    summary = capsys.readouterr().out
    clamped = int(re.search(r"(\d+) clamped back inside", summary).group(1))
    rows = (tmp_path / "o" / "diagnostics.csv").read_text().splitlines()
    header = rows[0].split(",")
    assert header[-1] == "clamped" and int(rows[-1].split(",")[-1]) == clamped > 0


# ----------------------------------------------------------------------------------------- CLI
def run_args(out, *extra):
    return ["run", str(JELLY), "--out", str(out), "--no-progress", *extra]


def test_rerun_into_a_used_out_is_refused_then_overwrite_replaces_it(tmp_path, capsys):
    out = tmp_path / "o"
    assert main(run_args(out, "--steps", "4")) == 0
    (out / "notes.txt").write_text("mine")
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    assert main(run_args(out, "--steps", "2")) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "already holds a run" in err and "--overwrite" in err and "--resume" in err
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert main(run_args(out, "--steps", "2", "--overwrite")) == 0
    assert (out / "notes.txt").read_text() == "mine"  # only the run's own files are cleared
    rows = (out / "diagnostics.csv").read_text().splitlines()
    assert [r.split(",")[0] for r in rows[1:]] == ["0", "2"] and not (out / "particles_000004.vtu").exists()


@pytest.mark.parametrize("out, expected", [("file", "existing file"), ("file/sub", "is a file"),
                                           ("/proc/mpmref-nope/x", "cannot write there")])
def test_out_problems_are_one_line_and_exit_2(tmp_path, capsys, out, expected):
    (tmp_path / "file").write_text("x")
    target = out if out.startswith("/") else str(tmp_path / out)
    assert main(["run", str(JELLY), "--out", target, "--steps", "1", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and expected in err and "--out" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]


@pytest.mark.parametrize("flags, named", [(["--steps", "-5"], "--steps"), (["--t-end", "nan"], "--t-end"),
                                          (["--t-end", "inf"], "--t-end"), (["--t-end", "-1"], "--t-end"),
                                          (["--resume"], "--resume"), (["--resume", "--overwrite"], "--overwrite")])
def test_bad_flags_are_one_line_and_exit_2(tmp_path, capsys, flags, named):
    assert main(run_args(tmp_path / "o", *flags)) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and named in err and not (tmp_path / "o").exists()


def test_ctrl_c_saves_a_checkpoint_and_the_printed_command_resumes_bit_identically(tmp_path, capsys, monkeypatch):
    straight = tmp_path / "straight"
    assert main(run_args(straight, "--steps", "6")) == 0
    step = Simulation.step

    def interrupted(self, dt=None, t_end=None):
        if self.step_count == 3:
            raise KeyboardInterrupt
        return step(self, dt, t_end)

    monkeypatch.setattr(Simulation, "step", interrupted)
    out = tmp_path / "cut"
    assert main(run_args(out, "--steps", "6")) == 130
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "interrupted at step 3" in err
    command = shlex.split(err.split("resume with: ", 1)[1])
    assert command[:2] == ["mpmref", "run"] and "--resume" in command
    assert command[command.index("--until-step") + 1] == "6"  # a total: the resumed run ends at the same step
    monkeypatch.setattr(Simulation, "step", step)
    assert main(command[1:]) == 0
    a, _ = load_checkpoint(straight / "checkpoint.npz")
    b, _ = load_checkpoint(out / "checkpoint.npz")
    assert a.step == b.step == 6
    for name, array in a.particles.arrays().items():
        np.testing.assert_array_equal(getattr(b.particles, name), array)


# ------------------------------------------------------------------------------------ cold start
def test_numba_warm_up_compiles_every_kernel_of_a_step_and_leaves_the_particles_alone():
    pytest.importorskip("numba")
    sim = Simulation(Scene.from_toml(JELLY), backend="numba")
    before = {k: a.copy() for k, a in sim.particles.arrays().items()}
    sim.backend.warm_up(sim.particles, substep)
    compiled = {"p2g": sim.backend._p2g_fused, "g2p": sim.backend._g2p}  # the P2G a plain step runs: fused
    counts = {k: len(d.signatures) for k, d in compiled.items()}
    assert all(n >= 1 for n in counts.values())
    for k, a in before.items():
        np.testing.assert_array_equal(getattr(sim.particles, k), a)
    sim.step()
    assert {k: len(d.signatures) for k, d in compiled.items()} == counts  # nothing compiled in the timed loop


def test_cli_says_it_compiles_before_the_timed_run(tmp_path, capsys):
    pytest.importorskip("numba")
    assert main(run_args(tmp_path / "o", "--steps", "1", "--backend", "numba")) == 0
    captured = capsys.readouterr()
    cache = re.escape(os.environ["NUMBA_CACHE_DIR"])
    assert re.search(rf"compiling kernels for this scene \(the first run only: they are cached in {cache}\)… done in "
                     r"\d+\.\d s", captured.err)
    assert "kernel compilation excluded" in captured.out


class _Terminal(io.StringIO):
    def isatty(self):
        return True


def test_a_compilation_on_a_terminal_counts_its_seconds():
    """On a terminal the line counts the seconds while the kernels compile, then says how long it took; elsewhere
    (a log) it is one line."""
    from mpmref.cli import compiling

    terminal, log = _Terminal(), io.StringIO()
    with compiling("mpmref", stream=terminal, every_s=0.05):
        time.sleep(0.3)
    with compiling("mpmref study", stream=log):
        pass
    assert re.search(r"\r.*first run only.* \d+ s", terminal.getvalue()) and terminal.getvalue().endswith(" s\n")
    assert log.getvalue().count("\n") == 1 and log.getvalue().startswith("mpmref study: compiling kernels")


def test_numba_cache_defaults_to_a_per_user_folder(tmp_path):
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "XDG_CACHE_HOME")}
    env["HOME"] = str(tmp_path)
    code = "import mpmref, numba; print(numba.config.CACHE_DIR)"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout
    assert out.strip() == str(tmp_path / ".cache" / "mpmref" / "numba")
    env["NUMBA_CACHE_DIR"] = str(tmp_path / "mine")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout
    assert out.strip() == str(tmp_path / "mine")


def test_a_command_loads_only_its_own_subcommand():
    """``mpmref run`` builds the parser of ``run`` alone: the other subcommands' modules (``compare`` imports SciPy's
    statistics, about a second) stay unimported; ``--help`` and a misspelt command still see every subcommand."""
    code = ("import sys; from mpmref.cli import main; status = main(['run', 'missing.toml']); "
            "print(status, sorted(m for m in sys.modules if m.startswith(('verification', 'scipy.stats', "
            "'mpmref.bench', 'mpmref.conformance'))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT).stdout
    assert out.split(maxsplit=1) == ["2", "[]\n"]
    from mpmref.cli import _command_of, _parser

    names = {"run", "bench", "conformance", "compare", "export", "study", "verify"}
    assert set(_parser()._subparsers._group_actions[0].choices) == names
    assert set(_parser("compare")._subparsers._group_actions[0].choices) == {"run", "compare"}
    assert [_command_of(w) for w in (["verify", "--quick"], ["verfy"], ["--help"], [])] == ["verify", None, None, None]
