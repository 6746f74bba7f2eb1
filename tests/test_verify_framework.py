"""The verification framework: the case registry and ``mpmref verify`` (verification/framework/cli.py)."""

import argparse
import html
import inspect
import json
import os
import re
import sys
import time
import types
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pytest

from mpmref.backends.numpy import backend as numpy_backend
from verification import momentum
from verification.framework import registry, warmup
from verification.framework.case import PRESETS, VerificationCase
from verification.framework.cli import add_parser
from verification.framework.common import Check
from verification.framework.report import case_record, pyplot, save_figure


def verify(argv):
    parser = argparse.ArgumentParser(prog="mpmref")
    add_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["verify", *argv])
    return args.func(args)


def small_momentum_quick(monkeypatch, **changes):
    """Make momentum's quick preset smaller for CLI tests (the full quick preset has its own tests)."""
    small = replace(momentum.Params.quick(), cells=24, steps=60, frames=3, **changes)
    monkeypatch.setattr(momentum.Params, "quick", classmethod(lambda cls: small))


def test_registry_lists_and_loads_the_cases():
    names = registry.available()
    assert {"momentum", "energy", "transfer_energy"} <= set(names)
    for name in names:
        case = registry.load(name)
        for preset in PRESETS:
            assert isinstance(case.params(preset), case.Params)
        assert case.main_figure.endswith(".png")  # the figure index.html shows for it
    with pytest.raises(KeyError, match="available: momentum"):
        registry.load("nonsense")
    with pytest.raises(ValueError, match="unknown preset 'tiny'"):
        registry.load("momentum").params("tiny")


def takes(function, *args, **kwargs):
    """Whether ``function`` can be called with these arguments (its signature binds them)."""
    try:
        inspect.signature(function).bind(*args, **kwargs)
    except TypeError:
        return False
    return True


@pytest.mark.parametrize("name", registry.available())
def test_every_registered_case_satisfies_the_case_protocol(name):
    """Each case module declares a VerificationCase whose members take the arguments the framework passes them."""
    case = registry.load(name)
    assert isinstance(case, VerificationCase) and case.title and case.title == case.doc.strip().splitlines()[0]
    params = case.params("quick")
    assert takes(case.run, params, backend="numpy", executor=None)
    assert all(takes(member, "result") for member in (case.checks, case.findings))
    assert takes(case.report, "result", "out_dir") and takes(case.backends_run, "result", "numpy")
    assert takes(case.compiled_scenes, params, "numpy") and isinstance(case.runs_alone, bool)
    assert not takes(case.run, params, "numpy", None, "extra")  # the check can fail


@dataclass(frozen=True)
class BareParams:
    slope: float = 1.0

    @classmethod
    def quick(cls):
        return cls(slope=0.5)

    @classmethod
    def full(cls):
        return cls(slope=2.0)


def bare_run(params, backend="numpy", executor=None):
    return {"slope": params.slope}


def bare_checks(result):
    return [Check("slope", result["slope"], "<=", 1.0, "the bare case's bound")]


def bare_report(result, out_dir):
    for name in ("first.png", "second.png"):
        fig, ax = pyplot().subplots()
        ax.plot([0.0, 1.0], [0.0, result["slope"]])
        save_figure(fig, Path(out_dir) / name, caption=name)


def test_a_case_with_only_the_required_members_gets_the_defaults(monkeypatch, tmp_path):
    """No findings, the backend asked for, nothing compiled ahead, not run alone, its first figure shown."""
    bare = VerificationCase("A bare case.\n\nIt declares Params, run, checks and report only.", BareParams, bare_run,
                            bare_checks, bare_report)
    assert bare.title == "A bare case."
    assert tuple(bare.findings({})) == () and tuple(bare.backends_run({}, "numba")) == ("numba",)
    assert bare.compiled_scenes(BareParams(), "numpy") == [] and bare.main_figure is None and not bare.runs_alone
    assert bare.tables({}) == {}
    assert [bare.params(p) for p in PRESETS] == [BareParams(0.5), BareParams(1.0), BareParams(2.0)]
    module = types.ModuleType("bare_case")
    module.CASE = bare
    monkeypatch.setitem(sys.modules, "bare_case", module)
    monkeypatch.setitem(registry.CASES, "bare", "bare_case")
    outcome = registry.run_case("bare", "quick", "numba", out_dir=tmp_path)
    assert outcome.passed and outcome.title == "A bare case." and outcome.params == BareParams(0.5)
    record = case_record(outcome, tmp_path)
    assert (record.backends == ("numba",) and record.findings == () and record.tables == {}
            and record.main_figure[:2] == (Path("first.png"), "first.png"))
    assert not warmup.compiles("bare", "quick", "numpy") and not warmup.runs_alone("bare")


@pytest.fixture(scope="module")
def report_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("verify")
    stale = out / "momentum" / "vtk" / "from_an_earlier_run" / "particles.pvd"
    stale.parent.mkdir(parents=True)
    stale.write_text("old")
    os.utime(stale, (time.time() - 3600, time.time() - 3600))
    with pytest.MonkeyPatch.context() as mp:
        small_momentum_quick(mp)
        code = verify(["momentum", "transfer_energy", "--quick", "--workers", "1", "--out", str(out)])
    return out, code


def test_cli_passes_and_writes_every_report_file(report_dir):
    out, code = report_dir
    assert code == 0
    for name in ("report.md", "index.html", "momentum/report.md", "momentum/momentum.md",
                 "momentum/momentum_drift.png", "momentum/vtk/mls/particles.pvd", "momentum/vtk/mls/particles_0003.vtu",
                 "transfer_energy/report.md", "transfer_energy/transfer_energy.md"):
        assert (out / name).is_file(), name
    case_md = (out / "momentum" / "report.md").read_text()
    assert "![momentum_drift](momentum_drift.png)" in case_md and "vtk/pic/particles.pvd" in case_md
    assert "from_an_earlier_run" not in case_md  # files older than the run are not reported


def test_index_lists_every_check_with_figure_bound_and_verdict(report_dir):
    out, _ = report_dir
    index, page = (out / "report.md").read_text(), (out / "index.html").read_text()
    for case in ("momentum", "transfer_energy"):
        assert f"| {case} |" in index and f"{case}/index.html" in page
        assert f"<img src='{case}/{registry.load(case).main_figure}'" in page  # its main figure, inline
    cells = [re.split(r"(?<!\\)\|", line)[1:-1] for line in index.splitlines()]
    checks = [[c.strip() for c in row] for row in cells if len(row) == 6 and row[0].strip() == "momentum"]
    assert len(checks) == 2 * len(momentum.VARIANTS)  # linear + angular per scheme
    for name, figure, bound, verdict, _ in (row[1:] for row in checks):
        assert float(figure) >= 0.0 and bound.split()[0] in ("<=", ">=", ">") and verdict == "pass"
        assert html.escape(name) in page
    assert "Machine: host" in index and "total wall time" in index


def test_a_broken_transfer_makes_verify_exit_1(monkeypatch, tmp_path, capsys):
    original, original_fused = numpy_backend.NumpyBackend.p2g, numpy_backend.NumpyBackend.p2g_fused

    def p2g_without_affine(self, particles, prepared=None):
        return original(self, particles.with_(C=np.zeros_like(particles.C)), prepared)

    def p2g_fused_without_affine(self, particles, dt, prepared=None):  # the P2G the steps run
        return original_fused(self, particles.with_(C=np.zeros_like(particles.C)), dt, prepared)

    monkeypatch.setattr(numpy_backend.NumpyBackend, "p2g", p2g_without_affine)
    monkeypatch.setattr(numpy_backend.NumpyBackend, "p2g_fused", p2g_fused_without_affine)
    small_momentum_quick(monkeypatch, variants=("mls",))
    assert verify(["momentum", "--quick", "--workers", "1", "--out", str(tmp_path)]) == 1
    assert "FAIL MLS-MPM (APIC, MLS force): angular momentum drift" in capsys.readouterr().out
    assert "| FAIL |" in (tmp_path / "report.md").read_text()


def test_a_case_that_raises_is_reported_and_fails(monkeypatch, tmp_path):
    def explode(params, backend="numpy", executor=None):
        raise RuntimeError("deliberate failure inside the case")

    monkeypatch.setattr(momentum, "CASE", replace(momentum.CASE, run=explode))
    assert verify(["momentum", "--quick", "--workers", "1", "--out", str(tmp_path)]) == 1
    assert "deliberate failure inside the case" in (tmp_path / "momentum" / "report.md").read_text()
    assert "| [momentum](momentum/report.md) | numpy | 0 | ERROR |" in (tmp_path / "report.md").read_text()


def test_an_unknown_case_exits_2(tmp_path, capsys):
    assert verify(["nonsense", "--out", str(tmp_path)]) == 2
    assert "unknown case(s) nonsense" in capsys.readouterr().err


def test_results_json_holds_every_check_of_the_real_cases(report_dir):
    out, _ = report_dir
    data = json.loads((out / "results.json").read_text())
    index = (out / "report.md").read_text().split("## Every check")[1]
    assert [c["case"] for c in data["cases"]] == ["momentum", "transfer_energy"]
    assert all(c["tables"] == {} for c in data["cases"])  # neither tabulates more than its checks
    assert len(data["checks"]) == data["summary"]["checks"] == index.count(" | pass | ") + index.count(" | FAIL | ")
    momentum_checks = [c for c in data["checks"] if c["case"] == "momentum"]
    assert len(momentum_checks) == 2 * len(momentum.VARIANTS)
    for c in data["checks"]:
        assert c["verdict"] == "pass" and c["reason"] and c["relation"] in ("<=", ">=", "<", ">")
        assert f"| {c['case']} | {c['name'].replace('|', chr(92) + '|')} | {c['figure']:.6g} | " in index


def test_the_warm_up_compiles_every_kernel_of_the_compiled_cases_once():
    """verify compiles ahead only what later cases run on Numba (and the compiled bookkeeping of an asynchronous
    scene they run on NumPy): each queued Numba scene compiles kernels that the scenes before it do not, the
    positions each case needs cover every kernel of its scenes, and a NumPy-only selection starts no process."""
    from mpmref.backends import make_backend
    from verification import backends
    from verification.framework import warmup

    cases = ["momentum", "backends", "speed_accuracy", "sync_vs_async"]
    queue, needs = warmup.plan(cases, "quick", "numpy")
    assert all(name == "numba" or scene.time.stepping == "async" for name, scene in queue)
    assert set(needs) == set(cases[1:])
    kernels = [make_backend(name, scene).compiled_kernels() if name == "numba" else set() for name, scene in queue]
    for k in range(1, len(kernels)):
        assert queue[k][0] != "numba" or not kernels[k] <= set().union(*kernels[:k])
    for case in needs:
        covered = set().union(*(kernels[k] for k in needs[case]))
        assert all(make_backend(name, scene).compiled_kernels() <= covered
                   for name, scene in warmup.declared_scenes(case, "quick", "numpy") if name == "numba")
    assert {v.scheme for v in backends.VARIANTS} <= {scene.method.scheme for _, scene in queue}
    assert warmup.start(["momentum", "transfer_energy"], "quick", "numpy") is None


def test_a_case_starts_early_only_when_its_kernels_are_compiled_and_it_times_nothing():
    """can_start: sync_vs_async once the scenes it needs are done; speed_accuracy (timed) never early."""
    from types import SimpleNamespace

    from verification.framework import warmup

    _, needs = warmup.plan(["sync_vs_async", "speed_accuracy"], "quick", "numpy")
    for flag in (0, 1):
        fake = SimpleNamespace(needs=needs, done=[flag] * (1 + max(max(v) for v in needs.values())))
        assert warmup.can_start(fake, "sync_vs_async") == bool(flag)
        assert not warmup.can_start(fake, "speed_accuracy")
    assert not warmup.can_start(None, "sync_vs_async")


def test_the_warm_up_queue_hands_out_every_scene_once_from_either_end():
    """The background process takes scenes from the front, the main process from the back: each once."""
    import multiprocessing

    from verification.framework import warmup

    queue = multiprocessing.Array("i", [0, 5])
    taken = [warmup.claim(queue, from_back=k % 2 == 1) for k in range(7)]
    assert taken == [0, 4, 1, 3, 2, None, None]


def test_the_quick_preset_runs_the_serial_kernel_builds_here_and_in_its_processes_unless_told_otherwise(
        monkeypatch):
    """``verify --quick`` compiles the serial builds (the same bits, compiled sooner: tests/test_numba_backend.py),
    in its own process and, through the environment, in those it starts; ``--threads`` above one, another preset or
    a mode the environment chose keep the mode in force, and the mode and environment before come back after."""
    from mpmref.backends.numba import twin
    from verification.framework.cli import kernel_builds

    monkeypatch.delenv(twin.BUILDS_VARIABLE)

    def builds_within(preset, threads=None):
        with kernel_builds(argparse.Namespace(preset=preset, threads=threads)):
            return twin.mode(), os.environ.get(twin.BUILDS_VARIABLE)

    before = twin.mode()
    with twin.builds("parallel"):  # what a user's process starts in
        assert builds_within("quick") == ("serial", "serial")
        assert twin.mode() == "parallel" and twin.BUILDS_VARIABLE not in os.environ
        assert builds_within("quick", threads=2) == ("parallel", None)
        assert builds_within("default") == ("parallel", None)
        monkeypatch.setenv(twin.BUILDS_VARIABLE, "parallel")
        assert builds_within("quick") == ("parallel", "parallel")
    assert twin.mode() == before
