#!/usr/bin/env python3
r"""An MPM code outside mpmref: MLS-MPM in plain NumPy, written from the equations, that never imports mpmref.

It stands for a code in C++, CUDA, Julia or Fortran: it reads what ``mpmref export`` writes (``scene.json`` and
``particles.npz`` or ``particles.csv``), runs, and writes a ParaView series (``particles.pvd`` and one ``.vtu`` per
frame, with the particles' ids); ``mpmref compare`` then judges the run. Given the vectors of ``mpmref conformance
export``, it computes its stages on them and writes their outputs for ``mpmref conformance check --results``.

What it implements, in 2D and 3D, float64 and float32:

* the quadratic B-spline, :math:`N(x) = 3/4 - x^2` for :math:`|x| < 1/2`, :math:`(3/2 - |x|)^2/2` for
  :math:`1/2 \le |x| < 3/2`, on the stencil from node :math:`\lfloor (x_p - o)/\Delta x - 1/2 \rfloor`;
* MLS-MPM (Hu et al. 2018): the APIC transfer (Jiang et al. 2015) with the MLS force, :math:`D = \Delta x^2/4`:

  - P2G: :math:`m_i = \sum_p w_{ip} m_p`, :math:`(mv)_i = \sum_p w_{ip} m_p (v_p + C_p (x_i - x_p))`,
    :math:`f_i = -\sum_p V_p^0 \tau_p w_{ip} D^{-1} (x_i - x_p)`;
  - grid: :math:`\tilde v_i = (mv)_i / m_i`, :math:`v_i = ((mv)_i + \Delta t f_i)/m_i + \Delta t g` on the nodes with
    mass, then each wall on its band of nodes (sticky: 0; slip: the tangential part; separate: when approaching,
    Coulomb friction :math:`\mu` on the tangential part);
  - G2P: :math:`v_p = \sum_i w_{ip} v_i`, :math:`C_p = \sum_i w_{ip} v_i (x_i - x_p)^T D^{-1}`,
    :math:`F_p \leftarrow (I + \Delta t C_p) F_p`, :math:`J_p \leftarrow (1 + \Delta t \operatorname{tr} C_p) J_p`,
    :math:`x_p \leftarrow x_p + \Delta t v_p`;
* materials: the weakly compressible fluid :math:`\tau = K (J - J^{1-\gamma}) I`; fixed-corotated
  :math:`\tau = 2\mu (F - R) F^T + \lambda (J - 1) J I`; Neo-Hookean :math:`\tau = \mu (F F^T - I) + \lambda \ln J I`;
* a fixed Δt, or the CFL rule of ``scene.json``.

Planted bugs (``--bug``), each a mistake real codes make: ``stiffness`` (material 0 one percent too stiff),
``wall-gravity`` (gravity added a second time on the wall nodes), ``half-dt-advect`` (G2P moves the particles by
Δt/2) and ``friction-sign`` (Coulomb friction with the wrong sign: walls push sliding material along). ``--reverse``
sums the stencil's nodes in the reverse order: a correct code whose round-off differs.

Usage::

    python outside_mpm.py run START_DIR OUT_DIR [--steps N] [--dtype float32] [--csv] [--bug NAME] [--reverse]
    python outside_mpm.py stages VECTORS_DIR RESULTS_DIR
"""

import argparse
import base64
import csv
import json
import sys
from dataclasses import dataclass
from itertools import product
from pathlib import Path

import numpy as np

BUGS = ("stiffness", "wall-gravity", "half-dt-advect", "friction-sign")
MATERIALS = ("fluid", "fixed_corotated", "neo_hookean")
WALLS = ("sticky", "slip", "separate", "open")
#: what this code implements, in the words of mpmref's declaration (written with its stage results)
IMPLEMENTS = {"dims": [2, 3], "schemes": ["apic", "mls"], "forces": ["mls"], "kernels": ["quadratic"],
              "materials": list(MATERIALS), "walls": list(WALLS), "friction": True, "colliders": [],
              "moving_colliders": False, "dtypes": ["float64", "float32"], "evolves": ["C", "F", "J"],
              "stepping": ["sync"], "rigid_bodies": False}
STAGES = ("stress", "p2g", "grid_update", "g2p", "step")
#: what of a scene each stage computes with
STAGE_NEEDS = {"stress": ("materials",), "p2g": ("method", "materials"), "grid_update": ("walls",),
               "g2p": ("method",), "step": ("method", "materials", "walls")}
AXES = "xyz"


class Unsupported(Exception):
    """What a scene or a case needs that this code does not have."""


@dataclass(frozen=True)
class Setup:
    """Everything a step needs of the scene."""

    dim: int
    dtype: type
    origin: np.ndarray
    dx: float
    cells: tuple
    materials: list  # dicts: type and parameters
    gravity: np.ndarray
    walls: list  # (axis, side, type, friction) in the order they act
    width: int
    bug: str | None = None
    reverse: bool = False

    @property
    def node_shape(self):
        return tuple(c + 1 for c in self.cells)

    @property
    def n_nodes(self):
        return int(np.prod(self.node_shape))

    @property
    def strides(self):
        shape = self.node_shape
        return np.array([int(np.prod(shape[a + 1:])) for a in range(self.dim)], dtype=np.int64)

    @property
    def inertia(self):
        return 0.25 * self.dx * self.dx


def setup_from(description, dtype, bug=None, reverse=False):
    """A :class:`Setup` from ``scene.json`` or a conformance case's ``resolved`` (same keys for what it reads)."""
    materials = [dict(m) for m in description["materials"]]
    if bug == "stiffness":
        materials[0] = stiffer(materials[0], 1.01)
    grid = description["grid"]
    dim = len(grid["cells"])
    walls = []
    for axis in range(dim):
        for side in ("min", "max"):
            wall = description["boundary"]["walls"][f"{AXES[axis]}_{side}"]
            walls.append((axis, side, wall["type"], float(wall["friction"])))
    return Setup(dim, np.dtype(dtype).type, np.asarray(grid["origin"], dtype=float), float(grid["dx"]),
                 tuple(grid["cells"]), materials, np.asarray(description["gravity"], dtype=float), walls,
                 int(description["boundary"]["width"]), bug, reverse)


def require(description, parts):
    """Raise :class:`Unsupported` when a part of the scene this code needs (``"method"``, ``"materials"``,
    ``"walls"``) is one it does not have."""
    method = description["method"]
    if "method" in parts and (method["kernel"] != "quadratic" or method["force"] != "mls"
                              or method["scheme"] not in ("apic", "mls")
                              or method.get("velocity_gradient", "mls") != "mls"):
        raise Unsupported(f"method {method}")
    if "materials" in parts and any(m["type"] not in MATERIALS for m in description["materials"]):
        raise Unsupported(f"materials {[m['type'] for m in description['materials']]}")
    walls = description["boundary"]["walls"].values()
    if "walls" in parts and (description.get("colliders") or any(w["type"] not in WALLS for w in walls)):
        raise Unsupported("colliders, or a wall type it does not have")
    if description.get("rigid_bodies"):
        raise Unsupported("rigid bodies")


def stiffer(material, factor):
    """``material`` with its stiffness (``K``, or ``mu`` and ``lam``) times ``factor``."""
    keys = ("K",) if material["type"] == "fluid" else ("mu", "lam")
    return {**material, **{k: material[k] * factor for k in keys}}


# ------------------------------------------------------------------------------------------------ physics
def offsets(setup):
    """The 3^d stencil offsets, in C order (reversed with ``--reverse``)."""
    found = [np.array(o) for o in product(range(3), repeat=setup.dim)]
    return found[::-1] if setup.reverse else found


def stencil(x, setup):
    """Each particle's lowest stencil node, its offset from it in cells and the per-axis weights (n, d, 3)."""
    t = setup.dtype
    xi = (x - setup.origin.astype(t)) / t(setup.dx)
    base = np.floor(xi - t(0.5)).astype(np.int64)
    fx = xi - base
    w = np.stack([t(0.5) * (t(1.5) - fx) ** 2, t(0.75) - (fx - t(1.0)) ** 2, t(0.5) * (fx - t(0.5)) ** 2], axis=-1)
    return base, fx, w


def weight(w, offset):
    out = w[:, 0, offset[0]].copy()
    for a in range(1, len(offset)):
        out *= w[:, a, offset[a]]
    return out


def rotation(F):
    """The rotation R of F = R S (by the SVD, with det R = +1)."""
    U, _, Vt = np.linalg.svd(F)
    flip = np.linalg.det(U @ Vt) < 0
    U[flip, :, -1] *= -1.0
    return U @ Vt


def stress(p, setup):
    """Kirchhoff stress of every particle, by its material."""
    n, d = p["x"].shape
    tau = np.zeros((n, d, d), dtype=setup.dtype)
    eye = np.eye(d, dtype=setup.dtype)
    for k, m in enumerate(setup.materials):
        sel = p["material"] == k
        if not sel.any():
            continue
        if m["type"] == "fluid":
            J = p["J"][sel]
            tau[sel] = (m["K"] * (J - J ** (1.0 - m["gamma"])))[:, None, None] * eye
            continue
        F = p["F"][sel]
        J = np.linalg.det(F)
        volume = (m["lam"] * (J - 1.0) * J if m["type"] == "fixed_corotated" else m["lam"] * np.log(J))[:, None, None]
        if m["type"] == "fixed_corotated":
            tau[sel] = 2.0 * m["mu"] * (F - rotation(F)) @ F.transpose(0, 2, 1) + volume * eye
        else:
            tau[sel] = m["mu"] * (F @ F.transpose(0, 2, 1) - eye) + volume * eye
    return tau


def p2g(p, tau, setup):
    """Node mass (N,), momentum (N, d) and force (N, d), dense in C order."""
    base, fx, w = stencil(p["x"], setup)
    d, t = setup.dim, setup.dtype
    sums = np.zeros((setup.n_nodes, 1 + 2 * d))
    stress_volume = -p["vol0"][:, None, None] * tau / t(setup.inertia)
    for o in offsets(setup):
        index = (base + o) @ setup.strides
        wp = weight(w, o)
        dpos = (o.astype(t) - fx) * t(setup.dx)
        wm = wp * p["mass"]
        momentum = wm[:, None] * (p["v"] + np.einsum("nab,nb->na", p["C"], dpos))
        force = wp[:, None] * np.einsum("nab,nb->na", stress_volume, dpos)
        values = np.concatenate([wm[:, None], momentum, force], axis=1)
        for c in range(values.shape[1]):
            sums[:, c] += np.bincount(index, weights=values[:, c], minlength=setup.n_nodes)
    return sums[:, 0].astype(t), sums[:, 1:1 + d].astype(t), sums[:, 1 + d:].astype(t)


def project(v, normal, kind, friction):
    """A wall's condition on node velocities ``v`` (m, d), ``normal`` pointing into the domain."""
    if kind == "sticky":
        return np.zeros_like(v)
    vn = v @ normal
    vt = v - vn[:, None] * normal
    if kind == "slip":
        return vt
    out = v.copy()
    approaching = vn < 0.0
    vt_norm = np.sqrt(np.sum(vt * vt, axis=1))
    stick = approaching & (vt_norm <= -friction * vn)
    slide = approaching & ~stick
    out[stick] = 0.0
    out[slide] = vt[slide] * (1.0 + friction * vn[slide] / vt_norm[slide])[:, None]
    return out


def grid_update(mass, momentum, force, dt, setup):
    """Node velocities after forces, gravity and walls, and before the forces."""
    t = setup.dtype
    has = mass > 0
    inverse = np.where(has, 1.0 / np.where(has, mass, 1.0), 0.0).astype(t)[:, None]
    v_tilde = momentum * inverse
    v = ((momentum + t(dt) * force) * inverse + (t(dt) * setup.gravity.astype(t)) * has[:, None]).astype(t)
    index = np.stack(np.unravel_index(np.arange(setup.n_nodes), setup.node_shape), axis=1)
    bands = [(index[:, a] < setup.width) if side == "min" else (index[:, a] > setup.cells[a] - setup.width)
             for a, side, _, _ in setup.walls]
    if setup.bug == "wall-gravity":
        on_wall = np.any(bands, axis=0) & has
        v[on_wall] += t(dt) * setup.gravity.astype(t)
    for band, (axis, side, kind, friction) in zip(bands, setup.walls):
        if kind == "open":
            continue
        sel = band & has
        normal = np.zeros(setup.dim, dtype=t)
        normal[axis] = 1.0 if side == "min" else -1.0
        mu = -friction if setup.bug == "friction-sign" else friction
        v[sel] = project(v[sel], normal, kind, t(mu))
    return v, v_tilde


def g2p(p, v_grid, dt, setup):
    """The particles after the grid: velocity, affine matrix, deformation and position."""
    base, fx, w = stencil(p["x"], setup)
    t = setup.dtype
    n, d = p["x"].shape
    v = np.zeros((n, d), dtype=t)
    B = np.zeros((n, d, d), dtype=t)
    for o in offsets(setup):
        vi = v_grid[(base + o) @ setup.strides]
        wp = weight(w, o)
        v += wp[:, None] * vi
        B += np.einsum("na,nb->nab", wp[:, None] * vi, (o.astype(t) - fx) * t(setup.dx))
    C = B / t(setup.inertia)
    new = {**p, "v": v, "C": C}
    if "F" in p:
        new["F"] = p["F"] + t(dt) * C @ p["F"]
    if "J" in p:
        new["J"] = p["J"] * (t(1.0) + t(dt) * np.trace(C, axis1=1, axis2=2))
    advect = 0.5 * dt if setup.bug == "half-dt-advect" else dt
    new["x"] = p["x"] + t(advect) * v
    return new


def step(p, dt, setup):
    mass, momentum, force = p2g(p, stress(p, setup), setup)
    v, _ = grid_update(mass, momentum, force, dt, setup)
    return g2p(p, v, dt, setup)


def wave_speed(p, setup):
    """Each particle's c_p + |v_p| (the CFL rule of scene.json)."""
    c = np.zeros(len(p["x"]))
    for k, m in enumerate(setup.materials):
        sel = p["material"] == k
        if m["type"] == "fluid":
            J = np.maximum(p["J"][sel], 1e-6)
            c[sel] = np.sqrt(m["gamma"] * m["K"] / (m["rho"] * J ** (m["gamma"] - 1.0)))
        else:
            J = np.maximum(np.linalg.det(p["F"][sel]), 1e-6)
            shear = 4.0 * m["mu"] * J / (3.0 * m["rho"])
            c[sel] = np.sqrt(np.maximum(shear + (2.0 * m["mu"] / 3.0 + m["lam"]) * (1.0 - np.log(J)) / m["rho"],
                                        shear))
    return c + np.sqrt(np.sum(p["v"].astype(float) ** 2, axis=1))


# ------------------------------------------------------------------------------------------------ files
def read_start(folder, dtype=None, from_csv=False):
    """The particles (a dict of arrays) and the scene of an ``mpmref export`` folder."""
    scene = json.loads((folder / "scene.json").read_text())
    dtype = np.dtype(dtype or scene["dtype"])
    if from_csv:
        with open(folder / scene["particles"]["files"]["csv"], newline="") as fh:
            rows = list(csv.reader(fh))
        columns = dict(zip(rows[0], np.array(rows[1:], dtype=np.float64).T))
        particles = {}
        for name, spec in scene["particles"]["fields"].items():
            names = csv_columns(name, spec["shape"])
            particles[name] = np.stack([columns[c] for c in names], axis=1).reshape(spec["shape"])
    else:
        with np.load(folder / scene["particles"]["files"]["npz"]) as npz:
            particles = {k: npz[k] for k in npz.files}
    for name, array in particles.items():
        kind = np.int64 if name == "id" else np.int32 if name == "material" else dtype
        particles[name] = np.asarray(array).astype(kind)
    return particles, scene, dtype


def csv_columns(name, shape):
    """The CSV columns of a field of ``shape`` (``x, y``; ``vx, vy``; ``F_xx, F_xy, ...``)."""
    if len(shape) == 1:
        return [name]
    d = shape[1]
    if len(shape) == 2:
        return list(AXES[:d]) if name == "x" else [f"{name}{AXES[a]}" for a in range(d)]
    return [f"{name}_{AXES[a]}{AXES[b]}" for a in range(d) for b in range(d)]


def _data_array(name, array, components):
    """A VTK XML DataArray, base64 binary with a 64-bit size header."""
    kinds = {"float64": "Float64", "float32": "Float32", "int64": "Int64", "int32": "Int32", "uint8": "UInt8"}
    raw = np.ascontiguousarray(array).tobytes()
    encoded = base64.b64encode(np.uint64(len(raw)).tobytes() + raw).decode()
    return (f'<DataArray type="{kinds[array.dtype.name]}" Name="{name}" NumberOfComponents="{components}" '
            f'format="binary">{encoded}</DataArray>')


def _padded(array, n):
    """Vectors (n, d) and matrices (n, d, d) padded with zeros to 3 and 3 x 3, flattened per particle."""
    if array.ndim == 2 and array.shape[1] < 3:
        return np.hstack([array, np.zeros((n, 3 - array.shape[1]), dtype=array.dtype)])
    if array.ndim == 3:
        d = array.shape[1]
        out = np.zeros((n, 3, 3), dtype=array.dtype)
        out[:, :d, :d] = array
        return out.reshape(n, 9)
    return array


def write_vtu(path, p, step_count, time):
    """One frame: the particles as VTK vertices with their id, velocity, J (or det F), F and material."""
    n = len(p["x"])
    fields = {"id": p["id"], "velocity": _padded(p["v"], n), "material": p["material"]}
    if "F" in p:
        fields["F"] = _padded(p["F"], n)
    fields["J"] = p["J"] if "J" in p else np.linalg.det(p["F"])
    point_data = "".join(_data_array(k, a, 1 if a.ndim == 1 else a.shape[1]) for k, a in fields.items())
    cells = (_data_array("connectivity", np.arange(n, dtype=np.int64), 1)
             + _data_array("offsets", np.arange(1, n + 1, dtype=np.int64), 1)
             + _data_array("types", np.ones(n, dtype=np.uint8), 1))  # 1: VTK_VERTEX
    field_data = (f'<FieldData><DataArray type="Int64" Name="step" NumberOfTuples="1" format="ascii">{step_count}'
                  f'</DataArray><DataArray type="Float64" Name="time" NumberOfTuples="1" format="ascii">{time!r}'
                  "</DataArray></FieldData>")
    text = ('<?xml version="1.0"?>\n<VTKFile type="UnstructuredGrid" version="1.0" byte_order="LittleEndian" '
            f'header_type="UInt64"><UnstructuredGrid>{field_data}<Piece NumberOfPoints="{n}" NumberOfCells="{n}">'
            f"<Points>{_data_array('Points', _padded(p['x'], n), 3)}</Points><Cells>{cells}</Cells>"
            f"<PointData>{point_data}</PointData></Piece></UnstructuredGrid></VTKFile>\n")
    path.write_text(text)


def write_pvd(path, entries):
    lines = "".join(f'<DataSet timestep="{t!r}" part="0" file="{name}"/>\n' for t, name in entries)
    path.write_text(f'<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1">\n<Collection>\n{lines}'
                    "</Collection>\n</VTKFile>\n")


# ------------------------------------------------------------------------------------------------ commands
def run(args):
    """Run the exported start; write a frame every ``output.every`` steps, at the start and at the end."""
    particles, scene, dtype = read_start(Path(args.start), args.dtype, args.csv)
    require(scene, ("method", "materials", "walls"))
    setup = setup_from(scene, dtype, args.bug, args.reverse)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    steps = args.steps if args.steps is not None else scene["time"]["steps"]
    every = scene["output"]["every"]
    time, entries = 0.0, []
    for k in range(steps + 1):
        if k % every == 0 or k == steps:
            name = f"particles_{k:06d}.vtu"
            write_vtu(out / name, particles, k, time)
            entries.append((time, name))
        if k == steps:
            break
        dt = scene["time"]["dt"] or scene["time"]["cfl"] * setup.dx / float(np.max(wave_speed(particles, setup)))
        particles = step(particles, dt, setup)
        time += dt
    write_pvd(out / "particles.pvd", entries)
    print(f"outside_mpm: {steps} steps of {len(particles['x'])} particles in {dtype.name}; frames in {out}")
    return 0


def case_outputs(case, inputs):
    """The outputs of one conformance case's stage on its inputs (``Unsupported`` if this code lacks them)."""
    stage = case["stage"]
    if stage not in STAGES:
        raise Unsupported(f"stage {stage}")
    require(case["resolved"], STAGE_NEEDS[stage])
    setup = setup_from(case["resolved"], np.dtype(case["dtype"]))
    particles = {k: inputs[k] for k in ("x", "v", "mass", "vol0", "material", "C", "F", "J") if k in inputs}
    if stage == "stress":
        return {"tau": stress(particles, setup)}
    if stage == "p2g":
        return dict(zip(("grid_mass", "grid_momentum", "grid_force"), p2g(particles, stress(particles, setup), setup)))
    if stage == "grid_update":
        v, v_tilde = grid_update(inputs["grid_mass"], inputs["grid_momentum"], inputs["grid_force"],
                                 float(inputs["dt"]), setup)
        return {"grid_v": v, "grid_v_tilde": v_tilde}
    if "C" not in particles or "modes" in inputs or "Jp" in inputs:
        raise Unsupported("a scheme without C, PolyPIC or plasticity")
    if stage == "g2p":
        new = g2p(particles, inputs["grid_v"], float(inputs["dt"]), setup)
    else:  # a multi-step case (in_steps) runs that many steps from its inputs
        new = particles
        for _ in range(int(inputs["steps"]) if "steps" in inputs else 1):
            new = step(new, float(inputs["dt"]), setup)
    return {k: new[k] for k in ("x", "v", "C", "F", "J") if k in new}


def stages(args):
    """Compute every case of a ``conformance export`` folder that this code implements; write each one's outputs to
    ``RESULTS/<case>.npz`` (``out_`` arrays) and this code's declaration to ``RESULTS/implements.json``."""
    vectors, results = Path(args.vectors), Path(args.results)
    results.mkdir(parents=True, exist_ok=True)
    manifest = json.loads((vectors / "manifest.json").read_text())
    done = 0
    for case in manifest["cases"]:
        with np.load(vectors / case["file"]) as npz:
            inputs = {k[3:]: npz[k] for k in npz.files if k.startswith("in_")}
        try:
            outputs = case_outputs(case, inputs)
        except Unsupported:
            continue
        with open(results / case["file"], "wb") as fh:
            np.savez(fh, **{f"out_{k}": np.asarray(v) for k, v in outputs.items()})
        done += 1
    (results / "implements.json").write_text(json.dumps({"implements": IMPLEMENTS, "stages": list(STAGES)}, indent=1))
    print(f"outside_mpm: {done} of {len(manifest['cases'])} cases computed; results in {results}")
    return 0


def main(argv=None):
    parser = argparse.ArgumentParser(description="An MPM code outside mpmref (MLS-MPM in plain NumPy).")
    commands = parser.add_subparsers(dest="command", required=True)
    r = commands.add_parser("run", help="run an exported start and write a .pvd series")
    r.add_argument("start", help="folder written by mpmref export")
    r.add_argument("out", help="folder for the frames")
    r.add_argument("--steps", type=int, help="steps to run (default: the scene's time.steps)")
    r.add_argument("--dtype", choices=("float64", "float32"), help="precision (default: the start's)")
    r.add_argument("--csv", action="store_true", help="read particles.csv instead of particles.npz")
    r.add_argument("--bug", choices=BUGS, help="plant a bug")
    r.add_argument("--reverse", action="store_true", help="sum the stencil's nodes in the reverse order")
    r.set_defaults(func=run)
    s = commands.add_parser("stages", help="compute the stages of conformance vectors")
    s.add_argument("vectors", help="folder written by mpmref conformance export")
    s.add_argument("results", help="folder for the outputs")
    s.set_defaults(func=stages)
    args = parser.parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
