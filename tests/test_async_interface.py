r"""Level interfaces of asynchronous stepping: impulse refluxing conserves momentum (mpmref.physics.interface).

An isolated scene (no gravity, no wall reached): a soft and a stiff disk (E ratio 100, so on levels three
apart) pressed together while spinning. Synchronous MPM conserves its linear momentum, and its angular
momentum for the affine transfers, to round-off; asynchronous stepping with ``time.interface =
"conservative"`` must too, at every synchronised time, while ``"reference"`` (Fang et al. 2018 as
published) does not. Bound: :math:`10^{-12}` of :math:`\sum_p m_p |v_p|` (of :math:`\sum_p m_p |x_p||v_p|`
for angular momentum) — a few hundred level updates of round-off, far below the reference's drift.
"""

import numpy as np
import pytest

from mpmref import Simulation
from mpmref.backends import BACKENDS
from mpmref.steppers import AsyncInterval
from verification import sync_vs_async as case

SCHEMES = {"pic": {}, "flip": {"flip_alpha": 0.95}, "apic": {}, "polypic": {}, "mls": {}}
AFFINE = ("apic", "polypic", "mls")
BOUND = 1e-12


def pressed_disks(scheme="mls", interface="conservative", stepping="async", **time):
    """The isolated scene of the ``sync_vs_async`` case, three synchronised intervals."""
    return case.pressed_disks(interface, stepping, scheme, SCHEMES[scheme], intervals=3, **time)


def drifts(sim):
    """Largest momentum and angular momentum change over the run's synchronised times, relative to their scales."""
    def totals():
        d = sim.diagnostics()
        return np.array([d["momentum_x"], d["momentum_y"]]), d["angular_momentum"]

    P0, L0 = totals()
    speed = np.linalg.norm(sim.v, axis=1)
    scale_P = float(np.sum(sim.mass * speed))
    scale_L = float(np.sum(sim.mass * np.linalg.norm(sim.x, axis=1) * speed))
    worst_P = worst_L = 0.0
    levels = set()
    for _ in range(sim.scene.time.steps):
        sim.step()
        P, L = totals()
        worst_P = max(worst_P, float(np.linalg.norm(P - P0)) / scale_P)
        worst_L = max(worst_L, abs(L - L0) / scale_L)
        levels |= set(sim.particles.level.tolist())
    return worst_P, worst_L, levels


@pytest.mark.parametrize("backend", list(BACKENDS))
@pytest.mark.parametrize("scheme", list(SCHEMES))
def test_conservative_interfaces_keep_momentum_at_every_synchronised_time(scheme, backend):
    sim = Simulation(pressed_disks(scheme), backend=backend)
    P, L, levels = drifts(sim)
    assert max(levels) - min(levels) >= 2  # the disks step on levels at least 4x apart
    assert sim.stepper.summary(sim.state)["ghost_updates"] > 0
    assert P <= BOUND
    if scheme in AFFINE:
        assert L <= BOUND


@pytest.mark.parametrize("scheme", ["pic", "mls"])
def test_the_reference_interface_does_not(scheme):
    """The same scene with ``time.interface = "reference"``: the drift the conservative treatment removes."""
    P, L, _ = drifts(Simulation(pressed_disks(scheme, "reference")))
    assert P > 1e4 * BOUND


class _TwiceApplied(AsyncInterval):
    def close_registers(self, idx):
        """Broken on purpose: each register applied twice."""
        if self.s.conservative and idx.size:
            self.dP[idx] *= 2.0
            self.dL[idx] *= 2.0
        super().close_registers(idx)


class _Dropped(AsyncInterval):
    def close_registers(self, idx):
        """Broken on purpose: registers cleared without being applied."""
        if self.s.conservative and idx.size:
            self.dP[idx] = 0.0
            self.dL[idx] = 0.0


@pytest.mark.parametrize("broken", [_TwiceApplied, _Dropped], ids=["applied twice", "dropped"])
def test_a_broken_register_fails_the_momentum_bound(broken, monkeypatch):
    sim = Simulation(pressed_disks("mls"))
    monkeypatch.setattr(sim.stepper, "interval_type", broken)
    P, L, _ = drifts(sim)
    assert P > 1e4 * BOUND and L > 1e4 * BOUND


def test_one_level_with_conservative_interfaces_is_sync_bit_for_bit():
    """With one level there are no ghosts: every kick is zero and the run is synchronous MPM's, to the bit."""
    tick, steps = 2e-5, 20
    scene = pressed_disks("mls").source
    a = Simulation(pressed_disks("mls").__class__.from_dict(
        {**scene, "time": {"stepping": "async", "cfl": 0.4, "tick": tick, "levels": 0, "steps": steps,
                           "interface": "conservative"}}))
    s = Simulation(pressed_disks("mls", stepping="sync", dt=tick, steps=steps))
    a.run()
    s.run()
    for name, array in s.particles.arrays().items():
        if name != "level":
            np.testing.assert_array_equal(getattr(a.particles, name), array, err_msg=name)


@pytest.mark.skipif("numba" not in BACKENDS, reason="no Numba backend")
def test_numba_follows_the_reference_with_conservative_interfaces():
    """Both backends take the same levels and updates, and their particles agree to round-off."""
    ref, cand = Simulation(pressed_disks("mls"), backend="numpy"), Simulation(pressed_disks("mls"), backend="numba")
    ref.run()
    cand.run()
    assert ref.stepper.summary(ref.state) == cand.stepper.summary(cand.state)
    np.testing.assert_array_equal(ref.particles.level, cand.particles.level)
    for name in ("x", "v", "C", "F"):
        r, c = getattr(ref.particles, name), getattr(cand.particles, name)
        assert np.max(np.abs(c - r)) <= 1e-11 * np.max(np.abs(r)), name


@pytest.mark.parametrize("scheme", ["pic", "mls"])
def test_a_body_force_hook_acts_in_every_update_with_ghosts(scheme):
    r"""A body force per unit mass :math:`b_p` (one for each disk, so the two levels feel different forces) given as
    a hook to the conservative run: it acts in every level update, those with ghosts included, so each particle
    receives :math:`m_p b_p` over its own steps, which add up to the run's time :math:`T`, and the total momentum
    changes by :math:`\sum_p m_p b_p T` (the exchanges between levels cancel), to the bound of the isolated run."""
    from mpmref.steppers import Hooks

    accelerations = np.array([[3.0, -1.0], [-0.5, 2.0]])  # per material (soft, stiff), m/s^2
    calls = []

    def body_force(particles, time):
        calls.append(particles.n)
        return accelerations[particles.material]

    sim = Simulation(pressed_disks(scheme), hooks=Hooks(body_force=body_force))
    P0 = np.sum(sim.mass[:, None] * sim.v, axis=0)
    expected = np.sum(sim.mass[:, None] * accelerations[sim.particles.material], axis=0)
    scale_P = float(np.sum(sim.mass * np.linalg.norm(sim.v, axis=1)))
    for _ in range(sim.scene.time.steps):
        sim.step()
    P = np.sum(sim.mass[:, None] * sim.v, axis=0)
    summary = sim.stepper.summary(sim.state)
    assert summary["ghost_updates"] > 0 and max(sim.particles.level) - min(sim.particles.level) >= 2
    assert len(calls) == sim.stepper.work.level_updates  # once per level update
    assert np.linalg.norm(P - P0 - expected * sim.time) <= BOUND * scale_P
    assert np.linalg.norm(expected * sim.time) > 1e-3 * scale_P  # the force's effect is far above the bound
