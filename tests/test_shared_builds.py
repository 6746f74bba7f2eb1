"""Two processes compile a first run's serial builds (:mod:`mpmref.backends.numba.shared_builds`; docs/performance.md,
"Two cores compile a first run").

The helper records the kernels of a scene's warm-up step without running them and compiles their serial builds from
the last back; this process compiles from the first on, and waits for what the helper has claimed. Checked here: that
what the helper records is what the run compiles (the same kernels, the same argument types, in the run's order, for
a scene pickled as the helper receives it), that a build is claimed once, that this process waits for a build the
helper compiles and not for one whose helper has ended, and that the helper compiles what it claims and nothing this
process has claimed. tests/test_first_run.py runs a first run from an empty cache, both processes together.
"""

import pickle
import threading
import time
import tomllib
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numba
import numpy as np
import pytest
from helpers import box_scene
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from numba import prange

from mpmref import SceneError
from mpmref.backends.numba import shared_builds, twin
from mpmref.run.simulation import Simulation
from mpmref.scene import Scene
from mpmref.state import Grid
from mpmref.steppers.pipeline import substep

ROOT = Path(__file__).resolve().parent.parent


def squares(x, out):
    for i in prange(x.shape[0]):
        out[i] = x[i] * x[i]


def untypable(x, out):
    out[0] = x.no_such_attribute


def identity(x):
    return x


def cubes(x, out):
    for i in prange(x.shape[0]):
        out[i] = x[i] * x[i] * x[i]


@pytest.fixture
def fresh_cache(tmp_path, monkeypatch):
    """Numba's disk cache in an empty folder for the kernels made within the test."""
    monkeypatch.setattr(numba.config, "CACHE_DIR", str(tmp_path / "numba"))
    return tmp_path


class Spy:
    """A share that runs every kernel and records each call's kernel and argument types, in order, once."""

    def __init__(self):
        self.calls = []

    def admit(self, kernel, build, args):
        call = (kernel, twin.signature_of(kernel.serial, args))
        if call not in self.calls:
            self.calls.append(call)
        return True


def recorded_and_run(scene):
    """What the helper records for ``scene`` (received pickled, as a spawned process receives it), and the calls a
    real warm-up step of the scene makes, both on the serial builds."""
    helper = Simulation(pickle.loads(pickle.dumps(scene)), backend="numba")
    recorder, spy = shared_builds.Recorder(), Spy()
    with twin.builds("serial"):
        with twin.sharing(recorder):
            helper.backend.warm_up(helper.particles, substep)
        with twin.sharing(spy):
            Simulation(scene, backend="numba").backend.warm_up(helper.particles, substep)
    return recorder.calls, spy.calls


def assert_records_what_runs(scene):
    recorded, run = recorded_and_run(scene)
    skipped = [(k, s) for k, s in run if not shared_builds.returns_value(k.py_func)]
    assert recorded == skipped
    assert {k.py_func.__name__ for k, _ in recorded} >= {"p2g", "block_grid_velocity", "g2p"}
    assert all(s in k.serial.overloads for k, s in recorded)  # the types the run compiled for


def example(name, **overrides):
    data = tomllib.loads((ROOT / "examples" / f"{name}.toml").read_text())
    return Scene.from_dict({**data, **overrides})


@pytest.mark.parametrize("example_name, dtype", [("mpm88", "float64"), ("snow_slope2d", "float64"),
                                                 ("snow88", "float32")])
def test_the_helper_records_the_kernels_a_step_compiles_with_their_types_in_order(example_name, dtype):
    assert_records_what_runs(example(example_name, dtype=dtype))


@pytest.mark.slow  # every drawn scene compiles its own kernels
@settings(max_examples=10)
@given(dim=st.sampled_from([2, 3]), scheme=st.sampled_from(["pic", "flip", "apic", "mls", "polypic"]),
       material=st.sampled_from(["fixed_corotated", "neo_hookean", "fluid", "snow", "sand"]),
       walls=st.sampled_from(["open", "sticky", "slip", "separate"]),
       kernel=st.sampled_from(["linear", "quadratic", "cubic"]), dtype=st.sampled_from(["float64", "float32"]))
def test_on_drawn_scenes_the_helper_records_what_the_step_compiles(dim, scheme, material, walls, kernel, dtype):
    try:
        scene = box_scene(dim, scheme, cells=8, material=material, walls=walls, kernel=kernel,
                          force="mls" if scheme == "mls" else "classic")
    except SceneError:  # a combination the scene rules refuse
        assume(False)
    assert_records_what_runs(replace(scene, dtype=np.dtype(dtype)))


@pytest.mark.slow  # the CPIC kernels of a scene with rigid bodies
def test_with_rigid_bodies_the_helper_records_the_cpic_kernels_too():
    recorded, run = recorded_and_run(example("cut2d"))
    assert recorded == [(k, s) for k, s in run if not shared_builds.returns_value(k.py_func)]
    assert "tags" in {k.py_func.__name__ for k, _ in recorded}


def test_a_pickled_grid_computes_its_read_only_strides_again():
    grid = Grid(np.zeros(2), 0.1, (4, 4))
    assert not grid.strides.flags.writeable
    copy = pickle.loads(pickle.dumps(grid))
    assert not copy.strides.flags.writeable and np.array_equal(copy.strides, grid.strides)


def test_a_build_is_claimed_once_and_a_removed_folder_claims_nothing(tmp_path):
    claims = shared_builds.Claims(str(tmp_path))
    assert claims.take("k") and not claims.take("k") and not claims.finished("k")
    claims.finish("k")
    assert claims.finished("k")
    assert not shared_builds.Claims(str(tmp_path / "gone")).take("k")


def test_the_claim_key_is_numbas_cache_key_of_the_build(fresh_cache):
    a, b = twin.parallel_kernel(squares, cache=True), twin.parallel_kernel(cubes, cache=True)
    x = np.ones(3)
    sig = twin.signature_of(a.serial, (x, x))
    key = shared_builds.claim_key(a.serial, sig)
    assert key == shared_builds.claim_key(twin.parallel_kernel(squares, cache=True).serial, sig)  # another process's
    assert key != shared_builds.claim_key(a.parallel, sig)  # the parallel build is another function
    assert key != shared_builds.claim_key(b.serial, sig)
    assert key != shared_builds.claim_key(a.serial, twin.signature_of(a.serial, (x.astype(np.float32),) * 2))


def helper_of(folder, alive=lambda: True):
    return SimpleNamespace(claims=shared_builds.Claims(str(folder)), alive=alive)


def test_this_process_waits_for_a_build_the_helper_compiles_and_then_loads_it(fresh_cache):
    kernel, x = twin.parallel_kernel(squares, cache=True), np.arange(4.0)
    helper = helper_of(fresh_cache)
    sig = twin.signature_of(kernel.serial, (x, x))
    key = shared_builds.claim_key(kernel.serial, sig)
    assert helper.claims.take(key)  # the helper's claim

    def compile_elsewhere():  # as the helper would: another copy of the kernel, cached on disk
        twin.parallel_kernel(squares, cache=True).serial.compile(sig)
        helper.claims.finish(key)

    leader = shared_builds.Leader(lambda: helper)
    timer = threading.Timer(0.3, compile_elsewhere)
    start = time.perf_counter()
    timer.start()
    assert leader.admit(kernel, kernel.serial, (x, x))
    assert time.perf_counter() - start >= 0.3 and helper.claims.finished(key)
    assert sig not in kernel.serial.overloads  # not compiled here while waiting
    assert twin.cached_build(kernel.serial, sig)  # but in the cache the other copy wrote


def test_this_process_does_not_wait_for_a_helper_that_has_ended(fresh_cache):
    kernel, x = twin.parallel_kernel(squares, cache=True), np.arange(4.0)
    helper = helper_of(fresh_cache, alive=lambda: False)
    helper.claims.take(shared_builds.claim_key(kernel.serial, twin.signature_of(kernel.serial, (x, x))))
    start = time.perf_counter()
    assert shared_builds.Leader(lambda: helper).admit(kernel, kernel.serial, (x, x))
    assert time.perf_counter() - start < 0.25


def test_the_helper_starts_at_the_first_build_to_compile_and_claims_it_for_this_process(fresh_cache):
    kernel, x = twin.parallel_kernel(squares, cache=True), np.arange(4.0)
    started = []
    leader = shared_builds.Leader(lambda: started.append(helper_of(fresh_cache)) or started[0])
    out = np.empty(4)
    with twin.builds("serial"), twin.sharing(leader):
        kernel(x, out)
        kernel(x, out)
    assert len(started) == 1 and np.array_equal(out, x * x)
    key = shared_builds.claim_key(kernel.serial, twin.signature_of(kernel.serial, (x, x)))
    assert not started[0].claims.take(key)  # this process's claim: the helper skips it


def test_the_helper_compiles_what_it_claims_from_the_last_call_back_and_skips_the_claimed(fresh_cache):
    first, last = twin.parallel_kernel(squares, cache=True), twin.parallel_kernel(cubes, cache=True)
    x = np.arange(4.0)
    calls = [(k, twin.signature_of(k.serial, (x, x))) for k in (first, last)]
    claims = shared_builds.Claims(str(fresh_cache))
    claims.take(shared_builds.claim_key(first.serial, calls[0][1]))  # this process compiles the first
    shared_builds.compile_recorded(calls, claims)
    assert calls[1][1] in last.serial.overloads and claims.finished(shared_builds.claim_key(last.serial, calls[1][1]))
    assert calls[0][1] not in first.serial.overloads
    assert all(s in k.parallel.overloads for k, s in calls)  # then every parallel build


def test_a_build_that_fails_in_the_helper_is_released_and_the_helper_goes_on(fresh_cache):
    broken, fine = twin.parallel_kernel(untypable, cache=True), twin.parallel_kernel(squares, cache=True)
    x = np.arange(4.0)
    calls = [(k, twin.signature_of(k.serial, (x, x))) for k in (fine, broken)]
    claims = shared_builds.Claims(str(fresh_cache))
    with pytest.raises(numba.core.errors.TypingError):  # the helper's parallel phase, as before: the run stays serial
        shared_builds.compile_recorded(calls, claims)
    assert claims.finished(shared_builds.claim_key(broken.serial, calls[1][1]))  # the run waits for it no longer
    assert calls[0][1] in fine.serial.overloads  # and the helper went on to the next


def test_a_kernel_that_returns_a_value_runs_while_recording_the_others_are_skipped():
    assert shared_builds.returns_value(identity) and not shared_builds.returns_value(squares)
    kernel, x, out = twin.parallel_kernel(squares, cache=False), np.arange(3.0), np.zeros(3)
    recorder = shared_builds.Recorder()
    with twin.builds("serial"), twin.sharing(recorder):
        assert kernel(x, out) is None
    assert not out.any() and [k for k, _ in recorder.calls] == [kernel]
