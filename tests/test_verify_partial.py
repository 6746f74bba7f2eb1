"""``mpmref verify`` on a code that implements a part (verification/framework/applicable.py, docs/verification.md).

* The partial example (examples/mpm88_backend.py: 2D, quadratic, MLS-MPM, one fluid carrying J, frictionless separate
  walls) runs the whole quick report through the command line: no error, every check that runs passes, momentum and
  energy run, and every item not applicable has its reason.
* Scenes are fitted to a declaration by one mechanism: a backend that implements a scene gets it unchanged; a lacking
  material becomes one the backend has, of the same density and P-wave speed, with the parameters it fixes; open walls
  become its walls on a padded domain; a scheme is never changed.
* A case with nothing applicable is *not applicable*, never an error or a failure; an exception inside an implemented
  feature is an error whose line names the scene and the backend's stage, also when raised in a worker process.
"""

import argparse
import json
import os
import pickle
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from mpmref import Scene, SceneBuilder
from verification import momentum
from verification.framework import registry
from verification.framework.applicable import Allow, Inapplicable, NothingApplicable, Triage, declaration_of, fit
from verification.framework.case import VerificationCase
from verification.framework.executor import Executor, located_call
from verification.framework.failure import locate

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = ROOT / "examples"
PARTIAL = "mpm88_backend:factory"
if str(EXAMPLES) not in sys.path:  # the partial example, as ``--backend mpm88_backend:factory`` from examples/ finds it
    sys.path.insert(0, str(EXAMPLES))

from mpm88_backend import Mpm88Backend


def block(material, walls="open", scheme="mls", kernel="quadratic", friction=0.0):
    types = {"solid": {"type": "fixed_corotated", "E": 1e3, "nu": 0.3, "rho": 2.0},
             "fluid": {"type": "fluid", "K": 50.0, "gamma": 7.0, "rho": 1.0},
             "sand": {"type": "sand", "E": 1e3, "nu": 0.3, "rho": 1.0}}
    return (SceneBuilder(dim=2, name="block").grid(size=1.0, cells=16).method(scheme, kernel=kernel)
            .material("m", **types[material]).box("m", lower=[0.3, 0.3], upper=[0.7, 0.7])
            .walls(walls, friction=friction).time(dt=1e-3).build())


# --------------------------------------------------------------------------------------------- the whole report
def test_the_partial_codes_quick_report_runs_what_it_implements_and_passes(tmp_path):
    """The one command-line run of the partial example in the default suite (about 15 s)."""
    run = subprocess.run([sys.executable, "-m", "mpmref.cli", "verify", "--quick", "--backend", PARTIAL, "--out",
                          str(tmp_path / "v"), "--no-progress"], cwd=EXAMPLES, capture_output=True, text=True,
                         timeout=600, env=dict(os.environ, PYTHONPATH=str(EXAMPLES)))
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    data = json.loads((tmp_path / "v" / "results.json").read_text())
    summary = data["summary"]
    assert summary["errors"] == 0 and summary["failing"] == 0 and summary["checks"] > 0
    cases = {c["case"]: c for c in data["cases"]}
    assert {name: c["verdict"] for name, c in cases.items()}["convergence"] == "not applicable"
    for name in ("momentum", "energy"):
        assert any(check["case"] == name for check in data["checks"]), name
    assert all(c["verdict"] != "ERROR" for c in cases.values())
    items = data["not_applicable"]
    assert len(items) == summary["not_applicable"] > 0 and all(item["reasons"] for item in items)
    assert {"case": "momentum", "name": momentum._variant_label("pic"), "reasons": ["needs the pic scheme"]} in items
    assert any("replaced by fluid" in change for a in cases["momentum"]["adapted"] for change in a["changes"])
    assert f"{summary['checks']} of {summary['checks']} checks pass, 0 fail" in run.stdout
    assert "## Not applicable to this backend" in (tmp_path / "v" / "momentum" / "report.md").read_text()


# ------------------------------------------------------------------------------------------------------ fitting
def test_a_backend_that_implements_a_scene_gets_it_unchanged():
    scene = block("solid")
    assert fit(scene, "numpy", Allow(materials="substitute", walls="static", kernel=True)).scene is scene
    assert fit(scene, "numpy").changes == ()


def test_a_lacking_material_becomes_the_backends_own_of_the_same_density_and_wave_speed():
    solid = block("solid")
    fitted = fit(solid, PARTIAL, Allow(materials="substitute", walls="open"))
    (fluid,) = fitted.scene.material_list
    assert type(fluid).__name__ == "WeaklyCompressibleFluid" and fluid.rho == 2.0
    assert np.isclose(fluid.wave_speed(), solid.max_wave_speed(), rtol=1e-14)
    assert any("replaced by fluid" in c for c in fitted.changes)
    assert not declaration_of(PARTIAL).missing(fitted.scene)


def test_open_walls_become_the_backends_walls_on_a_domain_padded_by_their_band():
    scene = block("fluid")
    fitted = fit(scene, PARTIAL, Allow(walls="open")).scene
    width = scene.boundary.width
    assert {w.type for w in fitted.boundary.walls.values()} == {"separate"}
    assert all(w.friction == 0.0 for w in fitted.boundary.walls.values())
    assert np.allclose(fitted.grid.origin, scene.grid.origin - width * scene.grid.dx)
    assert fitted.grid.dx == scene.grid.dx and fitted.grid.cells == tuple(c + 2 * width for c in scene.grid.cells)
    with pytest.raises(Inapplicable, match="needs open walls"):  # the claim does not allow it: as declared or nothing
        fit(scene, PARTIAL)


def test_what_a_claim_does_not_allow_is_not_applicable_with_its_reasons():
    with pytest.raises(Inapplicable) as info:
        fit(block("fluid", scheme="pic", walls="separate"), PARTIAL, Allow(materials="substitute", walls="static"))
    assert info.value.reasons == ("needs the pic scheme",)  # a scheme is never changed
    with pytest.raises(Inapplicable, match="needs the material sand"):  # a plastic material is never substituted
        fit(block("sand", walls="separate"), PARTIAL, Allow(materials="substitute"))
    with pytest.raises(Inapplicable, match="needs the cubic kernel"):
        fit(block("fluid", kernel="cubic", walls="separate"), PARTIAL, Allow(materials="substitute"))
    kernel = fit(block("fluid", kernel="cubic", walls="separate"), PARTIAL, Allow(kernel=True)).scene
    assert kernel.method.kernel == "quadratic"


class FixedGamma(Mpm88Backend):
    """The partial example declaring the Tait exponent of the 88-line program built in."""

    implements = replace(Mpm88Backend.implements, parameters={"fluid": {"gamma": 1.0}})


def test_the_parameters_a_backend_fixes_are_given_to_its_material():
    for material in ("solid", "fluid"):  # another material, or the backend's own with another exponent
        scene = block(material, walls="separate")
        (fluid,) = fit(scene, FixedGamma, Allow(materials="substitute")).scene.material_list
        assert fluid.gamma == 1.0 and np.isclose(fluid.wave_speed(), scene.max_wave_speed(), rtol=1e-14)
    with pytest.raises(Inapplicable, match=r"needs fluid gamma = 7 \(this backend fixes gamma = 1\)"):
        fit(block("fluid", walls="separate"), FixedGamma)


def test_subset_keeps_only_the_bodies_of_the_materials_the_backend_has():
    scene = (SceneBuilder(dim=2, name="two").grid(size=1.0, cells=16).method("mls")
             .material("solid", "fixed_corotated", E=1e3, nu=0.3).material("water", "fluid", K=50.0)
             .box("solid", lower=[0.2, 0.2], upper=[0.4, 0.4]).box("water", lower=[0.6, 0.6], upper=[0.8, 0.8])
             .walls("separate", friction=0.3).time(dt=1e-3).build())
    fitted = fit(scene, PARTIAL, Allow(materials="subset", friction=True)).scene
    assert list(fitted.materials) == ["water"] and len(fitted.bodies) == 1
    assert all(w.friction == 0.0 for w in fitted.boundary.walls.values())


def test_the_declaration_on_the_class_a_factory_makes_is_found():
    assert declaration_of(PARTIAL).materials == ("fluid",)
    assert declaration_of("numpy").implements(block("sand"))


# ----------------------------------------------------------------------------------------- not applicable, errors
def nothing_run(params, backend="numpy", executor=None):
    triage = Triage(backend)
    triage.scene("the only run", block("sand"), Allow(materials="substitute"))
    raise triage.nothing_ran()


def test_a_case_with_nothing_applicable_is_not_applicable_never_an_error():
    case = VerificationCase("Nothing applies.", momentum.Params, nothing_run, lambda r: [], lambda r, o: None)
    outcome = registry.run_case("nothing", "quick", PARTIAL, case=case)
    assert outcome.error is None and outcome.verdict == "not applicable" and outcome.ok and not outcome.passed
    assert [(i.name, i.reasons[0]) for i in outcome.not_applicable] == [("the only run", "needs the material sand")]


class BrokenG2P(Mpm88Backend):
    """The partial example with a G2P that breaks: an exception inside an implemented feature."""

    def g2p(self, particles, v_grid, v_tilde, dt, prepared=None, kicks=None):
        return particles.J - None


def test_an_exception_inside_a_stage_names_the_scene_and_the_stage():
    params = momentum.Params(cells=16, steps=2, frames=1, variants=("mls",))
    outcome = registry.run_case("momentum", "quick", "test_verify_partial:BrokenG2P", params=params)
    assert outcome.verdict == "ERROR"
    assert outcome.error_line.startswith("scene 'momentum_mls', stage g2p of BrokenG2P (raised at "
                                         "test_verify_partial.py:")
    assert "TypeError: unsupported operand type(s) for -" in outcome.error_line


def test_the_place_of_an_exception_travels_from_a_worker_process():
    def raising(item):
        raise ValueError(f"bad item {item}")

    with pytest.raises(ValueError) as info:
        located_call(raising, 3)
    sent = pickle.loads(pickle.dumps(info.value))  # what a process pool sends back
    assert sent.verification_where == info.value.verification_where == locate(info.value)
    assert "in test_verify_partial.raising" in sent.verification_where.stage
    assert any("verification: raised in" in note for note in sent.__notes__)


def test_the_executor_keeps_the_exception_type_with_its_place():
    with pytest.raises(ZeroDivisionError) as info:
        Executor(workers=1).map(divide, [1, 0])
    assert "in test_verify_partial.divide" in info.value.verification_where.stage


def divide(x):
    return 1 / x


def test_nothing_applicable_is_picklable_with_its_items():
    scene = Scene.from_toml(EXAMPLES / "jelly.toml")
    triage = Triage(PARTIAL)
    assert triage.scene("jelly", scene) is None
    sent = pickle.loads(pickle.dumps(triage.nothing_ran()))
    assert isinstance(sent, NothingApplicable) and sent.items == tuple(triage.not_applicable)


def test_a_run_where_no_check_applies_says_nothing_was_verified_and_exits_1(tmp_path, capsys):
    """``verify cpic`` on the partial example: the case is not applicable (never an error), and with no check run at
    all the command does not claim a pass."""
    from verification.framework.cli import add_parser

    parser = argparse.ArgumentParser(prog="mpmref")
    add_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["verify", "cpic", "--quick", "--backend", PARTIAL, "--out", str(tmp_path), "--workers",
                              "1", "--no-progress"])
    assert args.func(args) == 1
    captured = capsys.readouterr()
    assert "0 of 0 checks pass, 0 fail, in 0 of 1 cases" in captured.out and "nothing was verified" in captured.err
    assert "**NOTHING CHECKED**" in (tmp_path / "report.md").read_text()
    assert "needs rigid bodies (CPIC coupling)" in (tmp_path / "cpic" / "report.md").read_text()
