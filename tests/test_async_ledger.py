r"""The energy ledger of asynchronous stepping (mpmref.observe.ledger.LevelLedger): every level update books its active
particles' energy change by stage, the registers of conservative interfaces book theirs to ``interface``, and
together they are the run's measured energy change at every synchronised time.

``E0`` is a run's initial total energy; "round-off" is 1e-12 of it (a few hundred level updates of float64
sums, as the synchronous ledger's tests allow).
"""

import numpy as np
import pytest
from helpers import full_and_resumed_runs

from mpmref import Scene, Simulation
from mpmref.observe.ledger import ASYNC_COLUMNS, ASYNC_TERMS, TERMS
from verification import sync_vs_async as case

ROUND_OFF = 1e-12


def with_ledger(scene):
    """``scene`` with ``[output] energy_ledger = true``."""
    src = scene.source
    return Scene.from_dict({**src, "output": {**src.get("output", {}), "energy_ledger": True}}, base_dir=scene.base_dir)


def entries_of(sim):
    """The entries of ``sim``'s level updates, as they are booked (a list that grows as the run goes)."""
    entries, finish = [], sim.stepper.ledger.finish

    def recorded(new, rigid=None):
        entries.append(finish(new, rigid))
        return entries[-1]

    sim.stepper.ledger.finish = recorded
    return entries


def booked_and_measured(sim, intervals):
    """Per synchronised interval: the ledger's entry and the change of ``total_energy`` the diagnostics measure."""
    out = []
    for _ in range(intervals):
        before = sim.diagnostics()["total_energy"]
        sim.step()
        out.append((sim.stepper.ledger.last, sim.diagnostics()["total_energy"] - before))
    return out


@pytest.mark.parametrize("interface", ["conservative", "reference"])
def test_the_booked_change_is_the_measured_change_at_every_synchronised_time(interface, backend):
    """The pressed disks (levels three apart, pressing on each other): per interval, the terms add up to the
    booked change (``closure``) and the booked change is the diagnostics' change of total energy, to round-off;
    the energy that crosses the interfaces is a visible share of the change."""
    sim = Simulation(with_ledger(case.pressed_disks(interface, intervals=3)), backend=backend)
    e0 = sim.diagnostics()["total_energy"]
    for entry, measured in booked_and_measured(sim, 3):
        assert abs(entry["closure"]) <= ROUND_OFF * e0
        assert abs(entry["energy_change"] - measured) <= ROUND_OFF * e0
    total = {c: sim.diagnostics()[f"ledger_{c}"] for c in ASYNC_COLUMNS}
    assert total["interface"] < -1e-3 * e0 and total["p2g_transfer"] < 0.0 and total["g2p_transfer"] < 0.0
    assert sum(total[t] for t in ASYNC_TERMS) == pytest.approx(sim.diagnostics()["total_energy"] - e0,
                                                               abs=ROUND_OFF * e0)


def test_gravity_and_walls_are_booked_on_every_level():
    """A bonded stiff/soft pair under gravity near a slip floor, on two levels: gravity's work and the floor's
    share appear, and the terms still add up to the measured change (the potential energy is part of it)."""
    scene = case.two_bodies(cfl=0.4, tick=1e-5, levels=6, gravity=-10.0, walls="slip", bonded=True, steps=1)
    sim = Simulation(with_ledger(scene))
    e0 = abs(sim.diagnostics()["total_energy"])
    for entry, measured in booked_and_measured(sim, 6):
        assert abs(entry["closure"]) <= ROUND_OFF * e0
        assert abs(entry["energy_change"] - measured) <= ROUND_OFF * e0
    d = sim.diagnostics()
    assert abs(d["ledger_gravity_work"]) > 1e-4 * e0 and d["ledger_boundary"] < -1e-4 * e0
    assert len(set(sim.particles.level.tolist())) >= 2


def test_one_level_books_what_the_synchronous_ledger_books():
    """With one level there are no ghosts: each update is a synchronous step of every particle, its
    ``interface`` is zero and every other term is the synchronous ledger's."""
    tick, steps = 2e-5, 10
    src = case.pressed_disks().source
    a = Simulation(with_ledger(Scene.from_dict({**src, "time": {"stepping": "async", "cfl": 0.4, "tick": tick,
                                                                "levels": 0, "steps": steps}})))
    s = Simulation(with_ledger(case.pressed_disks(stepping="sync", dt=tick, steps=steps)))
    a.run()
    s.run()
    e0 = s.diagnostics()["total_energy"]
    for c in TERMS:
        assert a.diagnostics()[f"ledger_{c}"] == pytest.approx(s.diagnostics()[f"ledger_{c}"], abs=ROUND_OFF * e0), c
    assert abs(a.diagnostics()["ledger_interface"]) <= ROUND_OFF * e0


@pytest.mark.parametrize("scheme", ["pic", "apic", "polypic"])
def test_p2g_of_the_active_particles_never_gains_energy(scheme):
    """Class by class, a node's momentum from the active particles is a mass-weighted average of their velocity
    fields there (Cauchy–Schwarz, as for a synchronous P2G): ``p2g_transfer`` <= round-off in every update, also
    with ghosts present; what the active particles take from the ghosts' momentum is ``interface``."""
    sim = Simulation(with_ledger(case.pressed_disks("conservative", "async", scheme, intervals=2)))
    entries = entries_of(sim)
    sim.run()
    e0 = sim.diagnostics()["total_energy"] - sim.diagnostics()["ledger_energy_change"]
    assert max(e["p2g_transfer"] for e in entries) <= ROUND_OFF * e0
    assert any(abs(e["interface"]) > 1e-6 * e0 for e in entries)


def test_the_registers_kicks_are_booked_to_the_interface():
    """Conservative interfaces: the registers' kinetic energy change is booked to ``interface`` (and to the
    change), at the particles' step ends."""
    sim = Simulation(with_ledger(case.pressed_disks("conservative", intervals=2)))
    kicked, kicks = [], sim.stepper.ledger.kicks

    def recorded(particles, idx, apply):
        before = dict(sim.stepper.ledger.interval)
        kicks(particles, idx, apply)
        kicked.append(sim.stepper.ledger.interval["interface"] - before["interface"])

    sim.stepper.ledger.kicks = recorded
    sim.run()
    assert any(abs(k) > 0.0 for k in kicked)


def test_a_resumed_asynchronous_run_goes_on_adding_to_the_ledger(tmp_path):
    """The cumulative ledger is part of the asynchronous run's state: resumed from its checkpoint, the run ends
    with the same ledger, bit for bit."""
    scene = case.two_bodies(cfl=0.4, tick=1e-5, levels=6, steps=6)
    src = scene.source
    scene = Scene.from_dict({**src, "output": {"energy_ledger": True, "every": 1}})
    full, resumed = full_and_resumed_runs(scene, tmp_path, steps=6, stop_at=3)
    expected = {k: v for k, v in full.diagnostics().items() if k.startswith("ledger_")}
    assert set(expected) == {f"ledger_{c}" for c in ASYNC_COLUMNS}
    assert {k: v for k, v in resumed.diagnostics().items() if k.startswith("ledger_")} == expected
    assert np.isfinite(list(expected.values())).all()


@pytest.mark.parametrize("stepping", ["sync", "async"])
def test_a_body_force_hook_with_the_ledger_is_refused_with_the_reason(stepping):
    """The ledger has no term for a hook's work: asked for both, either stepper says so before any step."""
    from mpmref.errors import MpmrefError
    from mpmref.steppers import Hooks

    hooks = Hooks(body_force=lambda particles, time: np.zeros_like(particles.x))
    src = case.pressed_disks().source
    if stepping == "sync":
        src = {**src, "time": {"dt": 1e-4, "t_end": 1e-3}}
    scene = with_ledger(Scene.from_dict(src))
    with pytest.raises(MpmrefError, match="no term for a body force hook"):
        Simulation(scene, hooks=hooks)
