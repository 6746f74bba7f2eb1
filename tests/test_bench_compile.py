"""``mpmref bench --only compile``: the compile census of first runs (mpmref/bench/compile_census.py).

Its figures are CPU seconds (a benchmark's, never asserted); what is tested is that compilations are attributed to
the right dispatcher, nested ones apart, configurations and signatures counted, and a failed run reported.
"""

from numba import njit
from numba.core import event

from mpmref.bench.census_child import CompileRecorder, own_times
from mpmref.bench.compile_census import SCENES, TOP, cold_census, kernel_rows, render_census, run_census


class Stand:
    """A stand-in dispatcher: what the census reads of one."""

    def __init__(self, function):
        self.py_func = function


def outer():
    """A caller."""


def inner():
    """A callee."""


def test_a_compilation_costs_its_own_seconds_without_those_nested_in_it():
    a, b = Stand(outer), Stand(inner)
    events = [(0.0, True, a), (1.0, True, b), (3.5, False, b), (4.0, False, a), (5.0, True, b), (5.5, False, b)]
    compiles = own_times(events)
    assert [(label, cpu) for label, _, cpu in compiles] == [("test_bench_compile.inner", 2.5),
                                                            ("test_bench_compile.outer", 1.5),
                                                            ("test_bench_compile.inner", 0.5)]
    rows = kernel_rows(compiles)
    assert rows == [{"kernel": "test_bench_compile.inner", "signatures": 2, "cpu_s": 3.0},
                    {"kernel": "test_bench_compile.outer", "signatures": 1, "cpu_s": 1.5}]


def test_each_signature_numba_compiles_is_recorded_against_its_dispatcher():
    @njit(cache=False)
    def twice(x):
        return 2 * x

    recorder = CompileRecorder()
    with event.install_listener("numba:compile", recorder):
        twice(1)
        twice(1.0)
        twice(2.0)  # compiled already
    rows = [r for r in kernel_rows(own_times(recorder.events)) if r["kernel"].endswith("twice")]
    assert len(rows) == 1 and rows[0]["signatures"] == 2 and rows[0]["cpu_s"] > 0


def test_the_section_sums_each_scene_and_the_table_lists_the_costliest_kernels():
    kernels = [{"kernel": f"k{i}", "signatures": 1, "cpu_s": 10.0 - i} for i in range(TOP + 2)]
    runs = {"a.toml": {"status": 0, "process_cpu_s": 60.0, "kernels": kernels},
            "b.toml": {"status": 2, "process_cpu_s": None, "kernels": []}}
    lines = []
    section = run_census(lines.append, scenes=("a.toml", "b.toml"), census=lambda root, scene: runs[scene])
    a, b = section["scenes"]
    assert (a["configurations"], a["signatures"], a["compile_cpu_s"]) == (TOP + 2, TOP + 2, sum(range(1, 11)))
    assert b["configurations"] == 0 and b["status"] == 2 and lines == ["compile census: a.toml",
                                                                        "compile census: b.toml"]
    table = render_census(section)
    assert "| a.toml | 10 | 10 | 55.00 | 60.00 |" in table and "| b.toml | 0 | 0 | 0.00 | failed |" in table
    assert "| total | 10 | 10 | 55.00 | |" in table and "| 2 others | 2 | 3.00 |" in table
    assert "| k0 | 1 | 10.00 |" in table and "| k8 |" not in table


def test_the_census_covers_the_examples_and_reports_a_run_that_fails():
    assert "examples/mpm88.toml" in SCENES and all(s.endswith(".toml") for s in SCENES)
    failed = cold_census(run_census(print, scenes=())["root"], "examples/no_such_scene.toml")
    assert failed["status"] != 0 and failed["kernels"] == []
