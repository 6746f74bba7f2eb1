"""Peak memory of one MPM step on the Table-2 state, measured in a fresh process.

The probe builds the particles, runs one warm-up step on a few of them (so JIT compilation is not
counted), resets the kernel's peak-RSS mark (``/proc/self/clear_refs``), runs one full step and reads
the peak back (``VmHWM``). The figure is compared with the state it works on:

* particle bytes: every allocated particle array (``x, v, C, F, mass, vol0, material``);
* grid bytes: the node mass, momentum and force of P2G, ``n_nodes * (1 + 2 d)`` floats.

``peak_over_state = (particle bytes + step peak growth) / (particle bytes + grid bytes)``: the memory the
process needs at the peak of a step, relative to the particle and grid state (the project's goal is at most 1.5
at 1 M particles in 3D). A fresh process keeps earlier phases of the benchmark out of the figure, and a
fixed glibc mmap threshold keeps memory that the allocator would retain from sampling from being
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
WARM_UP_PARTICLES = 64
#: glibc serves every allocation above 128 KiB by mmap and returns it on free (a fixed threshold turns off
#: glibc's adaptive one), so memory freed before the step cannot hide the step's own allocations
FIXED_MALLOC = {"MALLOC_MMAP_THRESHOLD_": "131072", "MALLOC_TRIM_THRESHOLD_": "131072"}


def memory_probe(backend, cells, dtype, threads):
    """Peak memory of one MLS-MPM step of ``backend`` on the Table-2 state, in a fresh process (dict)."""
    code = (f"import json; from mpmref.bench.memory import probe_step; "
            f"print(json.dumps(probe_step({backend!r}, {int(cells)}, {str(dtype)!r}, {int(threads)})))")
    search_path = [str(Path(__file__).resolve().parents[2]), os.environ.get("PYTHONPATH", "")]  # this mpmref
    env = {**os.environ, **FIXED_MALLOC, "PYTHONPATH": os.pathsep.join(p for p in search_path if p)}
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False, env=env)
    if done.returncode != 0:
        raise MpmrefError(f"the memory probe of {backend} failed:\n{done.stderr.strip()}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def probe_step(backend, cells, dtype, threads):
    """Run one step on the Table-2 state in this process and report its peak memory (see the module doc)."""
    set_threads(backend, threads)
    scene = table2_scene(cells, "mls", dtype)
    particles = table2_particles(scene)
    stages = make_backend(backend, scene)
    dt = scene.time.dt
    substep(stages, particles.select(np.arange(particles.n) < WARM_UP_PARTICLES), dt, 0.0)
    gc.collect()
    resettable = _reset_peak()
    before = _status_bytes("VmRSS") if resettable else None
    tracemalloc.start()
    substep(stages, particles, dt, 0.0)
    traced_peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    growth = _status_bytes("VmHWM") - before if resettable else None
    particle_bytes = sum(a.nbytes for a in particles.arrays().values())
    grid_bytes = scene.grid.n_nodes * (1 + 2 * scene.dim) * np.dtype(dtype).itemsize
    return {"backend": backend, "dtype": str(np.dtype(dtype)), "threads": threads, "particles": particles.n,
            "particle_bytes": particle_bytes, "grid_bytes": grid_bytes, "step_peak_growth_bytes": growth,
            "tracemalloc_peak_bytes": traced_peak,
            "peak_over_state": None if growth is None else (particle_bytes + growth) / (particle_bytes + grid_bytes)}


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
