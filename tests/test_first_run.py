"""A first run on serial kernels while another process compiles the parallel ones (:mod:`mpmref.run.first_run`,
:mod:`mpmref.backends.numba.twin`; docs/performance.md, "The first run").

The bits of the serial builds are those of the parallel ones: tests/test_numba_backend.py runs every step both ways.
Here: which build a kernel runs, that the serial build is compiled and cached apart, and the command line's first run
from an empty cache, which starts serially, switches once the other process has cached the parallel builds, and
leaves the next run nothing to compile serially.
"""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from numba import prange

from mpmref.backends.numba import twin
from mpmref.errors import ArgumentError

ROOT = Path(__file__).resolve().parent.parent


def summed(x, out):
    for i in prange(x.shape[0]):
        out[i] = x[i] * x[i] + 1.0


@pytest.fixture
def serial_until_cached():
    with twin.builds("serial-until-cached"):
        yield


def test_a_kernel_without_a_cached_parallel_build_runs_serially_until_told(serial_until_cached):
    kernel = twin.parallel_kernel(summed)  # not cached on disk: no parallel build to load
    x, out = np.arange(5.0), np.zeros(5)
    kernel(x, out)
    assert kernel in twin.serial_kernels() and list(kernel.serial.overloads) and not kernel.parallel.overloads
    assert np.array_equal(out, x * x + 1.0)
    twin.use_parallel()
    kernel(x, 2 * out)
    assert kernel not in twin.serial_kernels() and list(kernel.parallel.overloads)


def test_a_kernel_whose_parallel_build_is_compiled_runs_it(serial_until_cached):
    kernel = twin.parallel_kernel(summed)
    x, out = np.arange(5.0), np.zeros(5)
    kernel.parallel(x, out)
    kernel(x, out)
    assert kernel not in twin.serial_kernels()


def test_by_default_every_kernel_runs_its_parallel_build():
    assert twin.mode_from_environment({}) == "parallel"
    kernel = twin.parallel_kernel(summed)
    with twin.builds("parallel"):
        kernel(np.arange(3.0), np.zeros(3))
        assert kernel not in twin.serial_kernels() and kernel._serial is None  # never built


def test_in_the_serial_mode_every_kernel_runs_its_serial_build_and_a_block_restores_the_mode_before():
    kernel = twin.parallel_kernel(summed)
    before = twin.mode()
    with twin.builds("serial"):
        kernel(np.arange(3.0), np.zeros(3))
        assert kernel in twin.serial_kernels() and not kernel.parallel.overloads
    assert twin.mode() == before


def test_an_unknown_mode_is_refused_with_the_allowed_ones():
    with pytest.raises(ArgumentError, match="MPMREF_KERNEL_BUILDS = 'threads' is invalid: allowed one of parallel"):
        twin.mode_from_environment({twin.BUILDS_VARIABLE: "threads"})
    with pytest.raises(ArgumentError, match="mode = 'fast' is invalid"):
        with twin.builds("fast"):
            pass


def test_the_serial_build_is_a_serial_compilation_cached_under_its_own_name():
    kernel = twin.parallel_kernel(summed, cache=True)
    assert kernel.parallel.targetoptions["parallel"] and not kernel.serial.targetoptions.get("parallel")
    assert kernel.serial.py_func.__qualname__ == "summed_serial" and kernel.parallel.py_func.__qualname__ == "summed"


def first_run(cache, *args):
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache), twin.BUILDS_VARIABLE: "parallel"}  # the default mode
    return subprocess.run([sys.executable, "-m", "mpmref.cli", "run", str(ROOT / "examples" / "mpm88.toml"),
                           "--backend", "numba", "--no-progress", "--overwrite", *args], env=env, cwd=ROOT,
                          capture_output=True, text=True, timeout=900)


@pytest.mark.slow  # two compilations of mpm88's kernels from an empty cache, and a run long enough to switch
def test_a_first_run_starts_serially_switches_when_the_parallel_kernels_are_cached_and_the_next_run_does_not(
        tmp_path):
    out = ["--out", str(tmp_path / "out")]
    long = first_run(tmp_path / "cache", "--t-end", "4", *out)
    assert long.returncode == 0, long.stderr
    assert "starts on serial kernels" in long.stderr and "parallel kernels ready" in long.stderr
    again = first_run(tmp_path / "cache", "--steps", "5", *out)
    assert again.returncode == 0, again.stderr
    assert "serial kernels" not in again.stderr, again.stderr
