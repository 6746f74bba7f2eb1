"""The sweeps of the sync-vs-async case (:mod:`verification.sync_vs_async`): the bonded stork at several CFL
numbers, the colliding balls over shrinking steps, and error against wall time on the 2D stork (the trade).
"""

from time import perf_counter

import numpy as np

from mpmref import Simulation
from mpmref.scene.factories import example_with_time

from .pairs import compare, position_difference, run_async, stork_pair
from .scenes import balls


def bonded_at_cfls(params, backend):
    """The 2D stork at each CFL number of ``params.bonded_cfls``, both treatments: energy difference from sync."""
    out = []
    for cfl in params.bonded_cfls:
        row = {"cfl": cfl}
        for itf in params.bonded_interfaces:
            pair = stork_pair("stork2d", params.stork_t_end, backend, 0, interface=itf, cfl=cfl)
            row[itf] = compare(pair)["energy_rel"]
        out.append(row)
    return out


def body_velocities(sim):
    """Centre-of-mass velocity of each material's particles, (materials, d)."""
    p = sim.particles
    return np.array([np.average(p.v[p.material == m], axis=0, weights=p.mass[p.material == m])
                     for m in range(len(sim.scene.materials))])


def ball_series(params, backend):
    """The colliding balls at each CFL number of ``params.series_cfls`` (the level ratio fixed): each treatment's
    end state against sync at the same finest step and at a 4x finer one (the balls' velocity, and energy)."""
    rows = []
    for cfl in params.series_cfls:
        ends = {itf: run_async(lambda stepping, dt, itf=itf, cfl=cfl: balls(params, stepping, cfl=cfl, tick=1e-6,
                                                                              levels=10, t_end=params.series_t_end,
                                                                              interface=itf),
                               backend, frames=0) for itf in params.series_interfaces}
        finest = min(e["summary"]["finest_dt_ticks"] for e in ends.values())
        syncs = {}
        finer = len(rows) < params.series_finer_rows
        for name, dt in (("sync", finest * 1e-6), ("sync/4", finest * 1e-6 / 4))[:2 if finer else 1]:
            s = Simulation(balls(params, "sync", dt=dt, t_end=params.series_t_end), backend=backend)
            s.run()
            syncs[name] = s
        row = {"cfl": cfl, "finest_ticks": finest,
               "sync_velocity": body_velocities(syncs["sync"]).tolist(),
               "sync_energy": syncs["sync"].diagnostics()["total_energy"]}
        speed = params.ball_speed
        for itf, e in ends.items():
            v = body_velocities(e["sim"])
            row[itf] = {name: float(np.max(np.abs(v - body_velocities(s)))) / speed for name, s in syncs.items()}
        if finer:
            row["sync_vs_sync4"] = float(np.max(np.abs(body_velocities(syncs["sync"])
                                                       - body_velocities(syncs["sync/4"])))) / speed
        rows.append(row)
    return rows


def fitted_slope(steps, errors):
    """Least-squares slope of log(error) against log(step)."""
    return float(np.polyfit(np.log(steps), np.log(np.maximum(errors, 1e-300)), 1)[0])


def trade(params, backend):
    """Error against wall time on the 2D stork: sync at ``params.trade_sync_divisions`` times finer than async's
    finest step, async
    at each CFL number and level count of ``params``, against sync at a ``params.trade_reference_division`` times
    finer step than async's finest;
    each run's end positions (by id) in Δx, and its stepping loop's wall time."""
    t_end = params.stork_t_end
    runs = []
    for cfl in params.trade_cfls:
        for levels in params.trade_levels:
            run = run_async(lambda stepping, dt, cfl=cfl, levels=levels: _stork_async(t_end, cfl, levels), backend,
                            frames=0)
            runs.append({"kind": "async", "label": f"async cfl {cfl} levels {levels}", "sim": run["sim"],
                         "wall": run["wall"], "finest": run["summary"]["finest_dt_ticks"]})
    finest = min(r["finest"] for r in runs)
    tick = runs[0]["sim"].scene.time.tick
    for div in params.trade_sync_divisions:
        s = Simulation(example_with_time("stork2d", t_end, dt=finest * tick / div), backend=backend)
        start = perf_counter()
        s.run()
        runs.append({"kind": "sync", "label": f"sync dt {finest / div:g} ticks", "sim": s,
                     "wall": perf_counter() - start})
    ref = Simulation(example_with_time("stork2d", t_end, dt=finest * tick / params.trade_reference_division),
                     backend=backend)
    ref.run()
    for r in runs:
        r["error_dx"] = position_difference(r.pop("sim"), ref)
    front = pareto_front([(r["wall"], r["error_dx"]) for r in runs])
    for i, r in enumerate(runs):
        r["pareto"] = i in front
    return runs


def _stork_async(t_end, cfl, levels):
    scene = example_with_time("stork2d", t_end)
    src = scene.source
    return scene.__class__.from_dict({**src, "time": {**src["time"], "cfl": cfl, "levels": levels}},
                                     base_dir=scene.base_dir)


def pareto_front(points):
    """Indices of the points (cost, error) that no other point beats in both (ties broken by position)."""
    return {i for i, (c, e) in enumerate(points)
            if not any((c2 <= c and e2 <= e) and (c2 < c or e2 < e) for c2, e2 in points)}
