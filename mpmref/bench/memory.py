"""Peak memory of one MPM step on the Table-2 state, measured in a fresh process.

The probe runs one step on a one-cell block (so JIT compilation is not counted), reads the resident
memory (``VmRSS``, the baseline), builds the particles, resets the kernel's peak-RSS mark
(``/proc/self/clear_refs``), runs :data:`PROBE_STEPS` steps keeping only the latest state, as a run does,
and reads the peak back (``VmHWM``). The figure is compared with the state it works on:

* particle bytes: every allocated particle array (``x, v, C, F, mass, vol0, material, id``);
* grid bytes: the node mass, momentum and force of P2G, ``n_nodes * (1 + 2 d)`` floats.

``peak_over_particles = (peak - baseline) / particle bytes``: all the memory the simulation needs at its
peak (the state, the state the step makes, the grid, the sort, any buffers a backend keeps), as a
multiple of one particle state. A step that writes a new state while the old one is kept for a rollback
needs at least the evolving arrays twice, so this is at least about 1.9 for the Table-2 solid.
``peak_over_state = (particle bytes + step peak growth) / (particle bytes + grid bytes)`` relates the same
peak to the particle and grid state together. A fresh process keeps earlier phases of the benchmark out of the figure,
and a fixed glibc mmap threshold keeps memory that the allocator would retain from sampling from being
silently reused by the step. ``tracemalloc_peak_bytes`` is the peak of the allocations Python's
``tracemalloc`` sees during the step (NumPy arrays; not memory allocated inside compiled Numba code).
Without Linux's ``/proc`` the RSS figures are ``None``.
"""

import gc
import json
import os
import subprocess
import sys
import tracemalloc
from pathlib import Path

import numpy as np

from ..backends import make_backend
from ..errors import MpmrefError
from ..steppers import substep
from .scenes import table2_particles, table2_scene
from .timing import set_threads

CLEAR_REFS = Path("/proc/self/clear_refs")
STATUS = Path("/proc/self/status")
#: how many steps the probe runs; the first allocates what a step keeps (a backend's reused buffers), the others reuse
#: it
PROBE_STEPS = 3
#: glibc serves every allocation above 128 KiB by mmap and returns it on free (a fixed threshold turns off
#: glibc's adaptive one), so memory freed before the step cannot hide the step's own allocations
FIXED_MALLOC = {"MALLOC_MMAP_THRESHOLD_": "131072", "MALLOC_TRIM_THRESHOLD_": "131072"}


def memory_probe(backend, cells, dtype, threads):
    """Peak memory of one MLS-MPM step of ``backend`` on the Table-2 state, in a fresh process (dict)."""
    return in_fresh_process("mpmref.bench.memory", "probe_step", backend, int(cells), str(dtype), int(threads))


def in_fresh_process(module, function, *args):
    """``module.function(*args)`` (plain, JSON-able arguments and result) in a fresh Python process, with
    glibc's fixed mmap threshold (:data:`FIXED_MALLOC`); its result."""
    code = (f"import json; from {module} import {function}; "
            f"print(json.dumps({function}(*{list(args)!r})))")
    search_path = [str(Path(__file__).resolve().parents[2]), os.environ.get("PYTHONPATH", "")]  # this mpmref
    env = {**os.environ, **FIXED_MALLOC, "PYTHONPATH": os.pathsep.join(p for p in search_path if p)}
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False, env=env)
    if done.returncode != 0:
        raise MpmrefError(f"the memory probe {function}{tuple(args)} failed:\n{done.stderr.strip()}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def probe_step(backend, cells, dtype, threads, steps=PROBE_STEPS):
    """Run ``steps`` steps on the Table-2 state in this process and report their peak memory (see the module doc)."""
    set_threads(backend, threads)
    scene = table2_scene(cells, "mls", dtype)
    stages = make_backend(backend, scene)
    dt = scene.time.dt
    substep(stages, table2_particles(table2_scene(1, "mls", dtype)), dt, 0.0)  # compile on a tiny state
    gc.collect()
    baseline = _status_bytes("VmRSS") if STATUS.exists() else None
    particles = table2_particles(scene)
    gc.collect()
    resettable = _reset_peak()
    before = _status_bytes("VmRSS") if resettable else None
    particle_bytes = sum(a.nbytes for a in particles.arrays().values())
    n = particles.n
    latest, particles = particles, None  # a run keeps its latest state only (and the one before, while a step runs)
    tracemalloc.start()
    for k in range(steps):
        latest = substep(stages, latest, dt, k * dt)
    traced_peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    peak = _status_bytes("VmHWM") if resettable else None
    grid_bytes = scene.grid.n_nodes * (1 + 2 * scene.dim) * np.dtype(dtype).itemsize
    growth = None if peak is None else peak - before
    return {"backend": backend, "dtype": str(np.dtype(dtype)), "threads": threads, "particles": n,
            "steps": steps, "particle_bytes": particle_bytes, "grid_bytes": grid_bytes,
            "step_peak_growth_bytes": growth, "tracemalloc_peak_bytes": traced_peak,
            "peak_over_state": None if growth is None else (particle_bytes + growth) / (particle_bytes + grid_bytes),
            "peak_over_particles": None if peak is None else (peak - baseline) / particle_bytes}


def _status_bytes(key):
    for line in STATUS.read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1]) * 1024
    raise KeyError(key)


def _reset_peak():
    """Reset the kernel's peak-RSS mark; False where that is not possible (no Linux ``/proc``)."""
    try:
        CLEAR_REFS.write_text("5")
    except OSError:
        return False
    return True
