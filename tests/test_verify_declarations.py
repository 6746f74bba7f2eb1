"""``mpmref verify --quick`` on correct codes unlike the repository's examples (tests/declared_backends.py): each runs
the checks its declaration's claims allow, exit 0, no error; a declaration mpmref cannot model is refused in one line.

The declarations are delegates of the NumPy reference, so every check that runs must pass: a failure or an error is
the checker's. The 3D ones whose claims include the energy case (its disks and jelly as 3D slabs) take one to three
minutes on two cores and are in the slow set.
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PATH = os.pathsep.join([str(ROOT / "tests"), str(ROOT / "examples")])

#: the cases whose checks each declaration's claims allow (measured: the checks that run are in the closing note)
CASES = {
    "Sulsky": {"momentum", "energy_ledger", "backends"},
    "Pic2d": {"momentum", "energy_ledger", "backends"},
    "Sand2d": {"momentum", "energy_ledger", "backends"},
    "Gamma1": {"momentum", "energy", "energy_ledger", "extremes", "backends"},
    "Mpm99": {"momentum", "energy", "energy_ledger", "extremes", "backends", "speed_accuracy"},
    "Poly3d": {"momentum", "energy", "energy_ledger", "backends"},
    "Mls3dFluid": {"momentum", "energy", "energy_ledger", "backends"},
}
SLOW = ("Poly3d", "Mls3dFluid")


def verify(name, out, *options):
    """``mpmref verify --quick --backend declared_backends:NAME`` into ``out``: the process and its results."""
    run = subprocess.run([sys.executable, "-m", "mpmref.cli", "verify", "--quick", "--backend",
                          f"declared_backends:{name}", "--out", str(out), "--no-progress", *options],
                         capture_output=True, text=True, timeout=1200, env=dict(os.environ, PYTHONPATH=PATH))
    data = json.loads((out / "results.json").read_text()) if (out / "results.json").exists() else None
    return run, data, out


@pytest.fixture(scope="module")
def reports(tmp_path_factory):
    """The quick report of each declaration (run once), by name."""
    cache = {}

    def report(name):
        if name not in cache:
            cache[name] = verify(name, tmp_path_factory.mktemp(name))
        return cache[name]

    return report


@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.slow) if n in SLOW else n for n in CASES])
def test_a_correct_partial_code_runs_the_checks_its_claims_allow_and_passes(reports, name):
    run, data, _ = reports(name)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    summary = data["summary"]
    assert summary["errors"] == 0 and summary["failing"] == 0 and summary["checks"] > 0
    checked = {c["case"] for c in data["checks"]}
    assert CASES[name] <= checked, f"{name}: no checks of {sorted(CASES[name] - checked)}"
    assert all(c["verdict"] != "ERROR" for c in data["cases"])
    assert all(item["reasons"] for item in data["not_applicable"])


def test_a_declared_tait_exponent_gives_no_error_at_the_extremes(reports):
    """γ = 1 fixed in the code: the extremes case's bisection runs past the stable limit on purpose, and a blow-up
    there (an unbounded velocity that leaves the domain) is a break of the probe, not an error of the case."""
    run, data, _ = reports("Gamma1")
    extremes = next(c for c in data["cases"] if c["case"] == "extremes")
    assert extremes["verdict"].startswith("pass"), run.stdout[-2000:]
    assert "ERROR" not in run.stdout


def test_a_snow_without_bounds_is_given_them_and_keeps_its_particles_step(reports):
    """A code that never clamps J_P declares bounds far outside any state: the checks give its snow those bounds
    (they say which parameter changed, never that snow was left out while the backend has it), and no step of its
    runs is warned about for a wave speed its particles never reach."""
    run, data, _ = reports("Mpm99")
    changes = [c for case in data["cases"] for a in case["adapted"] for c in a["changes"]]
    assert any("given the parameters the backend fixes: Jp_min = 1e-300 for 0.6" in c for c in changes), changes
    assert not any("left out" in c and "snow" in c for c in changes)
    assert "snow88" not in {i["name"].split()[0] for i in data["not_applicable"] if i["case"] == "energy_ledger"}
    assert "CFL number of time.dt" not in run.stderr


def test_the_backends_report_names_the_backend_it_compared(reports):
    _, _, out = reports("Pic2d")
    text = (out / "backends" / "report.md").read_text()
    assert "| candidate | declared_backends:Pic2d |" in text and "| candidate | numba |" not in text


def test_a_declaration_mpmref_cannot_model_is_refused_in_one_line(tmp_path):
    run, _, _ = verify("ApicLinear", tmp_path / "v")
    assert run.returncode == 2
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and "cannot model the apic scheme with the linear kernel" in lines[0], run.stderr
    assert "constant inertia D_p" in lines[0]
