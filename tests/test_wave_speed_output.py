"""The return map's output ``wave_speed`` (mpmref.backends.base): each stepped particle's wave speed in its new state,
bit for bit the separate pass's, on each material and backend, for a whole step and for a step of some rows.

The separate pass is the backend's own ``wave_speeds`` stage (what asynchronous stepping read before): for the NumPy
reference that is :func:`mpmref.steppers.limits.wave_speeds` bit for bit; the Numba backend's compiled laws agree with
it to round-off (``math.pow``, ``math.log`` against NumPy's), not bit for bit, as they did before."""

import numpy as np
import pytest
from test_async import _two_level_scene

from mpmref import Scene, Simulation
from mpmref.backends import make_backend
from mpmref.backends.base import gives_wave_speeds
from mpmref.scene.sampling import sample_particles
from mpmref.steppers import substep
from mpmref.steppers.limits import wave_speeds
from verification.sync_vs_async import two_bodies

MATERIALS = {
    "fixed_corotated": {"type": "fixed_corotated", "E": 400.0, "nu": 0.3, "rho": 1.0},
    "neo_hookean": {"type": "neo_hookean", "E": 400.0, "nu": 0.3, "rho": 1.0},
    "fluid": {"type": "fluid", "K": 40.0, "gamma": 7.0, "rho": 1.0},
    "snow": {"type": "snow", "E": 400.0, "nu": 0.2, "rho": 1.0, "theta_c": 0.01, "theta_s": 0.003},
    "sand": {"type": "sand", "E": 400.0, "nu": 0.3, "rho": 1.0},
}


def scene_of(material):
    """A jittered block of ``material`` thrown at the floor, on a 32-cell grid (2D)."""
    return Scene.from_dict({"dim": 2, "grid": {"size": 1.0, "cells": 32}, "method": {"scheme": "apic"},
                            "materials": {"m": MATERIALS[material]},
                            "bodies": [{"shape": "box", "material": "m", "lower": [0.3, 0.2], "upper": [0.6, 0.45],
                                        "ppc": 4, "sampling": "jittered", "seed": 2, "velocity": [1.0, -3.0]}],
                            "gravity": [0.0, -9.8], "time": {"dt": 5e-4, "steps": 4}})


def same_as_pass(name, backend, scene, c, particles, rows=None):
    """Whether ``c`` is bit for bit the backend's own pass over ``particles`` (the rows ``rows``), and, for the
    reference, :func:`~mpmref.steppers.limits.wave_speeds`; the Numba pass within 1e-12 of it."""
    idx = np.arange(particles.n) if rows is None else rows
    reference = wave_speeds(scene.material_list, particles.select(idx))
    own = backend.wave_speeds(particles, idx)
    close = np.allclose(own, reference, rtol=1e-12, atol=0.0)
    return np.array_equal(c, own) and close and (name != "numpy" or np.array_equal(c, reference))


def deformed(backend, particles, steps=6, dt=5e-4):
    """``particles`` with their deformation perturbed at random (beyond the yield surfaces of snow and sand), then
    ``steps`` steps."""
    rng = np.random.default_rng(7)
    n, d = particles.x.shape
    if particles.F is not None:
        particles.F = particles.F + 0.04 * rng.standard_normal((n, d, d))
    if particles.J is not None:
        particles.J = particles.J * (1.0 + 0.03 * rng.standard_normal(n))
    for k in range(steps):
        particles = substep(backend, particles, dt, k * dt)
    return particles


@pytest.mark.parametrize("material", list(MATERIALS))
@pytest.mark.parametrize("name", ["numpy", "numba"])
def test_the_return_maps_wave_speed_is_the_separate_pass_bit_for_bit(name, material):
    scene = scene_of(material)
    backend = make_backend(name, scene)
    assert gives_wave_speeds(backend)
    particles = deformed(backend, sample_particles(scene))
    c = np.full(particles.n, np.nan)
    new = substep(backend, particles, 5e-4, 0.0, wave_speed=c)
    assert same_as_pass(name, backend, scene, c, new)
    expected = wave_speeds(scene.material_list, new)
    if material in ("snow", "sand"):  # the projection changed some F: the speed is the projected state's
        trial = backend.g2p(particles, *backend.grid_update(backend.p2g(particles), 5e-4, 0.0), 5e-4)
        assert not np.array_equal(wave_speeds(scene.material_list, trial), expected)


@pytest.mark.parametrize("material", list(MATERIALS))
@pytest.mark.parametrize("name", ["numpy", "numba"])
def test_a_step_of_some_rows_writes_their_wave_speeds_and_no_other(name, material):
    scene = scene_of(material)
    backend = make_backend(name, scene)
    particles = deformed(backend, sample_particles(scene))
    rows = np.arange(3, particles.n - 5, 2, dtype=np.int64)
    c = np.full(particles.n, -1.0)
    stepped = particles.select(np.arange(particles.n))
    substep(backend, stepped, 5e-4, 0.0, rows=rows, wave_speed=c)
    assert same_as_pass(name, backend, scene, c[rows], stepped, rows)
    others = np.setdiff1d(np.arange(particles.n), rows)
    assert np.all(c[others] == -1.0)


def test_a_mixed_scene_gives_each_material_its_own_rule():
    data = {"dim": 2, "grid": {"size": 1.0, "cells": 32}, "method": {"scheme": "apic"},
            "materials": {k: v for k, v in MATERIALS.items()},
            "bodies": [{"shape": "box", "material": k, "lower": [0.1 + 0.16 * i, 0.2], "upper": [0.22 + 0.16 * i, 0.4],
                        "ppc": 4, "sampling": "jittered", "seed": i, "velocity": [0.5, -2.0]}
                       for i, k in enumerate(MATERIALS)],
            "gravity": [0.0, -9.8], "time": {"dt": 5e-4, "steps": 4}}
    scene = Scene.from_dict(data)
    for name in ("numpy", "numba"):
        backend = make_backend(name, scene)
        particles = deformed(backend, sample_particles(scene), steps=3)
        c = np.full(particles.n, np.nan)
        new = substep(backend, particles, 5e-4, 0.0, wave_speed=c)
        assert same_as_pass(name, backend, scene, c, new), name


@pytest.mark.parametrize("material", list(MATERIALS))
@pytest.mark.parametrize("name", ["numpy", "numba"])
def test_asynchronous_stepping_on_the_steps_wave_speeds_is_the_run_on_the_pass_bit_for_bit(name, material):
    """Two levels of ``material``: the level rule reading each particle's wave speed from its last update gives the
    run that a pass at every step boundary gives, bit for bit; the pass runs once, at the first interval."""
    scene = _two_level_scene(2, {"scheme": "mls"}, material)
    runs = []
    for from_step in (True, False):
        sim = Simulation(scene, backend=name)
        sim.stepper.speeds_from_step = from_step
        backend = sim.stepper.backend
        calls = []
        own_pass = backend.wave_speeds

        def counted(particles, idx, own_pass=own_pass, calls=calls):
            calls.append(idx.size)
            return own_pass(particles, idx)

        backend.wave_speeds = counted
        for _ in range(3):
            sim.step()
        runs.append((sim, calls))
    (fast, fast_calls), (slow, slow_calls) = runs
    assert len(set(fast.particles.level.tolist())) >= 2
    assert fast_calls == [fast.n_particles] and len(slow_calls) > 3
    for field in ("x", "v", "C", "F", "J", "Jp", "level", "id"):
        a, b = getattr(fast.particles, field), getattr(slow.particles, field)
        assert (a is None) == (b is None) and (a is None or np.array_equal(a, b)), field
    for key, value in fast.state.stepper.items():
        assert np.array_equal(value, slow.state.stepper[key]), key


@pytest.mark.parametrize("name", ["numpy", "numba"])
def test_an_asynchronous_run_resumed_from_its_checkpoint_is_bit_identical(name, tmp_path):
    """The resumed run starts from the backend's pass (no speeds carried over a checkpoint), the full run from the
    speeds its updates left: the same bits, on both backends."""
    scene = two_bodies(cfl=0.4, tick=1e-5, levels=6, steps=6)
    full = Simulation(scene, backend=name, out_dir=tmp_path / "full")
    full.run(steps=6)
    Simulation(scene, backend=name, out_dir=tmp_path / "half").run(steps=3)
    resumed = Simulation.resume(scene, tmp_path / "half", backend=name)
    resumed.run(steps=3)
    assert len(set(full.particles.level.tolist())) >= 2
    for field, array in full.particles.arrays().items():
        assert np.array_equal(array, getattr(resumed.particles, field)), field
    for key, value in full.state.stepper.items():
        assert np.array_equal(value, resumed.state.stepper[key]), key
