"""Cost against the domain size at a fixed body: what the Numba backend's sparse grid buys.

The same body — a block of :data:`BODY_CELLS`\\ ³ cells of the ``fluid3d`` fluid at 8 particles per cell
(32 768 particles), :data:`BODY_START` cells from the origin on every axis — sits in cubic domains of
:data:`DOMAIN_CELLS` cells per side with the same cell size. Per domain the section reports:

* the time of a whole step (:func:`mpmref.steppers.substep`; median of repeats, at the largest thread
  count) and its ratio to the smallest domain's;
* the memory, in a fresh process: the resident memory after compiling (``baseline``: Python, NumPy, Numba
  and the compiled kernels), and the peak resident memory of the process while it samples the body and
  runs the steps (``peak``, Linux's ``VmHWM`` after resetting the mark; the whole process, baseline
  included).

With a dense grid both grow with the domain (:math:`256^3` cells are 16.9 M nodes, 0.5 GB of float32 node
rows); with the sparse grid only the block-pointer table does. The NumPy reference's grid is dense by
design, so the section times the compiled backends only.
"""

from ..backends import make_backend
from ..scene import SceneBuilder
from ..scene.sampling import sample_particles
from ..steppers import substep
from .memory import STATUS, _reset_peak, _status_bytes, in_fresh_process
from .throughput import time_steps
from .timing import set_threads, thread_counts

#: domain sizes (cells per side) and the body (cells per side, and its offset from the origin in cells)
DOMAIN_CELLS = (32, 64, 128, 256)
BODY_CELLS = 16
BODY_START = 8
#: ``--quick``: a 4-cell body in 8- and 16-cell domains (a smoke test whose figures mean nothing)
QUICK = {"domains": (8, 16), "body": 4, "start": 2}
#: cell size of every domain: the body's cells are those of a 32-cell unit box
DX = 1.0 / 32


def domain_scene(cells, body=BODY_CELLS, start=BODY_START, dtype="float32"):
    """A ``body``\\ ³-cell block of the ``fluid3d`` fluid (8 particles per cell), ``start`` cells from the
    origin, in a cube of ``cells`` cells of size :data:`DX` with separating walls; falls from rest."""
    lower, upper = [start * DX] * 3, [(start + body) * DX] * 3
    return (SceneBuilder(dim=3, name=f"domain{cells}", dtype=dtype).grid(size=cells * DX, cells=cells).method("mls")
            .material("water", "fluid", K=400.0, gamma=1.0, rho=1.0)
            .box("water", lower=lower, upper=upper, ppc=8, sampling="regular")
            .gravity([0.0, -9.8, 0.0]).walls("separate", width=3).time(dt=4.0e-4).build())


def probe_domain(backend, cells, body, start, dtype, threads, steps):
    """Memory of ``steps`` steps of the domain scene in this process (see the module doc): a dict."""
    set_threads(backend, threads)
    scene = domain_scene(cells, body, start, dtype)
    stages, dt = make_backend(backend, scene), scene.time.dt
    substep(stages, sample_particles(domain_scene(cells, 1, start, dtype)), dt, 0.0)  # compile on one cell
    baseline = _status_bytes("VmRSS") if STATUS.exists() else None
    resettable = _reset_peak()
    particles = sample_particles(scene)
    for k in range(steps):
        particles = substep(stages, particles, dt, k * dt)
    peak = _status_bytes("VmHWM") if resettable else None
    return {"baseline_bytes": baseline, "peak_bytes": peak, "particles": particles.n}


def run_domain(backends, threads, dtypes, repeats, steps, quick=False, memory=True, log=print):
    """The ``domain`` section: one record per compiled backend, dtype and domain size."""
    sizes = QUICK if quick else {"domains": DOMAIN_CELLS, "body": BODY_CELLS, "start": BODY_START}
    records = []
    for backend in (b for b in backends if b != "numpy"):
        k = max(thread_counts(backend, threads))
        for dtype in dtypes:
            first = None
            for cells in sizes["domains"]:
                scene = domain_scene(cells, sizes["body"], sizes["start"], dtype)
                particles = sample_particles(scene)
                log(f"domain: {backend} {dtype} {cells}^3 cells, {particles.n} particles, {k} thread(s)")
                timing, _ = time_steps(backend, scene, particles, [k], repeats, steps)
                step_s = timing[0]["median_s"] / steps
                first = first or step_s
                record = {"backend": backend, "dtype": dtype, "threads": k, "cells": cells, "body_cells": sizes["body"],
                          "particles": particles.n, "nodes": scene.grid.n_nodes, "steps": steps, **timing[0],
                          "step_s": step_s, "step_over_smallest": step_s / first}
                if memory:
                    record.update(in_fresh_process("mpmref.bench.domain", "probe_domain", backend, cells, sizes["body"],
                                                   sizes["start"], dtype, k, steps))
                records.append(record)
    return {"domains": list(sizes["domains"]), "body_cells": sizes["body"], "results": records}


def render_domain(section):
    """One row per backend, dtype and domain: step time, ratio to the smallest domain, memory."""
    def mb(n):
        return "-" if n is None else f"{n / 2**20:.0f}"

    lines = [f"Domain size at a fixed body: a {section['body_cells']}^3-cell fluid block in growing domains "
             "(median step time; memory of a fresh process: after compiling, and its peak while running)",
             f"{'backend':8}{'dtype':9}{'thr':>4}{'cells':>7}{'nodes':>12}{'particles':>11}{'step ms':>10}"
             f"{'vs smallest':>13}{'baseline MB':>13}{'peak MB':>9}"]
    for r in section["results"]:
        lines.append(f"{r['backend']:8}{r['dtype']:9}{r['threads']:>4}{r['cells']:>6}^3{r['nodes']:>12,}"
                     f"{r['particles']:>11,}{r['step_s'] * 1e3:>10.2f}{r['step_over_smallest']:>12.2f}x"
                     f"{mb(r.get('baseline_bytes')):>13}{mb(r.get('peak_bytes')):>9}")
    return "\n".join(lines)
