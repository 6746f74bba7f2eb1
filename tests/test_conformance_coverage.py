"""What ``mpmref conformance check`` says it compared: a declaration of a method mpmref cannot model (APIC with the
linear kernel) passes the cases that apply to it, and is told that its P2G, G2P and steps were never compared and
why; a narrow declaration mpmref can model is not warned, and stages it does not claim (asynchronous, CPIC) are not
listed as missed."""

import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

from mpmref.backends.capabilities import Implements
from mpmref.conformance.coverage import compared_stages, coverage_lines, never_compared
from mpmref.conformance.report import NotApplicable, Report

ROOT = Path(__file__).resolve().parent.parent
PATH = os.pathsep.join([str(ROOT / "tests"), str(ROOT / "examples")])


def conformance_check(name):
    """``mpmref conformance check --backend declared_backends:NAME --dim 2``: the finished process."""
    return subprocess.run([sys.executable, "-m", "mpmref.cli", "conformance", "check", "--backend",
                           f"declared_backends:{name}", "--dim", "2", "--no-progress"],
                          capture_output=True, text=True, timeout=900, env=dict(os.environ, PYTHONPATH=PATH))


def test_apic_with_the_linear_kernel_is_told_its_transfers_were_never_compared():
    run = conformance_check("ApicLinear")
    lines = run.stdout.splitlines()
    assert run.returncode == 0 and lines[-4].startswith("PASSED"), run.stdout[-2000:] + run.stderr[-2000:]
    missed = next(line for line in lines if line.startswith("never compared, though provided: "))
    for stage in ("p2g", "g2p", "step"):
        assert f"{stage} (a declared method mpmref cannot model)" in missed
    warning = next(line for line in lines if line.startswith("warning: "))
    assert "cannot model the apic scheme with the linear kernel" in warning and "p2g" in warning
    assert not any(stage in missed for stage in ("cpic_", "wave_speeds", "return_map"))  # not claimed


def test_a_modelable_narrow_declaration_is_not_warned():
    run = conformance_check("Pic2d")
    lines = run.stdout.splitlines()
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    compared = next(line for line in lines if line.startswith("compared: "))
    assert all(f"{stage} (" in compared for stage in ("stress", "p2g", "grid_update", "g2p", "step"))
    assert not any(line.startswith(("warning: ", "never compared")) for line in lines)


# ------------------------------------------------------------------------------ on reports made by hand
def result(stage):
    return SimpleNamespace(case=SimpleNamespace(stage=stage), passed=True)


def not_applicable(stage, reason, kind="declared"):
    return NotApplicable(SimpleNamespace(stage=stage), (reason,), kind)


def test_a_stage_is_missed_only_when_provided_claimed_and_never_run():
    declaration = Implements(stepping=("sync",), rigid_bodies=False, materials=("fluid",))
    report = Report([result("stress"), result("p2g")],
                    [not_applicable("g2p", "needs 3D"), not_applicable("g2p", "needs 3D"),
                     not_applicable("g2p", "needs the cubic kernel"),
                     not_applicable("p2g", "needs 3D"),  # p2g ran on another case
                     not_applicable("step", "does not provide the stage step", "not provided"),
                     not_applicable("wave_speeds", "needs asynchronous time stepping"),
                     not_applicable("cpic_p2g", "needs rigid bodies (CPIC coupling)"),
                     not_applicable("return_map", "needs the material snow")],
                    declaration)
    assert compared_stages(report) == {"stress": 1, "p2g": 1}
    assert never_compared(report) == {"g2p": "needs 3D"}  # its most frequent reason
    claiming = Report(report.results, report.not_applicable,
                      Implements(stepping=("sync", "async"), rigid_bodies=True, materials=("fluid", "snow")))
    assert set(never_compared(claiming)) == {"g2p", "wave_speeds", "cpic_p2g", "return_map"}


def test_nothing_is_said_when_nothing_ran():
    assert coverage_lines(Report([], [not_applicable("p2g", "needs 3D")], Implements())) == []
