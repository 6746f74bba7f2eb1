"""A scene as a whole: :class:`Scene`, validated from a TOML file or nested dicts by the section parsers, and
:class:`SceneBuilder`, which writes those dicts from Python.

Every problem is reported as a :class:`~mpmref.errors.SceneError` naming the field (dotted path), the
value given and the allowed range. See ``docs/scenes.md`` for every field and its default.
"""

import copy
import json
import tomllib
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np

from ..errors import SceneError
from ..physics.kernels import get_kernel
from ..physics.scheme import resolve
from ..state import Grid
from . import memory_limits
from .bodies import parse_bodies, parse_colliders, parse_emitters
from .materials import parse_materials
from .parsers import cell_size_field, parse_boundary, parse_grid, parse_method, parse_output, parse_time
from .rigid_bodies import parse_rigid_bodies
from .specs import BoundarySpec, CpicSpec, MethodSpec, OutputSpec, TimeSpec
from .validation import choice, fail, integer, section, vector

TOP_KEYS = {"dim", "dtype", "grid", "method", "materials", "bodies", "colliders", "gravity", "boundary", "time",
            "output", "name", "rigid_bodies", "emitters"}
DTYPES = ("float64", "float32")


@dataclass
class Scene:
    """A validated scene. Build with :meth:`from_toml`, :meth:`from_dict` or :class:`SceneBuilder`.

    ``cpic`` holds the CPIC coupling settings (:class:`~mpmref.scene.specs.CpicSpec`) of a scene with
    ``[method] coupling = "cpic"``, and is ``None`` in a scene without coupling.
    """

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
    cpic: CpicSpec | None = None

    @cached_property
    def transfer(self):
        """The resolved :class:`~mpmref.physics.scheme.TransferSpec` (scheme, force, kernel, tracked state)."""
        return resolve(self.method, self.dim, self.material_list)

    # --------------------------------------------------------------------------- construction
    @classmethod
    def from_toml(cls, path):
        """Read and validate a TOML scene file; relative file paths resolve next to it."""
        return cls.from_dict(read_scene_file(path), base_dir=Path(path).parent)

    @classmethod
    def from_dict(cls, data, base_dir=None):
        """Validate a scene given as nested dicts (the TOML structure) and return a :class:`Scene`."""
        data = copy.deepcopy(data)
        section(data, "", TOP_KEYS)
        dim = integer(data, "dim", "", lo=2, hi=3, required=True)
        dtype = np.dtype(choice(data, "dtype", "", DTYPES, default="float64"))
        method, cpic = parse_method(data.get("method", {}))
        grid = parse_grid(data.get("grid", {}), dim, get_kernel(method.kernel).support)
        materials = parse_materials(data.get("materials"))
        bodies = parse_bodies(data.get("bodies"), dim, materials)
        colliders = parse_colliders(data.get("colliders", []), dim)
        gravity = vector(data, "gravity", "", dim, default=[0.0] * dim)
        boundary = parse_boundary(data.get("boundary", {}), dim, grid)
        time = parse_time(data.get("time", {}))
        rigid_bodies = parse_rigid_bodies(data.get("rigid_bodies", []), dim, grid, cpic, time, base_dir)
        output = parse_output(data.get("output", {}), time)
        emitters = parse_emitters(data.get("emitters", []), dim, materials, grid, get_kernel(method.kernel), time)
        memory_limits.check_scene_memory({"dim": dim, "dtype": dtype, "grid": grid,
                                          "transfer": resolve(method, dim, list(materials.values())),
                                          "bodies": bodies, "colliders": colliders,
                                          "grid_field": cell_size_field(data["grid"])[0],
                                          "grid_value": cell_size_field(data["grid"])[1]})
        name = data.get("name", "scene")
        if not isinstance(name, str) or not name or any(c in name for c in "/\\"):
            fail("name", name, "a non-empty string without path separators")
        return cls(name=name, dim=dim, dtype=dtype, grid=grid, method=method, materials=materials,
                   bodies=bodies, colliders=colliders, gravity=gravity, boundary=boundary, time=time, output=output,
                   source=data, base_dir=Path(base_dir) if base_dir else Path.cwd(), rigid_bodies=rigid_bodies,
                   emitters=emitters, cpic=cpic)

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


def read_scene_file(path):
    """The declarations of a TOML scene file as nested dicts, not yet validated (:meth:`Scene.from_dict` validates
    them), with ``name`` defaulting to the file's stem; what is not a readable UTF-8 TOML file is a
    :class:`SceneError`."""
    data = _load_scene_file(Path(path))
    data.setdefault("name", Path(path).stem)
    return data


class SceneFileError(SceneError):
    """A scene file that cannot be read as UTF-8 TOML: ``field`` is ``"scene file"``, ``value`` its path and
    ``allowed`` what it must be, as for every :class:`~mpmref.errors.SceneError`; the message says what is wrong
    with the file itself (``scene file 'disk.toml' does not exist (no such file: /home/me/disk.toml)``)."""

    def __init__(self, path, problem, allowed):
        super().__init__("scene file", str(path), allowed)
        self.problem = problem

    def __str__(self):
        return f"scene file '{self.value}' {self.problem}"


def _load_scene_file(path):
    """The parsed TOML of a scene file; what is not a readable UTF-8 TOML file is a :class:`SceneFileError`."""
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        where = "" if path.is_absolute() else f" (no such file: {path.absolute()})"
        raise SceneFileError(path, f"does not exist{where}", "an existing TOML file") from None
    except IsADirectoryError:
        raise SceneFileError(path, "is a folder, not a TOML file", "a TOML file, not a directory") from None
    except OSError as exc:
        raise SceneFileError(path, f"cannot be read ({exc.strerror})",
                             f"a readable TOML file ({exc.strerror})") from None
    return _parse_toml(path, _utf8_text(path, raw))


def _utf8_text(path, raw):
    """The text of a scene file's bytes ``raw``; a :class:`SceneFileError` for bytes that are not UTF-8 text."""
    if raw.startswith((b"\xff\xfe", b"\xfe\xff")):
        raise SceneFileError(path, "is UTF-16 text: save it as UTF-8",
                             "a UTF-8 text file (this one is UTF-16; save it as UTF-8)")
    nul = raw.find(b"\x00")
    if nul >= 0:
        why = f"byte {nul} is NUL: a binary or UTF-16 file"
        raise SceneFileError(path, f"is not UTF-8 text ({why})", f"a UTF-8 text file ({why})")
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        why = f"byte {exc.start} is not UTF-8: a binary file or another encoding"
        raise SceneFileError(path, f"is not UTF-8 text ({why})", f"a UTF-8 text file ({why})") from None


def _parse_toml(path, text):
    """The TOML of a scene file's ``text``; a :class:`SceneFileError` naming the parser's complaint."""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SceneFileError(path, f"is not valid TOML ({exc})", f"valid TOML ({exc})") from None


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
