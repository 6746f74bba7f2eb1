"""``mpmref bench --only startup``: cold runs here and at an older commit, side by side (mpmref/bench/startup.py).

The section's figures are timings (a benchmark's, never asserted); what is tested is that it runs each command in
both checkouts from empty caches, keeps their statuses, and refuses a revision that does not exist.
"""

import math
import subprocess

import pytest

from mpmref.bench.startup import cold_run, render_startup, repository_root, run_startup
from mpmref.errors import ArgumentError


def test_each_command_runs_here_and_at_the_older_commit_from_empty_caches():
    lines = []
    section = run_startup("HEAD~1", 1, lines.append, commands=(("help", ["--help"]), ("bad", ["run", "nothing"])))
    assert [r["command"] for r in section["rows"]] == ["help", "bad"]
    help_, bad = section["rows"]
    assert [r["status"] for r in help_["this"] + help_["against"]] == [0, 0]
    assert all(r["status"] == 2 for r in bad["this"] + bad["against"])  # a scene that does not exist: exit 2
    assert math.isfinite(help_["ratio"]) and help_["ratio"] > 0
    assert len(lines) == 4 and "against" in lines[0]
    table = render_startup(section)
    assert "| help |" in table and "(a run failed)" in table.splitlines()[-1]
    worktrees = subprocess.run(["git", "worktree", "list"], cwd=repository_root(), capture_output=True, text=True)
    assert "mpmref-startup-" not in worktrees.stdout  # removed afterwards


def test_a_run_starts_with_an_empty_numba_cache(tmp_path):
    root = repository_root()
    probe = ["run", "examples/mpm88.toml", "--steps", "1", "--out", "OUT", "--no-progress"]
    assert cold_run(root, probe)["status"] == 0


def test_a_revision_that_does_not_exist_is_refused():
    with pytest.raises(ArgumentError, match="--against = 'no-such-rev' is invalid: allowed a revision of"):
        run_startup("no-such-rev", 1, print, commands=(("help", ["--help"]),))
