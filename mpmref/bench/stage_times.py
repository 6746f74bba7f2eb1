"""Where a step's time goes: each backend stage timed inside real steps, and the cost per particle-step
against the particle count and the thread count.

* ``stages``: :class:`TimedStages` wraps a backend so that :func:`mpmref.steppers.substep` (the one step
  pipeline) runs unchanged while every stage call is timed: sort (``prepare``), P2G, grid update, G2P,
  return map, and any other stage the pipeline calls. A backend that computes the stress inside P2G (Numba)
  does not call ``stress`` in a step; its stress line is then the stress stage timed alone on the same
  particles once per step, outside the step, and marked as contained in P2G.
* ``scaling``: nanoseconds per particle-step of whole steps for growing particle counts at a fixed
  density (2D: the mpm88 fluid, the grid grown with the square root of the count; 3D: the fluid3d block on
  a grown grid), and the 2-over-1 thread speed-up of the ``large2d`` case.
"""

import time

import numpy as np

from ..backends import make_backend
from ..backends.base import BACKEND_STAGES, FUSED_BACKEND_STAGES
from ..scene.sampling import sample_particles
from ..steppers import substep
from .scenes import fluid3d_scene, mpm88_scene, throughput_cases
from .throughput import time_steps
from .timing import set_threads, thread_counts

#: particle counts of the scaling table: (2D counts, 3D grid sizes) by default and with ``--full``
SCALING_2D = (8192, 32768, 131072)
SCALING_2D_FULL = SCALING_2D + (524288, 1048576)
SCALING_3D_CELLS = (40, 64, 80)  # 16 000, 65 536 and 128 000 particles
SCALING_3D_CELLS_FULL = SCALING_3D_CELLS + (128, 160)  # 524 288 and 1 024 000
#: ``--quick``: tiny sizes (a smoke test whose figures mean nothing)
SCALING_QUICK = ((512, 2048), (8, 16))
#: the case of the thread-scaling figure (262 144 particles, 2D)
THREAD_CASE = "large2d"


class TimedStages:
    """A backend whose stage methods (``names``, default the standard stages and the fused P2G) add their wall time
    to ``seconds[stage]`` (everything else passes through); the fused P2G is booked as ``"p2g"``, the step's P2G,
    and ``fused`` says that it ran."""

    def __init__(self, backend, names=BACKEND_STAGES + FUSED_BACKEND_STAGES):
        self._backend = backend
        self._names = names
        self.seconds = {}
        self.fused = False

    def __getattr__(self, name):
        attr = getattr(self._backend, name)
        if name not in self._names:
            return attr
        key = "p2g" if name in FUSED_BACKEND_STAGES else name
        self.fused |= key != name

        def timed(*args, **kwargs):
            start = time.perf_counter()
            result = attr(*args, **kwargs)
            self.seconds[key] = self.seconds.get(key, 0.0) + time.perf_counter() - start
            return result
        return timed


def stage_times(backend_name, scene, threads, steps):
    """Mean seconds per step of each stage over ``steps`` steps (after one untimed step), and of whole steps."""
    backend = make_backend(backend_name, scene)
    set_threads(backend_name, threads)
    particles, dt = sample_particles(scene), scene.time.dt
    particles = substep(backend, particles, dt, 0.0)  # compile and fill the buffers
    timed = TimedStages(backend)
    stress_alone = 0.0
    start = time.perf_counter()
    for k in range(steps):
        particles = substep(timed, particles, dt, (k + 1) * dt)
    whole = time.perf_counter() - start
    if "stress" not in timed.seconds:  # computed inside P2G: time the stage alone, outside the steps
        with backend.running(particles.n):
            backend.stress(particles)  # compile
        for _ in range(steps):
            t0 = time.perf_counter()
            with backend.running(particles.n):
                backend.stress(particles)
            stress_alone += time.perf_counter() - t0
    per_step = {name: s / steps for name, s in timed.seconds.items()}
    return {"backend": backend_name, "threads": threads, "dtype": str(scene.dtype), "particles": particles.n,
            "steps": steps, "step_s": whole / steps, "stages_s": per_step,
            "stress_inside_p2g": "stress" not in timed.seconds, "p2g_fused": timed.fused,
            "stress_alone_s": stress_alone / steps if "stress" not in timed.seconds else None}


def run_stages(cases, backends, threads, dtypes, steps, log=print):
    """The ``stages`` section: one record per case, compiled backend, dtype and thread count."""
    records = []
    for case in cases:
        for backend in backends:
            for dtype in (dtypes if backend != "numpy" else ("float64",)):
                for k in thread_counts(backend, threads):
                    log(f"stages: {case.name} {backend} {dtype} {k} thread(s)")
                    records.append({"case": case.name, **stage_times(backend, case.scene(dtype), k, steps)})
    return {"stages": list(BACKEND_STAGES), "results": records}


def scaling_scenes(full=False, quick=False):
    """``(label, scene builder)`` of the scaling table, smallest first."""
    counts = SCALING_2D_FULL if full else SCALING_2D
    cells3 = SCALING_3D_CELLS_FULL if full else SCALING_3D_CELLS
    if quick:
        counts, cells3 = SCALING_QUICK
    two = [("2d", lambda dtype, n=n: mpm88_scene(n, scaled_cells(n), dtype)) for n in counts]
    three = [("3d", lambda dtype, c=c: fluid3d_scene(c, dtype)) for c in cells3]
    return two + three


def scaled_cells(count):
    """Cells per side of the mpm88 grid at ``count`` particles: 128 at 32 768, grown as the square root."""
    return int(round(128 * np.sqrt(count / 32768)))


def run_scaling(backends, threads, dtypes, repeats, steps, full=False, quick=False, log=print):
    """The ``scaling`` section: ``size`` records (ns per particle-step against the particle count, at the
    largest thread count) and ``threads`` records (the ``large2d`` case at each thread count, with the speed-up
    over one thread)."""
    sizes, by_threads = [], []
    compiled = [b for b in backends if b != "numpy"]
    for backend in compiled:
        k = max(thread_counts(backend, threads))
        for dtype in dtypes:
            for label, build in scaling_scenes(full, quick):
                scene = build(dtype)
                particles = sample_particles(scene)
                log(f"scaling: {label} {backend} {dtype} {particles.n} particles, {k} thread(s)")
                records, _ = time_steps(backend, scene, particles, [k], repeats, steps)
                sizes.append({"dim": scene.dim, "cells": list(scene.grid.cells), "particles": particles.n,
                              **records[0], "ns_per_particle_step": 1e9 / records[0]["particle_steps_per_s"]})
            case = next(c for c in throughput_cases(quick) if c.name == THREAD_CASE)
            scene = case.scene(dtype)
            particles = sample_particles(scene)
            log(f"scaling: {THREAD_CASE} {backend} {dtype} at {threads} thread(s)")
            records, _ = time_steps(backend, scene, particles, thread_counts(backend, threads), repeats, steps)
            one = next((r for r in records if r["threads"] == 1), None)
            for r in records:
                speedup = r["particle_steps_per_s"] / one["particle_steps_per_s"] if one else None
                by_threads.append({"case": THREAD_CASE, "particles": particles.n, **r, "speedup_over_1": speedup})
    return {"full": full, "quick": quick, "sizes": sizes, "threads": by_threads}


def plot_scaling(section, path):
    """Write the scaling table as a PNG: ns per particle-step against the particle count, one line per
    dimension, backend and dtype (log-log)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    keys = sorted({(r["dim"], r["backend"], r["dtype"], r["threads"]) for r in section["sizes"]})
    for dim, backend, dtype, k in keys:
        rows = [r for r in section["sizes"]
                if (r["dim"], r["backend"], r["dtype"], r["threads"]) == (dim, backend, dtype, k)]
        ax.loglog([r["particles"] for r in rows], [r["ns_per_particle_step"] for r in rows], "o-",
                  label=f"{dim}D {backend} {dtype}, {k} thread(s)")
    ax.set_xlabel("particles")
    ax.set_ylabel("ns per particle-step")
    ax.set_title("Cost per particle-step against particle count")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


STAGE_LABELS = (("prepare", "sort"), ("stress", "stress"), ("p2g", "P2G"), ("grid_update", "grid"), ("g2p", "G2P"),
                ("return_map", "return map"))


def render_stages(section):
    """One line per case, backend, dtype and thread count: ms per step of each stage and of the whole step."""
    lines = ["Stages of a step (mean ms per step inside real steps; sort = prepare; * stress computed inside "
             "P2G, timed alone; f: the step's P2G is the fused one, the force folded in)",
             f"{'case':9}{'particles':>10}  {'backend':8}{'dtype':9}{'thr':>4}"
             + "".join(f"{label:>12}" for _, label in STAGE_LABELS) + f"{'step':>10}"]
    for r in section["results"]:
        cells = []
        for stage, _ in STAGE_LABELS:
            if stage == "stress" and r["stress_inside_p2g"]:
                cells.append(f"{r['stress_alone_s'] * 1e3:>11.3f}*")
            else:
                value = r["stages_s"].get(stage)
                fused = stage == "p2g" and r.get("p2g_fused")
                cells.append(f"{'-':>12}" if value is None else f"{value * 1e3:>11.3f}{'f' if fused else ' '}")
        lines.append(f"{r['case']:9}{r['particles']:>10}  {r['backend']:8}{r['dtype']:9}{r['threads']:>4}"
                     + "".join(cells) + f"{r['step_s'] * 1e3:>10.3f}")
    return "\n".join(lines)


def render_scaling(section):
    """The cost per particle-step against the particle count, then the thread speed-up."""
    lines = ["Scaling: ns per particle-step of whole steps against the particle count (median of repeats)",
             f"{'dim':>4}{'cells':>16}{'particles':>11}  {'backend':8}{'dtype':9}{'thr':>4}{'ns/particle-step':>18}"]
    for r in section["sizes"]:
        cells = "x".join(str(c) for c in r["cells"])
        lines.append(f"{r['dim']:>4}{cells:>16}{r['particles']:>11}  {r['backend']:8}{r['dtype']:9}{r['threads']:>4}"
                     f"{r['ns_per_particle_step']:>18.1f}")
    lines += ["", f"Thread scaling, {THREAD_CASE}",
              f"{'particles':>10}  {'backend':8}{'dtype':9}{'threads':>8}{'M/s':>9}{'over 1 thread':>15}"]
    for r in section["threads"]:
        speedup = "-" if r["speedup_over_1"] is None else f"{r['speedup_over_1']:.2f}x"
        lines.append(f"{r['particles']:>10}  {r['backend']:8}{r['dtype']:9}{r['threads']:>8}"
                     f"{r['particle_steps_per_s'] / 1e6:>9.3f}{speedup:>15}")
    return "\n".join(lines)
