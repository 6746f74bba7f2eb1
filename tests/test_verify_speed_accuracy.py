"""The speed-vs-accuracy case (verification/speed_accuracy.py): its quick preset and its Pareto front."""

import pytest
from helpers import assert_every_figure_has_a_caption

from mpmref.backends import BACKENDS
from verification import speed_accuracy as case
from verification.framework.common import failed
from verification.framework.executor import Executor

pytestmark = pytest.mark.skipif("numba" not in BACKENDS, reason="no Numba backend")


@pytest.fixture(scope="module")
def result():
    return case.run(case.Params.quick())


def test_every_check_of_the_quick_preset_holds(result):
    failing = [c.line() for c in failed(case.checks(result))]
    assert not failing, "\n".join(failing)


def test_sweep_covers_scheme_kernel_resolution_and_backend(result):
    params = case.Params.quick()
    keys = {(p["series"].scheme, p["series"].kernel, p["cells"], p["backend"]) for p in result["points"]}
    assert len(keys) == len(case.SCHEMES) * len(params.kernels) * len(params.cells) * len(params.backends)


def test_pareto_front_is_exactly_the_undominated_runs(result):
    """On the front: no faster run is as accurate (errors equal to round-off count as equal)."""
    points = result["points"]
    for p in points:
        dominated = any(q is not p and (q["wall_s"], q["error_u"]) < (p["wall_s"], p["error_u"])
                        and p["error_u"] >= q["error_u"] * (1.0 - case.SAME_ERROR) for q in points)
        assert p["pareto"] == (not dominated)
    assert any(p["pareto"] for p in points)


def test_pic_made_second_order_fails_the_ordering_check(result):
    """If PIC's errors were those of APIC (a PIC that kept C), the first-order check must fail."""
    apic = {(p["cells"], p["backend"]): p["error_u"] for p in result["points"] if p["series"].scheme == "apic"}
    points = [{**p, "error_u": apic[(p["cells"], p["backend"])]} if p["series"].scheme == "pic" else p
              for p in result["points"]]
    broken = case.checks({**result, "points": points})
    assert not next(c for c in broken if "PIC's error" in c.name).passed


def test_report_writes_plot_tables_and_vtk(result, tmp_path):
    paths = case.report(result, tmp_path)
    assert all(p.exists() for p in paths)
    text = (tmp_path / "speed_accuracy.md").read_text()
    assert "Pareto front:" in text and "| yes |" in text and "FAIL" not in text
    assert (tmp_path / "vtk" / "most_accurate" / "particles.pvd").exists()
    assert_every_figure_has_a_caption(tmp_path)


def test_the_speed_ratio_is_a_finding_with_the_timing_conditions(result):
    """NumPy's wall time over Numba's on the finest grid, the median over the series; never a check."""
    finest = case.Params.quick().cells[-1]
    walls = {(p["series"], p["backend"]): p["wall_s"] for p in result["points"] if p["cells"] == finest}
    ratios = sorted(walls[(s, "numpy")] / walls[(s, "numba")] for s, b in walls if b == "numba")
    (finding,) = case.findings(result)
    assert finding.value == pytest.approx(ratios[len(ratios) // 2], rel=1e-12)  # three series: the middle one
    assert "at most one timed run per core" in finding.sentence and "warm-up" in finding.sentence
    assert not [c for c in case.checks(result) if "wall" in c.name]


def test_local_timing_runs_at_most_one_process_per_core_and_one_numba_thread(monkeypatch):
    monkeypatch.setattr(case.os, "cpu_count", lambda: 2)
    assert case.timing_executor(Executor(workers=8)).workers == 2
    same = Executor(workers=2)
    assert case.timing_executor(same) is same
    assert "more threads than cores" in case.timing_conditions(same, jobs=6, threads=2)
    assert "at most one timed run per core" in case.timing_conditions(same, jobs=6, threads=1)
    numba = pytest.importorskip("numba")
    before = numba.get_num_threads()
    with case.numba_threads("numba", 1):
        assert numba.get_num_threads() == 1
    assert numba.get_num_threads() == before
