"""The conformance harness on codes that implement a part: what a code implements is checked, and nothing
else; the others are not applicable, with their reasons, never a failure.

* The example partial code (examples/mpm88_backend.py: 2D, quadratic, MLS-MPM, one fluid with J only, frictionless
  separate walls, Δt g left on nodes without mass) passes every case of its own scene and every catalogue case it
  implements, and a wrong trace planted in a copy of it is caught on its scene.
* Grid velocities are compared on nodes with mass only: garbage on empty nodes passes, a wrong massive node fails.
* A P2G that takes the stress is given it, fused or not; fields a code does not evolve are not compared; a factory or
  a stage that raises NotImplementedError declines its case, any other exception fails it naming stage and scene.
* ``--material``, ``--scheme`` and ``--kernel`` select the catalogue without dropping its per-method cases.
"""

import sys
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from mpmref.backends.capabilities import Implements
from mpmref.backends.numpy import NumpyBackend
from mpmref.cli import main
from mpmref.conformance import check, make_cases, scene_cases
from mpmref.conformance.case import STAGE_PARTS
from mpmref.conformance.measures import ROW_FLOOR
from mpmref.conformance.scenes import scene_stages
from mpmref.scene import Scene

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = ROOT / "examples"
MPM88 = EXAMPLES / "mpm88.toml"
REFERENCE = "mpm88_backend:factory"
#: the J update of the example's G2P, and the same with the wrong trace (C_xx + C_xy)
RIGHT_TRACE = "J = particles.J * (1.0 + dt * (C[:, 0, 0] + C[:, 1, 1]))"
WRONG_TRACE = "J = particles.J * (1.0 + dt * (C[:, 0, 0] + C[:, 0, 1]))"


@pytest.fixture
def examples_on_path(monkeypatch):
    """examples/ importable, as ``cd examples`` makes it for ``mpmref conformance check``."""
    monkeypatch.syspath_prepend(str(EXAMPLES))


def run_cli(argv, capsys):
    code = main(argv)
    out, err = capsys.readouterr()
    return code, out, err


# ------------------------------------------------------------------------------------------- the 88-line program
def test_mpm88_passes_every_stage_its_scene_calls(examples_on_path, capsys):
    """Its own scene: every stage the scene's steps call (stress, P2G plain and fused, grid update, G2P, the step and
    its ledger) has five drawn cases and those at its extremes, all within 1e-12, none not applicable; an error would be
    a failed case."""
    code, out, _ = run_cli(["conformance", "check", "--backend", REFERENCE, "--scene", str(MPM88), "--no-progress"],
                           capsys)
    assert code == 0, out
    stages = scene_stages(Scene.from_toml(MPM88))
    assert stages == ["stress", "p2g", "p2g_fused", "grid_update", "g2p", "step", "ledger"]
    count = Counter(c.stage for c in scene_cases(MPM88))
    assert count == {"stress": 7, "p2g": 7, "p2g_fused": 7, "grid_update": 6, "g2p": 7, "step": 10, "ledger": 6}
    assert "PASSED: 50 of 50 cases within tolerance\n" in out
    assert "not applicable" not in out and "FAIL" not in out
    for stage in stages:
        assert any(line.split()[:4] == [stage, str(count[stage]), "0", "0"] for line in out.splitlines()), stage


def test_mpm88_on_the_catalogue_fails_nothing_and_says_why_each_other_case_does_not_apply(examples_on_path):
    """The catalogue fitted to its declaration: the fluid alone in the per-method cases (named so), its walls, and
    each case it does not implement with the reasons in words."""
    report = check(REFERENCE)
    assert report.passed and not report.failures()
    assert not any("raised" in r.note for r in report.results)
    ran = {r.case.name for r in report.results}
    assert {"stress-2d-fluid", "p2g-2d-mls-mls-quadratic-fluid", "p2g_fused-2d-mls-mls-quadratic-fluid",
            "grid_update-2d-separate-frictionless", "g2p-2d-mls-mls-quadratic-fluid",
            "step-2d-mls-mls-quadratic-fluid-separate-frictionless"} <= ran
    assert {r.case.stage for r in report.results} == {"stress", "p2g", "p2g_fused", "grid_update", "g2p", "step",
                                                      "ledger"}
    assert all(n.reasons and all(isinstance(t, str) and t for t in n.reasons) for n in report.not_applicable)
    reasons = {n.case.name: n.reasons for n in report.not_applicable}
    assert reasons["stress-3d-fluid"] == ("needs 3D",)
    assert reasons["p2g-2d-mls-mls-cubic-fluid"] == ("needs the cubic kernel",)
    assert reasons["stress-2d-fixed_corotated"] == ("needs the material fixed_corotated",
                                                    "compares F: this backend evolves C, J only")
    assert reasons["grid_update-2d-separate"] == ("needs friction (Coulomb, talk Eq. 25)",)
    assert reasons["grid_update-2d-sticky"] == ("needs sticky walls",)
    assert len(report.results) + len(report.not_applicable) == len(make_cases(implements=report.implements))
    table = report.table()
    assert "not applicable: " in table and "needs the cubic kernel: " in table and "FAIL" not in table


def test_a_wrong_trace_planted_in_a_copy_of_mpm88_is_caught_on_its_scene(tmp_path, monkeypatch, capsys):
    """J updated with C_xx + C_xy: the G2P cases fail on J (and nothing else), so do the steps and their ledgers
    (the multi-step ones from rest most on C: the wrong J has driven the stress for 40 steps); the stages before G2P
    pass. The failure lines name the case, the stage's output and the setting (γ = 1)."""
    source = (EXAMPLES / "mpm88_backend.py").read_text()
    assert source.count(RIGHT_TRACE) == 1
    (tmp_path / "mpm88_wrong_trace.py").write_text(source.replace(RIGHT_TRACE, WRONG_TRACE))
    monkeypatch.syspath_prepend(str(tmp_path))
    code, out, _ = run_cli(["conformance", "check", "--backend", "mpm88_wrong_trace:factory", "--scene", str(MPM88),
                            "--no-progress"], capsys)
    assert code == 1
    failed = [line.split() for line in out.splitlines() if line.strip().startswith("FAIL ")]
    assert {f[1].split("-2d-")[0] for f in failed} == {"g2p", "step", "ledger"}
    # the worst output: after the name, or after what a case at an extreme holds ("... (holds): J 1.2e-03")
    worst = [line.split("): ")[1].split()[0] if "): " in line else line.split()[2] for line in out.splitlines()
             if line.strip().startswith("FAIL ")]
    assert all(w == "J" for w, f in zip(worst, failed) if f[1].startswith(("g2p", "step")) and "from-rest" not in f[1])
    # after many steps the wrong J has driven the stress: the motion it makes (v, C) is further off than J itself
    from_rest = {w for w, f in zip(worst, failed) if "from-rest" in f[1]}
    assert from_rest and from_rest <= {"C", "v"}
    assert "outputs: x 0.000e+00, v 0.000e+00, C 0.000e+00, J " in out
    assert "fluid (K = 400, gamma = 1, rho = 1)" in out and "drawn from scene 'mpm88'" in out
    assert "FAILED: 27 of 50 cases within tolerance" in out  # 7 G2P, 10 steps and 6 ledgers fail
    sys.modules.pop("mpm88_wrong_trace", None)


# --------------------------------------------------------------------------------------------- massless nodes
class GarbageOnEmptyNodes(NumpyBackend):
    """The reference's grid update, with NaN and 1e30 on the nodes without mass (which no particle reads)."""

    def grid_update(self, grid_state, dt, time=0.0):
        v, v_tilde = super().grid_update(grid_state, dt, time)
        empty = grid_state.mass <= 0
        v, v_tilde = v.copy(), v_tilde.copy()
        v[empty], v_tilde[empty] = np.nan, 1e30
        return v, v_tilde


class WrongOnOneMassiveNode(NumpyBackend):
    """The reference's grid update, one node with mass 1e-9 off (relative to the largest velocity)."""

    def grid_update(self, grid_state, dt, time=0.0):
        v, v_tilde = super().grid_update(grid_state, dt, time)
        v = v.copy()
        node = int(np.flatnonzero(grid_state.mass > 0)[0])
        v[node, 0] += 1e-9 * np.abs(v).max()
        return v, v_tilde


def test_grid_velocities_are_compared_on_nodes_with_mass_only():
    cases = make_cases(dims=(2, 3), stages=("grid_update",))
    assert all((c.inputs()["grid_mass"] == 0).any() for c in cases)  # every case has empty nodes
    garbage = check(GarbageOnEmptyNodes, cases)
    assert garbage.passed and garbage.worst().error == 0.0
    wrong = check(WrongOnOneMassiveNode, cases)
    assert len(wrong.failures()) == len(cases)
    # case-wide 1e-9; on the node's own scale at least that and at most 1e-9 over the per-row floor
    outputs = [r.errors[r.worst_output] for r in wrong.failures()]
    assert all(r.worst_output == "grid_v" for r in wrong.failures())
    assert all(e.case_wide == pytest.approx(1e-9, rel=1e-6) for e in outputs)
    assert all(1e-9 * (1 - 1e-6) <= e <= 1e-9 / ROW_FLOOR["float64"] * (1 + 1e-6) for e in outputs)
    assert all(r.where.startswith("node ") for r in wrong.failures())


# --------------------------------------------------------------------------------------------- what is compared
def test_a_fused_p2g_that_takes_the_stress_is_given_the_reference_stress():
    seen = []

    def fused(scene, particles, dt, stress=None):
        seen.append(stress is not None)
        backend = NumpyBackend(scene)
        assert np.array_equal(stress, backend.stress(particles))
        gs = backend.p2g(particles)
        return type(gs)(mass=gs.mass, momentum=gs.momentum + dt * gs.force)

    cases = make_cases(dims=(2,), stages=("p2g_fused",))
    report = check({"p2g_fused": fused}, cases)
    assert report.passed and all(seen) and len(seen) == len(cases)


class DropsAffineInReturnMap(NumpyBackend):
    """A PIC code's return map: the particles it gives back carry no affine matrix."""

    implements = Implements(schemes=("pic",), evolves=("F", "J", "Jp"))

    def return_map(self, particles):
        return super().return_map(particles).with_(C=None)


def test_fields_a_code_does_not_evolve_are_not_compared():
    """The built-in return-map cases carry C (their scenes are MLS-MPM; the return map does not see the scheme): a
    code that evolves no C passes them, the same code declaring everything fails them for the missing C."""
    cases = make_cases(dims=(2,), stages=("return_map",))
    assert all("C" in c.inputs() for c in cases)
    assert check(DropsAffineInReturnMap, cases).passed

    class Undeclared(DropsAffineInReturnMap):
        implements = Implements()

    failed = check(Undeclared, cases).failures()
    assert len(failed) == len(cases) and all("no output C" in r.note for r in failed)


# ------------------------------------------------------------------------------------------- declining, raising
def factory_without_3d(scene):
    """A factory that declines 3D scenes by raising NotImplementedError."""
    if scene.dim == 3:
        raise NotImplementedError("this code is 2D only")
    return NumpyBackend(scene)


class RaisingP2g(NumpyBackend):
    """A P2G that raises NotImplementedError for the cubic kernel and a TypeError for PolyPIC."""

    def p2g(self, particles, prepared=None, contact=None, classes=None):
        if self.scene.transfer.polypic:
            raise TypeError("unsupported operand type(s) for -: 'NoneType' and 'int'")
        if self.scene.kernel.name == "cubic":
            raise NotImplementedError("no cubic kernel here")
        return super().p2g(particles, prepared, contact, classes)


def test_a_factory_or_stage_that_raises_not_implemented_declines_and_any_other_exception_fails():
    declined = check(factory_without_3d, make_cases(stages=("stress",)))
    assert declined.passed and {n.case.dim for n in declined.not_applicable} == {3}
    assert all(n.reasons == ("this code is 2D only",) and n.kind == "declined" for n in declined.not_applicable)
    report = check(RaisingP2g, make_cases(dims=(2,), stages=("p2g",)))
    cubic = {n.case.name for n in report.not_applicable}
    assert cubic and all("cubic" in name and "polypic" not in name for name in cubic)
    assert all(n.reasons == ("its stage p2g raised NotImplementedError: no cubic kernel here",)
               for n in report.not_applicable)
    failed = report.failures()
    assert failed and {r.case.scene().transfer.polypic for r in failed} == {True}
    assert all(f"stage p2g raised TypeError: unsupported operand type(s) for -: 'NoneType' and 'int' (scene "
               f"'conformance', case {r.case.name})" in r.note for r in failed)
    assert report.failed_stages() == {"p2g"} and not report.passed


def test_a_factory_that_fails_on_a_scene_it_declares_fails_that_scenes_cases():
    def broken(scene):
        if len(scene.materials) > 1:
            raise TypeError("cannot unpack non-iterable NoneType object")
        return NumpyBackend(scene)

    report = check(broken, make_cases(dims=(2,), stages=("stress",)))
    failed = report.failures()  # the mixed materials' case and its stiff twin at an extreme
    assert sorted(f.case.variant for f in failed) == ["mixed", "mixed-large-stiffness"]
    assert all("the factory raised TypeError: cannot unpack" in f.note for f in failed)
    assert all("for scene 'conformance'" in f.note for f in failed)


# ----------------------------------------------------------------------------------------------------- filters
def test_material_scheme_and_kernel_select_without_dropping_the_per_method_cases(capsys):
    fluid = make_cases(dims=(2,), stages=("p2g", "grid_update", "stress"), materials=("fluid",))
    per_method = [c for c in fluid if c.stage == "p2g" and c.variant.endswith("-fluid")]
    assert len(per_method) == 22 and all(c.materials == {"fluid"} for c in fluid if c.stage != "grid_update")
    assert {c.variant for c in fluid if c.stage == "stress" and c.extreme is None} == {"fluid"}
    assert {c.variant for c in fluid if c.stage == "stress" and c.extreme} == {"fluid-rest", "fluid-collapse"}
    # the grid update does not see the material
    assert len([c for c in fluid if c.stage == "grid_update" and c.extreme is None]) == 7
    chosen = make_cases(dims=(2,), stages=("p2g", "stress"), schemes=("mls",), kernels=("quadratic",))
    drawn = [c for c in chosen if c.extreme is None]
    assert {c.variant for c in drawn if c.stage == "p2g"} == {"mls-mls-quadratic", *make_material_sets()}
    assert len([c for c in drawn if c.stage == "stress"]) == 6  # the stress does not see the method
    assert {c.extreme.name for c in chosen if c.stage == "p2g" and c.extreme} == {"on-nodes-and-faces", "domain-edge"}
    code, out, _ = run_cli(["conformance", "check", "--backend", "numpy", "--dim", "2", "--stage", "g2p",
                            "--material", "fluid", "--scheme", "mls", "apic", "--kernel", "quadratic", "--verbose",
                            "--no-progress"], capsys)
    assert code == 0 and "g2p-2d-mls-mls-quadratic-fluid " in out and "g2p-2d-fluid " in out
    # MLS-MPM, APIC with either force and either velocity gradient, on the fluid alone; the fluid's own case; and
    # MLS-MPM's particles on nodes and faces and at the domain's edge
    assert "PASSED: 8 of 8" in out and "g2p-2d-mls-mls-quadratic-fluid-on-nodes-and-faces " in out


def make_material_sets():
    from mpmref.conformance.cases import MATERIAL_SETS

    return set(MATERIAL_SETS)


def test_scene_and_catalogue_options_are_refused_together(capsys):
    code, _, err = run_cli(["conformance", "check", "--backend", "numpy", "--scene", str(MPM88), "--dim", "2"], capsys)
    assert code == 2 and "--dim: not with --scene" in err
    code, _, err = run_cli(["conformance", "export", "x", "--scene", str(MPM88), "--stage", "return_map"], capsys)
    assert code == 2 and "scene 'mpm88' does not call them" in err and "return_map" in err
    code, _, err = run_cli(["conformance", "check", "--backend", "numpy", "--scene", "no_such_scene.toml"], capsys)
    assert code == 2 and "no_such_scene.toml" in err


def test_each_stage_declares_the_parts_of_a_scene_it_depends_on():
    """The parts each stage is asked about (not the walls for the stress, not the scheme for the grid update)."""
    assert "boundary" not in STAGE_PARTS["stress"] and "method" not in STAGE_PARTS["grid_update"]
    assert "materials" not in STAGE_PARTS["grid_update"] and "boundary" in STAGE_PARTS["step"]
