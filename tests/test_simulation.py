"""Runs as a user meets them: restart, failures caught with context, domain-exit policies, the CLI."""

import subprocess
import sys
from pathlib import Path

import meshio
import numpy as np
import pytest
import pyvista as pv

from mpmref import DomainExitError, NonFiniteError, Scene, SceneBuilder, Simulation
from mpmref.cli import main
from mpmref.errors import ArgumentError
from mpmref.io.checkpoint import load_checkpoint

ROOT = Path(__file__).resolve().parent.parent


def jelly_with_loner(loner_velocity=(0.0, 0.0), exit_policy="error", dt=None, cfl=None, steps=20, walls="separate"):
    """A jelly box plus one isolated particle far from it (so its fate touches no other particle)."""
    b = (SceneBuilder(dim=2, name="loner").grid(size=1.0, cells=16).method("mls")
         .material("jelly", "neo_hookean", E=1e3, nu=0.3, rho=1.0)
         .box("jelly", lower=[0.3, 0.3], upper=[0.5, 0.5], angular_velocity=1.0)
         .points("jelly", [[0.85, 0.85]], velocity=list(loner_velocity))
         .gravity([0.0, -9.8]).walls(walls, friction=0.2, domain_exit=exit_policy)
         .output(every=5, grid=True))
    b.time(**({"dt": dt} if dt else {"cfl": cfl or 0.3}), steps=steps)
    return b.build()


@pytest.mark.parametrize("time_rule", [{"dt": 1e-3}, {"cfl": 0.4}])
def test_restart_is_bit_identical(tmp_path, time_rule):
    scene = jelly_with_loner(**time_rule, steps=20)
    full = Simulation(scene, out_dir=tmp_path / "full")
    full.run()
    part = Simulation(scene, out_dir=tmp_path / "part")
    part.run(steps=10)
    del part  # the first process "dies" here; only its folder remains
    resumed = Simulation.resume(scene, tmp_path / "part")
    assert resumed.step_count == 10
    resumed.run()
    assert resumed.step_count == full.step_count == 20
    for name, a in full.particles.arrays().items():
        assert np.array_equal(a, resumed.particles.arrays()[name]), name
    assert resumed.time == full.time
    assert (tmp_path / "full/diagnostics.csv").read_text() == (tmp_path / "part/diagnostics.csv").read_text()
    assert (tmp_path / "full/particles.pvd").read_text() == (tmp_path / "part/particles.pvd").read_text()


def test_resume_refuses_a_different_scene(tmp_path):
    Simulation(jelly_with_loner(dt=1e-3, steps=5), out_dir=tmp_path).run()
    with pytest.raises(Exception, match="different scene"):
        Simulation.resume(jelly_with_loner(dt=2e-3, steps=5), tmp_path)


@pytest.mark.filterwarnings("ignore:invalid value encountered in log")
def test_non_finite_is_caught_at_its_step_with_context(tmp_path):
    scene = jelly_with_loner(dt=1e-3)
    sim = Simulation(scene, out_dir=tmp_path)
    sim.run(steps=3)
    F = sim.F.copy()
    F[-1] = np.diag([-1.0, 1.0])  # inverted element: Neo-Hookean log(J) is undefined
    sim.F = F
    before = sim.particles.copy()
    with pytest.raises(NonFiniteError) as info:
        sim.step()
    err = info.value
    assert err.step == 4 and err.particle == sim.n_particles - 1 and err.quantity in ("x", "v")
    # the CFL number uses each particle's current wave speed (elastic rule of Fang et al. 2018, J clamped at 1e-6)
    mat = scene.material_list[0]
    J = np.maximum(np.linalg.det(before.F), 1e-6)
    K = 2.0 * mat.mu / 3.0 + mat.lam
    c = np.sqrt(4.0 * mat.mu * J / (3.0 * mat.rho) + K * (1.0 - np.log(J)) / mat.rho)
    signal = c + np.linalg.norm(before.v, axis=1)
    assert err.cfl == pytest.approx(1e-3 * signal.max() / scene.grid.dx, rel=1e-12)
    # the simulation still holds the last good state, and it was written to disk
    assert sim.step_count == 3
    for name, a in before.arrays().items():
        assert np.array_equal(a, sim.particles.arrays()[name])
    saved, meta = load_checkpoint(err.checkpoint)
    assert meta["clock"]["step"] == saved.step == 3 and np.array_equal(saved.particles.F, F)


def test_domain_exit_error_is_default_and_keeps_last_good_state(tmp_path):
    sim = Simulation(jelly_with_loner(loner_velocity=(0.0, 150.0), dt=1e-3, walls="open"), out_dir=tmp_path)
    with pytest.raises(DomainExitError) as info:
        sim.run(steps=5)
    err = info.value
    assert list(err.particles) == [sim.n_particles - 1]
    assert Path(err.checkpoint).exists() and sim.step_count == err.step - 1


def test_domain_exit_clamp_and_delete():
    fast = {"loner_velocity": (0.0, 150.0), "dt": 1e-3, "walls": "open"}  # leaves in one step
    clamp = Simulation(jelly_with_loner(exit_policy="clamp", **fast))
    n_clamp = clamp.n_particles
    clamp.run(steps=3)
    lo, hi = clamp.scene.valid_region()
    assert clamp.n_particles == n_clamp
    assert np.all((clamp.x >= lo) & (clamp.x < hi))
    # clamped at step 1 with its outward (upward) velocity zeroed, the loner then falls freely for two steps
    assert clamp.clamped == 1 and clamp.diagnostics()["clamped"] == 1
    assert clamp.v[-1, 1] == pytest.approx(-2 * 9.8e-3, rel=1e-9)
    assert clamp.x[-1, 1] == pytest.approx(hi[1] - 1e-6 * (hi[1] - lo[1]) - 3 * 9.8e-6, abs=1e-12)
    delete = Simulation(jelly_with_loner(exit_policy="delete", **fast))
    n0, m0 = delete.n_particles, delete.mass.sum()
    delete.run(steps=3)
    d = delete.diagnostics()
    assert delete.n_particles == n0 - 1 and d["deleted"] == 1
    assert d["mass"] == pytest.approx(m0 - delete.scene.materials["jelly"].rho * 1 / 16**2 / 4, rel=1e-12)


def test_state_arrays_are_settable_with_shape_checks():
    sim = Simulation(jelly_with_loner(dt=1e-3))
    v = np.ones_like(sim.v)
    sim.v = v
    assert np.array_equal(sim.v, v)
    with pytest.raises(ValueError, match="shape"):
        sim.v = np.ones((3, 2))
    with pytest.raises(AttributeError, match="does not allocate 'J'"):
        sim.J = np.ones(sim.n_particles)


def test_cli_run_writes_a_series_that_meshio_and_pyvista_read(tmp_path, capsys):
    scene_file = tmp_path / "s.toml"
    scene_file.write_text((ROOT / "examples/jelly.toml").read_text().replace("every = 100", "every = 2\ngrid = true"))
    out = tmp_path / "out"
    assert main(["run", str(scene_file), "--steps", "4", "--out", str(out), "--no-progress"]) == 0
    printed = capsys.readouterr().out
    assert "particle-steps/s" in printed and "mass drift" in printed
    frames = sorted(out.glob("particles_*.vtu"))
    assert [f.name for f in frames] == ["particles_000000.vtu", "particles_000002.vtu", "particles_000004.vtu"]
    mesh = meshio.read(frames[-1])
    assert set(mesh.point_data) == {"id", "velocity", "mass", "volume", "J", "stress", "pressure", "material"}
    assert mesh.point_data["velocity"].shape == (len(mesh.points), 3)
    reader = pv.get_reader(str(out / "particles.pvd"))
    assert len(reader.time_values) == 3
    reader.set_active_time_value(reader.time_values[-1])
    block = reader.read()[0]
    np.testing.assert_allclose(block.points, mesh.points)
    grid = pv.read(out / "grid_000004.vti")  # the active region: whole 4-node blocks around the nodes with mass
    assert all(n % 4 == 0 and n < 65 for n in grid.dimensions[:2]) and grid.dimensions[2] == 1
    assert {"mass", "velocity"} <= set(grid.point_data.keys())
    # Σ_i w_ip = 1 and Σ_i w_ip x_i = x_p: grid mass and centre of mass equal the particles' (VTK axis order)
    m_grid = grid.point_data["mass"]
    m_part, x_part = mesh.point_data["mass"], mesh.points
    assert m_grid.sum() == pytest.approx(m_part.sum(), rel=1e-12)
    np.testing.assert_allclose(m_grid @ grid.points / m_grid.sum(), m_part @ x_part / m_part.sum(), rtol=1e-12)
    rows = (out / "diagnostics.csv").read_text().splitlines()
    assert rows[0].startswith("step,time,") and len(rows) == 4


def test_cli_resume_continues_to_the_requested_step(tmp_path):
    """--until-step is a total (the run stops at that step), --steps counts more steps: the rule of run()."""
    args = ["run", str(ROOT / "examples/jelly.toml"), "--out", str(tmp_path), "--no-progress"]
    assert main(args + ["--steps", "3"]) == 0
    assert main(args + ["--until-step", "6", "--resume"]) == 0
    assert main(args + ["--until-step", "6", "--resume"]) == 0  # already there: no step
    assert main(args + ["--steps", "2", "--resume"]) == 0
    rows = (tmp_path / "diagnostics.csv").read_text().splitlines()
    assert [r.split(",")[0] for r in rows[1:]] == ["0", "3", "6", "8"]


def test_run_counts_steps_more_and_until_step_as_a_total_and_takes_one_stop():
    sim = Simulation(Scene.from_toml(ROOT / "examples/jelly.toml"))
    sim.run(steps=3)
    sim.run(steps=3)
    assert sim.step_count == 6
    sim.run(until_step=7)
    sim.run(until_step=7)
    assert sim.step_count == 7
    for stops in ({"steps": 1, "t_end": 1.0}, {"steps": 1, "until_step": 9}, {"until_step": 9, "t_end": 1.0}):
        with pytest.raises(ArgumentError, match="one of steps"):
            sim.run(**stops)
    assert sim.step_count == 7


def test_cli_reports_bad_scene_with_exit_code_2(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text((ROOT / "examples/jelly.toml").read_text().replace("nu = 0.3", "nu = 0.5"))
    proc = subprocess.run([sys.executable, "-m", "mpmref.cli", "run", str(bad), "--out", str(tmp_path / "o")],
                          capture_output=True, text=True)
    assert proc.returncode == 2
    assert "materials.jelly.nu" in proc.stderr and "0.5" in proc.stderr and "[0.0, 0.5)" in proc.stderr
    assert not (tmp_path / "o").exists()  # validated before any work


def test_frames_follow_particles_by_id_through_deletion_and_emission(tmp_path):
    """A loner leaves the domain (deleted) while an emitter adds particles: every frame's ``id`` is the set of
    ``sim.id`` at its step, and each written position is the particle's position at that step, looked up by id."""
    from mpmref import Scene

    data = jelly_with_loner(loner_velocity=(30.0, 0.0), exit_policy="delete", dt=2e-4, steps=30,
                            walls="open").source
    data = {**data, "output": {"every": 1}, "emitters": [{"material": "jelly", "center": [0.7, 0.4], "radius": 0.04,
                                                          "velocity": [0.0, -5.0], "start": 1e-3, "interval": 0.02,
                                                          "until": 2e-3}]}
    sim = Simulation(Scene.from_dict(data), out_dir=tmp_path)
    seen = {0: dict(zip(sim.id.tolist(), sim.x.copy()))}
    for _ in range(30):
        sim.run(steps=1)
        seen[sim.step_count] = dict(zip(sim.id.tolist(), sim.x.copy()))
    assert set(seen[0]) - set(seen[30]) and set(seen[30]) - set(seen[0])  # particles left and particles arrived
    for step, positions in seen.items():
        frame = meshio.read(tmp_path / f"particles_{step:06d}.vtu")
        ids = frame.point_data["id"]
        assert set(ids.tolist()) == set(positions)
        for i, point in zip(ids.tolist(), frame.points):
            np.testing.assert_array_equal(point[:2], positions[i])


BAD_STEP_ARGUMENTS = [
    ("step", {"dt": -0.01}, "dt"), ("step", {"dt": 0.0}, "dt"), ("step", {"dt": float("nan")}, "dt"),
    ("step", {"dt": float("inf")}, "dt"), ("step", {"t_end": "now"}, "t_end"),
    ("run", {"steps": -3}, "steps"), ("run", {"steps": 2.5}, "steps"), ("run", {"t_end": "before"}, "t_end"),
    ("run", {"t_end": float("nan")}, "t_end"), ("run", {"t_end": float("inf")}, "t_end"),
    ("run", {"steps": 2, "dt": 0.0}, "dt"), ("run", {"steps": 2, "dt": -1e-3}, "dt"),
    ("run", {"steps": 2, "dt": float("nan")}, "dt"), ("run", {"t_end": 1.0, "dt": float("inf")}, "dt"),
]


@pytest.mark.parametrize("method, kwargs, name", BAD_STEP_ARGUMENTS,
                         ids=[f"{m}-{'-'.join(f'{k}={v}' for k, v in kw.items())}" for m, kw, _ in BAD_STEP_ARGUMENTS])
def test_step_and_run_refuse_bad_arguments_naming_them_before_any_work(method, kwargs, name):
    """A step backwards, a step of zero, a NaN or infinite step or end, negative steps, an end in the past: a
    ValueError naming the argument, and the simulation is where it was (no step counted, nothing moved)."""
    from mpmref.errors import ArgumentError

    sim = Simulation(jelly_with_loner(dt=1e-3))
    sim.run(steps=2)
    now, x = sim.time, sim.x.copy()
    kwargs = {k: {"now": now, "before": 0.5 * now}.get(v, v) for k, v in kwargs.items()}
    with pytest.raises(ValueError) as info:
        getattr(sim, method)(**kwargs)
    assert isinstance(info.value, ArgumentError) and info.value.name == name
    assert str(info.value).startswith(f"{name} = ")
    assert sim.step_count == 2 and sim.time == now and np.array_equal(sim.x, x)


def test_run_to_the_current_time_or_zero_steps_does_nothing_and_is_allowed():
    sim = Simulation(jelly_with_loner(dt=1e-3))
    sim.run(steps=2)
    assert sim.run(t_end=sim.time)["steps"] == 0 and sim.run(steps=0)["steps"] == 0 and sim.step_count == 2


def test_run_calls_each_step_after_every_step_on_the_stepped_state():
    """``each_step`` sees each step's state once, after it; a fixed ``dt`` steps as a loop of ``step(dt)`` does, to
    the bit; what the hook raises ends the run there and propagates."""
    seen = []
    sim = Simulation(jelly_with_loner(cfl=0.3))
    sim.run(steps=4, dt=7e-4, each_step=lambda s: seen.append((s.step_count, s.time, s.x.copy())))
    loop = Simulation(jelly_with_loner(cfl=0.3))
    for n in range(1, 5):
        loop.step(7e-4)
        assert seen[n - 1][:2] == (n, loop.time) and np.array_equal(seen[n - 1][2], loop.x)
    assert len(seen) == 4 and np.array_equal(sim.x, loop.x) and np.array_equal(sim.v, loop.v)

    def stop_at_2(s):
        if s.step_count == 2:
            raise KeyboardInterrupt

    stopped = Simulation(jelly_with_loner(cfl=0.3))
    with pytest.raises(KeyboardInterrupt):
        stopped.run(t_end=1.0, each_step=stop_at_2)
    assert stopped.step_count == 2


def test_run_to_an_end_time_calls_each_step_as_often_as_it_steps():
    sim = Simulation(jelly_with_loner(cfl=0.3))
    times = []
    summary = sim.run(t_end=0.01, each_step=lambda s: times.append(s.time))
    assert len(times) == summary["steps"] == sim.step_count and times[-1] == sim.time


def cadence_scene(steps=23):
    """The loner jelly writing frames every 10 steps and diagnostics rows every 3."""
    return Scene.from_dict({**jelly_with_loner(dt=1e-3, steps=steps).source, "output": {"every": 10,
                                                                                          "diagnostics_every": 3}})


def test_diagnostics_rows_have_their_own_cadence_independent_of_frames(tmp_path):
    """Rows every output.diagnostics_every steps, frames every output.every, both at the start and the end; the
    rows run() records without an output folder are the rows of diagnostics.csv, value for value."""
    import csv

    scene = cadence_scene()
    assert scene.output.diagnostics_every == 3 and scene.output.every == 10
    Simulation(scene, out_dir=tmp_path).run()
    with open(tmp_path / "diagnostics.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [int(r["step"]) for r in rows] == [0, 3, 6, 9, 12, 15, 18, 21, 23]
    assert sorted(p.name for p in tmp_path.glob("particles_*.vtu")) == [
        "particles_000000.vtu", "particles_000010.vtu", "particles_000020.vtu", "particles_000023.vtu"]
    series = Simulation(scene).run(record=True)["series"]
    assert [{k: repr(float(v)) for k, v in r.items()} for r in series] == \
           [{k: repr(float(v)) for k, v in r.items()} for r in rows]


def test_a_run_resumed_between_rows_and_frames_writes_the_same_rows(tmp_path):
    """The checkpoint (every 10 steps) carries the rows written so far (every 3): killed at step 14, resumed
    from step 10, the run writes diagnostics.csv and particles.pvd exactly as an uninterrupted one."""
    scene = cadence_scene()
    Simulation(scene, out_dir=tmp_path / "full").run()
    part = Simulation(scene, out_dir=tmp_path / "part")
    step = part.step_clipped

    def killed_at_14(t_end):
        if part.step_count == 14:
            raise KeyboardInterrupt
        return step(t_end)

    part.step_clipped = killed_at_14
    with pytest.raises(KeyboardInterrupt):
        part.run()
    resumed = Simulation.resume(scene, tmp_path / "part")
    assert resumed.step_count == 10
    resumed.run()
    for name in ("diagnostics.csv", "particles.pvd"):
        assert (tmp_path / "full" / name).read_text() == (tmp_path / "part" / name).read_text()


def test_the_default_diagnostics_cadence_is_the_frames_one():
    assert jelly_with_loner(dt=1e-3).output.diagnostics_every == 5
