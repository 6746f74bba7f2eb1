"""Ctrl-C stops ``mpmref study`` and ``mpmref verify`` at once: SIGINT sent to the whole process group (what
a terminal does) or to the main process alone ends the command with exit status 130 within seconds, its worker
processes (and ``verify``'s background compilation) gone, no leaked semaphore, and one line saying what is kept and
what running it again does; a study run again runs only the runs that had not finished.

Each test starts the command in a session of its own, waits until its workers are busy (polled), and sends the
signal. The processes are found with psutil (a dependency of ``dask.distributed``).
"""

import json
import os
import signal
import subprocess
import sys
import time

import psutil
import pytest

from mpmref.cli import main

#: a 2D elastic block on an 8-cell grid: a run to t = 0.01 takes a few steps
SCENE = """name = "tiny"
dim = 2
gravity = [0.0, -9.8]
[grid]
size = [1.0, 1.0]
cells = 8
[materials.jelly]
type = "fixed_corotated"
E = 1000.0
nu = 0.3
rho = 1.0
[[bodies]]
shape = "box"
material = "jelly"
lower = [0.3, 0.4]
upper = [0.7, 0.7]
ppc = 4
[time]
cfl = 0.5
"""

#: a study's ``--setup``: the runs on more than 8 cells spin (busy, as a long run is) until the file ``go`` exists,
#: each saying so first in a file ``holding-<pid>``
HOLD = """import os
from pathlib import Path

HERE = Path(__file__).parent


def hold(sim):
    if sim.scene.grid.cells[0] > 8:
        (HERE / f"holding-{os.getpid()}").touch()
        while not (HERE / "go").exists():
            pass
"""

#: seconds the command may take to exit after the signal, and its processes to be gone after that
EXIT_S, GONE_S = 10.0, 5.0
#: seconds to wait for the command to be ready for the signal
READY_S = 120.0


def start(args, cwd):
    """``python -m mpmref.cli ARGS`` in a new session (its own process group), in ``cwd``."""
    return subprocess.Popen([sys.executable, "-m", "mpmref.cli", *args], cwd=cwd, start_new_session=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def busy_workers(command):
    """The processes the fork server started for ``command`` (the executor's workers) that have run for a while."""
    servers = [c for c in command.children() if "forkserver" in " ".join(c.cmdline())]
    return [w for s in servers for w in s.children() if sum(w.cpu_times()[:2]) > 0.3]


def interrupt(process, ready, target):
    """Wait (polling) until ``ready(psutil process)``, send SIGINT to ``target`` (``"group"``: the process group, as a
    terminal does; ``"main"``: the main process alone); ``(exit status, seconds to exit, stdout, stderr, processes
    still alive GONE_S seconds later)``, the processes being every one the command had started."""
    command = psutil.Process(process.pid)
    deadline = time.monotonic() + READY_S
    while not ready(command):
        assert process.poll() is None, process.communicate()
        assert time.monotonic() < deadline, "the command never got ready to be interrupted"
        time.sleep(0.05)
    started = command.children(recursive=True)
    sent = time.monotonic()
    if target == "group":
        os.killpg(process.pid, signal.SIGINT)
    else:
        os.kill(process.pid, signal.SIGINT)
    try:
        out, err = process.communicate(timeout=EXIT_S)
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
        process.communicate()
        pytest.fail(f"still running {EXIT_S} s after SIGINT to the {target}")
    took = time.monotonic() - sent
    _, alive = psutil.wait_procs(started, timeout=GONE_S)
    return process.returncode, took, out, err, [p.pid for p in alive]


@pytest.fixture
def study_folder(tmp_path):
    (tmp_path / "scene.toml").write_text(SCENE)
    (tmp_path / "hold.py").write_text(HOLD)
    return tmp_path


@pytest.mark.parametrize("target", ["group", "main"])
def test_an_interrupted_study_stops_at_once_and_the_same_command_runs_only_the_rest(study_folder, target):
    out = study_folder / "out"
    args = ["study", "scene.toml", "--vary", "grid.cells=8,9", "--t-end", "0.01", "--setup", "hold:hold",
            "--workers", "2", "--out", str(out), "--no-progress"]

    def ready(command):  # the 8-cell run finished, the 9-cell one spins in the other worker
        return len(list(out.glob("runs/*.json"))) == 1 and len(list(study_folder.glob("holding-*"))) == 1

    status, took, stdout, stderr, alive = interrupt(start(args, study_folder), ready, target)
    print(f"study, SIGINT to the {target}: exit {status} after {took:.2f} s")
    assert (status, stdout, alive) == (130, "", [])
    assert "leaked" not in stderr and "Traceback" not in stderr, stderr
    length, line = stderr.strip().splitlines()
    assert length.startswith("mpmref study: the steps will take about ")
    assert f"1 of 2 runs finished (their results are in {out / 'runs'})" in line
    assert line.endswith(f"the same command reuses them and runs the other 1: mpmref {' '.join(args)}")

    (study_folder / "go").touch()
    again = subprocess.run([sys.executable, "-m", "mpmref.cli", *args], cwd=study_folder, capture_output=True,
                           text=True, timeout=120)
    assert again.returncode == 0, again.stderr
    assert "2 of 2 runs finished (1 reused from an earlier study)" in again.stdout
    assert [r["reused"] for r in json.loads((out / "results.json").read_text())["runs"]] == [True, False]


@pytest.mark.parametrize("target", ["group", "main"])
def test_an_interrupted_verify_stops_its_workers_and_its_background_compilation(tmp_path, target):
    out = tmp_path / "out"
    args = ["verify", "convergence", "backends", "--quick", "--workers", "2", "--out", str(out)]

    def ready(command):  # the background compilation runs, and the convergence case's sweep in two workers
        compiling = [c for c in command.children() if "spawn_main" in " ".join(c.cmdline())]
        return compiling and len(busy_workers(command)) == 2

    status, took, stdout, stderr, alive = interrupt(start(args, tmp_path), ready, target)
    print(f"verify, SIGINT to the {target}: exit {status} after {took:.2f} s")
    assert (status, alive) == (130, [])
    assert "leaked" not in stderr and "Traceback" not in stderr, stderr
    assert stderr.strip().splitlines()[-1] == ("mpmref verify: interrupted; 0 of 2 cases finished; the index was not "
                                               f"written; the same command runs every case again: mpmref "
                                               f"{' '.join(args)}")


def test_an_interrupted_verify_names_the_cases_whose_reports_it_keeps(tmp_path, monkeypatch, capsys):
    from verification.framework import cli

    finished = []

    def run_case(args, name, tag, executor, params=None, case=None):
        if finished:
            raise KeyboardInterrupt
        finished.append(name)
        return name

    monkeypatch.setattr(cli, "_run_case", run_case)
    monkeypatch.setattr(cli, "write_index", lambda *a: pytest.fail("an interrupted verify wrote its index"))
    status = main(["verify", "momentum", "energy", "--quick", "--out", str(tmp_path), "--no-progress"])
    assert (status, finished) == (130, ["momentum"])
    assert capsys.readouterr().err.splitlines() == [
        f"mpmref verify: interrupted; 1 of 2 cases finished (momentum: reports in {tmp_path}/<case>/); the index was "
        f"not written; the same command runs every case again: mpmref verify momentum energy --quick --out {tmp_path} "
        "--no-progress"]
