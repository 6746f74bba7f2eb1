"""What CPIC costs: a coupled step against a step without bodies on the same particles (the goal: at most 1.5x).

The case is the sand wheel (:func:`mpmref.rigid.polyline.wheel`: a ring of 60 segments and 18 blades welded to
it, pinned, plus a floor segment) half buried in a bed of Drucker–Prager sand (no sand inside the ring). The
same particles are stepped twice from the same state: with the three bodies coupled by CPIC, and in the same
scene without them (no ``[[rigid_bodies]]``, ``coupling = "none"``). Both are whole steps of
:func:`mpmref.steppers.substep` (the coupled one with the bodies' state), the median of ``repeats`` runs of
``steps`` steps, compilation excluded (reported as ``first_call_s``). The coupled step's stages are also
timed inside real steps (:class:`mpmref.bench.stage_times.TimedStages`): ``cpic_contact`` (the field, the tags and
the fit, the stress), ``p2g``, ``cpic_impulses``, ``grid_update``, ``cpic_g2p``, ``return_map``. Float64
only (the CPIC kernels keep the field and the fit in float64).
"""

import numpy as np

from ..backends import make_backend
from ..backends.base import BACKEND_STAGES
from ..rigid.dynamics import initial_state
from ..rigid.polyline import SAND_WHEEL, inside_closed, validate_polyline, wheel
from ..scene import SceneBuilder
from ..scene.factories import add_sand_wheel
from ..scene.sampling import sample_particles
from ..steppers import substep
from ..steppers.synchronous import with_cpic_tags
from .stage_times import TimedStages
from .timing import measure, set_threads, thread_counts

#: cells across the unit domain: the benchmark, and ``--quick``
CPIC_CELLS, CPIC_QUICK_CELLS = 256, 32
#: the goal for a CPIC step over a step without bodies
GOAL = 1.5
TIMED_CPIC_STAGES = ("prepare", "cpic_contact", "p2g", "cpic_impulses", "grid_update", "cpic_g2p", "return_map")


def wheel_bed_scene(cells, bodies=True):
    """The sand bed (0.05 .. 0.95 by 0.1 .. 0.45) with the wheel and floor (``bodies``) or without them."""
    dx = 1.0 / cells
    dt = 0.3 * dx / (np.sqrt(3e4 * 1.3462 / 1000.0) + 2.0)  # the sand's P-wave speed plus 2 m/s
    method = {"coupling": "cpic", "penalty": 1.0 / dt, "pushing_force": 0.0} if bodies else {}
    b = (SceneBuilder(dim=2, name="cpic_bench" if bodies else "cpic_bench_plain").grid(size=1.0, cells=cells)
         .method("mls", **method).walls("separate", domain_exit="delete").gravity([0.0, -10.0])
         .material("sand", "sand", E=3e4, nu=0.3, rho=1000.0, friction_angle=45.0)
         .box("sand", lower=[0.05, 0.1 + 0.5 * dx], upper=[0.95, 0.45]).time(dt=dt))
    return (add_sand_wheel(b) if bodies else b).build()


def bed_particles(scene):
    """The bed's particles without those inside the ring (the sand is outside the wheel)."""
    particles = sample_particles(scene)
    (ring, ring_segments), _ = wheel(**SAND_WHEEL)
    return particles.select(~inside_closed(validate_polyline(ring, ring_segments), particles.x))


def coupled_steps(backend, particles, rigid, dt, steps):
    """``steps`` CPIC steps from ``(particles, rigid)``; returns the final pair."""
    for i in range(steps):
        particles, rigid = substep(backend, particles, dt, i * dt, rigid=rigid)
    return particles, rigid


def plain_steps(backend, particles, dt, steps):
    """``steps`` steps without bodies; returns the final particles."""
    for i in range(steps):
        particles = substep(backend, particles, dt, i * dt)
    return particles


def time_pair(backend_name, cells, threads, repeats, steps):
    """The coupled and the plain step of one backend at one thread count, their ratio and the coupled stages."""
    coupled, plain = wheel_bed_scene(cells), wheel_bed_scene(cells, bodies=False)
    particles = bed_particles(coupled)
    tagged = with_cpic_tags(particles, len(coupled.rigid_bodies))
    rigid = initial_state(coupled.rigid_bodies)
    dt = coupled.time.dt
    set_threads(backend_name, threads)
    b_coupled, b_plain = make_backend(backend_name, coupled), make_backend(backend_name, plain)
    rec_c, _ = measure(lambda p: coupled_steps(b_coupled, p, rigid, dt, steps), repeats,
                       setup=lambda: (tagged.copy(),), first=lambda p: coupled_steps(b_coupled, p, rigid, dt, 1))
    rec_p, _ = measure(lambda p: plain_steps(b_plain, p, dt, steps), repeats, setup=lambda: (particles.copy(),),
                       first=lambda p: plain_steps(b_plain, p, dt, 1))
    timed = TimedStages(b_coupled, names=BACKEND_STAGES + TIMED_CPIC_STAGES)
    coupled_steps(timed, tagged.copy(), rigid, dt, steps)
    return {"backend": backend_name, "threads": threads, "dtype": "float64", "particles": particles.n,
            "coupled": rec_c, "plain": rec_p, "ratio": rec_c["median_s"] / rec_p["median_s"],
            "coupled_stages_s": {name: s / steps for name, s in timed.seconds.items()}}


def run_cpic(quick, backends, threads, repeats, steps, log=print):
    """The ``cpic`` section: the case, and one record per backend and thread count."""
    cells = CPIC_QUICK_CELLS if quick else CPIC_CELLS
    scene = wheel_bed_scene(cells)
    results = []
    for backend in backends:
        for k in thread_counts(backend, threads):
            log(f"cpic: sand wheel bed, {cells} cells, {backend}, {k} thread(s)")
            results.append(time_pair(backend, cells, k, repeats, steps))
    return {"case": {"cells": cells, "particles": bed_particles(scene).n, "bodies": len(scene.rigid_bodies),
                     "segments": sum(len(b.shape.segments) for b in scene.rigid_bodies), "dt": scene.time.dt,
                     "steps": steps}, "goal": GOAL, "results": results}


def render_cpic(section):
    """One line per backend and thread count: the coupled and the plain step, their ratio, the coupled stages."""
    c = section["case"]
    lines = [f"CPIC: a step with {c['bodies']} bodies ({c['segments']} segments) against the same {c['particles']} "
             f"particles without them (sand wheel bed, {c['cells']}^2 cells, float64; ms per step, median of "
             f"repeats; goal <= {section['goal']}x)",
             f"{'backend':8}{'thr':>4}{'CPIC':>10}{'plain':>10}{'ratio':>8}   stages of the CPIC step (ms)"]
    for r in section["results"]:
        per_step = {k: r[k]["median_s"] / c["steps"] * 1e3 for k in ("coupled", "plain")}
        stages = ", ".join(f"{name} {s * 1e3:.2f}" for name, s in r["coupled_stages_s"].items())
        lines.append(f"{r['backend']:8}{r['threads']:>4}{per_step['coupled']:>10.3f}{per_step['plain']:>10.3f}"
                     f"{r['ratio']:>7.2f}x   {stages}")
    return "\n".join(lines)
