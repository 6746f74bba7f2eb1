"""Scenes: what a user declares, as a TOML file or through ``SceneBuilder``, validated before any work.

Every problem is reported as a :class:`~mpmref.errors.SceneError` naming the field (dotted path), the
value given and the allowed range. See ``docs/scenes.md`` for every field and its default.
"""

import copy
import json
import math
import tomllib
from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path

import numpy as np

from . import limits
from .errors import SceneError
from .physics.boundary import BOUNDARY_TYPES
from .physics.colliders import Ball, Box, Collider, Cylinder, Plane
from .physics.kernels import KERNELS, get_kernel
from .physics.catalogue import MATERIALS as MATERIAL_TYPES
from .physics.materials import lame_parameters
from .physics.rigid import validate_polyline
from .physics.trimesh import mass_properties, read_trimesh, validate_trimesh
from .physics.rigid_dynamics import (CONTACT_TYPES, MOTIONS, RigidBody, area_mass_properties, encode_friction,
                                     line_mass_properties)
from .physics.scheme import resolve
from .state import Grid

SCHEMES = ("pic", "flip", "apic", "polypic", "mls")
FORCES = ("mls", "classic")
WALL_TYPES = BOUNDARY_TYPES + ("open",)
DOMAIN_EXIT_POLICIES = ("error", "clamp", "delete")
DTYPES = ("float64", "float32")
SHAPES = ("box", "disk", "sphere", "points", "mesh")
SAMPLINGS = ("regular", "jittered", "random")
OUTPUT_FIELDS = ("velocity", "mass", "volume", "J", "stress", "pressure", "material")
#: what the grid output covers: the block-aligned box of the nodes with mass, or every node of the grid
GRID_REGIONS = ("active", "all")
AXES = "xyz"
STEPPINGS = ("sync", "async")

TOP_KEYS = {"dim", "dtype", "grid", "method", "materials", "bodies", "colliders", "gravity", "boundary", "time",
            "output", "name", "rigid_bodies", "emitters"}
COUPLINGS = ("none", "cpic")
#: schemes CPIC is defined for (docs/cpic.md are written for PIC, APIC and MLS-MPM)
CPIC_SCHEMES = ("pic", "apic", "mls")
#: how a CPIC particle near several bodies gets its distance and normal (docs/cpic.md, "Per-body fit")
CPIC_FITS = ("single", "per_body")
RIGID_COMMON_KEYS = {"vertices", "segments", "closed", "motion", "type", "friction"}
#: the same in 3D: a triangle mesh inline (vertices, triangles) or from a file read by meshio (mesh)
RIGID_COMMON_KEYS_3D = {"vertices", "triangles", "mesh", "closed", "motion", "type", "friction"}
#: keys each rigid-body motion accepts besides the common ones
#: dynamic-body keys of the 2D sand wheel (a pin, angular damping, welds) that 3D bodies do not have yet
PINNED_KEYS_2D = {"pinned", "angular_damping", "welded_to"}
RIGID_MOTION_KEYS = {
    "fixed": set(),
    "scripted": {"velocity", "angular_velocity", "center", "keyframes"},
    "dynamic": {"density", "velocity", "angular_velocity", "gravity", "pinned", "angular_damping", "welded_to"},
}
COLLIDER_SHAPES = ("plane", "box", "disk", "sphere", "cylinder")
MATERIAL_KEYS = {
    "fixed_corotated": {"type", "E", "nu", "rho"},
    "neo_hookean": {"type", "E", "nu", "rho"},
    "fluid": {"type", "K", "gamma", "rho"},
    "snow": {"type", "E", "nu", "rho", "theta_c", "theta_s", "hardening", "Jp_min", "Jp_max"},
    "sand": {"type", "E", "nu", "rho", "friction_angle", "cohesion"},
}
EMITTER_KEYS = {"shape", "material", "center", "radius", "velocity", "ppc", "sampling", "seed", "start", "interval",
                "until"}
BODY_KEYS = {
    "shape", "material", "lower", "upper", "center", "radius", "positions", "file", "ppc", "sampling",
    "seed", "count", "particle_volume", "velocity", "angular_velocity", "rotation_center",
}


# ----------------------------------------------------------------------------------------- checks
def _fail(path, value, allowed):
    raise SceneError(path, value, allowed)


def _section(data, path, allowed_keys):
    if not isinstance(data, dict):
        _fail(path, data, "a table (mapping)")
    unknown = sorted(set(data) - set(allowed_keys))
    if unknown:
        _fail(f"{path}.{unknown[0]}" if path else unknown[0], data[unknown[0]],
              f"one of the known keys {sorted(allowed_keys)}")
    return data


def _number(data, key, path, default=None, lo=None, hi=None, lo_open=False, hi_open=False, required=False):
    full = f"{path}.{key}" if path else key
    if key not in data:
        if required:
            _fail(full, None, f"a number{_range_text(lo, hi, lo_open, hi_open)} (required)")
        return default
    value = data[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        _fail(full, value, f"a finite number{_range_text(lo, hi, lo_open, hi_open)}")
    bad_lo = lo is not None and (value <= lo if lo_open else value < lo)
    bad_hi = hi is not None and (value >= hi if hi_open else value > hi)
    if bad_lo or bad_hi:
        _fail(full, value, f"a number{_range_text(lo, hi, lo_open, hi_open)}")
    return float(value)


def _range_text(lo, hi, lo_open, hi_open):
    if lo is None and hi is None:
        return ""
    left = "(" if lo_open else "["
    right = ")" if hi_open else "]"
    return f" in {left}{'-inf' if lo is None else lo}, {'inf' if hi is None else hi}{right}"


def _integer(data, key, path, default=None, lo=None, hi=None, required=False):
    full = f"{path}.{key}" if path else key
    if key not in data:
        if required:
            _fail(full, None, f"an integer in [{lo}, {hi}] (required)")
        return default
    value = data[key]
    if isinstance(value, bool) or not isinstance(value, int) or (lo is not None and value < lo) or (
        hi is not None and value > hi
    ):
        _fail(full, value, f"an integer in [{lo if lo is not None else '-inf'}, {hi if hi is not None else 'inf'}]")
    return int(value)


def _choice(data, key, path, options, default=None, required=False):
    full = f"{path}.{key}" if path else key
    if key not in data:
        if required:
            _fail(full, None, f"one of {list(options)} (required)")
        return default
    if data[key] not in options:
        _fail(full, data[key], f"one of {list(options)}")
    return data[key]


def _vector(data, key, path, dim, default=None, required=False, positive=False):
    full = f"{path}.{key}" if path else key
    if key not in data:
        if required:
            _fail(full, None, f"a list of {dim} numbers (required)")
        return None if default is None else np.array(default, dtype=np.float64)
    value = data[key]
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        value = [value] * dim
    ok = isinstance(value, (list, tuple)) and len(value) == dim and all(
        isinstance(c, (int, float)) and not isinstance(c, bool) and math.isfinite(c) for c in value
    )
    if not ok or (positive and min(value) <= 0):
        _fail(full, value, f"a list of {dim} finite{' positive' if positive else ''} numbers")
    return np.array(value, dtype=np.float64)


# ------------------------------------------------------------------------------------------ specs
@dataclass(frozen=True)
class MethodSpec:
    """The declared transfer scheme, force discretisation and kernel (``Scene.transfer`` resolves them)."""

    scheme: str
    force: str
    kernel: str
    flip_alpha: float
    velocity_gradient: str = ""  # "" follows ``force`` (see ``_parse_method``)
    coupling: str = "none"
    pushing_force: float = 0.0
    penalty: float = 0.0
    momentum_exact: bool = False
    ghost_force: bool = True
    cpic_fit: str = "single"

    def __post_init__(self):
        if not self.velocity_gradient:
            object.__setattr__(self, "velocity_gradient", self.force)


@dataclass(frozen=True)
class WallSpec:
    type: str
    friction: float


@dataclass(frozen=True)
class BoundarySpec:
    width: int
    walls: dict  # "x_min" -> WallSpec
    domain_exit: str


@dataclass(frozen=True)
class TimeSpec:
    """Time stepping. ``stepping = "async"`` uses ``tick`` (seconds per integer time unit), ``levels``
    (block steps are ``2^k`` ticks, ``k = 0 .. levels``), ``cfl`` (the strength multiplier),
    ``advection_cfl`` (cells a particle may cross per step) and ``interface`` (how level interfaces exchange
    momentum: ``"conservative"``, impulse refluxing, or ``"reference"``, Fang et al. 2018 as published);
    see docs/async.md."""

    dt: float | None
    cfl: float | None
    steps: int | None
    t_end: float | None
    stepping: str = "sync"
    tick: float | None = None
    levels: int | None = None
    advection_cfl: float | None = None
    interface: str | None = None


@dataclass(frozen=True)
class OutputSpec:
    every: int
    fields: tuple
    grid: bool
    checkpoint: bool
    grid_region: str = "active"


@dataclass(frozen=True)
class BodySpec:
    index: int
    shape: str
    material: str
    params: dict


@dataclass(frozen=True)
class EmitterSpec:
    """A particle source (``[[emitters]]``): a disk (2D) or sphere (3D) of material released again and again.

    ``body`` is the release as a body at time 0 (sampled by :func:`mpmref.bodies.sample_body`); a release
    is made at the first step that starts at or after each time ``start + k interval`` before ``until``
    (:mod:`mpmref.emitters`).
    """

    index: int
    body: BodySpec
    start: float
    interval: float
    until: float


@dataclass
class Scene:
    """A validated scene. Build with :meth:`from_toml`, :meth:`from_dict` or :class:`SceneBuilder`."""

    name: str
    dim: int
    dtype: np.dtype
    grid: Grid
    method: MethodSpec
    materials: dict  # name -> material object (ordered: index = material id)
    bodies: list
    colliders: list
    gravity: np.ndarray
    boundary: BoundarySpec
    time: TimeSpec
    output: OutputSpec
    source: dict = field(repr=False)
    base_dir: Path = field(default_factory=Path.cwd, repr=False)
    rigid_bodies: list = field(default_factory=list)  # RigidBody objects (CPIC coupling)
    emitters: list = field(default_factory=list)  # EmitterSpec objects

    @cached_property
    def transfer(self):
        """The resolved :class:`~mpmref.physics.scheme.TransferSpec` (scheme, force, kernel, tracked state)."""
        return resolve(self.method, self.dim, self.material_list)

    # --------------------------------------------------------------------------- construction
    @classmethod
    def from_toml(cls, path):
        """Read and validate a TOML scene file; relative file paths resolve next to it."""
        path = Path(path)
        data = _load_scene_file(path)
        data.setdefault("name", path.stem)
        return cls.from_dict(data, base_dir=path.parent)

    @classmethod
    def from_dict(cls, data, base_dir=None):
        """Validate a scene given as nested dicts (the TOML structure) and return a :class:`Scene`."""
        data = copy.deepcopy(data)
        _section(data, "", TOP_KEYS)
        dim = _integer(data, "dim", "", lo=2, hi=3, required=True)
        dtype = np.dtype(_choice(data, "dtype", "", DTYPES, default="float64"))
        method = _parse_method(data.get("method", {}))
        grid = _parse_grid(data.get("grid", {}), dim, get_kernel(method.kernel).support)
        materials = _parse_materials(data.get("materials"))
        bodies = _parse_bodies(data.get("bodies"), dim, materials)
        colliders = _parse_colliders(data.get("colliders", []), dim)
        gravity = _vector(data, "gravity", "", dim, default=[0.0] * dim)
        boundary = _parse_boundary(data.get("boundary", {}), dim, grid)
        time = _parse_time(data.get("time", {}))
        rigid_bodies = _parse_rigid_bodies(data.get("rigid_bodies", []), dim, grid, method, time, base_dir)
        output = _parse_output(data.get("output", {}))
        emitters = _parse_emitters(data.get("emitters", []), dim, materials, grid, get_kernel(method.kernel), time)
        limits.check_scene_memory({"dim": dim, "dtype": dtype, "grid": grid,
                                   "transfer": resolve(method, dim, list(materials.values())),
                                   "bodies": bodies, "colliders": colliders,
                                   "grid_field": _cell_size_field(data["grid"])[0],
                                   "grid_value": _cell_size_field(data["grid"])[1]})
        name = data.get("name", "scene")
        if not isinstance(name, str) or not name or any(c in name for c in "/\\"):
            _fail("name", name, "a non-empty string without path separators")
        return cls(name=name, dim=dim, dtype=dtype, grid=grid, method=method, materials=materials,
                   bodies=bodies, colliders=colliders, gravity=gravity, boundary=boundary, time=time, output=output,
                   source=data, base_dir=Path(base_dir) if base_dir else Path.cwd(), rigid_bodies=rigid_bodies,
                   emitters=emitters)

    # ------------------------------------------------------------------------------- derived
    @property
    def kernel(self):
        return get_kernel(self.method.kernel)

    @property
    def material_list(self):
        return list(self.materials.values())

    def tracks(self, kind):
        """Whether any material of the scene tracks ``kind`` (``"F"``, ``"J"`` or ``"Jp"``)."""
        return getattr(self.transfer, f"tracks_{kind}")

    def max_wave_speed(self):
        """The largest rest-state wave speed of the scene's materials (for set-up; steps use the current one)."""
        return max(m.wave_speed() for m in self.materials.values())

    def valid_region(self):
        """Lower and upper bound of particle positions for which the kernel stencil fits on the grid."""
        k = self.kernel
        lo = self.grid.origin + k.low_margin * self.grid.dx
        hi = self.grid.origin + (np.array(self.grid.cells) - k.high_margin) * self.grid.dx
        return lo, hi

    def fingerprint(self):
        """A stable JSON text of the declared scene (used to match checkpoints to scenes)."""
        return json.dumps(self.source, sort_keys=True, default=str)


def _load_scene_file(path):
    """The parsed TOML of a scene file; what is not a readable UTF-8 TOML file is a :class:`SceneError`."""
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise SceneError("scene file", str(path), "an existing TOML file") from None
    except IsADirectoryError:
        raise SceneError("scene file", str(path), "a TOML file, not a directory") from None
    except OSError as exc:
        raise SceneError("scene file", str(path), f"a readable TOML file ({exc.strerror})") from None
    if raw.startswith((b"\xff\xfe", b"\xfe\xff")):
        raise SceneError("scene file", str(path), "a UTF-8 text file (this one is UTF-16; save it as UTF-8)")
    nul = raw.find(b"\x00")
    if nul >= 0:
        raise SceneError("scene file", str(path), f"a UTF-8 text file (byte {nul} is NUL: a binary or UTF-16 file)")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise SceneError("scene file", str(path), f"a UTF-8 text file (byte {exc.start} is not UTF-8: a binary "
                                                  "file or another encoding)") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SceneError("scene file", str(path), f"valid TOML ({exc})") from None


# ----------------------------------------------------------------------------------- sections
def _parse_grid(g, dim, support):
    _section(g, "grid", {"origin", "size", "dx", "cells", "block"})
    origin = _vector(g, "origin", "grid", dim, default=[0.0] * dim)
    size = _vector(g, "size", "grid", dim, required=True, positive=True)
    if ("dx" in g) == ("cells" in g):
        _fail("grid.dx", g.get("dx"), "exactly one of 'grid.dx' or 'grid.cells' (cells along the first axis)")
    if "dx" in g:
        dx = _number(g, "dx", "grid", lo=0.0, lo_open=True)
    else:
        dx = size[0] / _integer(g, "cells", "grid", lo=4, hi=4096)
    cells_f = size / dx
    limits.check_cells_per_axis(cells_f, *_cell_size_field(g), dim)
    cells = np.rint(cells_f).astype(int)
    if np.any(np.abs(cells_f - cells) > 1e-9 * cells_f) or np.any(cells < 4):
        _fail("grid.size", size.tolist(), f"a whole number (>= 4) of cells of dx = {dx} along every axis")
    block = _integer(g, "block", "grid", default=4, lo=1, hi=256)
    if block & (block - 1) or block < support:
        _fail("grid.block", block, f"a power of two >= {support} (the kernel support in nodes)")
    return Grid(origin=origin, dx=float(dx), cells=tuple(int(c) for c in cells), block=block)


def _cell_size_field(g):
    """The grid field that set the cell size, and its value (for memory-limit messages)."""
    return ("grid.dx", g["dx"]) if "dx" in g else ("grid.cells", g["cells"])


def _parse_method(m):
    _section(m, "method", {"scheme", "force", "kernel", "flip_alpha", "velocity_gradient", "coupling",
                           "pushing_force", "penalty", "momentum_exact", "ghost_force", "cpic_fit"})
    scheme = _choice(m, "scheme", "method", SCHEMES, default="mls")
    force = _choice(m, "force", "method", FORCES, default="mls")
    gradient = _choice(m, "velocity_gradient", "method", FORCES, default=force)
    kernel = _choice(m, "kernel", "method", tuple(KERNELS), default="quadratic")
    if "flip_alpha" in m and scheme != "flip":
        _fail("method.flip_alpha", m["flip_alpha"], f"only with method.scheme = 'flip' (scheme is '{scheme}')")
    alpha = _number(m, "flip_alpha", "method", default=0.95 if scheme == "flip" else 0.0, lo=0.0, hi=1.0)
    spec = MethodSpec(scheme=scheme, force=force, kernel=kernel, flip_alpha=alpha, velocity_gradient=gradient,
                      **_parse_coupling(m, scheme))
    _check_combination(spec)
    return spec


def _parse_coupling(m, scheme):
    """The CPIC options of ``[method]`` (docs/cpic.md): coupling, pushing force, penalty, exact variant."""
    coupling = _choice(m, "coupling", "method", COUPLINGS, default="none")
    if coupling == "none":
        for key in ("pushing_force", "penalty", "momentum_exact", "ghost_force", "cpic_fit"):
            if key in m:
                _fail(f"method.{key}", m[key], "only with method.coupling = 'cpic'")
        return {}
    if scheme not in CPIC_SCHEMES:
        why = ("FLIP's increment needs every stencil node's velocity before and after forces, and a CPIC particle "
               "has no such node on the far side of a body" if scheme == "flip" else
               "PolyPIC's higher modes are projected from all stencil nodes, and ghost velocities at incompatible "
               "nodes define no modes")
        _fail("method.scheme", scheme, f"one of {list(CPIC_SCHEMES)} with method.coupling = 'cpic' ({why})")
    exact, ghost_force = m.get("momentum_exact", False), m.get("ghost_force", True)
    for key, value in (("momentum_exact", exact), ("ghost_force", ghost_force)):
        if not isinstance(value, bool):
            _fail(f"method.{key}", value, "true or false")
    if exact and scheme != "pic":
        _fail("method.momentum_exact", exact, f"false with method.scheme = '{scheme}' (the exact variant needs PIC: "
              "the affine term is not given to bodies at incompatible nodes)")
    push = _number(m, "pushing_force", "method", default=0.0 if exact else 2e4, lo=0.0)
    if exact and push != 0.0:
        _fail("method.pushing_force", push, "0 with method.momentum_exact = true (the pushing force injects momentum "
              "that no body receives)")
    return {"coupling": coupling, "pushing_force": push, "momentum_exact": exact, "ghost_force": ghost_force,
            "penalty": _number(m, "penalty", "method", default=0.0, lo=0.0),
            "cpic_fit": _choice(m, "cpic_fit", "method", CPIC_FITS, default="single")}


def _check_combination(spec):
    """Refuse combinations of scheme, force and kernel that have no consistent discretisation."""
    if spec.scheme == "mls" and spec.force == "classic":
        _fail("method.force", "classic", "'mls' with method.scheme = 'mls' (MLS-MPM is the APIC transfer with "
              "the MLS force; for APIC with the classic force use scheme = 'apic', force = 'classic')")
    if spec.kernel == "linear" and spec.scheme in ("apic", "polypic", "mls"):
        _fail("method.kernel", "linear", f"'quadratic' or 'cubic' with method.scheme = '{spec.scheme}' (an affine "
              "scheme needs a constant inertia D_p, which the linear hat does not have)")
    for key in ("force", "velocity_gradient"):
        if spec.kernel == "linear" and getattr(spec, key) == "mls":
            _fail(f"method.{key}", "mls", "'classic' with method.kernel = 'linear' (the MLS force and velocity "
                  "gradient need a constant D_p = k dx^2 I; the linear hat's D_p varies with position and is "
                  "singular on nodes)")


def _parse_materials(mats):
    if not isinstance(mats, dict) or not mats:
        _fail("materials", mats, "a table with at least one named material, e.g. [materials.jelly]")
    out = {}
    for name, spec in mats.items():
        path = f"materials.{name}"
        if not isinstance(spec, dict):
            _fail(path, spec, "a table")
        kind = _choice(spec, "type", path, tuple(MATERIAL_TYPES), required=True)
        _section(spec, path, MATERIAL_KEYS[kind])
        rho = _number(spec, "rho", path, default=1000.0, lo=0.0, lo_open=True)
        if kind == "fluid":
            K = _number(spec, "K", path, required=True, lo=0.0, lo_open=True)
            gamma = _number(spec, "gamma", path, default=7.0, lo=1.0, hi=20.0)
            out[name] = MATERIAL_TYPES[kind](K=K, gamma=gamma, rho=rho)
        else:
            E = _number(spec, "E", path, required=True, lo=0.0, lo_open=True)
            nu = _number(spec, "nu", path, default=0.3, lo=0.0, hi=0.5, hi_open=True)
            out[name] = MATERIAL_TYPES[kind](E=E, nu=nu, rho=rho, **_plastic_parameters(kind, spec, path))
            mu, lam = lame_parameters(E, nu)
            if not (math.isfinite(mu) and math.isfinite(lam)):
                _fail(f"{path}.nu", nu, "a value for which the Lamé parameters are finite")
    return out


def _plastic_parameters(kind, spec, path):
    """Validated extra parameters of the plastic materials (defaults: Stomakhin 2013; Klar 2016)."""
    if kind == "snow":
        p = {"theta_c": _number(spec, "theta_c", path, default=2.5e-2, lo=0.0, hi=1.0, lo_open=True, hi_open=True),
             "theta_s": _number(spec, "theta_s", path, default=7.5e-3, lo=0.0),
             "hardening": _number(spec, "hardening", path, default=10.0, lo=0.0, hi=100.0),
             "Jp_min": _number(spec, "Jp_min", path, default=0.6, lo=0.0, hi=1.0, lo_open=True),
             "Jp_max": _number(spec, "Jp_max", path, default=20.0, lo=1.0)}
        return p
    if kind == "sand":
        return {"friction_angle": _number(spec, "friction_angle", path, default=30.0, lo=0.0, hi=90.0, hi_open=True),
                "cohesion": _number(spec, "cohesion", path, default=0.0, lo=0.0, hi=1.0)}
    return {}


def _parse_bodies(bodies, dim, materials):
    if not isinstance(bodies, list) or not bodies:
        _fail("bodies", bodies, "a non-empty array of tables, e.g. [[bodies]]")
    out = []
    for i, b in enumerate(bodies):
        path = f"bodies[{i}]"
        _section(b, path, BODY_KEYS)
        shape = _choice(b, "shape", path, SHAPES, required=True)
        material = _choice(b, "material", path, tuple(materials), required=True)
        p = {"velocity": _vector(b, "velocity", path, dim, default=[0.0] * dim)}
        if shape == "box":
            p["lower"] = _vector(b, "lower", path, dim, required=True)
            p["upper"] = _vector(b, "upper", path, dim, required=True)
            if np.any(p["upper"] <= p["lower"]):
                _fail(f"{path}.upper", p["upper"].tolist(), f"greater than lower = {p['lower'].tolist()} on every axis")
        elif shape in ("disk", "sphere"):
            want = 2 if shape == "disk" else 3
            if dim != want:
                _fail(f"{path}.shape", shape, f"'{'disk' if dim == 2 else 'sphere'}' in a {dim}D scene")
            p["center"] = _vector(b, "center", path, dim, required=True)
            p["radius"] = _number(b, "radius", path, required=True, lo=0.0, lo_open=True)
        elif shape == "points":
            p["positions"] = _points_array(b, path, dim)
        else:
            if not isinstance(b.get("file"), str):
                _fail(f"{path}.file", b.get("file"), "the path of a mesh or point cloud readable by meshio")
            p["file"] = b["file"]
        p["ppc"] = _integer(b, "ppc", path, default=2**dim, lo=1, hi=64)
        p["sampling"] = _choice(b, "sampling", path, SAMPLINGS, default="regular")
        samples = shape != "points"  # for given points, ppc only sets the particle volume
        if samples and p["sampling"] == "regular" and round(p["ppc"] ** (1.0 / dim)) ** dim != p["ppc"]:
            power = "square" if dim == 2 else "cube"
            _fail(f"{path}.ppc", p["ppc"], f"a perfect {power} (1, {2**dim}, {3**dim}, ...) for regular sampling")
        p["seed"] = _integer(b, "seed", path, default=0, lo=0)
        p["count"] = _integer(b, "count", path, default=None, lo=1)
        if p["count"] is not None and p["sampling"] != "random":
            _fail(f"{path}.count", p["count"], "only with sampling = 'random'")
        p["particle_volume"] = _number(b, "particle_volume", path, default=None, lo=0.0, lo_open=True)
        if dim == 2:
            p["angular_velocity"] = _number(b, "angular_velocity", path, default=0.0)
        else:
            p["angular_velocity"] = _vector(b, "angular_velocity", path, 3, default=[0.0, 0.0, 0.0])
        p["rotation_center"] = _vector(b, "rotation_center", path, dim)
        out.append(BodySpec(index=i, shape=shape, material=material, params=p))
    return out


def _parse_rigid_bodies(bodies, dim, grid, method, time, base_dir=None):
    """The ``[[rigid_bodies]]`` (CPIC): validated 2D polylines or 3D triangle meshes with their motion and contact."""
    if not isinstance(bodies, list):
        _fail("rigid_bodies", bodies, "an array of tables, e.g. [[rigid_bodies]]")
    if bodies and method.coupling != "cpic":
        _fail("method.coupling", method.coupling, "'cpic' when the scene has [[rigid_bodies]]")
    if method.coupling == "cpic" and not bodies:
        _fail("method.coupling", "cpic", "'none' in a scene without [[rigid_bodies]]")
    if bodies and time.stepping != "sync":
        _fail("time.stepping", time.stepping, "'sync' in a scene with [[rigid_bodies]] (CPIC runs in the synchronous "
              "step)")
    if dim == 3:
        if method.cpic_fit != "single":
            _fail("method.cpic_fit", method.cpic_fit, "'single' in 3D (the per-body fit is built in 2D only)")
        return [_parse_rigid_body3d(b, i, grid, base_dir) for i, b in enumerate(bodies)]
    return _welds([_parse_rigid_body(b, i, grid) for i, b in enumerate(bodies)], bodies, grid)


def _parse_rigid_body(b, i, grid):
    path = f"rigid_bodies[{i}]"
    if not isinstance(b, dict):
        _fail(path, b, "a table")
    motion = _choice(b, "motion", path, MOTIONS, default="fixed")
    _section(b, path, RIGID_COMMON_KEYS | RIGID_MOTION_KEYS[motion])
    closed = b.get("closed", False)
    if not isinstance(closed, bool):
        _fail(f"{path}.closed", closed, "true or false")
    shape = validate_polyline(b.get("vertices"), b.get("segments"), closed=closed, index=i)
    lo, hi = grid.origin, grid.origin + np.array(grid.cells) * grid.dx
    outside = np.nonzero(np.any((shape.vertices < lo) | (shape.vertices > hi), axis=1))[0]
    if outside.size:
        k = int(outside[0])
        _fail(f"{path}.vertices", shape.vertices[k].tolist(), f"inside the domain [{lo.tolist()}, {hi.tolist()}] "
              f"(vertex {k} is outside)")
    friction = _contact_sides(b, path)
    params = {"shape": shape, "motion": motion, "friction": friction, "center": shape.vertices.mean(axis=0)}
    if motion == "scripted":
        params.update(_script(b, path, shape))
    elif motion == "dynamic":
        params.update(_dynamic(b, path, shape))
    return RigidBody(**params)


def _parse_rigid_body3d(b, i, grid, base_dir):
    """One 3D ``[[rigid_bodies]]`` entry: a triangle mesh inline or read by meshio, its motion and contact."""
    path = f"rigid_bodies[{i}]"
    if not isinstance(b, dict):
        _fail(path, b, "a table")
    motion = _choice(b, "motion", path, MOTIONS, default="fixed")
    for key in PINNED_KEYS_2D & set(b):
        _fail(f"{path}.{key}", b[key], "absent in 3D (pinned, damped and welded bodies are 2D only for now)")
    _section(b, path, RIGID_COMMON_KEYS_3D | RIGID_MOTION_KEYS[motion])
    closed = b.get("closed", False)
    if not isinstance(closed, bool):
        _fail(f"{path}.closed", closed, "true or false")
    domain = (grid.origin, grid.origin + np.array(grid.cells) * grid.dx)
    if "mesh" in b:
        inline = sorted({"vertices", "triangles"} & set(b))
        if inline:
            _fail(f"{path}.{inline[0]}", b[inline[0]], "absent when mesh = \"file\" gives the geometry")
        if not isinstance(b["mesh"], str):
            _fail(f"{path}.mesh", b["mesh"], "a file name (a triangle mesh meshio can read)")
        shape = read_trimesh(b["mesh"], closed=closed, index=i, domain=domain, base_dir=base_dir or ".")
    else:
        shape = validate_trimesh(b.get("vertices"), b.get("triangles"), closed=closed, index=i, domain=domain)
    params = {"shape": shape, "motion": motion, "friction": _contact_sides(b, path),
              "center": shape.vertices.mean(axis=0), "velocity": np.zeros(3), "angular_velocity": np.zeros(3)}
    if motion == "scripted":
        params.update(_script3d(b, path, shape))
    elif motion == "dynamic":
        params.update(_dynamic3d(b, path, shape))
    return RigidBody(**params)


def _script3d(b, path, shape):
    """A scripted 3D body: constant ``velocity`` and ``angular_velocity`` vectors, or keyframes of offset and rotation."""
    center = _vector(b, "center", path, 3, default=shape.vertices.mean(axis=0))
    if "keyframes" not in b:
        return {"center": center, "velocity": _vector(b, "velocity", path, 3, default=[0.0] * 3),
                "angular_velocity": _vector(b, "angular_velocity", path, 3, default=[0.0] * 3)}
    for key in ("velocity", "angular_velocity"):
        if key in b:
            _fail(f"{path}.{key}", b[key], "absent when keyframes are given (the keyframes set the motion)")
    frames = b["keyframes"]
    if not isinstance(frames, list) or len(frames) < 2:
        _fail(f"{path}.keyframes", frames, "a list of at least two tables {time, offset, rotation}")
    out = []
    for k, f in enumerate(frames):
        where = f"{path}.keyframes[{k}]"
        _section(f, where, {"time", "offset", "rotation"})
        t = _number(f, "time", where, required=True, lo=0.0)
        if out and t <= out[-1][0]:
            _fail(f"{where}.time", t, f"greater than the previous keyframe's time {out[-1][0]}")
        out.append((t, _vector(f, "offset", where, 3, default=[0.0] * 3),
                    _vector(f, "rotation", where, 3, default=[0.0] * 3)))
    return {"center": center, "keyframes": tuple(out)}


def _dynamic3d(b, path, shape):
    """A dynamic 3D body: mass, centre and inertia tensor from ``density`` over the volume (closed) or area (open)."""
    density = _number(b, "density", path, required=True, lo=0.0, lo_open=True)
    gravity = b.get("gravity", True)
    if not isinstance(gravity, bool):
        _fail(f"{path}.gravity", gravity, "true or false")
    mass, center, inertia = mass_properties(shape, density)
    return {"mass": mass, "center": center, "inertia": inertia, "gravity": gravity,
            "velocity": _vector(b, "velocity", path, 3, default=[0.0] * 3),
            "angular_velocity": _vector(b, "angular_velocity", path, 3, default=[0.0] * 3)}


def _contact_sides(b, path):
    """The encoded friction of side 0 and side 1 from ``type`` and ``friction`` (each one value or two)."""
    kinds = b.get("type", "separate")
    kinds = [kinds, kinds] if isinstance(kinds, str) else kinds
    if not isinstance(kinds, list) or len(kinds) != 2 or any(k not in CONTACT_TYPES for k in kinds):
        _fail(f"{path}.type", b.get("type"), f"one of {list(CONTACT_TYPES)}, or a list of two (side 0, side 1)")
    mu = b.get("friction", 0.0)
    mu = [mu, mu] if not isinstance(mu, list) else mu
    if len(mu) != 2 or any(isinstance(c, bool) or not isinstance(c, (int, float)) or not math.isfinite(c) or c < 0
                           for c in mu):
        _fail(f"{path}.friction", b.get("friction"), "a number >= 0, or a list of two (side 0, side 1)")
    return np.array([encode_friction(k, c) for k, c in zip(kinds, mu)])


def _script(b, path, shape):
    center = _vector(b, "center", path, 2, default=shape.vertices.mean(axis=0))
    if "keyframes" not in b:
        return {"center": center, "velocity": _vector(b, "velocity", path, 2, default=[0.0, 0.0]),
                "angular_velocity": _number(b, "angular_velocity", path, default=0.0)}
    for key in ("velocity", "angular_velocity"):
        if key in b:
            _fail(f"{path}.{key}", b[key], "absent when keyframes are given (the keyframes set the motion)")
    frames = b["keyframes"]
    if not isinstance(frames, list) or len(frames) < 2:
        _fail(f"{path}.keyframes", frames, "a list of at least two tables {time, offset, angle}")
    out = []
    for k, f in enumerate(frames):
        where = f"{path}.keyframes[{k}]"
        _section(f, where, {"time", "offset", "angle"})
        t = _number(f, "time", where, required=True, lo=0.0)
        if out and t <= out[-1][0]:
            _fail(f"{where}.time", t, f"greater than the previous keyframe's time {out[-1][0]}")
        out.append((t, _vector(f, "offset", where, 2, default=[0.0, 0.0]), _number(f, "angle", where, default=0.0)))
    return {"center": center, "keyframes": tuple(out)}


def _dynamic(b, path, shape):
    density = _number(b, "density", path, required=True, lo=0.0, lo_open=True)
    gravity = b.get("gravity", True)
    if not isinstance(gravity, bool):
        _fail(f"{path}.gravity", gravity, "true or false")
    if shape.closed:
        starts = np.bincount(shape.segments[:, 0], minlength=len(shape.vertices))
        if np.any(starts != 1):
            _fail(f"{path}.segments", shape.segments.tolist(), "consistently oriented segments for a closed dynamic "
                  "body (each vertex starts exactly one segment)")
        mass, center, inertia = area_mass_properties(shape, density)
    else:
        mass, center, inertia = line_mass_properties(shape, density)
    pinned = b.get("pinned", False)
    if not isinstance(pinned, bool):
        _fail(f"{path}.pinned", pinned, "true or false")
    if pinned and "velocity" in b:
        _fail(f"{path}.velocity", b["velocity"], "absent for a pinned body (its centre of mass does not move)")
    return {"mass": mass, "center": center, "inertia": inertia, "gravity": gravity, "pinned": pinned,
            "velocity": _vector(b, "velocity", path, 2, default=[0.0, 0.0]),
            "angular_velocity": _number(b, "angular_velocity", path, default=0.0),
            "angular_damping": _number(b, "angular_damping", path, default=0.0, lo=0.0),
            "welded_to": _integer(b, "welded_to", path, default=-1, lo=0)}


def _welds(parsed, declared, grid):
    """Check each ``welded_to`` (a pinned body turning with an earlier, unwelded pinned body about the same
    centre) and give a welded body its root's initial angular velocity."""
    out = list(parsed)
    for i, body in enumerate(parsed):
        k = body.welded_to
        if k < 0:
            continue
        path = f"rigid_bodies[{i}].welded_to"
        if k >= i or parsed[k].motion != "dynamic" or parsed[k].welded_to >= 0:
            _fail(path, k, f"the index of an earlier dynamic body that is not itself welded (0 .. {i - 1})")
        if not (body.pinned and parsed[k].pinned):
            _fail(path, k, f"a weld of two pinned bodies (set pinned = true on rigid_bodies[{i}] and "
                  f"rigid_bodies[{k}]; welds of free bodies are not built)")
        gap = float(np.linalg.norm(body.center - parsed[k].center))
        if gap > 1e-6 * grid.dx:
            _fail(path, k, f"a body pinned at the same centre (centres of mass {body.center.tolist()} and "
                  f"{parsed[k].center.tolist()} differ by {gap:.3g})")
        if "angular_velocity" in declared[i]:
            _fail(f"rigid_bodies[{i}].angular_velocity", declared[i]["angular_velocity"],
                  "absent on a welded body (it turns with the body it is welded to)")
        out[i] = replace(body, angular_velocity=parsed[k].angular_velocity)
    return out


def _parse_emitters(emitters, dim, materials, grid, kernel, time):
    """The ``[[emitters]]``: validated particle sources (synchronous stepping only; docs/scenes.md)."""
    if not isinstance(emitters, list):
        _fail("emitters", emitters, "an array of tables, e.g. [[emitters]]")
    if emitters and time.stepping != "sync":
        _fail("time.stepping", time.stepping, "'sync' in a scene with [[emitters]] (particles are added between "
              "synchronous steps)")
    return [_parse_emitter(e, i, dim, materials, grid, kernel, time) for i, e in enumerate(emitters)]


def _parse_emitter(e, i, dim, materials, grid, kernel, time):
    path = f"emitters[{i}]"
    _section(e, path, EMITTER_KEYS)
    shape = "disk" if dim == 2 else "sphere"
    _choice(e, "shape", path, (shape,), default=shape)
    p = {"material": _choice(e, "material", path, tuple(materials), required=True),
         "center": _vector(e, "center", path, dim, required=True),
         "radius": _number(e, "radius", path, required=True, lo=0.0, lo_open=True),
         "velocity": _vector(e, "velocity", path, dim, required=True),
         "ppc": _integer(e, "ppc", path, default=2**dim, lo=1, hi=64),
         "sampling": _choice(e, "sampling", path, SAMPLINGS, default="regular"),
         "seed": _integer(e, "seed", path, default=0, lo=0), "count": None, "particle_volume": None,
         "angular_velocity": 0.0 if dim == 2 else np.zeros(3), "rotation_center": None}
    if p["sampling"] == "regular" and round(p["ppc"] ** (1.0 / dim)) ** dim != p["ppc"]:
        _fail(f"{path}.ppc", p["ppc"], f"a perfect {'square' if dim == 2 else 'cube'} for regular sampling")
    lo = grid.origin + kernel.low_margin * grid.dx
    hi = grid.origin + (np.array(grid.cells) - kernel.high_margin) * grid.dx
    if np.any(p["center"] - p["radius"] < lo) or np.any(p["center"] + p["radius"] >= hi):
        _fail(f"{path}.center", p["center"].tolist(), f"a {shape} of radius {p['radius']} inside the grid's valid "
              f"region {lo.tolist()} .. {hi.tolist()}")
    speed = float(np.linalg.norm(p["velocity"]))
    if speed == 0.0:
        _fail(f"{path}.velocity", p["velocity"].tolist(), "a nonzero velocity (releases at rest would overlap)")
    clear = 2.0 * p["radius"] / speed
    interval = _number(e, "interval", path, default=clear, lo=0.0, lo_open=True)
    if interval < clear * (1.0 - 1e-12):
        _fail(f"{path}.interval", interval, f"at least 2 radius / |velocity| = {clear:.6g} s (a release must have "
              "cleared the previous one, which moved interval |velocity| since)")
    if time.dt is not None and interval < time.dt:
        _fail(f"{path}.interval", interval, f"at least time.dt = {time.dt} (one release per step)")
    start = _number(e, "start", path, default=0.0, lo=0.0)
    until = _number(e, "until", path, required=True, lo=start, lo_open=True)
    body = BodySpec(index=i, shape=shape, material=p.pop("material"), params=p)
    return EmitterSpec(index=i, body=body, start=start, interval=interval, until=until)


def _parse_colliders(colliders, dim):
    if not isinstance(colliders, list):
        _fail("colliders", colliders, "an array of tables, e.g. [[colliders]]")
    out = []
    for i, c in enumerate(colliders):
        path = f"colliders[{i}]"
        _section(c, path, {"shape", "type", "friction", "velocity", "point", "normal", "center", "radius",
                           "lower", "upper", "axis"})
        shape = _choice(c, "shape", path, COLLIDER_SHAPES, required=True)
        if shape in ("disk", "sphere") and shape != ("disk" if dim == 2 else "sphere"):
            _fail(f"{path}.shape", shape, f"'{'disk' if dim == 2 else 'sphere'}' in a {dim}D scene")
        if shape == "cylinder" and dim != 3:
            _fail(f"{path}.shape", shape, "'cylinder' only in 3D (use 'disk' in 2D)")
        out.append(Collider(shape=_collider_shape(c, path, shape, dim),
                            type=_choice(c, "type", path, BOUNDARY_TYPES, default="separate"),
                            friction=_number(c, "friction", path, default=0.0, lo=0.0),
                            velocity=_vector(c, "velocity", path, dim, default=[0.0] * dim)))
    return out


def _collider_shape(c, path, shape, dim):
    if shape == "plane":
        normal = _vector(c, "normal", path, dim, required=True)
        if np.linalg.norm(normal) == 0:
            _fail(f"{path}.normal", normal.tolist(), "a non-zero vector")
        return Plane(point=_vector(c, "point", path, dim, required=True), normal=normal)
    if shape == "box":
        lower, upper = _vector(c, "lower", path, dim, required=True), _vector(c, "upper", path, dim, required=True)
        if np.any(upper <= lower):
            _fail(f"{path}.upper", upper.tolist(), f"greater than lower = {lower.tolist()} on every axis")
        return Box(lower=lower, upper=upper)
    radius = _number(c, "radius", path, required=True, lo=0.0, lo_open=True)
    if shape == "cylinder":
        axis = _vector(c, "axis", path, dim, required=True)
        if np.linalg.norm(axis) == 0:
            _fail(f"{path}.axis", axis.tolist(), "a non-zero vector")
        return Cylinder(point=_vector(c, "point", path, dim, required=True), axis=axis, radius=radius)
    return Ball(center=_vector(c, "center", path, dim, required=True), radius=radius)


def _points_array(b, path, dim):
    pos = b.get("positions")
    try:
        arr = np.asarray(pos, dtype=np.float64)
    except (TypeError, ValueError):
        arr = None
    if arr is None or arr.ndim != 2 or arr.shape[1] != dim or arr.shape[0] == 0 or not np.all(np.isfinite(arr)):
        _fail(f"{path}.positions", pos if arr is None else f"array of shape {arr.shape}",
              f"a finite array of shape (n, {dim}) with n >= 1")
    return arr


def _parse_boundary(bd, dim, grid):
    _section(bd, "boundary", {"width", "type", "friction", "walls", "domain_exit"})
    width_max = min(grid.cells) // 2 - 1
    width = _integer(bd, "width", "boundary", default=min(3, width_max), lo=0, hi=width_max)
    default_type = _choice(bd, "type", "boundary", WALL_TYPES, default="separate")
    default_mu = _number(bd, "friction", "boundary", default=0.0, lo=0.0)
    names = [f"{AXES[a]}_{side}" for a in range(dim) for side in ("min", "max")]
    walls_in = bd.get("walls", {})
    _section(walls_in, "boundary.walls", set(names))
    walls = {}
    for name in names:
        w = walls_in.get(name, {})
        path = f"boundary.walls.{name}"
        _section(w, path, {"type", "friction"})
        walls[name] = WallSpec(type=_choice(w, "type", path, WALL_TYPES, default=default_type),
                               friction=_number(w, "friction", path, default=default_mu, lo=0.0))
    exit_policy = _choice(bd, "domain_exit", "boundary", DOMAIN_EXIT_POLICIES, default="error")
    return BoundarySpec(width=width, walls=walls, domain_exit=exit_policy)


ASYNC_TIME_KEYS = ("tick", "levels", "advection_cfl", "interface")
#: how level interfaces of asynchronous stepping exchange momentum (:mod:`mpmref.physics.interface`)
INTERFACES = ("conservative", "reference")


def _parse_time(t):
    _section(t, "time", {"dt", "cfl", "steps", "t_end", "stepping", *ASYNC_TIME_KEYS})
    stepping = _choice(t, "stepping", "time", STEPPINGS, default="sync")
    if stepping == "sync":
        for key in ASYNC_TIME_KEYS:
            if key in t:
                _fail(f"time.{key}", t[key], "only with time.stepping = 'async'")
    elif "dt" in t:
        _fail("time.dt", t["dt"], "absent with time.stepping = 'async' (each block's step comes from time.cfl; "
              "time.levels = 0 with time.tick = dt gives one fixed step)")
    if ("dt" in t) == ("cfl" in t):
        _fail("time.dt", t.get("dt"), "exactly one of 'time.dt' (fixed step) or 'time.cfl' (CFL number)")
    dt = _number(t, "dt", "time", lo=0.0, lo_open=True)
    cfl = _number(t, "cfl", "time", lo=0.0, hi=10.0, lo_open=True)
    if "steps" in t and "t_end" in t:
        _fail("time.steps", t["steps"], "either 'time.steps' or 'time.t_end', not both")
    steps = _integer(t, "steps", "time", lo=0)
    t_end = _number(t, "t_end", "time", lo=0.0)
    if stepping == "sync":
        return TimeSpec(dt=dt, cfl=cfl, steps=steps, t_end=t_end)
    return TimeSpec(dt=None, cfl=cfl, steps=steps, t_end=t_end, stepping="async",
                    tick=_number(t, "tick", "time", default=1e-6, lo=0.0, lo_open=True),
                    levels=_integer(t, "levels", "time", default=13, lo=0, hi=30),
                    advection_cfl=_number(t, "advection_cfl", "time", default=1.0, lo=0.0, hi=10.0, lo_open=True),
                    interface=_choice(t, "interface", "time", INTERFACES, default="conservative"))


def _parse_output(o):
    _section(o, "output", {"every", "fields", "grid", "grid_region", "checkpoint"})
    every = _integer(o, "every", "output", default=50, lo=1)
    fields_ = o.get("fields", list(OUTPUT_FIELDS))
    if not isinstance(fields_, list) or any(f not in OUTPUT_FIELDS for f in fields_):
        _fail("output.fields", fields_, f"a list drawn from {list(OUTPUT_FIELDS)}")
    for key in ("grid", "checkpoint"):
        if key in o and not isinstance(o[key], bool):
            _fail(f"output.{key}", o[key], "true or false")
    region = o.get("grid_region", "active")
    if region not in GRID_REGIONS:
        _fail("output.grid_region", region, f"one of {list(GRID_REGIONS)}")
    return OutputSpec(every=every, fields=tuple(fields_), grid=o.get("grid", False),
                      checkpoint=o.get("checkpoint", True), grid_region=region)


# ------------------------------------------------------------------------------------ builder
class SceneBuilder:
    """Build a scene in Python; ``build()`` runs the same validation as a TOML file.

    Example
    -------
    >>> scene = (SceneBuilder(dim=2, name="drop").grid(size=1.0, cells=64)
    ...          .method("apic").material("jelly", "fixed_corotated", E=1e4, nu=0.3, rho=1.0)
    ...          .box("jelly", lower=[0.4, 0.4], upper=[0.6, 0.6]).gravity([0.0, -9.8])
    ...          .time(dt=1e-4, steps=100).build())
    """

    def __init__(self, dim, name="scene", dtype="float64"):
        self._data = {"dim": dim, "name": name, "dtype": dtype, "materials": {}, "bodies": []}

    def grid(self, size, dx=None, cells=None, origin=None, block=None):
        g = {"size": size}
        g.update({k: v for k, v in (("dx", dx), ("cells", cells), ("origin", origin), ("block", block))
                  if v is not None})
        self._data["grid"] = g
        return self

    def method(self, scheme, **options):
        self._data["method"] = {"scheme": scheme, **options}
        return self

    def material(self, name, type, **params):
        self._data["materials"][name] = {"type": type, **params}
        return self

    def body(self, shape, material, **params):
        self._data["bodies"].append({"shape": shape, "material": material, **params})
        return self

    def box(self, material, lower, upper, **params):
        return self.body("box", material, lower=list(lower), upper=list(upper), **params)

    def ball(self, material, center, radius, **params):
        shape = "disk" if self._data["dim"] == 2 else "sphere"
        return self.body(shape, material, center=list(center), radius=radius, **params)

    def points(self, material, positions, **params):
        return self.body("points", material, positions=np.asarray(positions).tolist(), **params)

    def collider(self, shape, type="separate", friction=0.0, **params):
        self._data.setdefault("colliders", []).append({"shape": shape, "type": type, "friction": friction,
                                                       **{k: list(v) if isinstance(v, (tuple, np.ndarray)) else v
                                                          for k, v in params.items()}})
        return self

    def rigid_body(self, vertices, segments, **params):
        """Add a ``[[rigid_bodies]]`` entry (CPIC; see docs/cpic.md for the keys); 3D: ``segments`` are triangles."""
        cells = "triangles" if self._data.get("dim") == 3 else "segments"
        entry = {"vertices": np.asarray(vertices).tolist(), cells: np.asarray(segments).tolist(), **params}
        self._data.setdefault("rigid_bodies", []).append(entry)
        return self

    def gravity(self, g):
        self._data["gravity"] = list(g)
        return self

    def walls(self, type="separate", friction=0.0, width=3, domain_exit="error", **per_wall):
        self._data["boundary"] = {"type": type, "friction": friction, "width": width,
                                  "domain_exit": domain_exit, "walls": per_wall}
        return self

    def time(self, **params):
        self._data["time"] = params
        return self

    def output(self, **params):
        self._data["output"] = params
        return self

    def as_dict(self):
        return copy.deepcopy(self._data)

    def build(self):
        return Scene.from_dict(self._data)
