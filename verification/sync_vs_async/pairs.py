"""The paired runs of the sync-vs-async case (:mod:`verification.sync_vs_async`): a scene run asynchronously, then
synchronously at its finest step, recorded at the synchronised times and compared.
"""

from time import perf_counter

import numpy as np

from mpmref import Simulation
from mpmref.scene.factories import example_with_time

from ..framework.report import snapshot
from .levels import with_stepper
from .scenes import balls


def _record(sim):
    d = sim.diagnostics()
    L = d.get("angular_momentum", d.get("angular_momentum_z", 0.0))
    P = np.array([d[k] for k in d if k.startswith("momentum_")])
    return {"time": sim.time, "energy": d["total_energy"], "P": P, "L": L}


def _frame(sim):
    """A VTK frame coloured by level: velocity, material and ``dt_level`` (log2 of the particle's step in ticks)."""
    time, x, data = snapshot(sim, ("velocity", "material"))
    return time, x, {**data, "dt_level": sim.particles.level.astype(np.int32)}


def run_async(make_scene, backend, frames=6, stepper=None):
    """Run ``make_scene("async", None)`` to its end: records at every synchronised time, frames, wall time."""
    a = Simulation(make_scene("async", None), backend=backend)
    if stepper is not None:
        with_stepper(a, stepper)
    t_end = a.scene.time.t_end
    rec, shots, start = [_record(a)], [_frame(a)], perf_counter()
    ticks, next_frame = [0], t_end / max(frames, 1)
    while a.time < t_end * (1.0 - 1e-12):
        a.step()
        rec.append(_record(a))
        ticks.append(a.state.tick)
        if frames and a.time >= next_frame * (1.0 - 1e-12):
            shots.append(_frame(a))
            next_frame += t_end / frames
    return {"sim": a, "records": rec, "frames": shots, "ticks": ticks, "wall": perf_counter() - start,
            "summary": a.stepper.summary(a.state)}


def run_pair(make_scene, backend, frames=6, stepper=None):
    """Run a scene asynchronously, then synchronously at its finest step; compare at synchronised times.

    ``make_scene(stepping, dt)`` builds the scene (``dt`` only for ``"sync"``); ``stepper`` replaces the
    asynchronous stepper class (the tests' broken variant). Returns both records, the position difference
    at the end (by id, in Δx), updates and wall times.
    """
    run = run_async(make_scene, backend, frames, stepper)
    a, summary, ticks = run["sim"], run["summary"], run["ticks"]
    finest = summary["finest_dt_ticks"]
    s = Simulation(make_scene("sync", finest * a.scene.time.tick), backend=backend)
    rec_s, start, k = [_record(s)], perf_counter(), 0
    targets = set(ticks[1:])
    while k * finest < ticks[-1]:
        s.step()
        k += 1
        if k * finest in targets:
            rec_s.append(_record(s))
    wall_s = perf_counter() - start
    return {"async": run["records"], "sync": rec_s, "position_dx": position_difference(a, s), "wall_async": run["wall"],
            "wall_sync": wall_s, "updates_async": summary["particle_updates"], "own_updates": summary["own_updates"],
            "updates_sync": s.n_particles * s.step_count, "finest_ticks": finest, "stale": summary["stale_shadows"],
            "n": a.n_particles, "mass": float(np.sum(a.mass)), "levels": sorted(set(a.particles.level.tolist())),
            "frames": run["frames"]}


def position_difference(a, b):
    """Largest distance between the same particles (matched by id) of two runs, in Δx."""
    pa, pb = a.x[np.argsort(a.id)], b.x[np.argsort(b.id)]
    return float(np.max(np.linalg.norm(pa - pb, axis=1))) / a.scene.grid.dx


def drift(recs, key):
    """Largest change of a record's quantity ``key`` from its first value."""
    first = recs[0][key]
    return max(float(np.linalg.norm(np.subtract(r[key], first))) for r in recs)


def compare(pair):
    """Energy difference (relative to the initial energy) and momentum drifts of a :func:`run_pair` result."""
    ea = np.array([r["energy"] for r in pair["async"]])
    es = np.array([r["energy"] for r in pair["sync"]])
    n = min(len(ea), len(es))
    e0 = abs(es[0])
    return {"energy_rel": float(np.max(np.abs(ea[:n] - es[:n]))) / e0, "energy_async": ea, "energy_sync": es,
            "times": np.array([r["time"] for r in pair["async"]]),
            "P_drift_async": drift(pair["async"], "P"), "P_drift_sync": drift(pair["sync"], "P"),
            "L_drift_async": drift(pair["async"], "L"), "L_drift_sync": drift(pair["sync"], "L")}


def ball_pair(params, backend, interface="reference", cfl=0.4, t_end=None, frames=None):
    t_end = t_end or params.ball_t_end

    def make(stepping, dt):
        if stepping == "async":
            return balls(params, "async", cfl=cfl, tick=1e-6, levels=10, t_end=t_end, interface=interface)
        return balls(params, "sync", dt=dt, t_end=t_end)
    return run_pair(make, backend, params.frames if frames is None else frames)


def stork_pair(name, t_end, backend, frames, stepper=None, cells=None, interface="reference", cfl=None, levels=None):
    """The example ``name`` (at ``cells`` cells if given, ``time.cfl``/``levels`` if given) asynchronously with
    ``interface``, and synchronously (:func:`run_pair`)."""
    def make(stepping, dt):
        scene = example_with_time(name, t_end, dt if stepping == "sync" else None, cells)
        if stepping == "sync":
            return scene
        src = scene.source
        time = {**src["time"], "interface": interface, **({"cfl": cfl} if cfl else {}),
                **({"levels": levels} if levels is not None else {})}
        return scene.__class__.from_dict({**src, "time": time}, base_dir=scene.base_dir)
    return run_pair(make, backend, frames, stepper)
