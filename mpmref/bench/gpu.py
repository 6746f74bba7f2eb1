"""The ``cuda`` section of ``mpmref bench``: the GPU backend's throughput beside a hand-written GPU yardstick and the
Numba backend on every core of the same machine, with the GPU backend's performance goals (docs/gpu.md).

Cases: the MLS-MPM fluid of the yardstick (the 88-line program's physics: quadratic kernel, Tait fluid with
:math:`\\gamma = 1`, :math:`K = 400`, separate walls three nodes thick) as an mpmref scene, a random block at about
four particles per cell, at 262 144, 1 048 576 and 4 194 304 particles in 2D (256², 512², 1024² cells) and 3D (100³,
160³, 256³ cells), in float32 and float64. On each:

* ``cuda``: whole steps of the GPU backend, the particles resident on the device (:func:`time_resident`);
  ``cuda-atomic``, the same with the opt-in atomic P2G;
* ``yardstick-atomic`` and ``yardstick-gather``: a hand-written numba-cuda step of the same physics (a single-file
  program, not part of mpmref, given by its path in ``MPMREF_GPU_YARDSTICK``; run as a subprocess with
  ``--dim --dtype --n-grid --n-particles --p2g atomic|gather --repeats --min-time``, printing a JSON line with
  ``particle_steps_per_s``) with the same particle count and grid, its atomic and its deterministic gather P2G;
* ``numba``: the Numba backend on every core of the machine.

Each figure is particle-steps per second, the median of ``repeats`` runs of at least :data:`MIN_TIME` seconds after
a warm-up (the yardstick's own protocol, its ``--min-time``). Without a GPU the section says so and measures nothing.
"""

import json
import os
import subprocess
import sys
from pathlib import Path

from ..scene import SceneBuilder
from ..scene.sampling import sample_particles
from .scenes import mpm88_scene
from .throughput import run_steps, time_steps
from .timing import measure

#: the cases: dimension -> ((particles, cells per side), ...)
SIZES = {2: ((262_144, 256), (1_048_576, 512), (4_194_304, 1024)), 3: ((262_144, 100), (1_048_576, 160),
                                                                      (4_194_304, 256))}
QUICK_SIZES = {2: ((4096, 64),), 3: ((4096, 16),)}
#: a timed run lasts at least this long (seconds)
MIN_TIME = 0.5
#: the environment variable that names the yardstick program
YARDSTICK = "MPMREF_GPU_YARDSTICK"
#: the goals: (name, figure's numerator, denominator, dim, dtype, bound)
GOALS = (
    ("cuda / yardstick-gather", "cuda", "yardstick-gather", 2, "float32", 1.0),
    ("cuda / yardstick-atomic", "cuda", "yardstick-atomic", 2, "float32", 0.5),
    ("cuda / yardstick-gather", "cuda", "yardstick-gather", 3, "float32", 1.0),
    ("cuda / yardstick-atomic", "cuda", "yardstick-atomic", 3, "float32", 0.5),
    ("cuda / yardstick-atomic", "cuda", "yardstick-atomic", 2, "float64", 0.5),
    ("cuda / yardstick-atomic", "cuda", "yardstick-atomic", 3, "float64", 0.5),
    ("cuda / numba (every core)", "cuda", "numba", 2, "float32", 25.0),
)
#: the particle count the goals are stated at (at least a million)
GOAL_PARTICLES = 1_048_576


def yardstick_scene(dim, particles, cells, dtype="float32"):
    """The yardstick's fluid as an mpmref scene: :func:`mpmref.bench.scenes.mpm88_scene` in 2D (a random block of
    ``[0.2, 0.6]^2`` falling at 1 m/s), its 3D counterpart (``[0.15, 0.55]^3`` at rest, ``dt = 4e-4 * 32 / cells``)."""
    if dim == 2:
        return mpm88_scene(particles, cells, dtype=dtype)
    return (SceneBuilder(dim=3, name="fluid3d_random", dtype=dtype).grid(size=1.0, cells=cells).method("mls")
            .material("water", "fluid", K=400.0, gamma=1.0, rho=1.0)
            .box("water", lower=[0.15] * 3, upper=[0.55] * 3, sampling="random", count=particles, seed=88)
            .gravity([0.0, -9.8, 0.0]).walls("separate", width=3).time(dt=4.0e-4 * 32 / cells).build())


def gpu_missing():
    """Why the GPU backend cannot run here (one line), or ``None`` when it can."""
    from ..errors import BackendError

    try:
        from ..backends.cuda.runtime import require_device

        require_device()
    except BackendError as exc:
        return str(exc)
    return None


def time_resident(backend, particles, dt, repeats, min_time=MIN_TIME):
    """Timing record of whole steps of a resident ``backend`` (the particles copied to the device before each run, the
    device synchronised at its end): ``steps`` per run chosen from a first run so that a run lasts ``min_time``."""
    from ..backends.cuda.runtime import cuda

    def run(p, steps):
        p = run_steps(backend, p, dt, steps)
        cuda.synchronize()
        return p

    def setup():
        on_device = backend.to_device(particles)
        cuda.synchronize()
        return on_device, 1

    probe, _ = measure(run, 1, setup=setup)
    steps = max(10, int(min_time / max(probe["median_s"], 1e-6)) + 1)
    record, _ = measure(run, repeats, setup=lambda: (setup()[0], steps))
    return {**record, "first_call_s": probe["first_call_s"], "steps": steps,
            "particle_steps_per_s": particles.n * steps / record["median_s"]}


def yardstick_path():
    """The yardstick program that :data:`YARDSTICK` names, if it names a file (else ``None``: no yardstick columns)."""
    path = Path(os.environ.get(YARDSTICK, ""))
    return path if os.environ.get(YARDSTICK) and path.is_file() else None


def run_yardstick(path, dim, particles, cells, dtype, variant, repeats, min_time=MIN_TIME):
    """The yardstick's JSON record for one case (its ``particle_steps_per_s``), run as a subprocess; a record with an
    ``error`` when it fails."""
    command = [sys.executable, str(path), "--dim", str(dim), "--dtype", "f32" if dtype == "float32" else "f64",
               "--n-grid", str(cells), "--n-particles", str(particles), "--p2g", variant, "--repeats", str(repeats),
               "--min-time", str(min_time)]
    done = subprocess.run(command, capture_output=True, text=True, cwd=path.parent, timeout=600)
    lines = [line for line in done.stdout.splitlines() if line.startswith("{")]
    if done.returncode or not lines:
        return {"error": (done.stderr.strip().splitlines() or [f"exit status {done.returncode}"])[-1]}
    return json.loads(lines[-1])


def run_cuda(options, log=print, sizes=None, numba_threads=None):
    """The ``cuda`` section of the benchmark JSON: ``available`` (and ``message`` without a GPU), ``device``,
    ``results`` (case, dim, particles, cells, dtype, code, ``particle_steps_per_s``, its ``record``: the timing, or
    the yardstick's JSON line, or its ``error``)
    and ``goals``. ``sizes`` overrides :data:`SIZES` (``{dim: ((particles, cells), ...)}``); the Numba backend runs on
    ``numba_threads`` (default: every core this process may use)."""
    missing = gpu_missing()
    if missing:
        return {"available": False, "message": missing}
    from ..backends import make_backend
    from ..backends.cuda.runtime import device_name

    sizes = sizes or (QUICK_SIZES if options.quick else SIZES)
    cores = numba_threads or (len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count())
    yardstick = yardstick_path()
    results = []
    for dim, cases in sizes.items():
        for particles, cells in cases:
            for dtype in options.dtypes:
                scene = yardstick_scene(dim, particles, cells, dtype)
                state = sample_particles(scene)
                case = {"case": f"{dim}d-{particles}", "dim": dim, "particles": state.n, "cells": cells,
                        "dtype": dtype}
                for code, mode in (("cuda", "gather"), ("cuda-atomic", "atomic")):
                    log(f"cuda: {case['case']} {dtype} {code}")
                    backend = make_backend("cuda" if mode == "gather" else "mpmref.backends.cuda:atomic", scene)
                    results.append(row(case, code, time_resident(backend, state, scene.time.dt, options.repeats)))
                for variant in ("atomic", "gather"):
                    if yardstick is None:
                        continue
                    log(f"cuda: {case['case']} {dtype} yardstick-{variant}")
                    record = run_yardstick(yardstick, dim, particles, cells, dtype, variant, options.repeats)
                    results.append(row(case, f"yardstick-{variant}", record))
                log(f"cuda: {case['case']} {dtype} numba on {cores} threads")
                records, _ = time_steps("numba", scene, state, [cores], options.repeats, options.steps)
                results.append(row(case, "numba", records[0]))
    return {"available": True, "device": device_name(), "numba_threads": cores,
            "yardstick": None if yardstick is None else str(yardstick), "results": results,
            "goals": gpu_goals(results)}


def row(case, code, record):
    """A result: the case, the code, its ``particle_steps_per_s`` (``None`` where it failed) and its ``record``."""
    return {**case, "code": code, "particle_steps_per_s": record.get("particle_steps_per_s"), "record": record}


def _rate(results, code, dim, dtype, particles):
    r = next((r for r in results if r["code"] == code and r["dim"] == dim and r["dtype"] == dtype
              and r["particles"] == particles), None)
    return None if r is None else r["particle_steps_per_s"]


def gpu_goals(results, particles=GOAL_PARTICLES):
    """The GPU backend's goals at ``particles`` particles: ``name``, ``figure`` (``None`` when not measured), ``bound``,
    ``met``."""
    out = []
    for name, top, bottom, dim, dtype, bound in GOALS:
        a, b = _rate(results, top, dim, dtype, particles), _rate(results, bottom, dim, dtype, particles)
        figure = None if a is None or b is None else a / b
        out.append({"name": f"{dim}D {dtype} {particles:,} particles: {name}", "figure": figure, "bound": bound,
                    "met": None if figure is None else figure >= bound})
    return out


def render_cuda(section):
    """The section's table: particle-steps/s per case and code, then the goals."""
    if not section.get("available"):
        return f"cuda: not run ({section.get('message')})"
    codes = ("cuda", "cuda-atomic", "yardstick-atomic", "yardstick-gather", "numba")
    lines = [f"GPU backend on {section['device']} (particle-steps/s; numba on {section['numba_threads']} threads)",
             f"{'case':16}{'dtype':>9}" + "".join(f"{c:>18}" for c in codes)]
    keys = dict.fromkeys((r["case"], r["dim"], r["particles"], r["dtype"]) for r in section["results"])
    for case, dim, particles, dtype in keys:
        cells = []
        for code in codes:
            rate = _rate(section["results"], code, dim, dtype, particles)
            cells.append("-" if rate is None else f"{rate / 1e6:.1f} M")
        lines.append(f"{case:16}{dtype:>9}" + "".join(f"{c:>18}" for c in cells))
    lines.append("goals ('-': not measured)")
    for g in section["goals"]:
        figure = "-" if g["figure"] is None else f"{g['figure']:.3g}"
        met = "-" if g["met"] is None else ("yes" if g["met"] else "no")
        lines.append(f"  {g['name']:70}{figure:>8} >= {g['bound']:<5g} {met}")
    return "\n".join(lines)

