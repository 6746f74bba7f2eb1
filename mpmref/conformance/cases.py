"""Conformance cases: which scenes each stage is checked on, and the seeded random state of each case.

Every case is one stage on one scene. The scene is an 8^d-cell unit box declared as a plain dict (the
TOML structure, so that it can be written to ``manifest.json``); the state is drawn from a generator
seeded by the case's name, so a case is the same on every machine and adding cases changes no other.
Why each stage varies only some axes is explained in :mod:`mpmref.conformance`.
"""

import zlib
from dataclasses import dataclass, field
from functools import partial
from itertools import product

import numpy as np

from ..backends import make_backend
from ..errors import SceneError
from ..physics.kernels import KERNELS, compute_stencil
from ..physics.polypic import higher_modes
from ..scene import CPIC_SCHEMES, FORCES, SCHEMES, Scene
from .cpic import RUNNERS, cpic_scene_dict, random_cpic_state, reference_grid_velocity
from .stages import (ALL_CONFORMANCE_STAGES, CONFORMANCE_STAGES, CPIC_CONFORMANCE_STAGES, composed_step, particles_from,
                     run_stage)

CELLS = 8
#: particles stay at least this many cells away from every face of the domain
EDGE_CELLS = 2
N_PARTICLES = {2: 64, 3: 128}
#: smallest per-axis kernel weight a particle may have (see :func:`random_positions`)
MIN_WEIGHT = 1.0e-4
DT = 1.0e-3
TIME = 0.05
GRAVITY = [0.3, -9.8, 0.5]
#: default pass threshold on the relative error, per dtype. In float32 the reference itself lies within
#: 1e-6 of the float64 result on the same inputs (9.2e-7 measured, PolyPIC modes); 1e-5 leaves ten times
#: that for the candidate's own rounding.
DEFAULT_RTOL = {"float64": 1.0e-12, "float32": 1.0e-5}

MATERIALS = {
    "fixed_corotated": {"type": "fixed_corotated", "E": 1.0e3, "nu": 0.3, "rho": 1.0},
    "neo_hookean": {"type": "neo_hookean", "E": 2.0e3, "nu": 0.35, "rho": 1.5},
    "fluid": {"type": "fluid", "K": 400.0, "gamma": 7.0, "rho": 1.0},
    "snow": {"type": "snow", "E": 1.4e3, "nu": 0.2, "rho": 0.4},
    "sand": {"type": "sand", "E": 3.5e3, "nu": 0.3, "rho": 1.6, "friction_angle": 30.0, "cohesion": 0.01},
}
#: material sets of the stress, return-map and per-material step cases: each material alone, then all together
MATERIAL_SETS = {**{name: (name,) for name in MATERIALS}, "mixed": tuple(MATERIALS)}
PLASTIC_SETS = ("snow", "sand", "mixed")
#: the material set of the per-method cases: a solid (F update) and the fluid (J update)
TRANSFER_MATERIALS = ("fixed_corotated", "fluid")
MIXED_WALLS = {"x_min": {"type": "sticky"}, "x_max": {"type": "slip"},
               "y_min": {"type": "separate", "friction": 0.5}, "y_max": {"type": "open"},
               "z_min": {"type": "separate", "friction": 0.0}, "z_max": {"type": "sticky"}}
UNIFORM_WALLS = {"sticky": {"type": "sticky"}, "slip": {"type": "slip"},
                 "separate": {"type": "separate", "friction": 0.3}, "open": {"type": "open"}}


# ------------------------------------------------------------------------------------------ scenes
def mixed_walls(dim):
    """A boundary with a different wall type on each face (catches walls applied to the wrong face)."""
    return {"type": "open", "walls": {k: dict(w) for k, w in MIXED_WALLS.items() if k[0] in "xyz"[:dim]}}


def collider_dicts(dim):
    """One collider of each shape and boundary type for a ``dim``-D scene, two of them moving."""
    pad = [0.0] * (dim - 2)
    colliders = [
        {"shape": "plane", "type": "slip", "point": [0.0, 0.3] + pad, "normal": [0.2, 1.0] + pad,
         "velocity": [0.0, 0.1] + pad},
        {"shape": "disk" if dim == 2 else "sphere", "type": "separate", "friction": 0.4, "center": [0.5] * dim,
         "radius": 0.2, "velocity": [1.0, -0.5] + pad},
        {"shape": "box", "type": "sticky", "lower": [0.7] * dim, "upper": [0.9] * dim},
    ]
    if dim == 3:
        colliders.append({"shape": "cylinder", "type": "separate", "friction": 0.1, "point": [0.2, 0.75, 0.0],
                          "axis": [0.0, 0.0, 1.0], "radius": 0.15})
    return colliders


def scene_dict(dim, materials, method=None, boundary=None, colliders=(), dtype="float64"):
    """The declaration of a case's scene: unit box of ``CELLS`` cells per axis, gravity, the given materials.

    ``boundary`` defaults to :func:`mixed_walls`. The one body only makes the scene valid; the cases draw
    their own particles.
    """
    return {"name": "conformance", "dim": dim, "dtype": dtype, "grid": {"size": 1.0, "cells": CELLS},
            "method": dict(method or {}), "materials": {name: dict(MATERIALS[name]) for name in materials},
            "bodies": [{"shape": "box", "material": materials[0], "lower": [0.25] * dim, "upper": [0.75] * dim}],
            "gravity": GRAVITY[:dim], "boundary": boundary or mixed_walls(dim),
            "colliders": [dict(c) for c in colliders], "time": {"dt": DT}}


def valid_methods():
    """Every ``{"scheme", "force", "kernel"}`` combination that the scene validator accepts, plus APIC
    (quadratic) with the velocity gradient of the other force (the force/F-update ablation of the
    convergence case)."""
    methods = []
    for scheme, force, kernel in product(SCHEMES, FORCES, KERNELS):
        method = {"scheme": scheme, "force": force, "kernel": kernel}
        try:
            Scene.from_dict(scene_dict(2, TRANSFER_MATERIALS, method=method))
        except SceneError:
            continue
        methods.append(method)
    crossed = [dict(m, velocity_gradient=g) for m in methods if m["scheme"] == "apic" and m["kernel"] == "quadratic"
               for g in FORCES if g != m["force"]]
    return methods + crossed


def method_label(method):
    gradient = method.get("velocity_gradient", method["force"])
    suffix = "" if gradient == method["force"] else f"-gradient-{gradient}"
    return f"{method['scheme']}-{method['force']}-{method['kernel']}{suffix}"


# ------------------------------------------------------------------------------------------- states
def random_rotations(rng, n, dim):
    """``n`` uniformly random proper rotations (QR of Gaussian matrices with the sign fixed)."""
    q, r = np.linalg.qr(rng.standard_normal((n, dim, dim)))
    q = q * np.sign(np.diagonal(r, axis1=1, axis2=2))[:, None, :]
    q[np.linalg.det(q) < 0, :, 0] *= -1.0
    return q


def random_deformation_gradients(rng, n, dim, min_det=0.3):
    """``F = R (I + s G)``: random rotation ``R``, Gaussian ``G``, ``s`` log-uniform in [1e-3, 0.2]; det F > min_det.

    Small ``s`` leave snow and sand inside their yield surface, large ones outside, so both branches of each
    return map are exercised.
    """
    F = np.empty((n, dim, dim))
    todo = np.arange(n)
    while todo.size:
        s = np.exp(rng.uniform(np.log(1e-3), np.log(0.2), todo.size))
        stretch = np.eye(dim) + s[:, None, None] * rng.standard_normal((todo.size, dim, dim))
        F[todo] = random_rotations(rng, todo.size, dim) @ stretch
        todo = todo[np.linalg.det(F[todo]) <= min_det]
    return F


def random_modes(rng, n, dim, support, dx):
    """PolyPIC coefficients scaled by ``dx^-degree``, so that each mode adds O(0.1) to a node's velocity."""
    degree = higher_modes(dim, support).sum(axis=1)
    return 0.1 * rng.standard_normal((n, len(degree), dim)) / (dx ** degree)[None, :, None]


def random_positions(scene, rng, n):
    """``n`` positions at least ``EDGE_CELLS`` cells inside the domain whose per-axis kernel weights are all
    at least ``MIN_WEIGHT``.

    Where a particle's outermost weight vanishes (at cell centres for the quadratic B-spline, on nodes for
    the cubic), PolyPIC's top mode norms vanish too and G2P divides by them: there a 1e-15 relative change of
    the inputs moved the output modes by up to 2.5e-7 relative, so no threshold near round-off could be
    asked of a correct implementation. With the margin the same perturbation moves every output by < 1e-13.
    """
    grid = scene.grid
    lo = grid.origin + EDGE_CELLS * grid.dx
    hi = grid.origin + (np.array(grid.cells) - EDGE_CELLS) * grid.dx
    x = np.empty((0, scene.dim))
    while len(x) < n:
        trial = lo + (hi - lo) * rng.random((n, scene.dim))
        weights = compute_stencil(scene.kernel, trial, grid.origin, grid.dx).w
        x = np.concatenate([x, trial[weights.min(axis=(1, 2)) >= MIN_WEIGHT]])
    return x[:n]


def random_particles(scene, rng):
    """A particle state for ``scene`` as a flat dict.

    Positions from :func:`random_positions`; random materials of the scene; volume a quarter cell (2D) or
    an eighth (3D) within ±20 %; mass ``rho * vol0``; velocities N(0, 1); ``C`` N(0, 4^2); ``F`` from
    :func:`random_deformation_gradients`; ``J`` in [0.9, 1.1]; ``Jp`` in [0.7, 1.2]; PolyPIC modes from
    :func:`random_modes`. ``C``, ``F``, ``J``, ``Jp`` and ``modes`` only where the scene needs them.
    """
    grid, dim = scene.grid, scene.dim
    n = N_PARTICLES[dim]
    material = rng.integers(len(scene.materials), size=n).astype(np.int32)
    vol0 = grid.dx**dim / 2**dim * rng.uniform(0.8, 1.2, n)
    rho = np.array([m.rho for m in scene.material_list])[material]
    flat = {"x": random_positions(scene, rng, n), "v": rng.standard_normal((n, dim)), "mass": rho * vol0,
            "vol0": vol0, "material": material}
    if scene.transfer.affine:
        flat["C"] = 4.0 * rng.standard_normal((n, dim, dim))
    if scene.tracks("F"):
        flat["F"] = random_deformation_gradients(rng, n, dim)
    if scene.tracks("J"):
        flat["J"] = rng.uniform(0.9, 1.1, n)
    if scene.tracks("Jp"):
        flat["Jp"] = rng.uniform(0.7, 1.2, n)
    if scene.transfer.polypic:
        flat["modes"] = random_modes(rng, n, dim, scene.kernel.support, grid.dx)
    return flat


def random_grid(scene, rng):
    """Grid state after a P2G: a quarter of the nodes empty, the others with mass in [0.2, 1.5] x rho dx^d,
    velocity N(0, 1) and force mass x N(0, 50^2) (so that dt f / m is a few percent of v)."""
    n_nodes, dim = scene.grid.n_nodes, scene.dim
    mass = scene.grid.dx**dim * rng.uniform(0.2, 1.5, n_nodes) * (rng.random(n_nodes) >= 0.25)
    return {"grid_mass": mass, "grid_momentum": mass[:, None] * rng.standard_normal((n_nodes, dim)),
            "grid_force": mass[:, None] * 50.0 * rng.standard_normal((n_nodes, dim))}


def reference_grid_velocities(scene, flat):
    """``grid_v`` and ``grid_v_tilde`` of the reference P2G and grid update of the particles ``flat``."""
    backend = make_backend("numpy", scene)
    v, v_tilde = backend.grid_update(backend.p2g(particles_from(flat)), DT, TIME)
    return {"grid_v": v, "grid_v_tilde": v_tilde}


def _as_dtype(flat, dtype):
    """Floating arrays of ``flat`` in ``dtype``; integer arrays and 0-d scalars unchanged."""
    return {k: a.astype(dtype) if a.ndim and a.dtype.kind == "f" else a for k, a in flat.items()}


# -------------------------------------------------------------------------------------------- cases
@dataclass(frozen=True, eq=False)
class Case:
    """One stage of a backend on one scene, with a seeded random state.

    Attributes
    ----------
    stage : str        one of :data:`~mpmref.conformance.stages.CONFORMANCE_STAGES`
    dim : int          2 or 3
    variant : str      what the case varies: a material set, a method ``scheme-force-kernel``, a boundary
    scene_dict : dict  the scene, as :meth:`mpmref.scene.Scene.from_dict` takes it
    dtype : str        ``"float64"`` or ``"float32"``
    """

    stage: str
    dim: int
    variant: str
    scene_dict: dict = field(repr=False)
    dtype: str = "float64"

    @property
    def name(self):
        """Unique, file-name safe: ``stage-<dim>d-variant`` (plus ``-f32`` in float32)."""
        suffix = "-f32" if self.dtype == "float32" else ""
        return f"{self.stage}-{self.dim}d-{self.variant}{suffix}"

    @property
    def seed(self):
        """Seed of the state: CRC-32 of the name without the dtype (a float32 case rounds the float64 state)."""
        return zlib.crc32(f"{self.stage}-{self.dim}d-{self.variant}".encode())

    @property
    def rtol(self):
        return DEFAULT_RTOL[self.dtype]

    def scene(self):
        return Scene.from_dict(self.scene_dict)

    def inputs(self):
        """The stage's inputs as a flat dict of arrays (same result on every call)."""
        scene, rng = self.scene(), np.random.default_rng(self.seed)
        if self.stage in CPIC_CONFORMANCE_STAGES:
            return _as_dtype(cpic_inputs(self.stage, scene, rng), self.dtype)
        if self.stage == "grid_update":
            flat = random_grid(scene, rng)
        else:
            flat = random_particles(scene, rng)
        if self.stage == "g2p":
            flat.update(reference_grid_velocities(scene, flat))
        if self.stage in ("grid_update", "g2p", "step"):
            flat["dt"] = np.array(DT)
        if self.stage in ("grid_update", "step"):
            flat["time"] = np.array(TIME)
        return _as_dtype(flat, self.dtype)

    def reference(self, inputs=None):
        """The NumPy reference's outputs of the stage on ``inputs`` (default: :meth:`inputs`), a flat dict."""
        backend = make_backend("numpy", self.scene())
        fn = backend_stage(backend, self.stage)
        return run_stage(self.stage, fn, self.inputs() if inputs is None else inputs)


def backend_stage(backend, stage):
    """The callable of ``stage`` for a backend object (``step``: the pipeline over its stages; CPIC stages:
    their runners of :mod:`mpmref.conformance.cpic` bound to it)."""
    if stage == "step":
        return partial(composed_step, backend)
    if stage in CPIC_CONFORMANCE_STAGES:
        return partial(RUNNERS[stage], backend)
    return getattr(backend, stage)


def cpic_inputs(stage, scene, rng):
    """A CPIC stage's inputs: :func:`random_particles`, previous tags and bodies (:func:`.cpic.random_cpic_state`),
    ``dt``, ``time`` and, for ``cpic_g2p``, the reference's ``grid_v`` of that state."""
    flat = random_cpic_state(scene, rng, random_particles(scene, rng))
    flat["dt"], flat["time"] = np.array(DT), np.array(TIME)
    if stage == "cpic_g2p":
        flat["grid_v"] = reference_grid_velocity(scene, flat)
    return flat


def cpic_methods():
    """Every valid ``{"scheme", "force", "kernel"}`` that CPIC is defined for (:data:`mpmref.scene.CPIC_SCHEMES`)."""
    return [m for m in valid_methods() if m["scheme"] in CPIC_SCHEMES]


def _cpic_case(stage, label, method, dim=2):
    return Case(stage, dim, label, cpic_scene_dict(scene_dict(dim, TRANSFER_MATERIALS), method))


def _cpic_cases(stage, dim, dtype):
    """The CPIC cases of ``stage`` (2D and 3D, float64; none in float32): the field once; the tags on each kernel
    (the compatibility is evaluated on the transfer stencil); P2G, G2P and steps on every CPIC method, and two
    variants of the step: momentum-exact, and ghost velocities without the particle's internal force; the tags,
    P2G, G2P and the step with the per-body fit (``method.cpic_fit = "per_body"``)."""
    if dtype != "float64":
        return []
    methods = cpic_methods()
    if stage == "cpic_field":
        return [_cpic_case(stage, "bodies", methods[0], dim)]
    if stage == "cpic_tags":
        first = {}
        for m in methods:
            first.setdefault(m["kernel"], m)
        cases = [_cpic_case(stage, method_label(m), m, dim) for m in first.values()]
        return cases + _per_body_cases(stage, dim)
    cases = [_cpic_case(stage, method_label(m), m, dim) for m in methods]
    if stage == "cpic_step":
        exact = {"scheme": "pic", "force": "mls", "kernel": "quadratic", "momentum_exact": True}
        plain_ghosts = {"scheme": "mls", "force": "mls", "kernel": "quadratic", "ghost_force": False}
        cases += [_cpic_case(stage, "pic-mls-quadratic-exact", exact, dim),
                  _cpic_case(stage, "mls-mls-quadratic-no-ghost-force", plain_ghosts, dim)]
    return cases + _per_body_cases(stage, dim)


def _per_body_cases(stage, dim):
    """The per-body fit's case of ``stage`` (many particles of the cases are tagged by two or three bodies)."""
    per_body = {"scheme": "mls", "force": "mls", "kernel": "quadratic", "cpic_fit": "per_body"}
    return [_cpic_case(stage, "mls-mls-quadratic-per-body", per_body, dim)]


def _material_cases(stage, dim, dtype, set_names):
    return [Case(stage, dim, name, scene_dict(dim, MATERIAL_SETS[name], dtype=dtype), dtype) for name in set_names]


def _method_cases(stage, dim, dtype):
    return [Case(stage, dim, method_label(m), scene_dict(dim, TRANSFER_MATERIALS, method=m, dtype=dtype), dtype)
            for m in valid_methods()]


def _grid_update_cases(dim, dtype):
    boundaries = {**UNIFORM_WALLS, "mixed": mixed_walls(dim)}
    cases = [Case("grid_update", dim, name, scene_dict(dim, ("fixed_corotated",), boundary=b, dtype=dtype), dtype)
             for name, b in boundaries.items()]
    colliders = scene_dict(dim, ("fixed_corotated",), boundary=UNIFORM_WALLS["open"], colliders=collider_dicts(dim),
                           dtype=dtype)
    return cases + [Case("grid_update", dim, "colliders", colliders, dtype)]


_STAGE_CASES = {
    "stress": lambda dim, dtype: _material_cases("stress", dim, dtype, MATERIAL_SETS),
    "return_map": lambda dim, dtype: _material_cases("return_map", dim, dtype, PLASTIC_SETS),
    "p2g": lambda dim, dtype: _method_cases("p2g", dim, dtype),
    "grid_update": _grid_update_cases,
    "g2p": lambda dim, dtype: _method_cases("g2p", dim, dtype),
    "step": lambda dim, dtype: _method_cases("step", dim, dtype) + _material_cases("step", dim, dtype, MATERIAL_SETS),
    **{stage: partial(_cpic_cases, stage) for stage in CPIC_CONFORMANCE_STAGES},
}


def make_cases(dims=(2, 3), stages=CONFORMANCE_STAGES, dtype="float64"):
    """The conformance cases of ``stages`` in the dimensions ``dims``, in ``dtype`` (a list of :class:`Case`).

    The default is the six stages of every backend; the CPIC stages (:data:`.stages.CPIC_CONFORMANCE_STAGES`, 2D and
    float64 only) are included when asked for, e.g. ``stages=ALL_CONFORMANCE_STAGES``.
    """
    unknown = sorted(set(stages) - set(ALL_CONFORMANCE_STAGES))
    if unknown:
        raise ValueError(f"unknown stages {unknown}: the stages are {list(ALL_CONFORMANCE_STAGES)}")
    if dtype not in DEFAULT_RTOL:
        raise ValueError(f"unknown dtype {dtype!r}: use one of {list(DEFAULT_RTOL)}")
    return [case for stage in stages for dim in dims for case in _STAGE_CASES[stage](dim, dtype)]
