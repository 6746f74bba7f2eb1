"""Conformance cases: which scenes each stage is checked on, and the seeded random state of each case.

Every case is one stage on one scene. The scene is declared as a plain dict (the TOML structure, so that it can be
written to ``manifest.json``): a box of 8 to 13 cells per axis (each axis its own count), a cell size drawn
log-uniformly over two and a half decades and an origin off zero (:func:`case_grid`). The state, Δt and the time
are drawn from generators seeded by the case's name, so a case is the same on every machine and adding cases
changes no other; Δt spans nearly four decades of CFL number inside the stable range (:func:`draw_step`), because
one Δt in every case cannot tell a stage that ignores its Δt from one that uses it. Why each stage varies only
some axes is explained in :mod:`mpmref.conformance`.
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
from .stages import (
    ALL_CONFORMANCE_STAGES,
    CONFORMANCE_STAGES,
    CPIC_CONFORMANCE_STAGES,
    STAGES_WITH_DT,
    STAGES_WITH_TIME,
    composed_step,
    ledger_step,
    particles_from,
    run_stage,
    unfused_then_force,
)

#: cells per axis of a case's grid: each axis draws its own count in this range (:func:`case_grid`)
CELL_RANGE = (8, 13)
#: a case's cell size is drawn log-uniformly in this range
DX_RANGE = (0.02, 5.0)
#: the cell size at which the state's velocities are of order 1; they scale with the cell size, so that a
#: state moves the same number of cells per second on every grid
REFERENCE_DX = 1.0 / 8
#: particles stay at least this many cells away from every face of the domain
EDGE_CELLS = 2
N_PARTICLES = {2: 64, 3: 128}
#: smallest per-axis kernel weight a particle may have (see :func:`random_positions`). 1e-4 was enough on the unit
#: box of 8 cells; with the drawn grids and steps, two 3D PolyPIC steps (classic force) moved their modes by
#: 1.0e-13 and 1.3e-13 for a 1e-15 input change (a top mode's norm is a product of per-axis factors, one per
#: axis); at 1e-3 the largest over every case is 4.1e-14
MIN_WEIGHT = 1.0e-3
#: the CFL number of a case, Δt (c + 4 s) / Δx, is drawn log-uniformly in this range (:func:`draw_step`)
CFL_RANGE = (1.0e-4, 0.5)
#: the time of a case (where colliders move) is drawn log-uniformly in this range
TIME_RANGE = (1.0e-4, 0.2)
#: Δt and time of the CPIC cases, whose bodies are declared in the coordinates of the unit box of 8 cells
CPIC_DT, CPIC_TIME = 1.0e-3, 0.05
GRAVITY = [0.3, -9.8, 0.5]
#: default pass threshold on the relative error, per dtype. In float32 the reference itself lies within
#: 3.7e-6 of the float64 result on the same inputs (3.6e-6 measured, PolyPIC modes after a classic-force step;
#: 9.2e-7 on the unit box of 8 cells, where dx = 1/8 and the origin are exact in float32); 5e-5 leaves more than
#: ten times that for the candidate's own rounding (the Numba backend in float32: 3.6e-6 at most).
DEFAULT_RTOL = {"float64": 1.0e-12, "float32": 5.0e-5}

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
def case_grid(label, dim):
    """The grid of the case called ``label`` (its name without the dtype): ``{"origin", "size", "dx"}`` as the
    scene's ``[grid]`` declares it, drawn from a generator seeded by the label.

    Each axis has its own number of cells in :data:`CELL_RANGE` (at least two axes differ, so a code that
    assumes a square grid or swaps the strides fails), the cell size is log-uniform in :data:`DX_RANGE`, and the
    origin puts between 35 % and 65 % of the box below zero on each axis (a code that forgets the origin fails;
    positions stay within about half the box of zero, so float32 cases keep the precision of the unit box).
    """
    rng = np.random.default_rng(zlib.crc32(f"grid-{label}".encode()))
    cells = rng.integers(CELL_RANGE[0], CELL_RANGE[1] + 1, size=dim)
    if np.all(cells == cells[0]):
        cells[-1] = CELL_RANGE[0] + (cells[0] - CELL_RANGE[0] + 1) % (CELL_RANGE[1] - CELL_RANGE[0] + 1)
    dx = float(np.exp(rng.uniform(*np.log(DX_RANGE))))
    size = cells * dx
    origin = -size * rng.uniform(0.35, 0.65, dim)
    return {"origin": origin.tolist(), "size": size.tolist(), "dx": dx}


def in_box(grid, unit):
    """The point of the case's box at the fractions ``unit`` (per axis) of its size."""
    return (np.asarray(grid["origin"]) + np.asarray(unit, dtype=float) * np.asarray(grid["size"])).tolist()


def unit_box_grid(dim):
    """The unit box of 8 cells per axis at the origin (the CPIC cases, whose bodies are declared in its
    coordinates)."""
    return {"origin": [0.0] * dim, "size": [1.0] * dim, "dx": 1.0 / 8}


def mixed_walls(dim):
    """A boundary with a different wall type on each face (catches walls applied to the wrong face)."""
    return {"type": "open", "walls": {k: dict(w) for k, w in MIXED_WALLS.items() if k[0] in "xyz"[:dim]}}


def collider_dicts(dim, grid):
    """One collider of each shape and boundary type, placed in the case's box ``grid`` (:func:`case_grid`), two of
    them moving (at a few cells per unit time, as the state's velocities)."""
    pad = [0.0] * (dim - 2)
    speed = grid["dx"] / REFERENCE_DX
    smallest = min(grid["size"])
    colliders = [
        {"shape": "plane", "type": "slip", "point": in_box(grid, [0.0, 0.3] + pad), "normal": [0.2, 1.0] + pad,
         "velocity": [0.0, 0.1 * speed] + pad},
        {"shape": "disk" if dim == 2 else "sphere", "type": "separate", "friction": 0.4,
         "center": in_box(grid, [0.5] * dim), "radius": 0.2 * smallest, "velocity": [speed, -0.5 * speed] + pad},
        {"shape": "box", "type": "sticky", "lower": in_box(grid, [0.7] * dim), "upper": in_box(grid, [0.9] * dim)},
    ]
    if dim == 3:
        colliders.append({"shape": "cylinder", "type": "separate", "friction": 0.1,
                          "point": in_box(grid, [0.2, 0.75, 0.0]), "axis": [0.0, 0.0, 1.0], "radius": 0.15 * smallest})
    return colliders


def scene_dict(dim, materials, method=None, boundary=None, colliders=(), dtype="float64", grid=None):
    """The declaration of a case's scene: the box ``grid`` (default: the unit box of 8 cells per axis), gravity,
    the given materials.

    ``boundary`` defaults to :func:`mixed_walls`. The one body only makes the scene valid; the cases draw
    their own particles.
    """
    grid = grid or unit_box_grid(dim)
    return {"name": "conformance", "dim": dim, "dtype": dtype, "grid": dict(grid),
            "method": dict(method or {}), "materials": {name: dict(MATERIALS[name]) for name in materials},
            "bodies": [{"shape": "box", "material": materials[0], "lower": in_box(grid, [0.25] * dim),
                        "upper": in_box(grid, [0.75] * dim)}],
            "gravity": GRAVITY[:dim], "boundary": boundary or mixed_walls(dim),
            "colliders": [dict(c) for c in colliders], "time": {"dt": CPIC_DT}}


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


def random_modes(rng, n, dim, support, dx, speed=1.0):
    """PolyPIC coefficients scaled by ``dx^-degree``, so that each mode adds O(0.1) ``speed`` to a node's velocity."""
    degree = higher_modes(dim, support).sum(axis=1)
    return 0.1 * speed * rng.standard_normal((n, len(degree), dim)) / (dx ** degree)[None, :, None]


def random_positions(scene, rng, n):
    """``n`` positions at least ``EDGE_CELLS`` cells inside the domain whose per-axis kernel weights are all
    at least ``MIN_WEIGHT``.

    Where a particle's outermost weight vanishes (at cell centres for the quadratic B-spline, on nodes for
    the cubic), PolyPIC's top mode norms vanish too and G2P divides by them: there a 1e-15 relative change of
    the inputs moved the output modes by up to 2.5e-7 relative, so no threshold near round-off could be
    asked of a correct implementation. With the margin the same perturbation moves every output by < 1e-13
    (4.1e-14 at most, measured on every case).
    """
    grid = scene.grid
    lo = grid.origin + EDGE_CELLS * grid.dx
    hi = grid.origin + (np.array(grid.cells) - EDGE_CELLS) * grid.dx  # each axis its own count
    x = np.empty((0, scene.dim))
    while len(x) < n:
        trial = lo + (hi - lo) * rng.random((n, scene.dim))
        weights = compute_stencil(scene.kernel, trial, grid.origin, grid.dx).w
        x = np.concatenate([x, trial[weights.min(axis=(1, 2)) >= MIN_WEIGHT]])
    return x[:n]


def speed_scale(scene):
    """The velocity scale of a case's state: 1 at :data:`REFERENCE_DX`, proportional to the cell size (a state
    moves as many cells per unit time on every grid)."""
    return scene.grid.dx / REFERENCE_DX


def random_particles(scene, rng):
    """A particle state for ``scene`` as a flat dict.

    Positions from :func:`random_positions`; random materials of the scene; volume a quarter cell (2D) or
    an eighth (3D) within ±20 %; mass ``rho * vol0``; velocities N(0, 1) times :func:`speed_scale`; ``C``
    N(0, 4^2); ``F`` from :func:`random_deformation_gradients`; ``J`` in [0.9, 1.1]; ``Jp`` in [0.7, 1.2];
    PolyPIC modes from :func:`random_modes`. ``C``, ``F``, ``J``, ``Jp`` and ``modes`` only where the scene
    needs them.
    """
    grid, dim, speed = scene.grid, scene.dim, speed_scale(scene)
    n = N_PARTICLES[dim]
    material = rng.integers(len(scene.materials), size=n).astype(np.int32)
    vol0 = grid.dx**dim / 2**dim * rng.uniform(0.8, 1.2, n)
    rho = np.array([m.rho for m in scene.material_list])[material]
    flat = {"x": random_positions(scene, rng, n), "v": speed * rng.standard_normal((n, dim)), "mass": rho * vol0,
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
        flat["modes"] = random_modes(rng, n, dim, scene.kernel.support, grid.dx, speed)
    return flat


def random_grid(scene, rng):
    """Grid state after a P2G: a quarter of the nodes empty, the others with mass in [0.2, 1.5] x rho dx^d,
    velocity N(0, 1) and force mass x N(0, 50^2), both times :func:`speed_scale`."""
    n_nodes, dim, speed = scene.grid.n_nodes, scene.dim, speed_scale(scene)
    mass = scene.grid.dx**dim * rng.uniform(0.2, 1.5, n_nodes) * (rng.random(n_nodes) >= 0.25)
    return {"grid_mass": mass, "grid_momentum": mass[:, None] * speed * rng.standard_normal((n_nodes, dim)),
            "grid_force": mass[:, None] * 50.0 * speed * rng.standard_normal((n_nodes, dim))}


def draw_step(label, scene):
    r"""Δt of the case called ``label``: :math:`\Delta t = \mathrm{CFL}\,\Delta x / (c + 4 s)` with the CFL number
    log-uniform in :data:`CFL_RANGE` (nearly four decades, all inside the stable range of every scheme,
    docs/stability.md), :math:`c` the scene's largest rest wave speed and :math:`s` the state's
    :func:`speed_scale` (four standard deviations bound the drawn speeds). Seeded by the label."""
    cfl = np.exp(np.random.default_rng(zlib.crc32(f"dt-{label}".encode())).uniform(*np.log(CFL_RANGE)))
    return float(cfl * scene.grid.dx / (scene.max_wave_speed() + 4.0 * speed_scale(scene)))


def cfl_number(scene):
    """The CFL number of a case's scene as :func:`draw_step` drew it: ``time.dt (c + 4 s) / dx``."""
    return scene.time.dt * (scene.max_wave_speed() + 4.0 * speed_scale(scene)) / scene.grid.dx


def draw_time(seed):
    """The time of a case (log-uniform in :data:`TIME_RANGE`): where the moving colliders are."""
    return float(np.exp(np.random.default_rng([seed, 1]).uniform(*np.log(TIME_RANGE))))


def reference_grid_velocities(scene, flat, dt, time):
    """``grid_v`` and ``grid_v_tilde`` of the reference P2G and grid update of the particles ``flat``."""
    backend = make_backend("numpy", scene)
    v, v_tilde = backend.grid_update(backend.p2g(particles_from(flat)), dt, time)
    return {"grid_v": v, "grid_v_tilde": v_tilde}


def _as_dtype(flat, dtype):
    """Floating arrays of ``flat`` in ``dtype``; integer arrays and 0-d scalars unchanged."""
    return {k: a.astype(dtype) if a.ndim and a.dtype.kind == "f" else a for k, a in flat.items()}


# -------------------------------------------------------------------------------------------- cases
@dataclass(frozen=True, eq=False)
class ConformanceCase:
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

    @property
    def materials(self):
        """The material types of the case's scene (a set)."""
        return {m["type"] for m in self.scene_dict["materials"].values()}

    def scene(self):
        return Scene.from_dict(self.scene_dict)

    def inputs(self):
        """The stage's inputs as a flat dict of arrays (same result on every call)."""
        scene, rng = self.scene(), np.random.default_rng(self.seed)
        if self.stage in CPIC_CONFORMANCE_STAGES:
            return _as_dtype(cpic_inputs(self.stage, scene, rng), self.dtype)
        flat = random_grid(scene, rng) if self.stage == "grid_update" else random_particles(scene, rng)
        dt, time = scene.time.dt, draw_time(self.seed)
        if self.stage == "g2p":
            flat.update(reference_grid_velocities(scene, flat, dt, time))
        if self.stage in STAGES_WITH_DT:
            flat["dt"] = np.array(dt)
        if self.stage in STAGES_WITH_TIME:
            flat["time"] = np.array(time)
        flat = _as_dtype(flat, self.dtype)
        if self.stage == "p2g":  # the optional input of a P2G that takes the stress (docs/conformance.md)
            flat["tau"] = make_backend("numpy", scene).stress(particles_from(flat))
        return flat

    def reference(self, inputs=None):
        """The NumPy reference's outputs of the stage on ``inputs`` (default: :meth:`inputs`), a flat dict."""
        backend = make_backend("numpy", self.scene())
        fn = backend_stage(backend, self.stage)
        return run_stage(self.stage, fn, self.inputs() if inputs is None else inputs)


def backend_stage(backend, stage):
    """The callable of ``stage`` for a backend object (``step``: the pipeline over its stages; ``ledger``: that
    step's energy ledger; CPIC stages: their runners of :mod:`mpmref.conformance.cpic` bound to it)."""
    if stage == "step":
        return partial(composed_step, backend)
    if stage == "p2g_fused":  # the truth is the unfused P2G plus dt times its force, whatever the backend folds
        return unfused_then_force(backend)
    if stage == "ledger":
        return partial(ledger_step, backend)
    if stage in CPIC_CONFORMANCE_STAGES:
        return partial(RUNNERS[stage], backend)
    return getattr(backend, stage)


def cpic_inputs(stage, scene, rng):
    """A CPIC stage's inputs: :func:`random_particles`, previous tags and bodies (:func:`.cpic.random_cpic_state`),
    ``dt``, ``time`` and, for ``cpic_g2p``, the reference's ``grid_v`` of that state."""
    flat = random_cpic_state(scene, rng, random_particles(scene, rng))
    flat["dt"], flat["time"] = np.array(CPIC_DT), np.array(CPIC_TIME)
    if stage == "cpic_g2p":
        flat["grid_v"] = reference_grid_velocity(scene, flat)
    return flat


def cpic_methods():
    """Every valid ``{"scheme", "force", "kernel"}`` that CPIC is defined for (:data:`mpmref.scene.CPIC_SCHEMES`)."""
    return [m for m in valid_methods() if m["scheme"] in CPIC_SCHEMES]


def _cpic_case(stage, label, method, dim=2):
    return ConformanceCase(stage, dim, label, cpic_scene_dict(scene_dict(dim, TRANSFER_MATERIALS), method))


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


def drawn_case(stage, dim, variant, dtype, materials, method=None, boundary=None, colliders=False):
    """A case whose grid (:func:`case_grid`) and Δt (:func:`draw_step`, the scene's ``time.dt``) are drawn from its
    name; ``colliders``: one of each shape in its box (:func:`collider_dicts`)."""
    label = f"{stage}-{dim}d-{variant}"
    grid = case_grid(label, dim)
    declared = scene_dict(dim, materials, method, boundary, collider_dicts(dim, grid) if colliders else (), dtype,
                          grid)
    declared["time"] = {"dt": draw_step(label, Scene.from_dict(declared))}
    return ConformanceCase(stage, dim, variant, declared, dtype)


def _material_cases(stage, dim, dtype, set_names):
    return [drawn_case(stage, dim, name, dtype, MATERIAL_SETS[name]) for name in set_names]


def _method_cases(stage, dim, dtype):
    return [drawn_case(stage, dim, method_label(m), dtype, TRANSFER_MATERIALS, method=m) for m in valid_methods()]


def _grid_update_cases(dim, dtype):
    boundaries = {**UNIFORM_WALLS, "mixed": mixed_walls(dim)}
    cases = [drawn_case("grid_update", dim, name, dtype, ("fixed_corotated",), boundary=b)
             for name, b in boundaries.items()]
    return cases + [drawn_case("grid_update", dim, "colliders", dtype, ("fixed_corotated",),
                               boundary=UNIFORM_WALLS["open"], colliders=True)]


def _transfer_cases(stage, dim, dtype):
    """Every method with the solid and the fluid together, then each material alone and all five together (with
    MLS-MPM): a code with one material checks its transfers on that material's cases."""
    return _method_cases(stage, dim, dtype) + _material_cases(stage, dim, dtype, MATERIAL_SETS)


def _ledger_cases(dim, dtype):
    """The step's cases (:func:`_transfer_cases`), then MLS-MPM with open walls and one collider of each shape, two
    of them moving: the nodes the colliders act on book ``boundary``, where a moving one may add energy."""
    colliders = drawn_case("ledger", dim, "colliders", dtype, TRANSFER_MATERIALS, boundary=UNIFORM_WALLS["open"],
                           colliders=True)
    return _transfer_cases("ledger", dim, dtype) + [colliders]


_STAGE_CASES = {
    "stress": lambda dim, dtype: _material_cases("stress", dim, dtype, MATERIAL_SETS),
    "return_map": lambda dim, dtype: _material_cases("return_map", dim, dtype, PLASTIC_SETS),
    "p2g": partial(_transfer_cases, "p2g"),
    "p2g_fused": lambda dim, dtype: [c for c in _transfer_cases("p2g_fused", dim, dtype)
                                     if not c.scene().transfer.flip],
    "grid_update": _grid_update_cases,
    "g2p": partial(_transfer_cases, "g2p"),
    "step": partial(_transfer_cases, "step"),
    "ledger": _ledger_cases,
    **{stage: partial(_cpic_cases, stage) for stage in CPIC_CONFORMANCE_STAGES},
}


def make_cases(dims=(2, 3), stages=CONFORMANCE_STAGES, dtype="float64", materials=None):
    """The conformance cases of ``stages`` in the dimensions ``dims``, in ``dtype`` (a list of
    :class:`ConformanceCase`).

    The default is the seven stages of every backend (its six and the energy ledger of a step); the CPIC stages
    (:data:`.stages.CPIC_CONFORMANCE_STAGES`, 2D and float64 only) are included when asked for, e.g.
    ``stages=ALL_CONFORMANCE_STAGES``. ``materials`` (material
    types, e.g. ``("fluid",)``) keeps the cases whose materials are all among them, and the grid update's (which
    does not see the material): what a code with only those constitutive models can run.
    """
    unknown = sorted(set(stages) - set(ALL_CONFORMANCE_STAGES))
    if unknown:
        raise ValueError(f"unknown stages {unknown}: the stages are {list(ALL_CONFORMANCE_STAGES)}")
    if dtype not in DEFAULT_RTOL:
        raise ValueError(f"unknown dtype {dtype!r}: use one of {list(DEFAULT_RTOL)}")
    unknown = sorted(set(materials or ()) - set(MATERIALS))
    if unknown:
        raise ValueError(f"unknown material types {unknown}: the types are {list(MATERIALS)}")
    cases = [case for stage in stages for dim in dims for case in _STAGE_CASES[stage](dim, dtype)]
    return cases if materials is None else [c for c in cases
                                            if c.stage == "grid_update" or c.materials <= set(materials)]
