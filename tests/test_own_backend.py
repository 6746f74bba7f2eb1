"""A user's own backend, plugged in end to end (docs/checking_your_code.md).

* The example third-party package (examples/my_mpm_backend, a delegate of the reference) passes the harness at
  zero error, and runs through ``Simulation``, ``mpmref run``, ``mpmref conformance check`` and ``mpmref verify``,
  named by ``MODULE:ATTRIBUTE`` or by the name its entry point registers.
* What real codes get wrong (tests/planted_backends.py) fails the harness at the stage that is wrong, and only
  there (and in the whole step, which composes it): a G2P that ignores Δt, a grid update without gravity, an MLS
  force with the wrong D_p (seen as one uniform ratio), a P2G that sums mass in float32. A code that evolves F
  only for solids and J only for the fluid is right, and passes.
* Bad references are refused before any work with a message naming the module, attribute or stage.
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import planted_backends as planted
import pytest
from my_mpm_backend.backend import MyBackend, factory

from mpmref import Scene, Simulation
from mpmref.backends import describe, make_backend, resolve
from mpmref.backends.numpy import transfers
from mpmref.conformance import check, export, make_cases
from mpmref.conformance.stages import STAGES_WITH_DT
from mpmref.errors import BackendError

ROOT = Path(__file__).resolve().parent.parent
EXAMPLE = ROOT / "examples" / "my_mpm_backend"
JELLY = ROOT / "examples" / "jelly.toml"
REFERENCE = "my_mpm_backend.backend:factory"
PLANE_CASES = make_cases(dims=(2,))


def failures_by_stage(report):
    return {stage: [r for r in report.failures() if r.case.stage == stage] for stage in report.failed_stages()}


def cases_of(stage, cases=PLANE_CASES):
    return [c for c in cases if c.stage == stage]


# ------------------------------------------------------------------------------------------ the example
def test_the_example_backend_passes_every_case_exactly():
    """It delegates every stage to the reference, so every output is the reference's, bit for bit (2D and 3D); the
    fused P2G is held to the unfused one plus Δt times its force, which the reference meets to round-off."""
    report = check(factory, make_cases())
    assert report.passed and not report.skipped
    assert all(r.error == 0.0 for r in report.results if r.case.stage != "p2g_fused")
    assert max(r.error for r in report.results if r.case.stage == "p2g_fused") < 2e-15


def test_a_backend_is_taken_as_a_name_a_reference_a_factory_a_class_or_an_object():
    scene = Scene.from_toml(JELLY)
    expected = Simulation(scene, backend="numpy")
    expected.run(steps=3)
    for backend in (REFERENCE, factory, MyBackend, MyBackend(scene)):
        sim = Simulation(scene, backend=backend)
        sim.run(steps=3)
        assert np.array_equal(sim.x, expected.x) and np.array_equal(sim.v, expected.v)
        assert isinstance(sim.backend, MyBackend)
    assert describe(REFERENCE, make_backend(REFERENCE, scene)) == {
        "backend": REFERENCE, "class": "my_mpm_backend.backend.MyBackend", "version": "0.1.0", "execution": None}


def test_bad_references_are_refused_naming_what_is_wrong():
    scene = Scene.from_toml(JELLY)
    with pytest.raises(BackendError, match="cannot import module 'no_such_module'"):
        make_backend("no_such_module:factory", scene)
    with pytest.raises(BackendError, match="has no attribute 'no_factory'"):
        make_backend("my_mpm_backend.backend:no_factory", scene)
    with pytest.raises(BackendError, match="unknown backend 'numbaa'.*numpy, numba"):
        make_backend("numbaa", scene)
    with pytest.raises(BackendError, match="made for another scene"):
        make_backend(MyBackend(Scene.from_toml(ROOT / "examples" / "mpm88.toml")), scene)


def test_a_missing_stage_or_a_stage_the_steppers_cannot_call_is_refused_before_any_work():
    class NoReturnMap(MyBackend):
        return_map = None

    class OldG2p(MyBackend):
        def g2p(self, particles, v_grid, v_tilde, dt):  # the public signature of docs/conformance.md, no `prepared`
            return super().g2p(particles, v_grid, v_tilde, dt)

    scene = Scene.from_toml(JELLY)
    with pytest.raises(BackendError, match=r"lacks the stage return_map\(particles\) -> Particles after the plastic"):
        Simulation(scene, backend=NoReturnMap)
    with pytest.raises(BackendError, match=r"g2p that does not accept the steppers' 5 positional.*g2p\(particles, "
                                           r"v_grid, v_tilde, dt, prepared=None, kicks=None\)"):
        Simulation(scene, backend=OldG2p)
    # the stages only some scenes need are asked for only there: asynchronous stepping, rigid bodies
    class SyncOnly(MyBackend):
        wave_speeds = interface_kicks = cpic_contact = cpic_impulses = cpic_g2p = None

    Simulation(scene, backend=SyncOnly)
    with pytest.raises(BackendError, match="lacks the stage wave_speeds"):
        Simulation(Scene.from_toml(ROOT / "examples" / "stork2d.toml"), backend=SyncOnly)
    with pytest.raises(BackendError, match="lacks the stage cpic_contact"):
        Simulation(Scene.from_toml(ROOT / "examples" / "cut2d.toml"), backend=SyncOnly)


# --------------------------------------------------------------------------------------- planted bugs
def test_a_g2p_that_ignores_dt_fails_g2p_and_the_step():
    """Every case draws its own Δt (none is the 1e-3 the bug uses), so every G2P case fails, and every step and its
    ledger (the energies of the particles G2P moved and deformed)."""
    report = check(planted.IgnoresDt, PLANE_CASES)
    failed = failures_by_stage(report)
    assert set(failed) == {"g2p", "step", "ledger"}
    assert all(len(failed[stage]) == len(cases_of(stage)) for stage in failed)
    assert all(r.worst_output in ("x", "F", "J") for r in failed["g2p"])
    assert all(float(c.inputs()["dt"]) != planted.FIXED_DT for c in cases_of("g2p"))


def test_a_grid_update_without_gravity_fails_the_grid_update_and_the_step():
    report = check(planted.DropsGravity, PLANE_CASES)
    failed = failures_by_stage(report)
    assert set(failed) == {"grid_update", "step", "ledger"}
    assert (len(failed["grid_update"]) == len(cases_of("grid_update"))
            and len(failed["ledger"]) == len(cases_of("ledger")))
    assert all(r.worst_output == "grid_v" and r.where.startswith("node ") for r in failed["grid_update"])


def test_the_wrong_mls_inertia_fails_the_mls_force_p2g_as_one_uniform_ratio():
    """D_p = dx²/3 in place of dx²/4 (quadratic kernel) scales every MLS force by exactly 3/4; with the cubic kernel
    (D_p = dx²/3 already) nothing changes. The classic force does not use D_p."""
    report = check(planted.WrongMlsInertia, PLANE_CASES)
    failed = failures_by_stage(report)
    assert set(failed) == {"p2g", "p2g_fused", "step", "ledger"}
    for stage in ("p2g", "ledger"):  # the ledger: the force's work, Δt Σ f·v, and what follows from it
        mls_quadratic = {c.name for c in cases_of(stage) if c.scene().transfer.force == "mls"
                         and c.scene().kernel.name == "quadratic"}
        assert {r.case.name for r in failed[stage]} == mls_quadratic
    for result in failed["p2g"]:
        assert result.worst_output == "grid_force" and result.ratio == pytest.approx(0.75, rel=1e-12)
    assert "× 0.75 everywhere" in report.table()


def test_a_p2g_summing_mass_in_float32_fails_p2g_on_the_mass():
    report = check(planted.Float32Mass, PLANE_CASES)
    failed = failures_by_stage(report)
    assert {"p2g", "p2g_fused"} <= set(failed) <= {"p2g", "p2g_fused", "step", "ledger"}
    assert len(failed["p2g"]) == len(cases_of("p2g")) and len(failed["p2g_fused"]) == len(cases_of("p2g_fused"))
    for result in failed["p2g"]:
        assert result.worst_output == "grid_mass"
        assert 1e-10 < result.error < 1e-6  # float32 rounding: a few units of 6e-8, far above 1e-12
        assert result.ratio is None and result.where.startswith("node ")


def test_a_code_that_evolves_f_only_for_solids_and_j_only_for_the_fluid_passes():
    candidate = planted.PerMaterialFields
    report = check(candidate, PLANE_CASES)
    assert report.passed
    mixed = [c for c in cases_of("g2p") if {"fluid", "fixed_corotated"} <= set(c.scene_dict["materials"])]
    assert mixed  # the cases where it matters exist: there F of the fluid and J of the solid are left alone
    case = mixed[0]
    got = candidate(case.scene()).g2p
    inputs = case.inputs()
    from mpmref.conformance.stages import particles_from

    new = got(particles_from(inputs), inputs["grid_v"], inputs["grid_v_tilde"], float(inputs["dt"]))
    fluid = inputs["material"] == list(case.scene_dict["materials"]).index("fluid")
    assert np.array_equal(new.F[fluid], inputs["F"][fluid]) and not np.array_equal(new.F[~fluid], inputs["F"][~fluid])


def test_a_p2g_that_takes_the_stress_is_given_the_reference_stress():
    """A code without constitutive models checks its transfer: P2G with a ``stress`` parameter gets ``tau``."""
    seen = []

    class TransferOnly(MyBackend):
        stress = None  # no constitutive model of its own: its stress cases are skipped

        def p2g(self, particles, prepared=None, contact=None, classes=None, stress=None):
            seen.append(stress is not None)
            scene = self.scene
            return transfers.p2g(particles, stress, scene.grid, scene.kernel, scene.transfer)

    report = check(TransferOnly, PLANE_CASES)
    # no step without a stress
    assert report.passed and {c.stage for c in report.skipped} == {"stress", "step", "ledger"}
    assert all(seen) and len(seen) == len(cases_of("p2g"))


# ------------------------------------------------------------------------------------------ the manifest
def test_the_manifest_lists_dt_per_case_and_the_fields_each_material_evolves(tmp_path):
    manifest = json.loads(export(tmp_path, PLANE_CASES).read_text())
    for stage in STAGES_WITH_DT:
        dts = [e["dt"] for e in manifest["cases"] if e["stage"] == stage]
        assert len(dts) == len(cases_of(stage)) and len(set(dts)) >= 5
    evolves = {m["type"]: m["evolves"] for e in manifest["cases"] for m in e["resolved"]["materials"]}
    assert evolves == {"fixed_corotated": ["F"], "neo_hookean": ["F"], "fluid": ["J"], "snow": ["F", "Jp"],
                       "sand": ["F", "Jp"]}
    assert "evolves" in manifest["conventions"] and "in_tau" in manifest["conventions"]["tau"]


# ------------------------------------------------------------------------------------------ the command line
def plugin_path(tmp_path):
    """A folder holding the example's distribution metadata with its entry point, as ``pip install`` would write
    it (no installation into the test environment): on the path, ``--backend my_mpm`` names the example."""
    info = tmp_path / "my_mpm_backend-0.1.0.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: my-mpm-backend\nVersion: 0.1.0\n")
    (info / "entry_points.txt").write_text("[mpmref.backends]\nmy_mpm = my_mpm_backend.backend:factory\n")
    (info / "top_level.txt").write_text("my_mpm_backend\n")
    return tmp_path


def mpmref(args, tmp_path, cwd=ROOT):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(EXAMPLE), str(ROOT / "tests"), str(plugin_path(tmp_path))]))
    return subprocess.run([sys.executable, "-m", "mpmref.cli", *args], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=600)


def test_conformance_check_exits_0_for_a_correct_backend_1_for_a_failing_one_2_for_a_bad_reference(tmp_path):
    select = ["--dim", "2", "--stage", "g2p", "--no-progress"]
    ok = mpmref(["conformance", "check", "--backend", REFERENCE, *select], tmp_path / "a")
    every = len(make_cases(dims=(2,), stages=("g2p",)))  # a complete code: every case of the stage applies
    assert ok.returncode == 0 and f"PASSED: {every} of {every} cases" in ok.stdout
    bad = mpmref(["conformance", "check", "--backend", "planted_backends:IgnoresDt", *select], tmp_path / "b")
    assert bad.returncode == 1 and f"FAILED: 0 of {every} cases" in bad.stdout and "worst at particle" in bad.stdout
    missing = mpmref(["conformance", "check", "--backend", "my_mpm_backend.backend:fatcory", *select], tmp_path / "c")
    assert missing.returncode == 2 and missing.stdout == ""
    assert "module 'my_mpm_backend.backend' has no attribute 'fatcory'" in missing.stderr
    assert "Traceback" not in missing.stderr


def test_the_entry_point_registers_the_example_by_name(tmp_path):
    assert resolve("numpy").__name__ == "NumpyBackend"
    run = mpmref(["conformance", "check", "--backend", "my_mpm", "--dim", "2", "--stage", "stress", "--no-progress"],
                 tmp_path)
    every = len(make_cases(dims=(2,), stages=("stress",)))
    assert run.returncode == 0 and f"PASSED: {every} of {every} cases" in run.stdout
    unknown = mpmref(["conformance", "check", "--backend", "my_mmp", "--no-progress"], tmp_path / "u")
    assert unknown.returncode == 2 and "installed plugins: my_mpm" in unknown.stderr


def test_run_names_the_backend_and_its_version(tmp_path):
    run = mpmref(["run", str(JELLY), "--steps", "2", "--out", str(tmp_path / "out"), "--no-progress", "--backend",
                  REFERENCE], tmp_path / "p")
    assert run.returncode == 0, run.stderr
    assert f"backend          {REFERENCE} (my_mpm_backend.backend.MyBackend 0.1.0)" in run.stdout
    refused = mpmref(["run", str(JELLY), "--steps", "2", "--out", str(tmp_path / "no"), "--backend",
                      "planted_backends:NoSuchThing"], tmp_path / "q")
    assert refused.returncode == 2 and not (tmp_path / "no").exists()


def test_verify_runs_a_case_on_the_users_backend_and_names_it(tmp_path):
    run = mpmref(["verify", "momentum", "--quick", "--backend", REFERENCE, "--out", str(tmp_path / "v"),
                  "--workers", "1", "--no-progress"], tmp_path / "p")
    assert run.returncode == 0, run.stdout + run.stderr
    results = json.loads((tmp_path / "v" / "results.json").read_text())
    assert results["backend"] == {"backend": REFERENCE, "class": "my_mpm_backend.backend.MyBackend",
                                  "version": "0.1.0", "execution": None}
    assert results["cases"][0]["backends"] == [REFERENCE]
    assert f"Backend under test: `{REFERENCE}`" in (tmp_path / "v" / "report.md").read_text()


def test_verify_refuses_a_backend_without_the_stages_every_scene_needs(tmp_path):
    run = mpmref(["verify", "momentum", "--quick", "--backend", "planted_backends:NoStages", "--out",
                  str(tmp_path / "v")], tmp_path / "p")
    assert run.returncode == 2 and "lacks the stage prepare(particles)" in run.stderr
    assert not (tmp_path / "v").exists()


@pytest.mark.slow  # 45 s of one core; the default run has every case on a user's backend through the CLI in the
# partial example's quick report (tests/test_verify_partial.py) and each case's quick preset on the reference
def test_the_whole_quick_report_passes_on_the_example_backend(tmp_path):
    """``mpmref verify --quick --backend my_mpm_backend.backend:factory``: every case, every check (the cases that
    compare two backends compare it with the reference, the sweeps of ``sync_vs_async`` that compare stepping schemes
    run on Numba as they do for every backend)."""
    run = mpmref(["verify", "--quick", "--backend", REFERENCE, "--out", str(tmp_path / "v"), "--no-progress"],
                 tmp_path / "p")
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    results = json.loads((tmp_path / "v" / "results.json").read_text())
    assert results["summary"]["failing"] == 0 and results["summary"]["errors"] == 0
    assert results["backend"]["backend"] == REFERENCE
