"""The compile census: what a first run of each example compiles, and the CPU seconds each compilation costs.

``mpmref bench --only compile`` runs each scene of :data:`SCENES` (``examples/*.toml``) for :data:`STEPS` steps on the
Numba backend, each in a fresh process with an empty Numba cache (a new ``NUMBA_CACHE_DIR`` and ``XDG_CACHE_HOME``),
and lists, per scene, the kernel configurations compiled: one row per dispatcher (a kernel factory's closure is one
dispatcher per configuration, so two configurations of one kernel are two rows, with one label), its number of
signatures and its own CPU seconds (the compilations nested in it left out, so that the rows add up to the total),
sorted, with totals. CPU seconds, not wall seconds: on a loaded machine they are the steadier figure. The child
process is :mod:`mpmref.bench.census_child`, which imports only the command line of the checkout it measures, so
:func:`run_census` measures an older checkout (``root``) the same way.
"""

import json
import os
import subprocess
import sys
import tempfile
from collections import defaultdict
from pathlib import Path

#: steps of each first run (the first step compiles the step's kernels, the next ones what a later step adds)
STEPS = 3
#: rows of each scene's table; the others are summed into one
TOP = 8
#: the example scenes the census runs, relative to the checkout's root
SCENES = tuple(f"examples/{p.name}" for p in sorted((Path(__file__).resolve().parents[2] / "examples").glob("*.toml")))
CHILD = Path(__file__).with_name("census_child.py")


def kernel_rows(compiles):
    """One row per dispatcher of the child's ``compiles`` (``[label, dispatcher id, cpu_s]`` each):
    ``{"kernel", "signatures", "cpu_s"}``, the costliest first."""
    rows = defaultdict(lambda: {"kernel": "", "signatures": 0, "cpu_s": 0.0})
    for label, dispatcher, cpu in compiles:
        row = rows[dispatcher]
        row["kernel"], row["signatures"], row["cpu_s"] = label, row["signatures"] + 1, row["cpu_s"] + cpu
    return sorted(rows.values(), key=lambda row: (-row["cpu_s"], row["kernel"]))


def cold_census(root, scene, steps=STEPS):
    """A first run of ``scene`` in a fresh process with the checkout ``root`` first on the import path and empty
    caches: ``{"status", "process_cpu_s", "kernels"}`` (:func:`kernel_rows`), or ``kernels`` empty and ``status``
    non-zero when the run failed."""
    with tempfile.TemporaryDirectory(prefix="mpmref-census-") as cache:
        env = dict(os.environ, PYTHONPATH=str(root), NUMBA_CACHE_DIR=str(Path(cache) / "numba"),
                   XDG_CACHE_HOME=cache)
        argv = [sys.executable, str(CHILD), scene, str(steps), str(Path(cache) / "out")]
        done = subprocess.run(argv, cwd=root, env=env, capture_output=True, text=True)
    lines = done.stdout.strip().splitlines()
    if done.returncode or not lines:
        return {"status": done.returncode or 1, "process_cpu_s": None, "kernels": []}
    child = json.loads(lines[-1])
    return {"status": child["status"], "process_cpu_s": child["cpu_s"], "kernels": kernel_rows(child["compiles"])}


def run_census(log, scenes=SCENES, root=None, census=cold_census):
    """The section's part of the JSON document: per scene, its first run's ``kernels``, their number
    (``configurations``), their ``signatures`` and ``compile_cpu_s`` summed, the process's CPU seconds and the run's
    status; the load averages before and after. ``root``: the checkout to measure (default this one)."""
    root = Path(root) if root is not None else Path(__file__).resolve().parents[2]
    load_before = os.getloadavg()
    rows = []
    for scene in scenes:
        log(f"compile census: {scene}")
        run = census(root, scene)
        rows.append({"scene": scene, "status": run["status"], "configurations": len(run["kernels"]),
                     "signatures": sum(k["signatures"] for k in run["kernels"]),
                     "compile_cpu_s": sum(k["cpu_s"] for k in run["kernels"]), "process_cpu_s": run["process_cpu_s"],
                     "kernels": run["kernels"]})
    return {"root": str(root), "steps": STEPS, "load_before": list(load_before), "load_after": list(os.getloadavg()),
            "scenes": rows}


def render_census(section):
    """A summary table (per scene: configurations, signatures, compile and process CPU seconds, with totals), then
    each scene's costliest :data:`TOP` kernels."""
    rows = section["scenes"]
    out = [f"Compile census: a first run of {section['steps']} steps per scene (numba, empty cache), CPU seconds; "
           f"load average before {section['load_before'][0]:.2f}, after {section['load_after'][0]:.2f}", "",
           "| scene | configurations | signatures | compile CPU [s] | process CPU [s] |", "|---|---|---|---|---|"]
    out += [f"| {r['scene']} | {r['configurations']} | {r['signatures']} | {r['compile_cpu_s']:.2f} | "
            + ("failed |" if r["status"] else f"{r['process_cpu_s']:.2f} |") for r in rows]
    out.append(f"| total | {sum(r['configurations'] for r in rows)} | {sum(r['signatures'] for r in rows)} | "
               f"{sum(r['compile_cpu_s'] for r in rows):.2f} | |")
    for r in rows:
        out += ["", f"{r['scene']}:", "", "| kernel | signatures | CPU [s] |", "|---|---|---|"]
        out += [f"| {k['kernel']} | {k['signatures']} | {k['cpu_s']:.2f} |" for k in r["kernels"][:TOP]]
        rest = r["kernels"][TOP:]
        if rest:
            out.append(f"| {len(rest)} others | {sum(k['signatures'] for k in rest)} | "
                       f"{sum(k['cpu_s'] for k in rest):.2f} |")
    return "\n".join(out)
