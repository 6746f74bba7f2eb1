"""Throughput: particle-steps per second of whole steps (:func:`mpmref.steppers.substep`, no outputs or checks).

Every repeat starts from a copy of the same sampled particles and runs ``steps`` steps; the first call
(one step, including JIT compilation) is reported apart. The NumPy reference runs in float64 on one
thread and is the denominator of ``vs_numpy``.
"""

from ..backends import make_backend
from ..scene.sampling import sample_particles
from ..steppers import substep
from .timing import measure, set_threads, thread_counts

REFERENCE = ("numpy", "float64")


def run_steps(backend, particles, dt, steps):
    """Advance ``particles`` by ``steps`` steps of ``backend``; returns the final particles."""
    for i in range(steps):
        particles = substep(backend, particles, dt, i * dt)
    return particles


def time_steps(backend_name, scene, particles, threads, repeats, steps):
    """Timing records of whole steps of one backend at each thread count, and the final particles."""
    backend = make_backend(backend_name, scene)
    dt = scene.time.dt
    records, final = [], None
    for k in threads:
        set_threads(backend_name, k)
        rec, final = measure(lambda p: run_steps(backend, p, dt, steps), repeats, setup=lambda: (particles.copy(),),
                             first=lambda p: substep(backend, p, dt, 0.0))
        rate = particles.n * steps / rec["median_s"]
        records.append({"backend": backend_name, "threads": k, "dtype": str(scene.dtype), **rec,
                        "particle_steps_per_s": rate})
    return records, final


def backend_runs(backends, dtypes):
    """``(backend, dtype)`` pairs to time: the reference in float64, every other backend in every dtype."""
    runs = [REFERENCE] if REFERENCE[0] in backends else []
    return runs + [(b, d) for b in backends if b != REFERENCE[0] for d in dtypes]


def run_throughput(cases, backends, threads, dtypes, repeats, steps, log=print):
    """The ``throughput`` section of the benchmark JSON: ``cases`` (what each case is) and ``results``."""
    results, described = [], []
    for case in cases:
        described.append(describe_case(case, steps))
        for backend, dtype in backend_runs(backends, dtypes):
            scene = case.scene(dtype)
            particles = sample_particles(scene)
            log(f"throughput: {case.name} {backend} {dtype} ({particles.n} particles)")
            records, _ = time_steps(backend, scene, particles, thread_counts(backend, threads), repeats, steps)
            results += [{"case": case.name, **r} for r in records]
    add_reference_ratios(results)
    return {"cases": described, "results": results}


def describe_case(case, steps):
    """What a throughput case is: dimension, grid, particle count, time step and timed steps."""
    scene = case.scene("float64")
    return {"case": case.name, "dim": scene.dim, "cells": list(scene.grid.cells),
            "particles": sample_particles(scene).n, "dt": scene.time.dt, "steps": steps}


def add_reference_ratios(results):
    """Set ``vs_numpy`` of each result: its rate over the NumPy float64 one-thread rate of the same case."""
    reference = {r["case"]: r["particle_steps_per_s"] for r in results
                 if (r["backend"], r["dtype"]) == REFERENCE and r["threads"] == 1}
    for r in results:
        r["vs_numpy"] = r["particle_steps_per_s"] / reference[r["case"]] if r["case"] in reference else None
