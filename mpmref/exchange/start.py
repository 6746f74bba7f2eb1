r"""The start of a scene in plain formats: the particles and every number of the scene, for a code in any language.

``export_start(scene, DIR)`` writes

* ``particles.npz``: one array per field (``id``, ``x``, ``v``, ``mass``, ``vol0``, ``material`` and, where the scene
  has them, ``C``, ``F``, ``J``, ``Jp``), uncompressed, no pickled objects, in the scene's dtype (``id`` int64,
  ``material`` int32);
* ``particles.csv``: the same, one row per particle, one column per component (``x, y[, z]``, ``vx, vy[, vz]``,
  ``C_xx, C_xy, ...``, ``F_xx, ...``), every number written so that it reads back to the same bits;
* ``particles.vtu``: the particles as VTK vertices with the same fields as point data (a 2D scene's points and
  vectors padded with zeros to 3D, as VTK wants), to open in ParaView;
* ``scene.json`` (last, so a folder with it is complete): :func:`start_record`.

The particles are those every run of the scene starts from (:func:`initial_particles`), so a code that reads them
starts from exactly mpmref's initial state, bit for bit.
"""

import csv
import io
import json
from pathlib import Path

import numpy as np

from ..conformance.vectors import resolved
from ..io.atomic import atomic_path, write_text_atomic
from ..io.vtk import write_particles_vtu
from ..scene.sampling import sample_particles

START_FORMAT = "mpmref-start"
START_VERSION = 1
SCENE_FILE = "scene.json"
PARTICLE_FILES = {"npz": "particles.npz", "csv": "particles.csv", "vtk": "particles.vtu"}
#: the particle fields a start holds, in this order, where the scene has them
START_FIELDS = ("id", "x", "v", "mass", "vol0", "material", "C", "F", "J", "Jp")
AXES = "xyz"
#: each material type's wave speed c_p, the CFL rule's (mpmref.physics.materials, .plasticity: ``wave_speeds``)
WAVE_SPEEDS = {
    "fluid": "c = sqrt(gamma K / (rho J^(gamma - 1))), J at least 1e-6",
    "fixed_corotated": "c^2 = 4 mu J / (3 rho) + (2 mu / 3 + lam) (1 - ln J) / rho, at least 4 mu J / (3 rho); "
                       "J = det F, at least 1e-6",
    "neo_hookean": "as fixed_corotated",
    "sand": "as fixed_corotated, with J = det F (the elastic part)",
    "snow": "c = sqrt((lam + 2 mu) exp(hardening (1 - Jp)) J / rho), J = det F Jp, at least 1e-6",
}
CONVENTIONS = {
    "units": "every number is in the scene's own consistent units (SI in the examples: m, s, kg, Pa)",
    "particles": "row k of every particle array is the particle with id[k]; ids are 0 .. n-1 at the start; write "
                 "them with your frames (point data 'id') so that mpmref compare can follow each particle",
    "material": "material[k] is an index into materials",
    "grid": "node i (a multi-index, 0 <= i_a <= cells_a) sits at origin + i dx",
    "kernel": "the quadratic B-spline's stencil of a particle starts at node floor((x - origin)/dx - 1/2); the APIC "
              "inertia is D = inertia_factor dx^2 (kernel.inertia)",
    "walls": "a wall acts on the nodes of its band (boundary.bands: node index range along its axis), in the order "
             "of boundary.order, after gravity, on the nodes with mass only",
    "time": "time.dt fixed, or time.cfl: dt = cfl dx / max_p (c_p + |v_p|) with each material's wave_speed",
}


def initial_particles(scene):
    """The particles every run of ``scene`` starts from (:func:`mpmref.scene.sampling.sample_particles`)."""
    return sample_particles(scene)


def particle_arrays(particles):
    """``{field: array}`` of :data:`START_FIELDS` that ``particles`` has (``id`` int64, ``material`` int32)."""
    arrays = {}
    for name in START_FIELDS:
        value = getattr(particles, name)
        if value is not None:
            arrays[name] = np.asarray(value)
    arrays["id"] = arrays["id"].astype(np.int64)
    arrays["material"] = arrays["material"].astype(np.int32)
    return arrays


def column_names(name, array):
    """The CSV columns of particle field ``name``: itself for a scalar, ``x, y, z`` for ``x``, ``vx, vy, vz`` for
    ``v``, ``F_xy`` and the like for a matrix (row, then column)."""
    if array.ndim == 1:
        return [name]
    d = array.shape[1]
    if array.ndim == 2:
        return list(AXES[:d]) if name == "x" else [f"{name}{AXES[a]}" for a in range(d)]
    return [f"{name}_{AXES[a]}{AXES[b]}" for a in range(d) for b in range(d)]


def csv_text(arrays):
    """The particle arrays as CSV text: a header of :func:`column_names`, then one row per particle; each number as
    the shortest text that reads back to the same bits in its own type (``str`` of a NumPy scalar)."""
    names, columns = [], []
    for name, array in arrays.items():
        names += column_names(name, array)
        flat = array.reshape(len(array), -1)
        columns += [[str(v) for v in flat[:, k]] for k in range(flat.shape[1])]
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(names)
    writer.writerows(zip(*columns))
    return buffer.getvalue()


def _walls(scene):
    """The walls in the order they act, each with its axis, side, inward normal and band of node indices."""
    width, walls = scene.boundary.width, {}
    for axis, cells in enumerate(scene.grid.cells):
        for side in ("min", "max"):
            name = f"{AXES[axis]}_{side}"
            normal = [0.0] * scene.dim
            normal[axis] = 1.0 if side == "min" else -1.0
            nodes = [0, width - 1] if side == "min" else [cells - width + 1, cells]
            wall = scene.boundary.walls[name]
            walls[name] = {"type": wall.type, "friction": wall.friction, "axis": axis, "normal": normal,
                           "nodes": nodes}
    return walls


def _time(scene):
    t = scene.time
    return {"stepping": t.stepping, "dt": t.dt, "cfl": t.cfl, "steps": t.steps, "t_end": t.t_end,
            "rule": "fixed dt" if t.dt is not None else "dt = cfl dx / max_p (c_p + |v_p|)"}


def start_record(scene, particles=None):
    """What ``scene.json`` holds: the scene's every number in plain units, as JSON-ready dicts.

    ``format``, ``version``, ``name``, ``dim``, ``dtype``; ``particles`` (count, files, each field's shape and dtype);
    ``grid`` (``origin``, ``dx``, ``cells``, ``node_shape``, ``n_nodes``, ``size``); ``method``; ``kernel``
    (``support``, ``inertia_factor``, ``inertia`` = D); ``materials`` (in material-index order, with every parameter,
    the Lamé ``mu``, ``lam`` of the solids, ``evolves`` and ``wave_speed``); ``gravity``; ``boundary`` (``width``,
    ``domain_exit``, ``walls`` in the order they act, each with its type, friction, axis, normal and band of nodes);
    ``colliders``; ``rigid_bodies``; ``time`` (``dt`` or ``cfl``, ``steps`` or ``t_end``); ``output`` (``every``);
    ``valid_region``; ``conventions`` in words.
    """
    particles = initial_particles(scene) if particles is None else particles
    arrays = particle_arrays(particles)
    base = resolved(scene, scene.source["materials"])
    materials = [{"index": k, **m, "wave_speed": WAVE_SPEEDS.get(m["type"], "")}
                 for k, m in enumerate(base["materials"])]
    lo, hi = scene.valid_region()
    grid = {**base["grid"], "size": (np.asarray(scene.grid.cells) * scene.grid.dx).tolist()}
    kernel = {**base["kernel"], "inertia": base["kernel"]["inertia_factor"] * scene.grid.dx**2
              if base["kernel"]["inertia_factor"] is not None else None}
    return {"format": START_FORMAT, "version": START_VERSION, "name": scene.name, "dim": scene.dim,
            "dtype": scene.dtype.name,
            "particles": {"count": int(particles.n), "files": PARTICLE_FILES,
                          "fields": {k: {"shape": list(a.shape), "dtype": a.dtype.name} for k, a in arrays.items()}},
            "grid": grid, "method": base["method"], "kernel": kernel, "materials": materials,
            "gravity": base["gravity"],
            "boundary": {"width": scene.boundary.width, "domain_exit": scene.boundary.domain_exit,
                         "order": list(_walls(scene)), "walls": _walls(scene)},
            "colliders": base["colliders"], "rigid_bodies": base["rigid_bodies"], "cpic": base["cpic"],
            "polypic_modes": base["polypic_modes"], "time": _time(scene), "output": {"every": scene.output.every},
            "valid_region": [lo.tolist(), hi.tolist()], "conventions": CONVENTIONS}


def export_start(scene, out_dir):
    """Write the start of ``scene`` into ``out_dir`` (created if missing): the particle files of
    :data:`PARTICLE_FILES` and ``scene.json`` last, each atomically. Returns the path of ``scene.json``."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    particles = initial_particles(scene)
    arrays = particle_arrays(particles)
    with atomic_path(out_dir / PARTICLE_FILES["npz"]) as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)
    write_text_atomic(out_dir / PARTICLE_FILES["csv"], csv_text(arrays))
    write_particles_vtu(out_dir / PARTICLE_FILES["vtk"], arrays["x"], {k: a for k, a in arrays.items() if k != "x"})
    write_text_atomic(out_dir / SCENE_FILE, json.dumps(start_record(scene, particles), indent=1))
    return out_dir / SCENE_FILE
