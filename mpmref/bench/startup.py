"""The first minute, measured: a user's first commands from empty caches, beside an older commit's in the same run.

``mpmref bench --only startup [--against REV]`` runs, each in a fresh process with an empty Numba cache (a new
``NUMBA_CACHE_DIR`` and ``XDG_CACHE_HOME`` per run), the commands of :data:`COMMANDS`: a first ``mpmref run`` of
``examples/mpm88.toml``, of ``examples/jelly.toml`` and of ``examples/snow88.toml`` (the plastic laws) on the Numba
backend, and a cold ``mpmref verify --quick``.
Each runs once on this checkout and once on ``REV`` (a git worktree of the same repository, on the same Python, the
older code first on the import path), alternating, ``--repeats`` times; the table gives the median wall time and
the CPU time of each (the process and its children), and this checkout's wall time over ``REV``'s. The load average
before and after is recorded beside: on a busy machine the ratios mean little.
"""

import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

from ..backends.numba.twin import BUILDS_VARIABLE
from ..errors import ArgumentError

#: the commit the startup goals are measured against (issue "The first minute")
DEFAULT_AGAINST = "11a2006"
#: what a new user runs first: ``(label, arguments of python -m mpmref.cli)``; ``OUT`` is a fresh folder
COMMANDS = (
    ("run mpm88 (10 steps, numba)", ["run", "examples/mpm88.toml", "--steps", "10", "--backend", "numba",
                                     "--out", "OUT", "--no-progress"]),
    ("run jelly (10 steps, numba)", ["run", "examples/jelly.toml", "--steps", "10", "--backend", "numba",
                                     "--out", "OUT", "--no-progress"]),
    ("run snow88 (10 steps, numba)", ["run", "examples/snow88.toml", "--steps", "10", "--backend", "numba",
                                      "--out", "OUT", "--no-progress"]),
    ("verify --quick", ["verify", "--quick", "--out", "OUT", "--no-progress"]),
)


def repository_root():
    """The root of the git checkout this package was imported from."""
    here = Path(__file__).resolve().parent
    try:
        out = subprocess.run(["git", "rev-parse", "--show-toplevel"], cwd=here, capture_output=True, text=True,
                             check=True)
    except (OSError, subprocess.CalledProcessError):
        raise ArgumentError("the startup section's checkout", str(here), "a git checkout (it compares two of its "
                            "commits)") from None
    return Path(out.stdout.strip())


@contextmanager
def worktree(root, rev):
    """A detached git worktree of ``rev`` (removed afterwards); :class:`ArgumentError` for an unknown revision."""
    folder = Path(tempfile.mkdtemp(prefix="mpmref-startup-"))
    made = subprocess.run(["git", "worktree", "add", "--detach", str(folder / "tree"), rev], cwd=root,
                          capture_output=True, text=True)
    if made.returncode:
        raise ArgumentError("--against", rev, f"a revision of {root} ({made.stderr.strip().splitlines()[-1]})")
    try:
        yield folder / "tree"
    finally:
        subprocess.run(["git", "worktree", "remove", "--force", str(folder / "tree")], cwd=root, capture_output=True)


def cold_run(root, args):
    """Run ``python -m mpmref.cli ARGS`` in ``root`` with that checkout first on the import path, empty caches and the
    default kernel builds:
    ``{"wall_s", "cpu_s", "status"}`` (CPU: the process and its children)."""
    with tempfile.TemporaryDirectory(prefix="mpmref-cold-") as cache:
        out = Path(cache) / "out"
        env = dict(os.environ, PYTHONPATH=str(root), NUMBA_CACHE_DIR=str(Path(cache) / "numba"),
                   XDG_CACHE_HOME=cache)
        env.pop(BUILDS_VARIABLE, None)  # the kernel builds a user gets by default
        argv = [sys.executable, "-m", "mpmref.cli", *[str(out) if a == "OUT" else a for a in args]]
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        start = time.perf_counter()
        done = subprocess.run(argv, cwd=root, env=env, capture_output=True, text=True)
        wall = time.perf_counter() - start
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"wall_s": wall, "cpu_s": cpu, "status": done.returncode}


def run_startup(against, repeats, log, commands=COMMANDS):
    """The section's part of the JSON document: per command, this checkout's and ``against``'s runs and the ratio
    of their median wall times."""
    root = repository_root()
    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True, text=True)
    load_before = os.getloadavg()
    rows = []
    with worktree(root, against) as old:
        for label, args in commands:
            runs = {"this": [], "against": []}
            for k in range(repeats):
                for side, where in (("against", old), ("this", root)):
                    log(f"startup: {label}, {side} ({k + 1}/{repeats})")
                    runs[side].append(cold_run(where, args))
            rows.append({"command": label, **runs, "ratio": _median(runs["this"]) / _median(runs["against"])})
    return {"against": against, "this": head.stdout.strip() + (" (with uncommitted changes)" if _dirty(root) else ""),
            "repeats": repeats, "load_before": list(load_before), "load_after": list(os.getloadavg()), "rows": rows}


def _median(runs, key="wall_s"):
    return statistics.median(r[key] for r in runs)


def _dirty(root):
    status = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=root, capture_output=True,
                            text=True)
    return bool(status.stdout.strip())


def render_startup(section):
    """The table: median wall and CPU seconds of each command, here and at ``against``, and the wall-time ratio."""
    head = [f"Startup from empty caches: this checkout ({section['this']}) against {section['against']}, "
            f"median of {section['repeats']}; load average before {section['load_before'][0]:.2f}, after "
            f"{section['load_after'][0]:.2f}",
            "", "| command | wall [s] here | CPU [s] here | wall [s] against | CPU [s] against | wall ratio |",
            "|---|---|---|---|---|---|"]
    body = [f"| {r['command']} | {_median(r['this']):.1f} | {_median(r['this'], 'cpu_s'):.1f} | "
            f"{_median(r['against']):.1f} | {_median(r['against'], 'cpu_s'):.1f} | {r['ratio']:.2f} |"
            + ("" if all(x["status"] == 0 for x in r["this"] + r["against"]) else " (a run failed)")
            for r in section["rows"]]
    return "\n".join(head + body)
