"""The Numba backend against the reference: thread-count determinism, trajectories, float32.

Stage-by-stage agreement for every combination is the conformance harness's job
(``tests/test_conformance.py`` runs it on every backend); here are the properties it does not cover.
"""

import tomllib
from pathlib import Path

import numba
import numpy as np
import pytest

from mpmref import Scene
from mpmref.backends import make_backend
from mpmref.backends.numba import threads as numba_threads
from mpmref.backends.numba import twin
from mpmref.errors import BackendError
from mpmref.scene.sampling import sample_particles
from mpmref.steppers import substep

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"


def example(name, **overrides):
    data = tomllib.loads((EXAMPLES / f"{name}.toml").read_text())
    data.update(overrides)
    return Scene.from_dict(data)


def run(backend, particles, steps, dt):
    for k in range(steps):
        particles = substep(backend, particles, dt, k * dt)
    return particles


def with_threads(threads, fn):
    before = numba.get_num_threads()
    numba.set_num_threads(threads)
    try:
        return fn()
    finally:
        numba.set_num_threads(before)


def block_3d(method, material):
    """A jittered 3D block on a 16^3 grid, moving, for the thread-count test."""
    return Scene.from_dict({"dim": 3, "grid": {"size": 1.0, "cells": 16}, "method": method,
                            "materials": {"m": material},
                            "bodies": [{"shape": "box", "material": "m", "lower": [0.3] * 3, "upper": [0.7] * 3,
                                        "ppc": 8, "sampling": "jittered", "seed": 3, "velocity": [0.5, -0.2, 0.1]}],
                            "gravity": [0.0, -9.8, 0.0], "time": {"dt": 1e-4, "steps": 10}})


def wide_layer():
    """The mpm88 fluid as a layer across a 256-cell domain: 60 slabs hold particles, so P2G goes by slabs."""
    data = tomllib.loads((EXAMPLES / "mpm88.toml").read_text())
    data["grid"]["cells"] = 256
    data["bodies"] = [{"shape": "box", "material": next(iter(data["materials"])), "lower": [0.03, 0.1],
                       "upper": [0.97, 0.16], "ppc": 4, "sampling": "jittered", "seed": 5, "velocity": [0.3, -1.0]}]
    return Scene.from_dict(data)


@pytest.mark.parametrize("scene, by_slabs", [(example("mpm88"), False), (wide_layer(), True)], ids=["mpm88", "layer"])
def test_p2g_goes_by_slabs_only_when_each_colour_has_enough(scene, by_slabs):
    """Few slabs (a compact body) are grouped by single blocks in 2^d colours, many by slabs in two; either
    way every particle is in exactly one group (the bitwise test below runs both kinds)."""
    blocks = make_backend("numba", scene).prepare(sample_particles(scene))
    start, groups, colours = blocks.p2g_groups
    assert (len(colours) == 3) == by_slabs and (len(colours) == 5) != by_slabs  # 2 colours, or 2^2
    members = np.concatenate([blocks.order[start[g]:start[g + 1]] for g in groups])
    assert np.array_equal(np.sort(members), np.arange(len(blocks.order)))


@pytest.mark.parametrize("scene", [
    example("mpm88"),
    example("snow88"),
    wide_layer(),
    block_3d({"scheme": "mls"}, {"type": "fluid", "K": 400.0, "gamma": 1.0, "rho": 1.0}),
    # the widest stencil with modes: a fresh Numba cache spends ~17 s compiling it, so it runs with the slow set
    pytest.param(block_3d({"scheme": "polypic", "kernel": "cubic"},
                          {"type": "neo_hookean", "E": 1e3, "nu": 0.3, "rho": 1.0}), marks=pytest.mark.slow),
], ids=["mpm88", "snow88", "layer-by-slabs", "3d-mls-fluid", "3d-polypic-cubic"])
def test_p2g_and_steps_are_bitwise_identical_for_one_and_two_threads_and_the_serial_builds(scene, monkeypatch):
    """Coloured block-parallel P2G has a fixed summation order per node, whatever the thread count; so the kernels
    compiled serially, which a first run uses while their parallel builds compile (:mod:`mpmref.run.first_run`),
    give the same bits."""
    monkeypatch.setattr(numba_threads, "SERIAL_BELOW", 0)  # small scenes would otherwise run on one thread
    backend = make_backend("numba", scene)
    particles = sample_particles(scene)
    stirred = particles.v + 0.5 * np.random.default_rng(7).standard_normal(particles.v.shape)
    particles = particles.with_(v=stirred.astype(particles.v.dtype))  # so that the state gets stressed
    dt = 1e-4

    def p2g_after_steps():
        after = run(backend, particles, 10, dt)
        return backend.p2g(after), after

    with twin.builds("parallel"):
        one = with_threads(1, p2g_after_steps)
        two = with_threads(2, p2g_after_steps)
    with twin.builds("serial"):
        serial = p2g_after_steps()
        assert twin.serial_kernels()
    for other in (two, serial):
        for name in ("mass", "momentum", "force"):
            assert np.array_equal(getattr(one[0], name), getattr(other[0], name)), name
        for name, array in one[1].arrays().items():
            assert np.array_equal(array, other[1].arrays()[name]), name
    assert np.abs(one[0].force).max() > 0  # a stressed state: the force scatter is exercised too


@pytest.mark.parametrize("name, dt, steps", [("mpm88", 2e-4, 200), ("jelly", 1e-4, 200)])
def test_trajectory_stays_within_the_references_own_round_off_sensitivity(name, dt, steps):
    """A multi-step trajectory on the Numba backend stays as close to the reference as the reference stays
    to itself when its initial positions move by one ulp.

    Justification of the tolerance: the two backends evaluate the same expressions with different summation
    orders, so they differ by round-off at every stage; the flow then amplifies any round-off the way it
    amplifies a one-ulp perturbation of the initial state. Running the reference from ``x (1 + 2^-52)``
    measures that amplification independently; the Numba trajectory must stay within 10 times it (plus
    8 ulp of the domain size, the floor of a comparison of positions near 1). A transfer bug of relative
    size 1e-10 in any stage already exceeds the bound after one step.
    """
    scene = example(name)
    particles = sample_particles(scene)
    reference = run(make_backend("numpy", scene), particles, steps, dt)
    perturbed = run(make_backend("numpy", scene), particles.with_(x=particles.x * (1.0 + 2.0**-52)), steps, dt)
    numba_run = run(make_backend("numba", scene), particles, steps, dt)
    for field in ("x", "v"):
        sensitivity = np.abs(getattr(perturbed, field) - getattr(reference, field)).max()
        floor = 8 * np.finfo(float).eps * np.abs(getattr(reference, field)).max()
        difference = np.abs(getattr(numba_run, field) - getattr(reference, field)).max()
        assert difference <= 10 * sensitivity + floor, (field, difference, sensitivity)


def test_float32_step_matches_the_float32_reference_to_single_precision_round_off():
    """In float32 the backends round differently (the reference sums the grid in float64, Numba in float32),
    so one step agrees to a few hundred float32 ulps, not bitwise: bound 1e-4 (~800 eps32) relative to each
    field's scale, for sums of up to 9 contributions per node followed by a division by the node mass. The
    scale of C is that of a velocity gradient, max|v|/dx: a falling block has C = 0 in exact arithmetic."""
    scene = example("jelly", dtype="float32")
    particles = sample_particles(scene)
    reference = substep(make_backend("numpy", scene), particles, 1e-4, 0.0)
    fast = substep(make_backend("numba", scene), particles, 1e-4, 0.0)
    for name, array in reference.arrays().items():
        assert fast.arrays()[name].dtype == array.dtype, name
        scale = np.abs(reference.v).max() / scene.grid.dx if name == "C" else np.abs(array).max()
        assert np.abs(fast.arrays()[name] - array).max() <= 1e-4 * scale, name


def test_unknown_backend_is_refused_with_the_list():
    with pytest.raises(BackendError, match="numpy, numba"):
        make_backend("vulkan", example("mpm88"))


def test_a_state_someone_holds_is_never_overwritten_and_a_plain_loop_swaps_two_buffers():
    """G2P writes into pooled arrays: a run that keeps only its latest state reuses two sets (a double
    buffer, so the state before the latest step survives for a rollback), while every state a caller keeps
    stays bit for bit what it was when it was made."""
    scene = example("mpm88")
    backend = make_backend("numba", scene)
    particles = sample_particles(scene)
    kept = [run(backend, particles, 1, 1e-4)]
    snapshot = {k: a.copy() for k, a in kept[0].arrays().items()}
    for _ in range(3):
        kept.append(run(backend, kept[-1], 1, 1e-4))
    assert len({id(p.x) for p in kept}) == len(kept)  # four states held: four different arrays
    for name, array in kept[0].arrays().items():
        assert np.array_equal(array, snapshot[name]), name

    del kept
    latest, previous = particles, None
    for _ in range(6):
        latest = run(backend, latest, 1, 1e-4)
        assert backend.buffers.holds(latest.x)  # a pooled set, not a new allocation
        assert id(latest.x) != previous  # not the set of the state it was made from
        previous = id(latest.x)  # (an id, not a reference, which would keep that set in use)


def test_buffer_pool_lets_go_of_shapes_no_longer_asked_for():
    """The asynchronous stepper advances groups of many sizes: the pool keeps sets of the latest two shapes
    of a kind only, so its memory does not grow with the number of sizes seen."""
    from mpmref.backends.residency import ArrayPool

    pool = ArrayPool(np.empty, "float32")
    for n in range(1, 50):
        pool.take("particles", (n, 2), (n,))
    pool.take("grid", (7, 5))
    assert pool.nbytes() == 4 * ((48 * 2 + 48) + (49 * 2 + 49) + 7 * 5)
    reused = pool.take("particles", (49, 2), (49,))
    assert pool.holds(reused[0]) and pool.holds(reused[1])


@pytest.mark.parametrize("blocks_per_axis", [(5, 7), (4, 3, 6)])
def test_colour_classes_hold_each_occupied_block_once_by_the_parities_of_its_coordinates(blocks_per_axis):
    """Against the definition, block by block: colour sum_a (b_a mod 2) 2^a, occupied blocks only, in
    increasing block number within a colour (the scan skips empty slabs, never an occupied block)."""
    from mpmref.backends.numba.blocks import colour_classes

    shape = np.array(blocks_per_axis, dtype=np.int64)
    n_blocks = int(np.prod(shape))
    rng = np.random.default_rng(4)
    counts = rng.integers(1, 3, n_blocks) * (rng.random(n_blocks) < 0.4)
    counts[: n_blocks // shape[0]] = 0  # an empty first slab
    block_start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    blocks, start = colour_classes(block_start, shape)
    d = len(shape)
    colour = [sum((i % 2) << a for a, i in enumerate(np.unravel_index(b, shape))) for b in range(n_blocks)]
    expected = [[b for b in range(n_blocks) if counts[b] and colour[b] == c] for c in range(2**d)]
    assert [list(blocks[start[c]:start[c + 1]]) for c in range(2**d)] == expected
