"""``mpmref verify --scene SCENE.toml --backend B``: the user's scene turned into the checks that apply to it
(verification/scene/, docs/verification.md).

* The theory behind the checks: the linear stability limit of each B-spline, the growth of the top mode above it, the
  momentum check's scene (nothing external, a rigid start, a domain padded so that nothing leaves it).
* The partial example's own scene, made small, passes every check on the partial example; the same with a J update of
  the wrong trace, or without gravity, fails with a line naming the check, the scene and what differs; a stage that
  raises is an error naming the scene and the stage.
* Bad use is refused before any work (exit 2): a case named beside ``--scene``, a scene that is not one, a backend that
  does not implement the scene.
* Slow: the full-size example scenes on the partial example and on Numba.
"""

import argparse
import json
import math
import re
import sys
from pathlib import Path

import numpy as np
import pytest

from mpmref import Scene, Simulation
from mpmref.cli import main
from mpmref.observe.ledger import ASYNC_COLUMNS
from mpmref.scene.sampling import sample_particles
from verification.framework.cli import add_parser
from verification.scene import PRESETS, Params, as_run, resume, snapshot
from verification.scene import ledger as ledger_check
from verification.scene.momentum import momentum_scene, rigid_motion
from verification.scene.reference import differences
from verification.scene.stability import growth_per_step, linear_limit, probe, steps_to_catch

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = ROOT / "examples"
if str(EXAMPLES) not in sys.path:  # the partial example, as ``--backend mpm88_backend:factory`` from examples/ finds it
    sys.path.insert(0, str(EXAMPLES))

from mpm88_backend import Mpm88Backend  # the partial example
from test_emitter_ledger import SCENE as EXCHANGING  # a scene whose particles enter (an emitter) and leave (deleted)

PARTIAL = "mpm88_backend:factory"


def verify(argv):
    parser = argparse.ArgumentParser(prog="mpmref")
    add_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["verify", *argv])
    return args.func(args)


@pytest.fixture
def small88(tmp_path):
    """examples/mpm88.toml at 32 cells and 512 particles (its particle volume (dx/2)^2)."""
    text = (EXAMPLES / "mpm88.toml").read_text()
    for old, new in (('name = "mpm88"', 'name = "small88"'), ("cells = 128", "cells = 32"),
                     ("count = 8192", "count = 512"), ("1.52587890625e-05", "0.000244140625")):
        assert old in text
        text = text.replace(old, new)
    path = tmp_path / "small88.toml"
    path.write_text(text)
    return path


# ------------------------------------------------------------------------------------------------------- theory
def test_the_linear_limits_of_the_b_splines_are_those_of_their_symbols():
    """sqrt(3) for the quadratic B-spline (the extremes case's derivation), 1 for the linear one (linear elements),
    2 / sqrt(8/15) for the cubic one."""
    assert linear_limit(2) == pytest.approx(math.sqrt(3.0), rel=1e-14)
    assert linear_limit(1) == pytest.approx(1.0, rel=1e-14)
    assert linear_limit(3) == pytest.approx(2.0 / math.sqrt(8.0 / 15.0), rel=1e-14)


def test_above_the_limit_the_top_mode_grows_as_symplectic_euler_says():
    """The spectral radius of symplectic Euler's step matrix for x'' = -w^2 x at h w = 2 r, computed directly."""
    for ratio in (0.5, 0.9, 1.5, 2.0):  # (at 1 the double root -1 is ill-conditioned)
        hw = 2.0 * ratio
        step = np.array([[1.0 - hw**2, 1.0], [-hw**2, 1.0]])  # (x, h v): v += -w^2 x h, then x += h v
        assert growth_per_step(ratio) == pytest.approx(max(abs(np.linalg.eigvals(step))), rel=1e-12)
    assert steps_to_catch(np.finfo(np.float64).eps, growth_per_step(2.0)) == pytest.approx(13.95, abs=0.01)


def test_the_momentum_scene_has_nothing_external_and_a_rigid_start(small88):
    scene = Scene.from_toml(small88)
    moved = momentum_scene(scene, steps=50)
    assert np.all(moved.gravity == 0.0) and not moved.colliders and not moved.rigid_bodies
    assert {w.type for w in moved.boundary.walls.values()} == {"open"} and moved.boundary.domain_exit == "error"
    center, velocity, radius, omega = rigid_motion(scene)
    particles = sample_particles(moved)
    r = particles.x - center
    expected = velocity + omega * np.stack([-r[:, 1], r[:, 0]], axis=1)
    assert np.allclose(particles.v, expected, rtol=0, atol=1e-12)
    assert omega * radius == pytest.approx(0.01 * scene.max_wave_speed())
    assert np.all(particles.C[:, 1, 0] == omega) and np.all(particles.C[:, 0, 1] == -omega)
    assert np.all(moved.grid.origin < scene.grid.origin) and moved.grid.dx == scene.grid.dx


def test_a_run_is_shortened_to_the_budget_and_never_below_its_floor():
    quick = Params.of("any.toml", "quick")
    assert quick.steps(8192) == PRESETS["quick"]["budget"] // 8192
    assert quick.steps(10) == PRESETS["quick"]["max_steps"] and quick.steps(10**9) == quick.min_steps


# ----------------------------------------------------------------------------------------- the partial example
def test_the_partial_example_passes_every_check_of_its_own_scene(small88, tmp_path, capsys):
    assert verify(["--scene", str(small88), "--quick", "--backend", PARTIAL, "--out", str(tmp_path / "v"),
                   "--no-progress"]) == 0
    data = json.loads((tmp_path / "v" / "results.json").read_text())
    assert [c["case"] for c in data["cases"]] == ["momentum", "energy_ledger", "reference", "stability"]
    assert data["summary"]["checks"] >= 10 and data["summary"]["failing"] == data["summary"]["errors"] == 0
    assert "The checks of the scene" in (tmp_path / "v" / "report.md").read_text()
    assert "from each of steps 0, 331, 662 of the first 667 of its own 2000" in (
        tmp_path / "v" / "reference" / "reference.md").read_text()


class WrongTrace(Mpm88Backend):
    """J updated with the wrong trace: the difference of C's diagonal instead of its sum."""

    def g2p(self, particles, v_grid, v_tilde, dt, prepared=None, kicks=None):
        new = super().g2p(particles, v_grid, v_tilde, dt, prepared, kicks)
        return new.with_(J=particles.J * (1.0 + dt * (new.C[:, 0, 0] - new.C[:, 1, 1])))


class NoGravity(Mpm88Backend):
    """The grid update without gravity."""

    def grid_update(self, grid_state, dt, time=0.0):
        gravity, self.gravity = self.gravity, 0.0 * self.gravity
        try:
            return super().grid_update(grid_state, dt, time)
        finally:
            self.gravity = gravity


@pytest.mark.parametrize("bug", ["WrongTrace", pytest.param("NoGravity", marks=pytest.mark.slow)])
def test_a_planted_bug_fails_the_comparison_naming_the_scene_the_field_and_where(bug, small88, tmp_path, capsys):
    """The wrong trace grows J's error until the run blows up (past step 400): the comparison from a few steps
    before names what differs (and that the candidate's run stops where the reference's does not); the missing gravity
    differs from the first step."""
    assert verify(["--scene", str(small88), "--quick", "--backend", f"test_verify_scene:{bug}", "--out",
                   str(tmp_path / "v"), "--no-progress"]) == 1
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("reference: FAIL")]
    assert lines and all(line.startswith(f"reference: FAIL small88 on test_verify_scene:{bug}: ") for line in lines)
    assert any(re.search(r"max relative difference \(water\.[xvCJ], from step \d+\)", line) for line in lines)


class RaisesInGridUpdate(Mpm88Backend):
    def grid_update(self, grid_state, dt, time=0.0):
        raise FloatingPointError("planted")


def test_an_exception_in_a_stage_is_an_error_naming_the_scene_and_the_stage(small88, tmp_path, capsys):
    assert verify(["--scene", str(small88), "--quick", "--backend", "test_verify_scene:RaisesInGridUpdate", "--out",
                   str(tmp_path / "v"), "--no-progress"]) == 1
    out = capsys.readouterr().out
    assert "momentum: ERROR in scene 'small88_momentum', stage grid_update of RaisesInGridUpdate (raised at " \
           "test_verify_scene.py:" in out and "FloatingPointError: planted" in out


# ------------------------------------------------------------------------------------- particles enter and leave
@pytest.fixture
def exchanging(tmp_path):
    """tests/test_emitter_ledger.py's scene as a file, and its run at step 20 (t = 0.05, a release due at the next
    step, the thrown disk about to leave through the open floor): ``(path, scene, state)``."""
    path = tmp_path / "exchanging.toml"
    path.write_text(EXCHANGING)
    scene = as_run(Scene.from_toml(path))
    sim = Simulation(scene)
    sim.run(steps=20)
    return path, scene, snapshot(sim.state)


def test_a_check_resumed_from_a_state_of_the_run_releases_what_the_run_releases(exchanging):
    """The emitters' releases so far go with the state: the resumed run is the scene's run, particle for particle."""
    _, scene, state = exchanging
    run, resumed = resume(scene, "numpy", state), resume(scene, "numpy", state)
    run.state = state  # the scene's own run, its records and all
    for _ in range(30):
        run.step()
        resumed.step()
        assert np.array_equal(resumed.id, run.id) and np.array_equal(resumed.x, run.x)
    assert run.state.stepper["emitter_releases"][0] == 3  # at t = 0, 0.05 and 0.1


def test_the_stability_probe_follows_the_particles_by_id_while_they_enter_and_leave(exchanging):
    """The largest velocity change per step over the particles present before and after each step, against the same
    steps with each particle's velocity looked up by its id."""
    _, scene, state = exchanging
    out = probe(scene, "numpy", 30, state)
    sim, largest = resume(scene, "numpy", state), 0.0
    for _ in range(30):
        before = dict(zip(sim.id.tolist(), sim.v.copy()))
        sim.step()
        largest = max(largest, *(np.linalg.norm(v - before[i]) for i, v in zip(sim.id.tolist(), sim.v) if i in before))
    assert sim.deleted > 0 and sim.state.stepper["entered"][0] > 0  # particles left and entered over the probe
    assert out["steps"] == 30 and out["caught"] is None
    assert out["jump"] == pytest.approx(largest * scene.time.dt / scene.grid.dx, rel=1e-12)


def test_the_reference_comparison_matches_the_particles_by_id(exchanging):
    """The same particles in another order step to the same state but for the order of P2G's sums (round-off, the
    conformance bound); a particle that only one of the two holds is an infinite difference, named."""
    _, scene, state = exchanging
    ref, cand = resume(scene, "numpy", state), resume(scene, "numpy", state)
    cand.particles = cand.particles.select(np.arange(cand.n_particles)[::-1])
    for _ in range(5):
        ref.step()
        cand.step()
        worst = max(e for fields in differences(ref, cand).values() for e in fields.values())
        assert worst <= 1e-12
    cand.particles = cand.particles.select(np.arange(1, cand.n_particles))
    assert differences(ref, cand)["particles"] == {"ids differ": math.inf}


def test_the_ledger_check_books_what_enters_and_leaves_and_closes(exchanging):
    """From the last kept state (step 49 of the quick span) the ledger's run releases particles and deletes some at
    the open floor: its terms, inflow and outflow among them, add up to the measured change, and the signs hold."""
    path, _, _ = exchanging
    result = ledger_check.run(Params.of(path, "quick"), "numpy")
    last = dict(zip(ASYNC_COLUMNS, result["run"]["ledger"][-1]))
    assert result["run"]["left"] > 0 and last["inflow"] > 0.0 and last["outflow"] < 0.0
    assert result["checked"] and not result["not_applicable"]
    checks = ledger_check.checks(result)
    assert len(checks) == 4 and all(c.passed for c in checks), [c.line() for c in checks]


def test_the_ledger_check_is_not_applicable_where_particles_are_clamped(exchanging):
    """A clamp moves a particle outside every stage: no term books it."""
    path, _, _ = exchanging
    clamping = path.with_name("clamping.toml")
    clamping.write_text(path.read_text().replace('domain_exit = "delete"', 'domain_exit = "clamp"'))
    result = ledger_check.run(Params.of(clamping, "quick"), "numpy")
    assert not result["checked"] and ledger_check.checks(result) == []
    (item,) = result["not_applicable"]
    assert "particles were clamped back inside at the domain's edge" in item.why


# ------------------------------------------------------------------------------------------------------ refusals
def test_bad_use_is_refused_before_any_work(small88, tmp_path, capsys):
    out = tmp_path / "v"
    cases = main(["verify", "momentum", "--scene", str(small88), "--backend", PARTIAL, "--out", str(out)])
    assert cases == 2 and "--scene runs its own checks" in capsys.readouterr().err
    missing = main(["verify", "--scene", str(tmp_path / "nothing.toml"), "--out", str(out)])
    assert missing == 2 and "nothing.toml" in capsys.readouterr().err
    jelly = main(["verify", "--scene", str(EXAMPLES / "jelly.toml"), "--backend", PARTIAL, "--out", str(out)])
    err = capsys.readouterr().err
    assert jelly == 2 and "does not implement what scene 'jelly' needs: needs the material fixed_corotated" in err
    assert not out.exists()


# ---------------------------------------------------------------------------------------------------------- slow
@pytest.mark.slow
def test_the_partial_example_passes_its_full_size_scene(tmp_path):
    assert verify(["--scene", str(EXAMPLES / "mpm88.toml"), "--backend", PARTIAL, "--out", str(tmp_path / "v"),
                   "--no-progress"]) == 0


@pytest.mark.slow
@pytest.mark.parametrize("example", sorted(p.stem for p in EXAMPLES.glob("*.toml")))
def test_numba_passes_every_check_of_the_example_scenes(example, tmp_path):
    """Every example scene, the sand wheel's emitter and the cuts' deletions at the domain's edge among them."""
    assert verify(["--scene", str(EXAMPLES / f"{example}.toml"), "--quick", "--backend", "numba", "--out",
                   str(tmp_path / "v"), "--no-progress"]) == 0
    data = json.loads((tmp_path / "v" / "results.json").read_text())
    assert data["summary"]["checks"] >= 8 and data["summary"]["failing"] == data["summary"]["errors"] == 0


def test_the_momentum_scene_runs_nothing_but_its_particles(small88):
    """No particle leaves the padded domain over the run, with open walls and the error exit policy."""
    scene = Scene.from_toml(small88)
    sim = Simulation(momentum_scene(scene, steps=20), backend="numpy")
    sim.run(steps=20, progress=False)
    assert sim.deleted == sim.clamped == 0


def test_a_body_at_rest_under_gravity_is_judged_on_the_step_s_velocity_scale():
    """A PIC block settled on a sticky floor: its velocities are round-off of the g Δt each step adds and its stress
    takes back (max |v| 2e-5 after 2000 steps). Two correct codes differ there by round-off of g Δt, which is 1e-12 of
    max |v| and more; judged on max(|v|, |g| Δt) they agree to 1e-15 (the reference check's scale, speed_scale)."""
    from mpmref import SceneBuilder
    from verification.scene.reference import compare_from, speed_scale

    scene = (SceneBuilder(dim=2, name="rest").grid(size=1.0, cells=16).method("pic", force="mls")
             .material("m", "fixed_corotated", E=1e3).box("m", lower=[0.3, 0.1], upper=[0.7, 0.3])
             .gravity([0.0, -9.8]).walls("sticky").time(cfl=0.5).build())
    sim = Simulation(scene)
    sim.run(steps=2000)
    dt = sim.stepper.time_step(sim.particles)
    largest = float(np.max(np.linalg.norm(sim.v, axis=1)))
    assert largest < 1e-4 and speed_scale(sim.v, scene.gravity, dt) == pytest.approx(9.8 * dt)
    history = compare_from(scene, "numba", sim.state, 3)
    assert max(d["m"]["v"] for d in history) <= 1e-13
    ref, cand = resume(scene, "numpy", sim.state), resume(scene, "numba", sim.state)
    ref.step(dt)
    cand.step(dt)
    assert np.max(np.abs(ref.v - cand.v)) / largest > 1e-12  # what the speed alone as the scale would have failed
