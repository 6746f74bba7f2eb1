"""Asynchronous (regional) time stepping: level rules, validation and restart.

The schedule, the census, free fall and agreement with sync are the ``sync_vs_async`` verification case
(``tests/test_verify_sync_vs_async.py``).
"""

import numpy as np
import pytest

from mpmref import SceneBuilder, Simulation
from mpmref.backends import BACKENDS
from mpmref.errors import TickTooLongError
from mpmref.steppers.asynchronous import alignment, relevel
from verification.sync_vs_async import two_bodies

from helpers import full_and_resumed_runs, valid_methods

from test_scene_validation import check_refused

# ----------------------------------------------------------------------------------------- level rules
def test_quantisation_of_the_advection_limit():
    """AsyncMPM acceptance test 2: dx = 1/256, |v| = 2, advection CFL 1, strength not binding: C = 1953 -> 1024 ticks."""
    scene = (SceneBuilder(dim=2).grid(size=1.0, cells=256).material("m", "fixed_corotated", E=1e-6, rho=1.0)
             .box("m", lower=[0.5, 0.5], upper=[0.51, 0.51], velocity=[2.0, 0.0])
             .time(stepping="async", cfl=10.0, tick=1e-6, levels=13, advection_cfl=1.0, steps=1).build())
    sim = Simulation(scene)
    limit = sim.stepper.particle_limits(sim.particles)
    assert np.all(limit == 1953)
    sim.step()
    assert set(sim.particles.level.tolist()) == {10}  # 2^10 = 1024 ticks


def test_doubling_waits_for_alignment_and_halving_is_immediate():
    """AsyncMPM acceptance test 3: at dt = 4 with L = 16 the step is 4 at t = 4, 8 at t = 8 and 16 at t = 16; L = 3 halves to 2."""
    dt = np.array([4])
    assert relevel(dt, np.array([16]), 4)[0] == 4
    assert relevel(dt, np.array([16]), 8)[0] == 8
    assert relevel(np.array([8]), np.array([16]), 16)[0] == 16
    assert relevel(dt, np.array([3]), 4)[0] == 2
    assert [alignment(t, 64) for t in (0, 1, 6, 8, 96)] == [64, 1, 2, 8, 32]


def test_a_tick_longer_than_the_stability_limit_is_refused_at_the_step():
    scene = two_bodies(cfl=0.5, tick=1e-2, levels=3, steps=1)
    with pytest.raises(TickTooLongError, match="lower 'time.tick'"):
        Simulation(scene).step()


@pytest.mark.parametrize("field, value, allowed", [
    (("time", "tick"), 0.0, "(0.0, inf]"), (("time", "tick"), -1e-6, "(0.0, inf]"),
    (("time", "levels"), -1, "[0, 30]"), (("grid", "block"), 6, "power of two"),
    (("grid", "block"), 2, "power of two >= 3")])
def test_bad_async_values_are_refused_with_the_field_named(field, value, allowed):
    d = SceneBuilder(dim=2).grid(size=1.0, cells=16).material("m", "fixed_corotated", E=1e3).box(
        "m", lower=[0.4, 0.4], upper=[0.6, 0.6]).time(stepping="async", cfl=0.5, steps=1).as_dict()
    d[field[0]][field[1]] = value
    check_refused(d, f"{field[0]}.{field[1]}", allowed)


def test_dt_with_async_and_async_keys_with_sync_are_refused():
    base = SceneBuilder(dim=2).grid(size=1.0, cells=16).material("m", "fixed_corotated", E=1e3).box(
        "m", lower=[0.4, 0.4], upper=[0.6, 0.6])
    check_refused(base.time(stepping="async", dt=1e-4, steps=1).as_dict(), "time.dt", "absent")
    check_refused(base.time(dt=1e-4, tick=1e-6, steps=1).as_dict(), "time.tick", "stepping = 'async'")


# -------------------------------------------------------------------------------------------- restart
def test_async_resume_is_bit_identical(tmp_path):
    scene = two_bodies(cfl=0.4, tick=1e-5, levels=6, steps=6)
    full, resumed = full_and_resumed_runs(scene, tmp_path, steps=6, stop_at=3)
    assert resumed.state.tick == full.state.tick
    for key in ("block_dt", "updates", "sync_updates"):
        assert np.array_equal(full.state.stepper[key], resumed.state.stepper[key]), key


# ------------------------------------------------------------------------------- every method and material
def _two_level_scene(dim, method, material):
    """A stiff and a soft block of ``material`` touching (two levels), in ``dim`` D, briefly."""
    b = SceneBuilder(dim=dim, name="all").grid(size=1.0, cells=16, block=4).method(**method)
    if material == "fluid":
        b.material("soft", "fluid", K=1e2, gamma=7.0, rho=1.0).material("stiff", "fluid", K=1e4, gamma=7.0, rho=1.0)
    else:
        b.material("soft", material, E=1e2, nu=0.3, rho=1.0).material("stiff", material, E=1e4, nu=0.3, rho=1.0)
    lo = [0.3] + [0.3] * (dim - 1)
    b.box("stiff", lower=lo, upper=[0.5] + [0.55] * (dim - 1), velocity=[0.3] + [0.0] * (dim - 1))
    b.box("soft", lower=[0.5] + lo[1:], upper=[0.7] + [0.55] * (dim - 1))
    return b.gravity([0.0, -5.0] + [0.0] * (dim - 2)).time(stepping="async", cfl=0.4, tick=1e-5, levels=5,
                                                              steps=2).build()


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("method", valid_methods(), ids=lambda m: "-".join(str(v) for v in m.values()))
def test_every_method_steps_asynchronously_on_two_levels(dim, method):
    sim = Simulation(_two_level_scene(dim, method, "fixed_corotated"))
    sim.run()
    assert len(set(sim.particles.level.tolist())) >= 2 and np.all(np.isfinite(sim.x))
    assert np.array_equal(np.sort(sim.id), np.arange(sim.n_particles))


@pytest.mark.parametrize("material", ["neo_hookean", "fluid", "snow", "sand"])
def test_every_material_steps_asynchronously_on_both_backends(material, backend):
    sim = Simulation(_two_level_scene(2, {"scheme": "mls"}, material), backend=backend)
    sim.run()
    assert len(set(sim.particles.level.tolist())) >= 2 and np.all(np.isfinite(sim.x))
    assert sim.stepper.summary(sim.state)["particle_updates"] > 0


# ------------------------------------------------------------------------------- compiled bookkeeping
def test_zone_members_is_the_chebyshev_dilation_of_the_active_base_nodes():
    """The compiled ghost zone against an independent computation (scipy's maximum filter over the lattice)."""
    from scipy.ndimage import maximum_filter

    from mpmref.steppers.async_kernels import zone_members

    rng = np.random.default_rng(5)
    for d in (2, 3):
        shape = np.array([30, 25, 20][:d])
        for _ in range(40):
            active = rng.integers(0, shape, size=(int(rng.integers(1, 20)), d))
            candidates = rng.integers(0, shape, size=(300, d))
            reach = int(rng.integers(1, 7))
            mask = np.zeros(shape, dtype=bool)
            mask[tuple(active.T)] = True
            expected = np.flatnonzero(maximum_filter(mask, size=2 * reach + 1, mode="constant")[tuple(candidates.T)])
            got = zone_members(np.arange(len(active)), active, np.arange(len(candidates)), candidates, reach, shape)
            np.testing.assert_array_equal(got, expected)


def test_the_compiled_relevel_follows_the_rule():
    from mpmref.steppers.async_kernels import relevel_one

    rng = np.random.default_rng(6)
    dt = 2 ** rng.integers(0, 8, size=500)
    limit = rng.integers(1, 300, size=500)
    for t in (0, 4, 8, 24, 64, 96, 128):
        aligned = dt[t % dt == 0]
        lim = limit[t % dt == 0]
        np.testing.assert_array_equal([relevel_one(a, b, t) for a, b in zip(aligned, lim)], relevel(aligned, lim, t))


@pytest.mark.skipif("numba" not in BACKENDS, reason="no Numba backend")
def test_wave_speeds_of_every_material_agree_across_backends():
    """The step limits' wave speeds: the Numba backend's compiled rules against each material's own (NumPy)."""
    from mpmref.backends import make_backend

    scene = (SceneBuilder(dim=2, name="waves").grid(size=1.0, cells=16).method("mls")
             .material("fc", "fixed_corotated", E=1e3, nu=0.3, rho=1.0).material("nh", "neo_hookean", E=2e3, nu=0.2, rho=2.0)
             .material("w", "fluid", K=400.0, gamma=7.0, rho=1.0).material("s", "snow", E=1.4e5, nu=0.2, rho=400.0)
             .material("d", "sand", E=3.5e5, nu=0.3, rho=2200.0)
             .box("fc", lower=[0.2, 0.2], upper=[0.3, 0.3]).box("nh", lower=[0.3, 0.2], upper=[0.4, 0.3])
             .box("w", lower=[0.4, 0.2], upper=[0.5, 0.3]).box("s", lower=[0.5, 0.2], upper=[0.6, 0.3])
             .box("d", lower=[0.6, 0.2], upper=[0.7, 0.3]).walls("open").time(dt=1e-4, steps=1).build())
    sim = Simulation(scene)
    rng = np.random.default_rng(7)
    p = sim.particles
    p.F[:] = np.eye(2) + 0.2 * rng.standard_normal(p.F.shape)
    p.J[:] = 0.8 + 0.4 * rng.random(p.n)
    p.Jp[:] = 0.7 + 0.6 * rng.random(p.n)
    idx = rng.permutation(p.n)[: p.n // 2]
    ref = make_backend("numpy", scene).wave_speeds(p, idx)
    got = make_backend("numba", scene).wave_speeds(p, idx)
    assert np.all(np.isfinite(ref)) and np.max(np.abs(got - ref) / ref) <= 1e-13
