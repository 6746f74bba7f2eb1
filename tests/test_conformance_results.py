"""``conformance check --results``: stage outputs computed by a program outside Python's import path, from
``conformance export``'s vectors, checked as the same code run as a backend is (mpmref/conformance/results.py)."""

import importlib.util
import json
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from mpmref.backends.capabilities import Implements
from mpmref.conformance import check, export, make_cases, scene_cases
from mpmref.conformance.results import ResultsError, check_results, read_declaration
from mpmref.conformance.vectors import resolved
from mpmref.state import GridState

ROOT = Path(__file__).resolve().parents[1]
PROGRAM = ROOT / "examples" / "outside_mpm" / "outside_mpm.py"
SCENE = ROOT / "examples" / "outside_mpm" / "two_blocks.toml"
STAGES = ("stress", "p2g", "p2g_fused", "grid_update", "g2p", "step", "ledger")


def program():
    """The outside program as a module (only to wrap it as a backend: it never imports mpmref)."""
    spec = importlib.util.spec_from_file_location("outside_mpm", PROGRAM)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def as_backend(om, force_factor=1.0):
    """The outside program's stages as a backend factory (a mapping of stage callables), with its declaration;
    ``force_factor`` scales its P2G force (a planted bug)."""

    def factory(scene):
        description = resolved(scene, scene.source["materials"])

        def stage(name, fn):
            def call(*args):
                try:
                    om.require(description, om.STAGE_NEEDS[name])
                except om.Unsupported as exc:
                    raise NotImplementedError(str(exc)) from None
                return fn(om.setup_from(description, scene.dtype), *args)
            return call

        def particles_of(p):
            return {k: getattr(p, k) for k in ("x", "v", "mass", "vol0", "material", "C", "F", "J")
                    if getattr(p, k) is not None}

        def p2g(setup, p):
            mass, momentum, force = om.p2g(particles_of(p), om.stress(particles_of(p), setup), setup)
            return GridState(mass, momentum, force * force_factor)

        def moved(new, p):
            return p.with_(**{k: new[k] for k in ("x", "v", "C", "F", "J") if k in new})

        return {"stress": stage("stress", lambda setup, p: om.stress(particles_of(p), setup)),
                "p2g": stage("p2g", p2g),
                "grid_update": stage("grid_update", lambda setup, gs, dt, time: om.grid_update(
                    gs.mass, gs.momentum, gs.force, dt, setup)),
                "g2p": stage("g2p", lambda setup, p, v, v_tilde, dt: moved(om.g2p(particles_of(p), v, dt, setup), p)),
                "step": stage("step", lambda setup, p, dt, time: moved(om.step(particles_of(p), dt, setup), p))}

    factory.implements = Implements(**om.IMPLEMENTS)
    return factory


def outside_results(tmp_path, cases):
    """Export ``cases``, run the outside program on them in its own process, return its results folder."""
    export(tmp_path / "vectors", cases)
    subprocess.run([sys.executable, str(PROGRAM), "stages", str(tmp_path / "vectors"), str(tmp_path / "results")],
                   check=True, capture_output=True)
    return tmp_path / "results"


def same_table(a, b):
    """The two reports count the same per stage and give the same reasons."""
    counts = {stage: row[:3] for stage, row in a.stage_summary().items()}
    assert counts == {stage: row[:3] for stage, row in b.stage_summary().items()}
    assert a.reasons() == b.reasons()
    assert a.verdict() == b.verdict()


@pytest.fixture(scope="module")
def om():
    return program()


@pytest.fixture(scope="module")
def catalogue(om):
    return make_cases(dims=(2,), stages=STAGES, implements=Implements(**om.IMPLEMENTS))


def test_results_of_the_outside_program_count_as_the_same_code_run_as_a_backend(om, catalogue, tmp_path):
    results = outside_results(tmp_path, catalogue)
    report = check_results(results, catalogue)
    same_table(report, check(as_backend(om), catalogue))
    assert report.passed and len(report.results) >= 20
    # one stage from its inputs: round-off alone; the multi-step cases from rest (40 steps in 2D) pass at rtol
    assert max(r.error for r in report.results if not (r.case.extreme and r.case.extreme.multi_step)) <= 1e-14
    assert {r.case.stage for r in report.results} == {"stress", "p2g", "grid_update", "g2p", "step"}
    reasons = report.reasons()
    assert "does not provide the stage ledger" in reasons and "needs the cubic kernel" in reasons
    assert "does not provide the optional stage p2g_fused" in reasons


def test_cases_drawn_from_a_scene_count_the_same(om, tmp_path):
    cases = scene_cases(SCENE, stages=STAGES)
    report = check_results(outside_results(tmp_path, cases), cases)
    same_table(report, check(as_backend(om), cases))
    assert report.passed and {r.case.stage for r in report.results} == {"stress", "p2g", "grid_update", "g2p", "step"}


def test_a_wrong_output_gets_the_diagnosis_a_backend_gets(om, tmp_path):
    cases = [c for c in make_cases(dims=(2,), stages=("p2g",), implements=Implements(**om.IMPLEMENTS))
             if c.variant == "apic-mls-quadratic"]
    results = outside_results(tmp_path, cases)
    for case in cases:
        path = results / f"{case.name}.npz"
        with np.load(path) as npz:
            arrays = dict(npz)
        arrays["out_grid_force"] = 0.75 * arrays["out_grid_force"]
        np.savez(path, **arrays)
    report = check_results(results, cases)
    backend = check(as_backend(om, force_factor=0.75), cases)
    same_table(report, backend)
    assert not report.passed and report.failed_stages() == {"p2g"}
    assert report.table() == backend.table()
    assert "× 0.75 everywhere" in report.table() and "worst at node" in report.table()


def test_missing_and_malformed_results_name_the_case_and_the_field(om, catalogue, tmp_path):
    cases = [c for c in catalogue if c.stage in ("grid_update", "stress")][:4]
    results = outside_results(tmp_path, cases)
    first, second, third = (results / f"{c.name}.npz" for c in cases[:3])
    first.unlink()
    with np.load(second) as npz:
        arrays = {k: v for k, v in npz.items() if k not in ("out_tau", "out_grid_v")}
    np.savez(second, **arrays)
    with np.load(third) as npz:
        arrays = {k: v[:-1] for k, v in npz.items()}
    np.savez(third, **arrays)
    with pytest.raises(ResultsError) as caught:
        check_results(results, cases)
    text = str(caught.value)
    assert f"case {cases[0].name} ({first.name}): no results file" in text
    assert f"case {cases[1].name} ({second.name}): no field out_" in text
    assert f"case {cases[2].name} ({third.name}): field out_" in text and "expected numbers of shape" in text


def test_declarations_are_read_and_bad_ones_name_the_field(tmp_path):
    assert read_declaration(tmp_path).stages[0] == "stress"  # no file: everything
    (tmp_path / "implements.json").write_text(json.dumps({"implements": {"dims": [2], "kernels": ["cubic"]},
                                                          "stages": ["p2g"]}))
    declaration = read_declaration(tmp_path)
    assert declaration.implements.dims == (2,) and declaration.stages == ("p2g",)
    (tmp_path / "implements.json").write_text(json.dumps({"implements": {"kernels": ["hat"]}}))
    with pytest.raises(ResultsError, match="field 'implements': Implements.kernels: unknown"):
        read_declaration(tmp_path)
    (tmp_path / "implements.json").write_text(json.dumps({"stages": ["p3g"]}))
    with pytest.raises(ResultsError, match="field 'stages': unknown"):
        read_declaration(tmp_path)


def test_the_command_line_round_trip_export_implements_then_check_results(om, tmp_path, capsys):
    """``conformance export --implements FILE`` fits the catalogue to the code's declaration as ``check --backend``
    fits it; ``check --results DIR`` on the outside program's outputs prints the table ``check_results`` gives; a
    results file that is missing is refused in one line naming the case, exit 2."""
    from mpmref.cli import main

    def mpmref_cli(*words):
        capsys.readouterr()
        status = main(list(words))
        out, err = capsys.readouterr()
        return SimpleNamespace(returncode=status, stdout=out, stderr=err)

    declaration = tmp_path / "implements.json"
    declaration.write_text(json.dumps({"implements": om.IMPLEMENTS, "stages": list(STAGES)}))
    selection = ["--dim", "2", "--stage", "stress", "grid_update", "g2p"]
    exported = mpmref_cli("conformance", "export", str(tmp_path / "vectors"), "--implements", str(declaration),
                          *selection)
    assert exported.returncode == 0, exported.stderr
    cases = make_cases(dims=(2,), stages=("stress", "grid_update", "g2p"), implements=Implements(**om.IMPLEMENTS))
    manifest = json.loads((tmp_path / "vectors" / "manifest.json").read_text())
    assert sorted(c["name"] for c in manifest["cases"]) == sorted(c.name for c in cases)
    subprocess.run([sys.executable, str(PROGRAM), "stages", str(tmp_path / "vectors"), str(tmp_path / "results")],
                   check=True, capture_output=True)
    checked = mpmref_cli("conformance", "check", "--results", str(tmp_path / "results"), "--no-progress", *selection)
    report = check_results(tmp_path / "results", cases)
    assert checked.returncode == 0 and report.passed, checked.stdout[-2000:] + checked.stderr[-2000:]
    assert checked.stdout.startswith(report.table()) and "compared: stress (" in checked.stdout
    (tmp_path / "results" / f"{cases[0].name}.npz").unlink()
    refused = mpmref_cli("conformance", "check", "--results", str(tmp_path / "results"), "--no-progress", *selection)
    assert refused.returncode == 2 and len(refused.stderr.strip().splitlines()) == 1
    assert f"case {cases[0].name} ({cases[0].name}.npz): no results file" in refused.stderr
    both = mpmref_cli("conformance", "check", "--results", str(tmp_path), "--backend", "numpy", "--no-progress")
    assert both.returncode == 2 and "not allowed with argument" in both.stderr
