"""The built-in catalogue of conformance cases: which scenes each stage is checked on.

Every case is one stage on one scene (:class:`~.case.ConformanceCase`). The scene is declared as a plain dict (the
TOML structure, so that it can be written to ``manifest.json``): a box of 8 to 13 cells per axis (each axis its own
count), a cell size drawn log-uniformly over two and a half decades and an origin off zero (:func:`case_grid`). The
state, Δt and the time are drawn from generators seeded by the case's name (:mod:`.states`), so a case is the same on
every machine and adding cases changes no other; Δt spans nearly four decades of CFL number inside the stable range
(:func:`~.states.draw_step`), because one Δt in every case cannot tell a stage that ignores its Δt from one that uses
it. Why each stage varies only some axes is explained in :mod:`mpmref.conformance`.

The catalogue is fitted to what a backend implements (:func:`make_cases` with ``implements``,
:class:`~mpmref.backends.capabilities.Implements`): the axes a stage does not depend on (the walls of a stress case,
the scheme of a grid-update case) are set to ones the backend has, and the per-method cases run on the materials it
has (the fluid alone for a fluid-only code; the case name says so) with the parameters it fixes. For a backend that
implements everything, the catalogue is the same.
"""

import zlib
from dataclasses import dataclass, replace
from functools import cache, cached_property, partial
from itertools import product

import numpy as np

from ..backends.capabilities import EVERYTHING, SCHEMES, Implements
from ..backends.fitting import closest_method, implemented_methods, implements_material
from ..errors import ArgumentError, SceneError
from ..physics.catalogue import MATERIALS as MATERIAL_CLASSES
from ..physics.kernels import KERNELS
from ..physics.parameters import declared as declared_parameters
from ..physics.scheme import TRANSFER_OF
from ..run.stability import stable_cfl
from ..scene import CPIC_SCHEMES, FORCES, Scene
from ..scene import SCHEMES as SCENE_SCHEMES
from .case import DEFAULT_RTOL, STAGE_PARTS, ConformanceCase, backend_stage, seeded_label
from .cpic import cpic_scene_dict
from .extremes import BLOCK_CELLS, EXTREMES, REST_CFL, STIFFNESS_FACTOR, holds_for
from .stages import ALL_CONFORMANCE_STAGES, ASYNC_CONFORMANCE_STAGES, CONFORMANCE_STAGES, CPIC_CONFORMANCE_STAGES
from .states import (
    CFL_RANGE,
    EDGE_CELLS,
    MIN_WEIGHT,
    N_PARTICLES,
    REFERENCE_DX,
    TIME_RANGE,
    catalogue_scales,
    cfl_number,
    draw_step,
    draw_time,
    drawn_wave_speed,
    random_grid,
    random_particles,
    step_at,
)

__all__ = ["CELL_RANGE", "CFL_RANGE", "DEFAULT_RTOL", "DX_RANGE", "EDGE_CELLS", "MATERIALS", "MIN_WEIGHT",
           "N_PARTICLES", "REFERENCE_DX", "TIME_RANGE", "ConformanceCase", "backend_stage", "case_grid", "cfl_number",
           "cpic_methods", "draw_step", "draw_time", "make_cases", "random_grid", "random_particles", "scene_dict",
           "valid_methods"]  # the states' names too, where the docs and the tests have always found them

#: cells per axis of a case's grid: each axis draws its own count in this range (:func:`case_grid`)
CELL_RANGE = (8, 13)
#: a case's cell size is drawn log-uniformly in this range
DX_RANGE = (0.02, 5.0)
GRAVITY = [0.3, -9.8, 0.5]
#: the time stepping of the cases of asynchronous stepping's stages (their Δt is drawn, :attr:`ConformanceCase.dt`)
ASYNC_TIME = {"stepping": "async", "cfl": 0.4}

MATERIALS = {
    "fixed_corotated": {"type": "fixed_corotated", "E": 1.0e3, "nu": 0.3, "rho": 1.0},
    "neo_hookean": {"type": "neo_hookean", "E": 2.0e3, "nu": 0.35, "rho": 1.5},
    "fluid": {"type": "fluid", "K": 400.0, "gamma": 7.0, "rho": 1.0},
    "snow": {"type": "snow", "E": 1.4e3, "nu": 0.2, "rho": 0.4},
    "sand": {"type": "sand", "E": 3.5e3, "nu": 0.3, "rho": 1.6, "friction_angle": 30.0, "cohesion": 0.01},
}
#: material sets of the stress, return-map and per-material step cases: each material alone, then all together
MATERIAL_SETS = {**{name: (name,) for name in MATERIALS}, "mixed": tuple(MATERIALS)}
#: the material sets of the return-map cases: each plastic material alone (read from the material classes), then all
PLASTIC_SETS = (*(name for name, spec in MATERIALS.items() if MATERIAL_CLASSES[spec["type"]].plastic), "mixed")
#: the material set of the per-method cases: a solid (F update) and the fluid (J update)
TRANSFER_MATERIALS = ("fixed_corotated", "fluid")
MIXED_WALLS = {"x_min": {"type": "sticky"}, "x_max": {"type": "slip"},
               "y_min": {"type": "separate", "friction": 0.5}, "y_max": {"type": "open"},
               "z_min": {"type": "separate", "friction": 0.0}, "z_max": {"type": "sticky"}}
#: one wall type on every face; ``separate-frictionless`` is the one wall of the 88-line program
UNIFORM_WALLS = {"sticky": {"type": "sticky"}, "slip": {"type": "slip"},
                 "separate": {"type": "separate", "friction": 0.3}, "open": {"type": "open"},
                 "separate-frictionless": {"type": "separate", "friction": 0.0}}
#: the methods of the cases of P2G by classes and G2P with kicks: each kernel, each transfer and both forces
ASYNC_METHODS = ("mls-mls-quadratic", "pic-classic-linear", "flip-mls-cubic", "polypic-classic-quadratic")
#: the methods of the node-kick cases: the kick depends on the scheme only through FLIP's momentum share
KICK_METHODS = ("mls-mls-quadratic", "flip-mls-quadratic")


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
    cells = distinct_cells(rng, dim, CELL_RANGE)
    dx = float(np.exp(rng.uniform(*np.log(DX_RANGE))))
    size = cells * dx
    origin = -size * rng.uniform(0.35, 0.65, dim)
    return {"origin": origin.tolist(), "size": size.tolist(), "dx": dx}


def distinct_cells(rng, dim, cell_range):
    """Cells per axis drawn in ``cell_range`` (inclusive), not all equal."""
    cells = rng.integers(cell_range[0], cell_range[1] + 1, size=dim)
    if np.all(cells == cells[0]):
        cells[-1] = cell_range[0] + (cells[0] - cell_range[0] + 1) % (cell_range[1] - cell_range[0] + 1)
    return cells


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


def uniform_walls(name):
    """A boundary with the wall :data:`UNIFORM_WALLS` ``[name]`` on every face."""
    wall = UNIFORM_WALLS[name]
    return {"type": wall["type"], **({"friction": wall["friction"]} if "friction" in wall else {})}


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


def material_dicts(names, parameters=None):
    """The declared materials ``names`` of :data:`MATERIALS`, with the values a backend fixes (``parameters``, as
    :attr:`~mpmref.backends.capabilities.Implements.parameters`) in place of the catalogue's."""
    out = {}
    for name in names:
        kind = MATERIALS[name]["type"]
        keys = {p.name for p in declared_parameters(MATERIAL_CLASSES[kind])}
        fixed = {k: v for k, v in (parameters or {}).get(kind, {}).items() if k in keys}
        out[name] = {**MATERIALS[name], **fixed}
    return out


def scene_dict(dim, materials, method=None, boundary=None, colliders=(), dtype="float64", grid=None,
               parameters=None):
    """The declaration of a case's scene: the box ``grid`` (default: the unit box of 8 cells per axis), gravity,
    the given materials (names of :data:`MATERIALS`, with the values ``parameters`` fixes, :func:`material_dicts`).

    ``boundary`` defaults to :func:`mixed_walls`. The one body only makes the scene valid; the cases draw
    their own particles.
    """
    grid = grid or unit_box_grid(dim)
    return {"name": "conformance", "dim": dim, "dtype": dtype, "grid": dict(grid),
            "method": dict(method or {}), "materials": material_dicts(materials, parameters),
            "bodies": [{"shape": "box", "material": materials[0], "lower": in_box(grid, [0.25] * dim),
                        "upper": in_box(grid, [0.75] * dim)}],
            "gravity": GRAVITY[:dim], "boundary": boundary or mixed_walls(dim),
            "colliders": [dict(c) for c in colliders], "time": {"dt": 1.0e-3}}


def valid_methods():
    """Every ``{"scheme", "force", "kernel"}`` combination that the scene validator accepts, plus APIC
    (quadratic) with the velocity gradient of the other force (the force/F-update ablation of the
    convergence case)."""
    return [dict(m) for m in _valid_methods()]


@cache
def _valid_methods():
    methods = []
    for scheme, force, kernel in product(SCENE_SCHEMES, FORCES, KERNELS):
        method = {"scheme": scheme, "force": force, "kernel": kernel}
        try:
            Scene.from_dict(scene_dict(2, TRANSFER_MATERIALS, method=method))
        except SceneError:
            continue
        methods.append(method)
    crossed = [dict(m, velocity_gradient=g) for m in methods if m["scheme"] == "apic" and m["kernel"] == "quadratic"
               for g in FORCES if g != m["force"]]
    return tuple(methods + crossed)


def method_label(method):
    gradient = method.get("velocity_gradient", method["force"])
    suffix = "" if gradient == method["force"] else f"-gradient-{gradient}"
    return f"{method['scheme']}-{method['force']}-{method['kernel']}{suffix}"


def method_of(label):
    """The method ``{"scheme", "force", "kernel"}`` of a label ``scheme-force-kernel``."""
    return next(m for m in valid_methods() if method_label(m) == label)


def cpic_methods():
    """Every valid ``{"scheme", "force", "kernel"}`` that CPIC is defined for (:data:`mpmref.scene.CPIC_SCHEMES`)."""
    return [m for m in valid_methods() if m["scheme"] in CPIC_SCHEMES]


# ---------------------------------------------------------------------------- fitting to a backend
#: the method a scene declares when it declares none: MLS-MPM, quadratic
DEFAULT_METHOD = {"scheme": "mls", "force": "mls", "kernel": "quadratic"}
#: the walls a stage that does not see them is given, in order of preference, when the backend lacks the mixed walls
WALL_PREFERENCE = ("separate", "separate-frictionless", "slip", "sticky", "open")


@dataclass(frozen=True, eq=False)
class Fit:
    """The catalogue fitted to a declaration (:class:`~mpmref.backends.capabilities.Implements`): for each axis of a
    scene, the catalogue's choice if the declaration has it, else one it has.

    ``target`` is what the cases are fitted to (a backend's declaration, narrowed by the filters); ``filters`` is the
    selection (``--material``, ``--scheme``, ``--kernel``): a case whose materials, scheme or kernel it excludes is
    left out of the catalogue (a case the backend lacks stays in, and is reported as not applicable). ``seed`` is the
    base seed of every case's draws (:func:`~.case.seeded_label`).
    """

    target: Implements = EVERYTHING
    materials: tuple | None = None
    schemes: tuple | None = None
    kernels: tuple | None = None
    seed: int = 0

    def _check(self, dim, parts, **declared):
        """Whether the target implements ``parts`` of a unit-box scene with ``declared`` (keyword arguments of
        :func:`scene_dict`)."""
        declared.setdefault("materials", ("fixed_corotated",))
        return not self.target.missing(Scene.from_dict(scene_dict(dim, **declared)), parts)

    @cached_property
    def method(self):
        """The method of the cases that are not per method: ``None`` (the scene's default, MLS-MPM) if the target
        implements it, else the one :func:`mpmref.backends.fitting.fit` gives the default scene when any method may
        change (the fewest changes; with the affine matrix or modes it carries), or ``None`` if it implements
        none."""
        if self._check(2, ("method",), method=DEFAULT_METHOD):
            return None
        methods = implemented_methods(self.target)
        if not methods:
            return None
        own = Scene.from_dict(scene_dict(2, ("fixed_corotated",), method=DEFAULT_METHOD)).method
        scheme, force, gradient, kernel = closest_method(own, methods)
        method = {"scheme": scheme, "force": force, "kernel": kernel}
        return method if gradient == force else {**method, "velocity_gradient": gradient}

    def method_suffix(self):
        """``-<method>`` for the names of cases on :attr:`method` when it is not the default, else ``""``."""
        return "" if self.method is None else f"-{method_label(self.method)}"

    def walls(self, dim):
        """``(boundary, suffix)``: the mixed walls if the target has them, else the uniform walls it has first in
        :data:`WALL_PREFERENCE` (with ``-<walls>`` for the case names of the stages that see the walls)."""
        if self._check(dim, ("boundary",), boundary=mixed_walls(dim)):
            return mixed_walls(dim), ""
        name = next((w for w in WALL_PREFERENCE if self._check(dim, ("boundary",), boundary=uniform_walls(w))), None)
        return (uniform_walls(name), f"-{name}") if name else (mixed_walls(dim), "")

    @cached_property
    def kinds(self):
        """The material types of :data:`MATERIALS` that the target implements, with the parameters it fixes and the
        fields they carry (:func:`mpmref.backends.fitting.implements_material`)."""
        specs = material_dicts(MATERIALS, self.target.parameters)
        return tuple(k for k, spec in specs.items()
                     if implements_material(MATERIAL_CLASSES[spec["type"]](**_parameters(spec)), self.target))

    def material_set(self, wanted):
        """``(names, suffix)``: the materials of ``wanted`` that the target implements (all of them, the suffix
        empty, if it implements each), else those (``-<names>``), else its first material; ``wanted`` itself if it
        implements none."""
        have = tuple(m for m in wanted if m in self.kinds)
        if have == tuple(wanted):
            return tuple(wanted), ""
        have = have or self.kinds[:1]
        return (have, "-" + "-".join(have)) if have else (tuple(wanted), "")

    def mixed_set(self):
        """``(names, variant)`` of the set of every material: all five (``mixed``), or every one the target
        implements if that is at least two (``mixed-<names>``)."""
        if len(self.kinds) == len(MATERIALS) or len(self.kinds) < 2:
            return MATERIAL_SETS["mixed"], "mixed"
        return self.kinds, "mixed-" + "-".join(self.kinds)

    def selects(self, case):
        """Whether the filters keep ``case``: its materials among ``materials``, and where its stage depends on the
        method, its scheme among ``schemes`` and its kernel among ``kernels``."""
        if self.materials is not None and "materials" in STAGE_PARTS[case.stage] \
                and not case.materials <= set(self.materials):
            return False
        method = {"scheme": "mls", "kernel": "quadratic", **case.scene_dict["method"]}
        if "method" not in STAGE_PARTS[case.stage]:
            return True
        return ((self.schemes is None or method["scheme"] in self.schemes)
                and (self.kernels is None or method["kernel"] in self.kernels))


def _parameters(spec):
    return {k: v for k, v in spec.items() if k != "type"}


def fit_for(implements=None, materials=None, schemes=None, kernels=None, seed=0):
    """The :class:`Fit` of a backend's declaration ``implements`` (default: everything) narrowed by the filters, with
    the base seed ``seed``."""
    target = implements or EVERYTHING
    narrowed = {"parameters": {k: dict(v) for k, v in target.parameters.items()}}
    if materials is not None:
        kept = tuple(m for m in target.materials if m in materials)
        narrowed.update(materials=kept, parameters={k: v for k, v in target.parameters.items() if k in kept})
    if schemes is not None:
        have = {TRANSFER_OF[s] for s in target.schemes}
        narrowed["schemes"] = tuple(s for s in SCHEMES if s in schemes and TRANSFER_OF[s] in have)
    if kernels is not None:
        narrowed["kernels"] = tuple(k for k in target.kernels if k in kernels)
    if len(narrowed) > 1:
        target = replace(target, **narrowed)
    return Fit(target, materials, schemes, kernels, seed)


# -------------------------------------------------------------------------------------------- cases
def drawn_case(stage, dim, variant, dtype, materials, method=None, boundary=None, colliders=False, fit=None,
               stepping=None, extreme=None):
    """A case whose grid (:func:`case_grid`) and Δt (:func:`~.states.draw_step`, the scene's ``time.dt``, or the
    case's own Δt for asynchronous stepping) are drawn from its name; ``colliders``: one of each shape in its box
    (:func:`collider_dicts`); the materials with the parameters ``fit`` fixes. A case that holds an ``extreme``
    (:class:`~.extremes.Extreme`) is named after it and may have its own grid, scene and Δt
    (:func:`extreme_scene`)."""
    fit = fit or Fit()
    if extreme is not None:
        variant = f"{variant}-{extreme.name}"
    label = seeded_label(f"{stage}-{dim}d-{variant}", fit.seed)
    grid = case_grid(label, dim)
    parameters = fit.target.parameters
    declared = scene_dict(dim, materials, method, boundary, collider_dicts(dim, grid) if colliders else (), dtype,
                          grid, parameters)
    if extreme is not None:
        declared, dt = extreme_scene(declared, extreme, label)
    else:
        dt = draw_step(label, Scene.from_dict(declared))
    if stepping == "async":
        declared["time"] = dict(ASYNC_TIME)
        return ConformanceCase(stage, dim, variant, declared, dtype, dt=dt, seed_label=label)
    declared["time"] = {"dt": dt}
    return ConformanceCase(stage, dim, variant, declared, dtype, extreme=extreme, seed_label=label)


def _material_cases(stage, dim, dtype, set_names, fit, stepping=None):
    """Each material set of ``set_names`` (:data:`MATERIAL_SETS`), with the method and walls ``fit`` gives the stages
    that do not see them (a material the target lacks is kept: the case is not applicable to it)."""
    walls, _ = fit.walls(dim)
    cases = []
    for name in set_names:
        names, variant = fit.mixed_set() if name == "mixed" else (MATERIAL_SETS[name], name)
        cases.append(drawn_case(stage, dim, variant, dtype, names, fit.method, walls, fit=fit, stepping=stepping))
    return cases


def _transfer_material_cases(stage, dim, dtype, fit):
    """Each material set with MLS-MPM (or the target's method, named), on the walls ``fit`` gives (named where the
    stage sees them): a code with one material checks its transfers on that material's cases."""
    walls, wall_suffix = fit.walls(dim)
    wall_suffix = wall_suffix if "boundary" in STAGE_PARTS[stage] else ""
    cases = []
    for name in MATERIAL_SETS:
        names, variant = fit.mixed_set() if name == "mixed" else (MATERIAL_SETS[name], name)
        cases.append(drawn_case(stage, dim, variant + fit.method_suffix() + wall_suffix, dtype, names, fit.method,
                                walls, fit=fit))
    return cases


def _method_cases(stage, dim, dtype, fit, methods=None, stepping=None):
    """Every valid method (or ``methods``, labels) on the solid and the fluid together, or the materials of them the
    target implements (named), on the walls ``fit`` gives (named where the stage sees them)."""
    names, material_suffix = fit.material_set(TRANSFER_MATERIALS)
    walls, wall_suffix = fit.walls(dim)
    wall_suffix = wall_suffix if "boundary" in STAGE_PARTS[stage] else ""
    chosen = valid_methods() if methods is None else [method_of(label) for label in methods]
    return [drawn_case(stage, dim, method_label(m) + material_suffix + wall_suffix, dtype, names, method=m,
                       boundary=walls, fit=fit, stepping=stepping) for m in chosen]


def _grid_update_cases(dim, dtype, fit):
    """Each uniform wall (:data:`UNIFORM_WALLS`), the mixed walls, and one collider of each shape with open walls, on
    a material and a method the target has (the grid update sees neither)."""
    material = fit.kinds[:1] or ("fixed_corotated",)
    boundaries = {**{name: uniform_walls(name) for name in UNIFORM_WALLS}, "mixed": mixed_walls(dim)}
    cases = [drawn_case("grid_update", dim, name, dtype, material, fit.method, boundary=b, fit=fit)
             for name, b in boundaries.items()]
    return cases + [drawn_case("grid_update", dim, "colliders", dtype, material, fit.method,
                               boundary=uniform_walls("open"), colliders=True, fit=fit)]


def _transfer_cases(stage, dim, dtype, fit):
    """Every method with the solid and the fluid together, then each material alone and all five together (with
    MLS-MPM): a code with one material checks its transfers on that material's cases."""
    return _method_cases(stage, dim, dtype, fit) + _transfer_material_cases(stage, dim, dtype, fit)


def _ledger_cases(dim, dtype, fit):
    """The step's cases (:func:`_transfer_cases`), then MLS-MPM with open walls and one collider of each shape, two
    of them moving: the nodes the colliders act on book ``boundary``, where a moving one may add energy."""
    names, suffix = fit.material_set(TRANSFER_MATERIALS)
    colliders = drawn_case("ledger", dim, "colliders" + suffix, dtype, names, boundary=uniform_walls("open"),
                           colliders=True, fit=fit)
    return _transfer_cases("ledger", dim, dtype, fit) + [colliders]


def _fused_cases(dim, dtype, fit):
    """The P2G cases without FLIP (whose G2P needs the velocity before the force, so its steps never fuse)."""
    return [c for c in _transfer_cases("p2g_fused", dim, dtype, fit) if c.scene_dict["method"].get("scheme") != "flip"]


def _async_cases(stage, dim, dtype, fit):
    """The stages of asynchronous stepping: the wave speeds of each material set; P2G by classes and G2P with kicks on
    :data:`ASYNC_METHODS` (each kernel, each transfer, both forces); the node kicks with and without FLIP's momentum
    share (:data:`KICK_METHODS`)."""
    if stage == "wave_speeds":
        return _material_cases(stage, dim, dtype, MATERIAL_SETS, fit, stepping="async")
    methods = KICK_METHODS if stage == "interface_kicks" else ASYNC_METHODS
    return _method_cases(stage, dim, dtype, fit, methods, stepping="async")


def _cpic_case(stage, label, method, dim, fit):
    """A CPIC case: the bodies of :mod:`.cpic` in the unit box, Δt drawn from its name inside the stable range (CFL
    numbers as the other stages', and the penalty's :math:`k \\Delta t \\le 1`)."""
    names, suffix = fit.material_set(TRANSFER_MATERIALS)
    label += suffix
    declared = cpic_scene_dict(scene_dict(dim, names, parameters=fit.target.parameters), method)
    scene = Scene.from_dict(declared)
    penalty = scene.cpic.penalty
    seed_label = seeded_label(f"{stage}-{dim}d-{label}", fit.seed)
    declared["time"] = {"dt": draw_step(seed_label, scene, limit=1.0 / penalty if penalty else None)}
    return ConformanceCase(stage, dim, label, declared, seed_label=seed_label)


def _cpic_cases(stage, dim, dtype, fit):
    """The CPIC cases of ``stage`` (2D and 3D, float64; none in float32): the field once; the tags on each kernel
    (the compatibility is evaluated on the transfer stencil); P2G, G2P and steps on every CPIC method, and two
    variants of the step: momentum-exact, and ghost velocities without the particle's internal force; the tags,
    P2G, G2P and the step with the per-body fit (``method.cpic_fit = "per_body"``)."""
    if dtype != "float64":
        return []
    methods = cpic_methods()
    case = partial(_cpic_case, stage, dim=dim, fit=fit)
    if stage == "cpic_field":
        return [case("bodies", methods[0])]
    if stage == "cpic_tags":
        first = {}
        for m in methods:
            first.setdefault(m["kernel"], m)
        return [case(method_label(m), m) for m in first.values()] + [_per_body_case(case)]
    cases = [case(method_label(m), m) for m in methods]
    if stage == "cpic_step":
        exact = {"scheme": "pic", "force": "mls", "kernel": "quadratic", "momentum_exact": True}
        plain_ghosts = {"scheme": "mls", "force": "mls", "kernel": "quadratic", "ghost_force": False}
        cases += [case("pic-mls-quadratic-exact", exact), case("mls-mls-quadratic-no-ghost-force", plain_ghosts)]
    return cases + [_per_body_case(case)]


def _per_body_case(case):
    """The per-body fit's case (many particles of the cases are tagged by two or three bodies)."""
    return case("mls-mls-quadratic-per-body", {"scheme": "mls", "force": "mls", "kernel": "quadratic",
                                               "cpic_fit": "per_body"})


_STAGE_CASES = {
    "stress": lambda dim, dtype, fit: _material_cases("stress", dim, dtype, MATERIAL_SETS, fit),
    "return_map": lambda dim, dtype, fit: _material_cases("return_map", dim, dtype, PLASTIC_SETS, fit),
    "p2g": partial(_transfer_cases, "p2g"),
    "p2g_fused": _fused_cases,
    "grid_update": _grid_update_cases,
    "g2p": partial(_transfer_cases, "g2p"),
    "step": partial(_transfer_cases, "step"),
    "ledger": _ledger_cases,
    **{stage: partial(_async_cases, stage) for stage in ASYNC_CONFORMANCE_STAGES},
    **{stage: partial(_cpic_cases, stage) for stage in CPIC_CONFORMANCE_STAGES},
}


# -------------------------------------------------------------------------------------- extreme cases
#: the methods of the position and Δt extremes: each kernel once, both forces, an affine scheme and FLIP
EXTREME_METHODS = ("mls-mls-quadratic", "pic-classic-linear", "flip-classic-cubic")
#: the strain a ``from-rest`` block settles to on the floor under the gravity of :func:`extreme_scene`
REST_STRAIN = 1e-3


def exact_grid(grid):
    """The box ``grid`` (:func:`case_grid`) with its cell size rounded to a power of two and its origin to a whole
    number of cells: every node and face position, and every grid coordinate computed from one, is exact in any
    arithmetic, so that a particle placed on a line is on it for every code."""
    dx = 2.0 ** round(float(np.log2(grid["dx"])))
    cells = np.round(np.asarray(grid["size"]) / grid["dx"])
    origin = np.round(np.asarray(grid["origin"]) / grid["dx"]) * dx
    return {"origin": origin.tolist(), "size": (cells * dx).tolist(), "dx": dx}


def extreme_scene(declared, extreme, label):
    r"""``(declared, dt)``: the scene of a catalogue case that holds ``extreme``, and its Δt.

    * an exact grid (:func:`exact_grid`) for the position extremes;
    * the materials :data:`~.extremes.STIFFNESS_FACTOR` times stiffer (``E``, ``K``) for ``large-stiffness``;
    * for ``from-rest``, gravity along the catalogue's of :math:`g = \epsilon c^2 / H`, the strain
      :math:`\epsilon` = :data:`REST_STRAIN` of the block of :func:`~.extremes.at_rest_block` on the floor (its height
      :math:`H`, :data:`~.extremes.BLOCK_CELLS`) at the rest wave speed :math:`c`; none for ``pushed-from-rest``;
    * Δt at the scheme's measured stability limit (``cfl-limit``, :func:`mpmref.run.stability.stable_cfl`), at
      :data:`~.extremes.REST_CFL` at rest, else drawn (:func:`~.states.draw_step`).
    """
    declared = dict(declared)
    if extreme.exact_grid:
        declared["grid"] = exact_grid(declared["grid"])
    if extreme.name == "large-stiffness":
        declared["materials"] = {name: {k: v * STIFFNESS_FACTOR if k in ("E", "K") else v for k, v in m.items()}
                                 for name, m in declared["materials"].items()}
    if extreme.multi_step:
        scene = Scene.from_dict(declared)
        g = np.asarray(GRAVITY[:scene.dim])
        strength = REST_STRAIN * drawn_wave_speed(scene) ** 2 / (BLOCK_CELLS[scene.dim][1] * scene.grid.dx)
        declared["gravity"] = (0.0 * g if extreme.name == "pushed-from-rest" else strength * g / np.linalg.norm(g))
        declared["gravity"] = declared["gravity"].tolist()
    scene = Scene.from_dict(declared)
    if extreme.cfl == "limit":
        return declared, step_at(scene, stable_cfl(scene.method.scheme), catalogue_scales(scene).speed)
    if extreme.cfl == "rest":
        return declared, step_at(scene, REST_CFL, 0.0)
    return declared, draw_step(label, scene)


def _extreme_material_cases(stage, dim, dtype, fit, families):
    """Each material alone (:data:`MATERIALS`, the plastic ones for the return map), holding each family of
    ``families(material type)`` that applies to it."""
    walls, _ = fit.walls(dim)
    names = PLASTIC_SETS[:-1] if stage == "return_map" else tuple(MATERIALS)
    return [drawn_case(stage, dim, name, dtype, (name,), fit.method, walls, fit=fit, extreme=EXTREMES[family])
            for name in names for family in families(MATERIALS[name]["type"])]


def _stress_families(kind):
    """The deformation families of a stress case of material ``kind``: the near-symmetric one for solids only."""
    solid = MATERIAL_CLASSES[kind].tracks == "F"
    return ("rest", "near-symmetric-F", "collapse") if solid else ("rest", "collapse")


def _extreme_method_cases(stage, dim, dtype, fit, families):
    """The methods of :data:`EXTREME_METHODS` (no FLIP for the fused P2G) on the solid and the fluid, each holding each
    of ``families`` that holds for its kernel (:func:`~.extremes.holds_for`)."""
    names, material_suffix = fit.material_set(TRANSFER_MATERIALS)
    walls, wall_suffix = fit.walls(dim)
    wall_suffix = wall_suffix if "boundary" in STAGE_PARTS[stage] else ""
    methods = [method_of(m) for m in EXTREME_METHODS if not (stage == "p2g_fused" and m.startswith("flip"))]
    return [drawn_case(stage, dim, method_label(m) + material_suffix + wall_suffix, dtype, names, method=m,
                       boundary=walls, fit=fit, extreme=EXTREMES[family]) for m in methods for family in families
            if holds_for(EXTREMES[family], KERNELS[m["kernel"]])]


def _extreme_mixed_cases(stage, dim, dtype, fit, families):
    """Every material together (:meth:`Fit.mixed_set`) on the method and walls ``fit`` gives, holding each of
    ``families``."""
    names, variant = fit.mixed_set()
    walls, wall_suffix = fit.walls(dim)
    return [drawn_case(stage, dim, variant + fit.method_suffix() + wall_suffix, dtype, names, fit.method, walls,
                       fit=fit, extreme=EXTREMES[family]) for family in families]


POSITION_FAMILIES = ("on-nodes-and-faces", "domain-edge")


def extreme_cases(stage, dim, dtype, fit):
    """The catalogue's cases at the extremes (:mod:`~mpmref.conformance.extremes`) of ``stage``: the stress of each
    material at rest, near symmetric and collapsing, and all of them a million times stiffer; the return maps at
    their yield surfaces and collapsing; P2G, G2P and steps with particles on nodes and faces and at the domain's
    edge; the grid update with empty and nearly empty nodes beside full ones; steps and ledgers at the stability
    limit; steps from rest, on the floor and pushed, and stiff. None for the stages of asynchronous stepping and
    CPIC."""
    walls, _ = fit.walls(dim)
    cases = {
        "stress": lambda: _extreme_material_cases(stage, dim, dtype, fit, _stress_families)
        + _extreme_mixed_cases(stage, dim, dtype, fit, ("large-stiffness",)),
        "return_map": lambda: _extreme_material_cases(stage, dim, dtype, fit, lambda kind: ("yield-surface",
                                                                                           "collapse")),
        "grid_update": lambda: [drawn_case(stage, dim, "mixed", dtype, fit.kinds[:1] or ("fixed_corotated",),
                                           fit.method, walls, fit=fit, extreme=EXTREMES["massless-neighbours"])],
        "step": lambda: _extreme_method_cases(stage, dim, dtype, fit, (*POSITION_FAMILIES, "cfl-limit"))
        + _extreme_mixed_cases(stage, dim, dtype, fit, ("from-rest", "pushed-from-rest", "large-stiffness")),
        "ledger": lambda: _extreme_method_cases(stage, dim, dtype, fit, ("cfl-limit",)),
    }
    if stage in ("p2g", "p2g_fused", "g2p"):
        made = _extreme_method_cases(stage, dim, dtype, fit, POSITION_FAMILIES)
    else:
        made = cases[stage]() if stage in cases else []
    return [c for c in made if dtype == "float64" or c.extreme.float32]


def _validated(name, values, allowed):
    unknown = sorted(set(values or ()) - set(allowed))
    if unknown:
        raise ValueError(f"unknown {name} {unknown}: the {name} are {list(allowed)}")


def base_seed(value):
    """``value`` if it is a base seed (an integer >= 0), else :class:`~mpmref.errors.ArgumentError` (a
    ``ValueError``) naming it."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
        raise ArgumentError("seed", value, "an integer >= 0 (the base seed of the draws)")
    return int(value)


def make_cases(dims=(2, 3), stages=CONFORMANCE_STAGES, dtype="float64", materials=None, implements=None,
               schemes=None, kernels=None, seed=0, extremes=True):
    """The conformance cases of ``stages`` in the dimensions ``dims``, in ``dtype`` (a list of
    :class:`~.case.ConformanceCase`).

    The default is the seven stages of every backend (its six and the energy ledger of a step); the stages of
    asynchronous stepping (:data:`.stages.ASYNC_CONFORMANCE_STAGES`) and the CPIC stages
    (:data:`.stages.CPIC_CONFORMANCE_STAGES`, float64 only) are included when asked for, e.g.
    ``stages=ALL_CONFORMANCE_STAGES``.

    ``implements`` (a backend's :class:`~mpmref.backends.capabilities.Implements`) fits the catalogue to that backend
    (module docstring); the cases it does not implement stay, for the check to list as not applicable. ``materials``
    (material types, e.g. ``("fluid",)``), ``schemes`` and ``kernels`` select: the catalogue is fitted to those
    materials (the per-method cases run on the fluid alone for ``("fluid",)``), and a case whose stage depends on
    the materials or the method and whose materials, scheme or kernel are not among them is left out. ``seed`` (an
    integer >= 0, ``--seed``) is the base seed of the draws: 0, the default, gives the same cases on every machine;
    another gives every case a new grid, Δt, time and state (:func:`~.case.seeded_label`). ``extremes`` adds the cases
    at the extremes (:func:`extreme_cases`, :mod:`~mpmref.conformance.extremes`) after each stage's drawn ones.
    """
    _validated("stages", stages, ALL_CONFORMANCE_STAGES)
    if dtype not in DEFAULT_RTOL:
        raise ValueError(f"unknown dtype {dtype!r}: use one of {list(DEFAULT_RTOL)}")
    _validated("material types", materials, MATERIALS)
    _validated("schemes", schemes, SCENE_SCHEMES)
    _validated("kernels", kernels, KERNELS)
    base_seed(seed)
    fit = fit_for(implements, materials, schemes, kernels, seed)
    cases = [case for stage in stages for dim in dims
             for case in _STAGE_CASES[stage](dim, dtype, fit) + (extreme_cases(stage, dim, dtype, fit) if extremes
                                                                 else [])]
    return [c for c in cases if fit.selects(c)]

