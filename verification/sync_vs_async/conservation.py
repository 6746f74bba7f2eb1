"""The isolated pressed disks of the sync-vs-async case (:mod:`verification.sync_vs_async`): their momentum drift,
and the energy ledger's split of their energy change.
"""

import numpy as np

from mpmref import Scene, Simulation

from .pairs import _record, drift
from .scenes import pressed_disks


def isolated(params, backend, interface):
    """Momentum drifts of the pressed disks over ``params.isolated_intervals`` synchronised intervals, relative to
    :math:`\\sum_p m_p|v_p|` (linear) and :math:`\\sum_p m_p|x_p||v_p|` (angular)."""
    sim = Simulation(pressed_disks(interface), backend=backend)
    speed = np.linalg.norm(sim.v, axis=1)
    scale_P = float(np.sum(sim.mass * speed))
    scale_L = float(np.sum(sim.mass * np.linalg.norm(sim.x, axis=1) * speed))
    recs, levels = [_record(sim)], set()
    for _ in range(params.isolated_intervals):
        sim.step()
        recs.append(_record(sim))
        levels |= set(sim.particles.level.tolist())
    return {"P": drift(recs, "P") / scale_P, "L": drift(recs, "L") / scale_L, "levels": sorted(levels),
            "ghost_updates": sim.stepper.summary(sim.state)["ghost_updates"]}


def ledger_split(params, backend, interface):
    """The pressed disks with the energy ledger over ``params.isolated_intervals`` synchronised intervals: the
    largest gap between the change it books and the change of total energy the diagnostics measure, per interval,
    and its cumulative terms, all relative to the initial energy."""
    src = pressed_disks(interface).source
    sim = Simulation(Scene.from_dict({**src, "output": {**src.get("output", {}), "energy_ledger": True}}),
                     backend=backend)
    e0 = sim.diagnostics()["total_energy"]
    gap = 0.0
    for _ in range(params.isolated_intervals):
        before = sim.diagnostics()["total_energy"]
        sim.step()
        measured = sim.diagnostics()["total_energy"] - before
        gap = max(gap, abs(sim.stepper.ledger.last["energy_change"] - measured) / abs(e0))
    d = sim.diagnostics()
    return {"gap": gap, "terms": {k[len("ledger_"):]: v / e0 for k, v in d.items() if k.startswith("ledger_")}}
