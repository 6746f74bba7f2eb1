"""Asynchronous (regional) time stepping: level rules, validation and restart.

The schedule, the census, free fall and agreement with sync are the ``sync_vs_async`` verification case
(``tests/test_verify_sync_vs_async.py``).
"""

from pathlib import Path

import numpy as np
import pytest
from helpers import full_and_resumed_runs, valid_methods
from test_scene_validation import check_refused

from mpmref import Scene, SceneBuilder, Simulation
from mpmref.backends import BACKENDS
from mpmref.errors import TickTooLongError
from mpmref.steppers.asynchronous import alignment
from verification.sync_vs_async import two_bodies

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"

# ----------------------------------------------------------------------------------------- level rules
def test_quantisation_of_the_advection_limit():
    """AsyncMPM acceptance test 2: dx = 1/256, |v| = 2, advection CFL 1, strength not binding: C = 1953 -> 1024
    ticks."""
    scene = (SceneBuilder(dim=2).grid(size=1.0, cells=256).material("m", "fixed_corotated", E=1e-6, rho=1.0)
             .box("m", lower=[0.5, 0.5], upper=[0.51, 0.51], velocity=[2.0, 0.0])
             .time(stepping="async", cfl=10.0, tick=1e-6, levels=13, advection_cfl=1.0, steps=1).build())
    sim = Simulation(scene)
    limit = sim.stepper.particle_limits(sim.particles)
    assert np.all(limit == 1953)
    sim.step()
    assert set(sim.particles.level.tolist()) == {10}  # 2^10 = 1024 ticks


def relevel(dt, limit, t):
    """The block step rule written plainly over arrays (Fang et al. 2018 §4): the oracle of the compiled
    :func:`mpmref.steppers.async_kernels.relevel_one` that runs. Halve while ``dt > limit``, then double while
    ``2 dt <= limit`` and ``t mod 2 dt == 0``."""
    dt = dt.copy()
    while (over := dt > limit).any():
        dt[over] //= 2
    while (grow := (2 * dt <= limit) & (t % (2 * dt) == 0)).any():
        dt[grow] *= 2
    return dt


def test_doubling_waits_for_alignment_and_halving_is_immediate():
    """AsyncMPM acceptance test 3: at dt = 4 with L = 16 the step is 4 at t = 4, 8 at t = 8 and 16 at t = 16; L = 3
    halves to 2."""
    from mpmref.steppers.async_kernels import relevel_one

    assert [relevel_one(4, 16, t) for t in (4, 8)] == [4, 8] and relevel_one(8, 16, 16) == 16
    assert relevel_one(4, 3, 4) == 2
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
             .material("fc", "fixed_corotated", E=1e3, nu=0.3, rho=1.0)
             .material("nh", "neo_hookean", E=2e3, nu=0.2, rho=2.0)
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


def _relevel_all_blocks(block_dt, owner, idx, limit, t, max_units):
    """The block rule over every block, written plainly: the due blocks that own some of ``idx`` relevel to
    their smallest limit, the due blocks that own none follow the coarsest of the blocks that own some."""
    own = {}
    for p, lim in zip(idx, limit):
        own[owner[p]] = min(own.get(owner[p], np.inf), lim)
    new = block_dt.copy()
    for b, lim in own.items():
        if t % block_dt[b] == 0:
            new[b] = relevel(block_dt[b:b + 1], np.array([min(lim, max_units)]), t)[0]
    coarsest = max((new[b] for b in own), default=max_units)
    for b in range(block_dt.size):
        if b not in own and t % block_dt[b] == 0:
            new[b] = relevel(block_dt[b:b + 1], np.array([coarsest]), t)[0]
    return new


def test_relevelling_only_the_due_blocks_follows_the_rule_over_every_block():
    """The compiled rule visits the blocks due at a tick (a prefix of the blocks ordered by step) and the blocks
    owning particles at their boundary; it must give what the rule applied to every block gives, tick after tick."""
    from mpmref.steppers.async_kernels import blocks_by_level, relevel_due

    rng = np.random.default_rng(8)
    levels, n_blocks = 6, 300
    max_units = 2**levels
    block_dt = np.full(n_blocks, max_units, dtype=np.int64)
    order, level_start = blocks_by_level(block_dt, levels)
    scratch = np.full(n_blocks, np.inf)
    owner = rng.integers(0, n_blocks, size=2000)
    due_counts = []
    for t in range(0, 400):
        idx = np.flatnonzero(rng.random(owner.size) < 0.05)
        limit = np.floor(2.0 ** rng.uniform(0, levels + 1, size=idx.size))
        expected = _relevel_all_blocks(block_dt, owner, idx, limit, t, max_units)
        due_counts.append(relevel_due(block_dt, order, level_start, owner, idx, limit, t, alignment(t, max_units),
                                      max_units, scratch))
        np.testing.assert_array_equal(block_dt, expected, err_msg=f"tick {t}")
        assert np.all(np.isinf(scratch))
        assert np.array_equal(np.sort(order), np.arange(n_blocks))
        np.testing.assert_array_equal(np.diff(level_start), np.bincount(np.log2(block_dt).astype(int),
                                                                        minlength=levels + 1))
        assert np.all(np.diff(block_dt[order]) >= 0)  # still ordered by step
    assert min(due_counts) < n_blocks / 4  # most ticks visit few blocks


def test_the_ghost_search_by_block_finds_what_a_search_over_every_candidate_finds():
    """A cohort bucketed by block, searched only in the blocks near the zone (grown by the shadows' drift): the
    same particles as testing every one of them."""
    from mpmref.steppers.async_kernels import bucket_by_block, bucket_zone_members, zone, zone_test

    rng = np.random.default_rng(9)
    for d in (2, 3):
        cells = np.array([40, 33, 20][:d])
        node_shape, block = cells + 1, 4
        blocks_per_axis = cells // block + 1
        for _ in range(30):
            n = 400
            base = rng.integers(0, node_shape, size=(n, d))
            drift = int(rng.integers(0, 4))
            shadow_base = np.clip(base + rng.integers(-drift, drift + 1, size=(n, d)), 0, node_shape - 1)
            owner = np.ravel_multi_index(tuple((base // block).T), tuple(blocks_per_axis))
            active = np.sort(rng.choice(n, size=int(rng.integers(1, 30)), replace=False))
            cohort = np.setdiff1d(np.arange(n), active)[rng.random(n - active.size) < 0.6]
            members, blocks, starts = bucket_by_block(cohort, owner)
            assert np.array_equal(np.sort(members), cohort) and np.all(np.diff(blocks) > 0)
            assert all(np.all(owner[members[starts[j]:starts[j + 1]]] == blocks[j]) for j in range(blocks.size))
            z = zone(active, base, int(rng.integers(1, 7)), node_shape)
            found, examined = bucket_zone_members(*z, drift, block, blocks_per_axis, members, blocks, starts,
                                                  shadow_base)
            np.testing.assert_array_equal(np.sort(found), zone_test(*z, cohort, shadow_base))
            assert examined <= cohort.size


def test_the_bookkeeping_visits_what_the_updates_touch():
    """Counted on the example stork: the ghost searches examine about as many particles as they find (not every
    mid-step particle at every update), and the work over every particle happens once per interval."""
    from mpmref.scene.factories import example_with_time

    sim = Simulation(example_with_time("stork2d", 0.004))
    sim.run()
    counts, summary, n = sim.stepper.work.counts, sim.stepper.summary(sim.state), sim.n_particles
    found = summary["ghost_updates"]
    assert found > 0 and counts["ghost_candidates"] <= 1.5 * found
    assert counts["ghost_candidates"] < 0.2 * n * sim.stepper.work.level_updates  # a scan of everyone would be n each
    assert counts["boundary_particles"] == summary["own_updates"]
    assert counts["interval_particles"] == n * sim.step_count and counts["intervals"] == sim.step_count
    assert counts["group_rows"] == summary["particle_updates"]


def test_the_run_summary_gives_the_updates_the_levels_and_the_ledger(tmp_path, capsys):
    """``mpmref run`` of the async example: own steps and ghost updates, the update ratio named as a ratio of work
    (never a "saved" figure alone), the levels at the end, the run ending at ``t_end``; with the energy ledger asked
    for, its ``ledger_interface`` column in diagnostics.csv."""
    import csv

    from mpmref.cli import main

    scene = tmp_path / "stork.toml"
    text = (EXAMPLES / "stork2d.toml").read_text().replace("t_end = 0.05", "t_end = 0.002")
    scene.write_text(text.replace("[output]\n", "[output]\nenergy_ledger = true\n"))
    assert main(["run", str(scene), "--out", str(tmp_path / "o"), "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "own steps +" in out and "ghost updates" in out and "update ratio" in out and "not of wall time" in out
    assert "saved" not in out
    assert "levels           [" in out and "stale shadows" in out and "t = 0.002)" in out
    rows = list(csv.DictReader(open(tmp_path / "o" / "diagnostics.csv")))
    assert "ledger_interface" in rows[-1] and float(rows[-1]["ledger_closure"]) == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("t_end, ticks", [(0.002, 1250), (0.0020005, 1251)])
def test_an_asynchronous_run_ends_at_t_end(t_end, ticks):
    """The stork (tick 1.6e-6 s) run to ``t_end``: it ends at that tick exactly when ``t_end`` is a whole number of
    ticks (0.002 s = 1 250 ticks, with steps of up to 2^7 ticks that do not divide it), else at the next tick; the
    steps near the end are shortened, and the finest step reported is still the one the limits chose."""
    scene = Scene.from_toml(EXAMPLES / "stork2d.toml")
    free = Simulation(scene)
    free.run(steps=3)
    sim = Simulation(scene)
    sim.run(t_end=t_end)
    assert sim.state.tick == ticks
    assert sim.time == ticks * scene.time.tick
    assert 1250 % 128 != 0  # the unshortened intervals would not stop there
    assert sim.stepper.summary(sim.state)["finest_dt_ticks"] == free.stepper.summary(free.state)["finest_dt_ticks"]
