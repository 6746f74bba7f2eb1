"""The Numba backend runs every material of a class in one call (its kernels read each particle's parameter row by
the particle's material index: :class:`mpmref.backends.base.EachParticlesMaterial`). Checked on drawn scenes unlike
the examples: one to five materials, of any classes and parameters, repeated or not, the particles assigned to them
at random (some materials left with none), at random rows, some particles exactly at rest (F = I, J = 1), in float64
and float32: the stress and the return map with its wave speeds are the NumPy reference's, which calls each material
apart, to the harness's bound, and each stage makes one call per class present."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from mpmref import Scene
from mpmref.backends import make_backend
from mpmref.conformance.case import DEFAULT_RTOL
from mpmref.scene.sampling import sample_particles

#: the harness's bounds on agreement, by dtype (docs/conformance.md)
RTOL = DEFAULT_RTOL

#: each class with ranges of its parameters (the plastic ones near their yield surfaces)
CLASSES = {
    "fixed_corotated": lambda e, nu: {"type": "fixed_corotated", "E": e, "nu": nu, "rho": 1.0},
    "neo_hookean": lambda e, nu: {"type": "neo_hookean", "E": e, "nu": nu, "rho": 2.0},
    "fluid": lambda e, nu: {"type": "fluid", "K": e / 10.0, "gamma": 1.0 + 20.0 * nu, "rho": 1.0},
    "snow": lambda e, nu: {"type": "snow", "E": e, "nu": nu, "rho": 1.0, "theta_c": 0.01, "theta_s": 0.003},
    "sand": lambda e, nu: {"type": "sand", "E": e, "nu": nu, "rho": 1.5},
}

materials = st.lists(st.tuples(st.sampled_from(sorted(CLASSES)), st.floats(100.0, 1e4), st.floats(0.05, 0.45)),
                     min_size=1, max_size=5)


def scene_of(drawn, dtype):
    """A 2D scene with one small box per drawn material (so that the scene holds every field they need)."""
    return Scene.from_dict({
        "dim": 2, "dtype": dtype, "grid": {"size": 1.0, "cells": 16}, "method": {"scheme": "apic"},
        "materials": {f"m{i}": CLASSES[kind](e, nu) for i, (kind, e, nu) in enumerate(drawn)},
        "bodies": [{"shape": "box", "material": f"m{i}", "lower": [0.2, 0.1 + 0.12 * i],
                    "upper": [0.3, 0.2 + 0.12 * i], "ppc": 4} for i in range(len(drawn))],
        "gravity": [0.0, -9.8], "time": {"dt": 1e-4, "steps": 1}})


def relative(a, b):
    scale = np.linalg.norm(b)
    return np.linalg.norm(a - b) / scale if scale > 0 else np.linalg.norm(a)


@settings(max_examples=25, deadline=None)
@given(drawn=materials, seed=st.integers(0, 2**16), every_row=st.booleans(), at_rest=st.floats(0.0, 1.0),
       dtype=st.sampled_from(["float64", "float32"]))
def test_one_call_per_class_gives_each_particle_its_own_materials_law(drawn, seed, every_row, at_rest, dtype):
    scene = scene_of(drawn, dtype)
    rng = np.random.default_rng(seed)
    particles = sample_particles(scene)
    n, d = particles.x.shape
    used = rng.choice(len(drawn), rng.integers(1, len(drawn) + 1), replace=False)  # the others keep no particle
    particles.material = used[rng.integers(0, used.size, n)].astype(particles.material.dtype)
    resting = rng.random(n) < at_rest  # F = I, J = 1 exactly: zero stress, the rest state's wave speed
    if particles.F is not None:
        F = np.eye(d) + 0.05 * rng.standard_normal((n, d, d))
        F[resting] = np.eye(d)
        particles.F = F.astype(dtype)
    if particles.J is not None:
        particles.J = np.where(resting, 1.0, 1.0 + 0.05 * rng.standard_normal(n)).astype(dtype)
    if particles.Jp is not None:
        particles.Jp = (1.0 + 0.02 * rng.standard_normal(n)).astype(dtype)
    rows = np.arange(n) if every_row else np.sort(rng.choice(n, n // 2, replace=False)).astype(np.int64)
    numba, numpy = (make_backend(name, scene).materials for name in ("numba", "numpy"))

    classes = {type(scene.material_list[m]) for m in np.unique(particles.material[rows])}
    assert len(numba.groups(particles, rows)) == len(classes)
    assert len(numpy.groups(particles, rows)) == len(np.unique(particles.material[rows]))

    tau = {}
    for name, table in (("numba", numba), ("numpy", numpy)):
        tau[name] = np.zeros((n, d, d), dtype)
        table.stress_into(particles, rows, tau[name])
    assert relative(tau["numba"][rows], tau["numpy"][rows]) <= RTOL[dtype]

    projected, speeds = {}, {}
    for name, table in (("numba", numba), ("numpy", numpy)):
        projected[name] = particles.select(np.arange(n))
        speeds[name] = np.full(n, -1.0)
        table.return_map_rows(projected[name], rows, speeds[name])
    assert relative(speeds["numba"][rows], speeds["numpy"][rows]) <= RTOL[dtype]
    assert np.all(speeds["numba"][np.setdiff1d(np.arange(n), rows)] == -1.0)
    for field in ("F", "Jp"):
        if getattr(particles, field) is not None:
            assert relative(getattr(projected["numba"], field), getattr(projected["numpy"], field)) <= RTOL[dtype]
