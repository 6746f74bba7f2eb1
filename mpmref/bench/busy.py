"""Two threads against one with a core held by another process: the thread trap, measured.

A thread pool whose idle workers spin (OpenMP's active wait, GNU libgomp's default) turns a busy core into a
trap: a worker that waits for the core the other process holds keeps the step's join waiting, and two threads
run slower than one (2.3 times slower was measured here; docs/performance.md, "Threads on a shared machine").
This section runs the ``examples/mpm88.toml`` fluid (:func:`.scenes.mpm88_scene`, 8 192 particles) through
:class:`~mpmref.run.simulation.Simulation` (checks included, as ``mpmref run`` does) for ``steps`` steps on one and
on two threads, in turn, ``repeats`` times: first with the machine as it is, then with a busy loop holding one
core (a child process that spins for at most :data:`BUSY_SECONDS` and is ended after the measurement). Each run
is a process of its own, as ``mpmref run --threads N`` is (``python -m mpmref.bench.busy THREADS STEPS``): in one
process, a worker that had spun after a two-thread run went on spinning through the one-thread runs that
followed, which doubled their time and hid the trap in the ratio. It reports the median wall times (of the
steps, not the process) and the ratio two threads over one in both conditions, and the threading layer.
"""

import json
import statistics
import subprocess
import sys
import time

from ..run.simulation import Simulation
from .scenes import mpm88_scene

#: the particles of examples/mpm88.toml
PARTICLES = 8192
#: the busy loop ends itself after this many seconds if nothing ends it first
BUSY_SECONDS = 600
#: steps per timed run (``--quick``: a tenth)
STEPS = 100
#: the backend whose threads are measured
BACKEND = "numba"


def busy_loop():
    """A child process that spins on one core for at most :data:`BUSY_SECONDS`; the caller ends it."""
    code = f"import time\nend = time.monotonic() + {BUSY_SECONDS}\nwhile time.monotonic() < end:\n    pass\n"
    return subprocess.Popen([sys.executable, "-c", code])


def timed_run(threads, steps):
    """Wall seconds of ``steps`` steps of the example on ``threads`` threads, in a process of its own."""
    out = subprocess.run([sys.executable, "-m", __name__, str(threads), str(steps)], capture_output=True, text=True,
                         check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])["wall_s"]


def timed_runs(steps, repeats):
    """Wall seconds of ``repeats`` runs on 1 and on 2 threads, alternating: ``{1: [...], 2: [...]}``."""
    times = {1: [], 2: []}
    for _ in range(repeats):
        for threads in (1, 2):
            times[threads].append(timed_run(threads, steps))
    return times


def measure_here(threads, steps):
    """Compile (or load) the example's kernels, then time ``steps`` steps on ``threads`` threads, in this process."""
    from ..backends.numba.threads import use_threads

    use_threads(threads)
    sim = Simulation(mpm88_scene(PARTICLES), backend=BACKEND)
    sim.warm_up()
    start = time.perf_counter()
    sim.run(steps=steps)
    return time.perf_counter() - start


def run_busy(quick, backends, repeats, log):
    """The section's JSON part: ``scene``, ``particles``, ``steps``, ``threading_layer`` and ``results`` (per
    ``load`` ``"as it is"`` and ``"one core busy"``: ``times_s`` and ``median_s`` per thread count and ``ratio``,
    two threads over one; none unless the Numba backend is among ``backends``)."""
    from ..backends.numba.threads import threading_layer

    steps = STEPS // 10 if quick else STEPS
    results = []
    if BACKEND not in backends:
        return {"scene": "examples/mpm88.toml", "particles": PARTICLES, "steps": steps,
                "threading_layer": threading_layer(), "results": results}
    for load in ("as it is", "one core busy"):
        log(f"busy: examples/mpm88.toml, {steps} steps on 1 and 2 threads, the machine {load}")
        hog = busy_loop() if load == "one core busy" else None
        try:
            if hog is not None:
                time.sleep(0.5)  # let it reach its core
            times = timed_runs(steps, repeats)
        finally:
            if hog is not None:
                hog.kill()
                hog.wait()
        medians = {k: statistics.median(v) for k, v in times.items()}
        results.append({"load": load, "times_s": {str(k): v for k, v in times.items()},
                        "median_s": {str(k): m for k, m in medians.items()}, "ratio": medians[2] / medians[1]})
    return {"scene": "examples/mpm88.toml", "particles": PARTICLES, "steps": steps,
            "threading_layer": threading_layer(), "results": results}


def render_busy(section):
    """The section as a table: per load, the median wall time on 1 and 2 threads and the ratio."""
    lines = [f"Threads on a busy machine: examples/mpm88.toml ({section['particles']:,} particles), "
             f"{section['steps']} steps through Simulation.run, Numba ({section['threading_layer']} threading layer)",
             f"{'load':16}{'1 thread s':>12}{'2 threads s':>13}{'2 / 1':>8}"]
    for r in section["results"]:
        lines.append(f"{r['load']:16}{r['median_s']['1']:>12.4f}{r['median_s']['2']:>13.4f}{r['ratio']:>8.2f}")
    lines.append("A ratio above 1 means two threads are slower than one: the workers wait for a core another "
                 "process holds.")
    return "\n".join(lines)


if __name__ == "__main__":  # one timed run: python -m mpmref.bench.busy THREADS STEPS
    print(json.dumps({"wall_s": measure_here(int(sys.argv[1]), int(sys.argv[2]))}))
