"""Storage that follows the schedule: asynchronous stepping keeps the particles in rows ordered by step
(:mod:`mpmref.steppers.async_store`), moves only the rows out of their level's run, and steps a level's rows in place
through the row stages of :class:`mpmref.backends.base.RowBackend`; a backend without them steps the same rows through
the gathering adapter (:func:`mpmref.steppers.pipeline.gathered_substep`) with the same bits, and one level is the
synchronous step with nothing copied.
"""

import numpy as np
import pytest
from test_async import _two_level_scene

from mpmref import Simulation
from mpmref.backends import BACKENDS
from mpmref.backends.base import ROW_BACKEND_STAGES, steps_rows
from mpmref.physics.interface import ACTIVE, COARSER, FINER
from mpmref.state import Particles
from mpmref.steppers import AsyncInterval
from mpmref.steppers.async_kernels import misplaced_rows, permute_rows
from mpmref.steppers.async_store import StorePool
from mpmref.steppers.pipeline import LevelExchange, gathered_substep, substep
from verification import sync_vs_async as case

needs_numba = pytest.mark.skipif("numba" not in BACKENDS, reason="no Numba backend")


def _numba_backend():
    from mpmref.backends.numba import NumbaBackend

    return NumbaBackend


# ------------------------------------------------------------------------------------------ the row stages
def _store_with_ghosts(sim, rng):
    """``sim``'s particles followed by spare rows holding copies of some of them, perturbed (as ghosts at other
    states), and the rows of an update: a run of the particles and the ghost rows."""
    p = sim.particles
    ghosts = p.select(np.sort(rng.choice(p.n, size=p.n // 3, replace=False)))
    ghosts.v += 0.05 * rng.standard_normal(ghosts.v.shape)
    store = Particles.concatenate([p, ghosts])
    a, b = p.n // 4, 3 * p.n // 4
    rows = np.concatenate([np.arange(a, b), np.arange(p.n, store.n)])
    classes = np.full(rows.size, ACTIVE)
    classes[b - a:] = np.where(rng.random(ghosts.n) < 0.5, FINER, COARSER)
    return store, rows, classes


@needs_numba
@pytest.mark.parametrize("dim, method, material", [(2, {"scheme": "mls"}, "fixed_corotated"),
                                                   (2, {"scheme": "mls"}, "snow"),
                                                   (2, {"scheme": "flip", "flip_alpha": 0.95}, "fixed_corotated"),
                                                   # a fresh Numba cache compiles the 3D kernels: 17 s of one core
                                                   pytest.param(3, {"scheme": "mls"}, "fixed_corotated",
                                                                marks=pytest.mark.slow)])
@pytest.mark.parametrize("kicks", [False, True], ids=["plain", "by classes, kicks"])
def test_the_row_stages_give_the_bits_of_the_gathering_adapter(dim, method, material, kicks):
    """One level update's rows (a run of the particles and ghost rows after them) stepped in place by the Numba row
    stages, and the same rows gathered into a group, stepped by the plain stages and written back: every array the
    same to the bit, the impulses too, and no other row touched."""
    sim = Simulation(_two_level_scene(dim, method, material), backend="numba")
    sim.run(steps=1)
    store, rows, classes = _store_with_ghosts(sim, np.random.default_rng(3))
    backend, dt, time = sim.backend, 2e-5, sim.time
    results = []
    for step in (substep, gathered_substep):
        stepped = store.copy()
        exchange = LevelExchange(classes, kicks=True) if kicks else None
        if step is substep:
            substep(backend, stepped, dt, time, exchange=exchange, rows=rows)
        else:
            gathered_substep(backend, stepped, rows, dt, time, exchange=exchange)
        results.append((stepped, exchange))
    (native, native_exchange), (gathered, gathered_exchange) = results
    untouched = np.setdiff1d(np.arange(store.n), rows)
    for name, array in native.arrays().items():
        np.testing.assert_array_equal(array, getattr(gathered, name), err_msg=name)
        np.testing.assert_array_equal(array[untouched], getattr(store, name)[untouched], err_msg=name)
    assert not np.array_equal(native.x[rows], store.x[rows])  # the rows did step
    if kicks:
        for mine, theirs in zip(native_exchange.impulses, gathered_exchange.impulses):
            np.testing.assert_array_equal(mine, theirs)
        assert np.any(native_exchange.impulses[0] != 0.0)


@needs_numba
def test_the_numba_backend_has_the_row_stages_with_the_protocols_arguments():
    """:class:`~mpmref.backends.base.RowBackend`'s stages, as declared; the NumPy reference has none (it steps rows
    through the adapter)."""
    import inspect

    from mpmref.backends import make_backend
    from mpmref.backends.base import RowBackend

    scene = case.pressed_disks()
    backend = make_backend("numba", scene)
    assert isinstance(backend, RowBackend) and steps_rows(backend) and not steps_rows(make_backend("numpy", scene))
    for stage in ROW_BACKEND_STAGES:
        declared = list(inspect.signature(getattr(RowBackend, stage)).parameters)[1:]
        assert list(inspect.signature(getattr(backend, stage)).parameters)[:len(declared)] == declared


@needs_numba
def test_a_sort_of_rows_is_reused_while_the_rows_keep_their_blocks():
    """``prepare_rows`` hands back its kept sort for the same rows in the same blocks, the one a fresh backend makes;
    a particle moved to another block, or other rows, are sorted again; the caller's rows array is not the kept one."""
    from mpmref.backends.numba.rows import KEPT_ROW_SORTS

    scene = case.pressed_disks()
    sim = Simulation(scene, backend="numba")
    backend, particles = sim.backend, sim.particles
    rows = np.arange(1, particles.n, 2)
    first = backend.prepare_rows(particles, rows)
    rows[:] = 0  # the caller's array, used again: the kept sort has its own
    rows = np.arange(1, particles.n, 2)
    again = backend.prepare_rows(particles, rows)
    fresh = _numba_backend()(scene).prepare_rows(particles, rows)
    assert again is first
    for name in ("order", "block_start", "rows"):
        np.testing.assert_array_equal(getattr(again, name), getattr(fresh, name), err_msg=name)
    moved = particles.copy()
    moved.x[rows[0]] += scene.grid.dx * scene.grid.block  # into the next block along the first axis
    assert backend.prepare_rows(moved, rows) is not first
    others = [backend.prepare_rows(particles, np.arange(k, particles.n, 3)) for k in range(KEPT_ROW_SORTS)]
    assert all(backend.prepare_rows(particles, np.arange(k, particles.n, 3)) is b for k, b in enumerate(others))
    assert backend.prepare_rows(particles, rows) is not first  # pushed out by the others


def _plain_numba(scene):
    """The Numba backend without its row stages (as a user's plain backend is): asynchronous stepping gathers for
    it."""
    backend = _numba_backend()(scene)
    for stage in ROW_BACKEND_STAGES:
        setattr(backend, stage, None)
    assert not steps_rows(backend)
    return backend


@needs_numba
def test_a_backend_without_the_row_stages_runs_the_same_bits_through_the_adapter():
    """The pressed disks (levels three apart, conservative interfaces), on the Numba backend with its row stages and
    without them: the same particles, bit for bit, and the same updates."""
    native = Simulation(case.pressed_disks("conservative", intervals=2), backend="numba")
    plain = Simulation(case.pressed_disks("conservative", intervals=2), backend=_plain_numba)
    native.run()
    plain.run()
    assert native.stepper.summary(native.state) == plain.stepper.summary(plain.state)
    assert native.stepper.summary(native.state)["ghost_updates"] > 0
    for name, array in native.particles.arrays().items():
        np.testing.assert_array_equal(array, getattr(plain.particles, name), err_msg=name)


@needs_numba
def test_the_same_bits_on_one_thread_and_two(monkeypatch, parallel_builds):
    """The level updates' stages are the backend's (coloured P2G, a fixed order per node) and the bookkeeping's
    parallel passes only write each particle's own entries: an asynchronous run gives the same bits on one thread
    and on two (with the small scene run in parallel too)."""
    from test_numba_backend import with_threads

    from mpmref.backends.numba import threads as numba_threads

    monkeypatch.setattr(numba_threads, "SERIAL_BELOW", 0)

    def run():
        sim = Simulation(case.pressed_disks("conservative", intervals=2), backend="numba")
        sim.run()
        return sim.particles

    one, two = with_threads(1, run), with_threads(2, run)
    for name, array in one.arrays().items():
        np.testing.assert_array_equal(array, getattr(two, name), err_msg=name)


# ---------------------------------------------------------------------------------------- ordered by step
def test_the_misplaced_rows_are_all_that_moves():
    """Random steps over a prefix of rows: after the moves of :func:`misplaced_rows` the prefix is ordered by step
    (each step's particles one run, finest first), the rows after it and the rows already in their run stay, and
    every particle is still there once."""
    rng = np.random.default_rng(4)
    for _ in range(300):
        top, n = int(rng.integers(0, 6)), int(rng.integers(0, 80))
        level = rng.integers(0, top + 1, size=n + 7)
        n_due = int(rng.integers(0, n + 1))
        src, dst, level_start = misplaced_rows(level, n_due, top)
        runs = np.repeat(np.arange(top + 1), np.diff(level_start))
        out_of_place = np.flatnonzero(level[:n_due] != runs)
        assert np.array_equal(np.sort(src), out_of_place) and np.array_equal(np.sort(dst), out_of_place)
        ids, moved = np.arange(n + 7)[:, None].copy(), level[:, None].copy()
        permute_rows((ids, moved), src, dst)
        assert np.array_equal(moved[:n_due, 0], runs)
        assert np.array_equal(np.sort(ids[:, 0]), np.arange(n + 7))
        stays = np.setdiff1d(np.arange(n + 7), src)
        assert np.array_equal(ids[stays, 0], stays)


class _Checked(AsyncInterval):
    """Checks after every tick that the rows are ordered by step and that each cohort is the run of its step."""

    ticks = 0

    def tick_once(self):
        super().tick_once()
        if self.store is None:
            return
        steps = self.dt_p[:self.n]
        assert np.all(np.diff(steps) >= 0)
        for cohort in self.cohorts:
            assert np.all(steps[cohort.start:cohort.stop] == cohort.D)
        _Checked.ticks += 1


def test_the_rows_stay_ordered_by_step_under_random_level_changes():
    """The census scene with each block's limit drawn at random at every boundary (levels change all the time):
    after every tick the particles' rows are ordered by step and each cohort is one run; rows moved, every id kept."""
    from verification.sync_vs_async.levels import RandomLevels, with_stepper
    from verification.sync_vs_async.scenes import census_scene

    sim = with_stepper(Simulation(census_scene(), backend="numba"), RandomLevels)
    sim.stepper.interval_type = _Checked
    ids = np.sort(sim.id.copy())
    while sim.state.tick < 400:
        sim.step()
    assert _Checked.ticks > 50 and sim.stepper.work.counts["moved_rows"] > 0
    assert np.array_equal(np.sort(sim.id), ids)


# ---------------------------------------------------------------------------------------- what is copied
def test_one_level_is_the_synchronous_step_with_nothing_copied(backend):
    """With one level every interval is one update of every particle and no ghost: the synchronous step of the
    state's particles (no store taken, no row copied or moved, the backend's own stages), bit for bit sync's."""
    tick, steps = 2e-5, 6
    a = Simulation(case.two_bodies(cfl=0.5, tick=tick, levels=0, steps=steps, block=4), backend=backend)
    s = Simulation(case.two_bodies(stepping="sync", dt=tick, steps=steps, block=4), backend=backend)
    a.run()
    s.run()
    counts = a.stepper.work.counts
    assert counts["ghost_rows_copied"] == counts["run_rows_copied"] == counts["moved_rows"] == 0
    assert a.stepper.stores.stores == []
    assert a.stepper.work.level_updates == steps and counts["group_rows"] == steps * a.n_particles
    for name, array in s.particles.arrays().items():
        np.testing.assert_array_equal(getattr(a.particles, name), array, err_msg=name)


def test_an_update_copies_its_ghosts_and_not_its_particles():
    """On the example stork: the rows copied one by one are the ghosts (into spare rows, then the shadows they propose
    and commit), between one and three per ghost update, however many own steps the updates take (a gather of each
    update's group and a scatter of its results copied every own step twice); the rows copied as runs (the state
    into a store, each coarse cohort's shadows at its step's start) are at most twice the particles per interval."""
    from mpmref.scene.factories import example_with_time

    sim = Simulation(example_with_time("stork2d", 0.004))
    sim.run()
    counts, summary, n = sim.stepper.work.counts, sim.stepper.summary(sim.state), sim.n_particles
    ghosts = summary["ghost_updates"]
    assert 0 < ghosts <= counts["ghost_rows_copied"] <= 3 * ghosts
    assert n * sim.step_count <= counts["run_rows_copied"] <= 2 * n * sim.step_count


# ---------------------------------------------------------------------------------------------- the stores
def test_a_store_is_handed_out_again_only_when_no_state_holds_it():
    """The pool's store is reused once nothing outside refers to its rows, kept apart while a state's view of it
    lives, and grows with its rows kept."""
    rng = np.random.default_rng(5)
    p = Particles(x=rng.random((50, 2)), v=rng.random((50, 2)), mass=np.ones(50), vol0=np.ones(50),
                  material=np.zeros(50, dtype=np.int64))
    pool = StorePool()
    first = pool.take(p, spare=10)
    assert first.capacity >= 60 and first.free()
    view = first.live()
    np.testing.assert_array_equal(view.x, p.x)
    second = pool.take(p, spare=10)
    assert second is not first  # a state holds a view of the first
    del view
    assert pool.take(p, spare=10) is first
    bigger = pool.grown(first, spare=500)
    assert bigger.capacity >= 550 and bigger in pool.stores and first not in pool.stores
    np.testing.assert_array_equal(bigger.live().x, p.x)
