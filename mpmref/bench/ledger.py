"""What the energy ledger costs: the same run with the ledger off and on.

The step (:func:`mpmref.steppers.substep`) calls the ledger only where it is given one (``[output] energy_ledger``
gives the synchronous stepper one), so a run with the ledger off is the plain step that every other section times:
no test, no copy, no energy is computed for it. This section shows it: for each case, backend and thread count it
times ``steps`` whole steps from a copy of the same particles twice, with no ledger (``off``) and observed by a
fresh :class:`~mpmref.observe.ledger.EnergyLedger` (``on``, which computes the energies in NumPy and float64 whatever
the backend), the median of ``repeats`` (the first call, with compilation, apart), and reports both and their ratio.

Cases: the ``mpm88`` fluid of the throughput section (:func:`.scenes.mpm88_scene`; the fluid's energy is cheap) and
the 2D Table-2 block (:func:`.scenes.table2_scene`, fixed-corotated: one SVD per particle for its stored energy,
three times a step with the ledger on), float64.
"""

from ..backends import make_backend
from ..observe.ledger import EnergyLedger
from ..scene.sampling import sample_particles
from ..steppers import substep
from .scenes import mpm88_scene, table2_particles, table2_scene
from .timing import measure, set_threads, thread_counts

#: the sizes of the cases, the mpm88 fluid's particle count and grid cells and the 2D block's cells per side (4
#: particles per cell), in the benchmark and with ``--quick``
SIZES = {"mpm88": (32768, 128), "block2d": (96,)}
QUICK_SIZES = {"mpm88": (512, 128), "block2d": (12,)}


def ledger_cases(quick):
    """``{name: (scene, particles)}``: the cases of the section."""
    sizes = QUICK_SIZES if quick else SIZES
    fluid, block = mpm88_scene(*sizes["mpm88"]), table2_scene(*sizes["block2d"], dim=2)
    return {"mpm88": (fluid, sample_particles(fluid)), "block2d": (block, table2_particles(block))}


def booked_steps(backend, particles, dt, steps, ledger=None):
    """``steps`` steps of ``backend`` from ``particles``, observed by ``ledger`` (none: the plain step); returns the
    final particles."""
    for i in range(steps):
        particles = substep(backend, particles, dt, i * dt, ledger=ledger)
    return particles


def time_off_and_on(backend_name, scene, particles, threads, repeats, steps):
    """The timings of ``steps`` steps with the ledger off and on, at ``threads`` threads, and their ratio."""
    backend = make_backend(backend_name, scene)
    dt = scene.time.dt
    set_threads(backend_name, threads)
    record = {"backend": backend_name, "threads": threads, "particles": particles.n}
    for name, ledger in (("off", None), ("on", EnergyLedger(scene))):
        record[name], _ = measure(lambda p, ledger=ledger: booked_steps(backend, p, dt, steps, ledger), repeats,
                                  setup=lambda: (particles.copy(),),
                                  first=lambda p, ledger=ledger: booked_steps(backend, p, dt, 1, ledger))
    record["ratio"] = record["on"]["median_s"] / record["off"]["median_s"]
    return record


def run_ledger(quick, backends, threads, repeats, steps, log=print):
    """The ``ledger`` section: ``cases`` (case, scene, particles, dt, steps) and ``results`` (case, backend,
    threads, particles, the ``off`` and ``on`` timing records, ``ratio`` on / off)."""
    cases, described, results = ledger_cases(quick), [], []
    for name, (scene, particles) in cases.items():
        described.append({"case": name, "scene": scene.name, "particles": particles.n, "dt": scene.time.dt,
                          "steps": steps})
        for backend in backends:
            for k in thread_counts(backend, threads):
                log(f"ledger: {name} ({particles.n} particles), {backend}, {k} thread(s), ledger off and on")
                results.append({"case": name, **time_off_and_on(backend, scene, particles, k, repeats, steps)})
    return {"cases": described, "results": results}


def render_ledger(section):
    """One line per case, backend and thread count: ms per step with the ledger off and on, and their ratio."""
    steps = {c["case"]: c["steps"] for c in section["cases"]}
    lines = ["Energy ledger: the same steps with the ledger off (the plain step, what every other section times) "
             "and on; ms per step, median of repeats, float64",
             f"{'case':9}{'particles':>10}  {'backend':8}{'threads':>8}{'off':>10}{'on':>10}{'on/off':>8}"]
    for r in section["results"]:
        off, on = (r[k]["median_s"] / steps[r["case"]] * 1e3 for k in ("off", "on"))
        lines.append(f"{r['case']:9}{r['particles']:>10}  {r['backend']:8}{r['threads']:>8}{off:>10.3f}{on:>10.3f}"
                     f"{r['ratio']:>7.2f}x")
    return "\n".join(lines)
