"""The Numba backend's threads (docs/performance.md, "Threads on a shared machine").

* Workers that wait without spinning: with the ``tbb`` package installed, Numba's threading layer is TBB (loaded by
  ``import mpmref``, although the wheel's library is not on the loader's path in a virtual environment), and an
  OpenMP runtime gets the passive wait unless the user chose otherwise.
* ``--threads N`` chooses the count a step uses, in the command's process and in the worker processes it starts;
  the summary says it; a count the pool cannot give is refused with exit status 2.
* A step of fewer than ``SERIAL_BELOW`` particles runs on one thread.
"""

import json
import os
import subprocess
import sys
from importlib import metadata
from pathlib import Path

import numba
import pytest

from mpmref.backends.numba import threads
from mpmref.cli import main

ROOT = Path(__file__).resolve().parent.parent
MPM88 = ROOT / "examples" / "mpm88.toml"
PROBE = ("import json, os, numba, mpmref\n"
         "from mpmref.backends.numba.threads import threading_layer\n"
         "print(json.dumps({'layer': threading_layer(), 'wait': os.environ.get('OMP_WAIT_POLICY')}))")


def has_tbb():
    try:
        return bool(metadata.version("tbb"))
    except metadata.PackageNotFoundError:
        return False


def probe(**env):
    clean = {k: v for k, v in os.environ.items() if k not in ("NUMBA_THREADING_LAYER", "OMP_WAIT_POLICY",
                                                               "LD_LIBRARY_PATH")}
    out = subprocess.run([sys.executable, "-c", PROBE], env={**clean, **env}, capture_output=True, text=True,
                         check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.skipif(not has_tbb(), reason="the tbb package is not installed on this platform")
def test_the_default_threading_layer_is_tbb_and_openmp_would_wait_passively():
    assert probe() == {"layer": "tbb", "wait": "passive"}


def test_a_threading_layer_or_wait_policy_the_user_chose_is_kept():
    assert probe(NUMBA_THREADING_LAYER="workqueue", OMP_WAIT_POLICY="active") == {"layer": "workqueue",
                                                                                   "wait": "active"}


@pytest.fixture
def numba_threads_restored():
    before = numba.get_num_threads()
    yield
    numba.set_num_threads(before)


def test_a_step_uses_the_chosen_count_and_a_small_step_one_thread(monkeypatch, numba_threads_restored):
    numba.set_num_threads(2)
    with threads.threads_for(threads.SERIAL_BELOW - 1):
        assert numba.get_num_threads() == 1
    with threads.threads_for(threads.SERIAL_BELOW):
        assert numba.get_num_threads() == 2  # nothing chosen: Numba's count
    threads.use_threads(1)
    numba.set_num_threads(2)  # another count set since: a step still uses the chosen one
    with threads.threads_for(10 * threads.SERIAL_BELOW):
        assert numba.get_num_threads() == 1
    assert numba.get_num_threads() == 2  # and restores what was there
    assert threads.describe_threads().startswith("1 thread (")
    assert os.environ[threads.THREADS_VARIABLE] == "1"  # what worker processes started from now on read


def test_run_prints_the_thread_count_and_refuses_one_the_pool_cannot_give(tmp_path, capsys, numba_threads_restored):
    args = ["run", str(MPM88), "--steps", "2", "--backend", "numba", "--no-progress", "--threads"]
    assert main(args + ["1", "--out", str(tmp_path / "one")]) == 0
    assert f"1 thread ({threads.threading_layer()})" in capsys.readouterr().out.splitlines()[0]
    too_many = threads.thread_limit() + 1
    assert main(args + [str(too_many), "--out", str(tmp_path / "many")]) == 2
    assert f"threads = {too_many} is invalid: allowed 1 to {threads.thread_limit()}" in capsys.readouterr().err
    assert main(args + ["0", "--out", str(tmp_path / "none")]) == 2
    assert "an integer >= 1" in capsys.readouterr().err


def test_the_chosen_count_reaches_the_worker_processes(tmp_path):
    """``mpmref conformance check --threads 1`` and a child process it starts agree on the count: the environment
    variable carries it (as to the local processes of verify and study)."""
    env = {**os.environ, threads.THREADS_VARIABLE: "1"}
    code = ("import numba\nfrom mpmref.backends.numba.threads import threads_for\n"
            "with threads_for(10**6):\n    print(numba.get_num_threads())")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "1"
