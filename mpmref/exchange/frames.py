r"""Read the frames another MPM code wrote, and match its particles to the start's.

A frame source is a ParaView series (``.pvd``), a folder of frame files, or one frame file. A frame file is

* VTK: ``.vtu`` or legacy ``.vtk`` (read with meshio), ``.vtp`` (read with pyvista): the points are the particle
  positions (a 2D code's padded with zeros to 3D), the point data the fields;
* ``.npz``: an array ``x`` (n, d), the fields, and optionally ``step`` and ``time`` (0-d);
* CSV: a header, one row per particle, the columns of ``particles.csv`` of the start (``x, y[, z]``, ``vx, ...``,
  ``F_xx, ...``, ``J``, ``Jp``, ``id``).

The fields read, where present (:data:`FIELD_NAMES` lists the names accepted for each): ``id``, the velocity ``v``,
the deformation gradient ``F`` (a 2D one may be padded to 3 x 3), ``J`` and ``Jp``. Which step or time a frame is:
its own ``step`` or ``time`` (an ``.npz`` entry, a VTK field-data array ``step``, ``time`` or ``TimeValue``), else
the time of its ``DataSet`` in the ``.pvd``, else the last integer in its file name, read as the step.

Particle identity is the ``id`` array, or the row order when a file has none (then no frame may have one). What
cannot be compared is refused before any comparison with a :class:`FrameError` naming the file and the reason: a
file that cannot be read, no positions, a particle count other than the start's, a non-finite value, an id that is
missing or repeated, a 2D frame with a nonzero third coordinate, two frames of the same step.
"""

import csv
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import MpmrefError

#: the frame files read, by suffix
FRAME_SUFFIXES = (".vtu", ".vtk", ".vtp", ".npz", ".csv")
#: the names accepted for each field (case-sensitive), first found wins
FIELD_NAMES = {
    "id": ("id", "ids", "particle_id", "pid", "ID"),
    "v": ("v", "velocity", "vel", "Velocity"),
    "F": ("F", "deformation_gradient"),
    "J": ("J",),
    "Jp": ("Jp", "J_p"),
}
#: the names of a frame's step and time (``.npz`` entries, VTK field data)
STEP_NAMES, TIME_NAMES = ("step", "STEP", "cycle"), ("time", "TIME", "TimeValue", "t")
AXES = "xyz"


class FrameError(MpmrefError, ValueError):
    """A frame that cannot be compared: ``path`` and ``reason`` (the command line exits with status 2)."""

    def __init__(self, path, reason):
        self.path, self.reason = str(path), reason
        super().__init__(f"frame {path}: {reason}")


@dataclass(frozen=True)
class Frame:
    """One frame a code wrote, its rows in the order of the start's ids.

    Attributes
    ----------
    path : Path                 the file
    step : int or None          the step it says it is
    time : float or None        the time it says it is
    x : (n, d) float64          positions
    fields : dict               ``v`` (n, d), ``F`` (n, d, d), ``J`` (n,), ``Jp`` (n,) where the file has them, float64
    dtype : numpy dtype or None the type the file stored its positions in (``None`` for CSV text)
    """

    path: Path
    step: int | None
    time: float | None
    x: np.ndarray = field(repr=False)
    fields: dict = field(repr=False, default_factory=dict)
    dtype: object = None

    @property
    def label(self):
        """``step 100`` or ``t = 0.02``: how the frame names itself."""
        return f"step {self.step}" if self.step is not None else f"t = {self.time:.6g}"


def frame_files(source):
    """``[(path, time from the .pvd or None)]`` of a frame source: a ``.pvd``, a folder or one frame file."""
    source = Path(source)
    if not source.exists():
        raise FrameError(source, "does not exist")
    if source.suffix == ".pvd":
        return pvd_entries(source)
    if source.is_file():
        if source.suffix not in FRAME_SUFFIXES:
            raise FrameError(source, f"is not a frame file: allowed suffixes .pvd, {', '.join(FRAME_SUFFIXES)}")
        return [(source, None)]
    series = sorted(source.glob("*.pvd"))
    if len(series) == 1:
        return pvd_entries(series[0])
    if len(series) > 1:
        raise FrameError(source, f"holds {len(series)} .pvd series ({', '.join(p.name for p in series)}): name one")
    return _folder_files(source)


def _folder_files(folder):
    kinds = {p.suffix for p in folder.iterdir() if p.suffix in FRAME_SUFFIXES and not p.name.startswith(".")}
    if not kinds:
        raise FrameError(folder, f"holds no frame file (suffixes {', '.join(FRAME_SUFFIXES)}) and no .pvd series")
    if len(kinds) > 1:
        raise FrameError(folder, f"holds frames of several kinds ({', '.join(sorted(kinds))}): keep one kind, or "
                         "name a .pvd series")
    files = [p for p in folder.glob(f"*{kinds.pop()}") if not p.name.startswith(".")]
    unnumbered = [p.name for p in files if _name_number(p) is None]
    if unnumbered:
        raise FrameError(folder / unnumbered[0], "has no number in its name, so its place in the series is unknown "
                         "(name frames like particles_000100.vtu, or list them in a .pvd)")
    return [(p, None) for p in sorted(files, key=_name_number)]


def pvd_entries(path):
    """``[(file, time)]`` of a ParaView collection, in its order; files relative to its folder."""
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError) as exc:
        raise FrameError(path, f"cannot be read as a .pvd collection ({exc})") from None
    entries = []
    for k, dataset in enumerate(root.iter("DataSet")):
        name = dataset.get("file")
        if not name:
            raise FrameError(path, f"DataSet {k} has no 'file' attribute")
        timestep = dataset.get("timestep")
        try:
            time = None if timestep is None else float(timestep)
        except ValueError:
            raise FrameError(path, f"DataSet {k} has timestep {timestep!r}, not a number") from None
        entries.append((path.parent / name, time))
    if not entries:
        raise FrameError(path, "lists no DataSet")
    return entries


def _name_number(path):
    numbers = re.findall(r"\d+", path.stem)
    return int(numbers[-1]) if numbers else None


# ------------------------------------------------------------------------------------------------- one file
def read_raw(path):
    """The arrays of one frame file as ``(points, {name: array}, dtype of the points)``; :class:`FrameError` if it
    cannot be read."""
    path = Path(path)
    if not path.is_file():
        raise FrameError(path, "does not exist (listed in the series but not there)")
    readers = {".vtu": _read_meshio, ".vtk": _read_meshio, ".vtp": _read_pyvista, ".npz": _read_npz,
               ".csv": _read_csv}
    reader = readers.get(path.suffix)
    if reader is None:
        raise FrameError(path, f"unknown frame kind {path.suffix!r}: allowed {', '.join(FRAME_SUFFIXES)}")
    try:
        return reader(path)
    except FrameError:
        raise
    except Exception as exc:  # a reader's own error, whatever it is, says why the file cannot be read
        raise FrameError(path, f"cannot be read ({type(exc).__name__}: {exc})") from None


def _read_meshio(path):
    import meshio

    mesh = meshio.read(path)
    data = {k: np.asarray(v) for k, v in mesh.point_data.items()}
    data.update({k: np.asarray(v) for k, v in mesh.field_data.items() if k in STEP_NAMES + TIME_NAMES})
    return np.asarray(mesh.points), data, np.asarray(mesh.points).dtype


def _read_pyvista(path):
    import pyvista as pv

    mesh = pv.read(path)
    data = {k: np.asarray(mesh.point_data[k]) for k in mesh.point_data.keys()}
    data.update({k: np.asarray(mesh.field_data[k]) for k in mesh.field_data.keys() if k in STEP_NAMES + TIME_NAMES})
    return np.asarray(mesh.points), data, np.asarray(mesh.points).dtype


def _read_npz(path):
    with np.load(path, allow_pickle=False) as npz:
        data = {k: npz[k] for k in npz.files}
    name = next((k for k in ("x", "positions", "position") if k in data), None)
    if name is None:
        raise FrameError(path, f"has no positions: an array 'x' (n, d) is needed (it has {', '.join(data) or 'none'})")
    x = data.pop(name)
    return x, data, x.dtype


def _read_csv(path):
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    if not rows:
        raise FrameError(path, "is empty")
    header, body = rows[0], rows[1:]
    try:
        values = np.array(body, dtype=np.float64).reshape(len(body), len(header))
    except ValueError as exc:
        raise FrameError(path, f"has a row that is not {len(header)} numbers ({exc})") from None
    columns = dict(zip(header, values.T))
    axes = [a for a in AXES if a in columns]
    if axes[:2] != ["x", "y"]:
        raise FrameError(path, f"has no position columns x, y[, z] (its columns: {', '.join(header)})")
    data = {"id": columns["id"]} if "id" in columns else {}
    for name in ("J", "Jp"):
        if name in columns:
            data[name] = columns[name]
    velocity = [f"v{a}" for a in axes]
    if all(c in columns for c in velocity):
        data["v"] = np.stack([columns[c] for c in velocity], axis=1)
    gradient = [f"F_{a}{b}" for a in axes for b in axes]
    if all(c in columns for c in gradient):
        data["F"] = np.stack([columns[c] for c in gradient], axis=1)
    return np.stack([columns[a] for a in axes], axis=1), data, None


# ------------------------------------------------------------------------------------------------ checks
def _named(data, name):
    return next((data[k] for k in FIELD_NAMES[name] if k in data), None)


def _points(path, points, dim, count):
    points = np.asarray(points)
    if points.ndim != 2 or points.shape[1] < dim:
        raise FrameError(path, f"has positions of shape {points.shape}, expected ({count}, {dim})")
    if points.shape[0] != count:
        raise FrameError(path, f"has {points.shape[0]} particles, the start has {count}: compare follows every "
                         "particle of the start through every frame (no particle deleted or added)")
    return _first_axes(path, "x", points, dim)


def _first_axes(path, name, vectors, dim):
    """The first ``dim`` components of ``vectors`` (a 2D code's padded to 3D), float64; the others must be zero."""
    extra = vectors[:, dim:]
    if extra.size and np.any(extra != 0.0):
        raise FrameError(path, f"{name} of a {dim}D scene has a nonzero component beyond axis {dim - 1}")
    return vectors[:, :dim].astype(np.float64)


def _field(path, name, value, dim, count):
    """A field read from a frame, in the start's shape: ``v`` (n, d), ``F`` (n, d, d), ``J``/``Jp`` (n,)."""
    value = np.asarray(value, dtype=np.float64)
    rows = value.shape[0] if value.ndim else 0
    if rows != count:
        raise FrameError(path, f"field {name} has {rows} rows, the frame has {count} particles")
    flat = value.reshape(count, -1)
    width = flat.shape[1]
    if name == "v" and width in (dim, 3):
        return _first_axes(path, name, flat, dim)
    side = int(round(np.sqrt(width)))
    if name == "F" and side * side == width and side in (dim, 3):
        return flat.reshape(count, side, side)[:, :dim, :dim].copy()
    if name in ("J", "Jp") and width == 1:
        return flat[:, 0]
    raise FrameError(path, f"field {name} has shape {value.shape}, which is not one "
                     f"{'vector' if name == 'v' else 'matrix' if name == 'F' else 'value'} per particle")


def _finite(path, name, value):
    bad = ~np.isfinite(value.reshape(len(value), -1)).all(axis=1)
    if bad.any():
        raise FrameError(path, f"{name} is not finite for {int(bad.sum())} particles (first: row "
                         f"{int(np.argmax(bad))})")


def _rows(path, ids, start_ids):
    """The rows of a frame in the order of the start's ids (its ``ids`` matched to ``start_ids``)."""
    ids = np.asarray(ids)
    if ids.ndim == 2 and ids.shape[1] == 1:
        ids = ids[:, 0]
    if ids.shape != np.shape(start_ids):
        raise FrameError(path, f"has an id array of shape {ids.shape}, expected one id per particle "
                         f"({len(start_ids)},)")
    if ids.dtype.kind == "f":
        if np.any(ids != np.round(ids)):
            raise FrameError(path, "has ids that are not integers")
    ids = ids.astype(np.int64)
    order = np.argsort(ids, kind="stable")
    sorted_ids = ids[order]
    if not np.array_equal(sorted_ids, np.sort(start_ids)):
        missing = np.setdiff1d(start_ids, ids)
        repeated = np.unique(sorted_ids[1:][sorted_ids[1:] == sorted_ids[:-1]])
        unknown = np.setdiff1d(ids, start_ids)
        found = ((missing, "ids of the start missing"), (repeated, "ids repeated"), (unknown, "ids not in the start"))
        problems = [f"{len(a)} {what} (first: {a[:5].tolist()})" for a, what in found if len(a)]
        raise FrameError(path, "ids do not match the start's: " + "; ".join(problems))
    rank = np.argsort(np.argsort(start_ids, kind="stable"), kind="stable")
    return order[rank]


def _scalar(path, data, names, kind):
    for name in names:
        if name in data:
            value = np.asarray(data[name]).ravel()
            if value.size != 1 or not np.isfinite(value[0]):
                raise FrameError(path, f"its {kind} '{name}' is not one finite number")
            return value[0]
    return None


def read_frame(path, pvd_time, dim, start_ids):
    """``(frame, has_ids)``: the :class:`Frame` of ``path``, checked and put in the order of ``start_ids`` (by its ids,
    or its rows when it has none), and whether it has ids."""
    points, data, dtype = read_raw(path)
    count = len(start_ids)
    x = _points(path, points, dim, count)
    _finite(path, "x", x)
    fields = {}
    for name in ("v", "F", "J", "Jp"):
        value = _named(data, name)
        if value is not None:
            fields[name] = _field(path, name, value, dim, count)
            _finite(path, name, fields[name])
    ids = _named(data, "id")
    rows = _rows(path, ids, start_ids) if ids is not None else np.arange(count)
    step = _scalar(path, data, STEP_NAMES, "step")
    time = _scalar(path, data, TIME_NAMES, "time")
    if step is None and time is None:
        time = pvd_time
    if step is None and time is None:
        step = _name_number(Path(path))
    return Frame(Path(path), None if step is None else int(step), None if time is None else float(time), x[rows],
                 {k: v[rows] for k, v in fields.items()}, dtype), ids is not None


def read_frames(source, dim, start_ids):
    """Every frame of ``source`` (a ``.pvd``, a folder or a file: :func:`frame_files`), checked, each in the order of
    ``start_ids``, sorted by step (or time).

    Raises :class:`FrameError` for the first frame that cannot be compared (module docstring), also when some frames
    have ids and others do not, or two frames are the same step or time.
    """
    frames, with_ids = [], []
    for path, time in frame_files(source):
        frame, has_ids = read_frame(path, time, dim, np.asarray(start_ids))
        frames.append(frame)
        with_ids.append(has_ids)
    if any(with_ids) and not all(with_ids):
        path = frames[with_ids.index(False)].path
        raise FrameError(path, "has no id array while other frames of the series do: write ids in every frame, "
                         "or in none (then rows are matched by order)")
    frames.sort(key=lambda f: (f.step if f.step is not None else -1, f.time if f.time is not None else -1.0))
    for a, b in zip(frames, frames[1:]):
        if (a.step, a.time) == (b.step, b.time):
            raise FrameError(b.path, f"is the same {a.label} as {a.path.name}")
    return frames
