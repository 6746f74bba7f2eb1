"""The ``[[bodies]]`` sampled into particles, the ``[[emitters]]`` that release more of them, and the level-set
``[[colliders]]``."""

import numpy as np

from ..physics.boundary import BOUNDARY_TYPES
from ..physics.colliders import Ball, Box, Collider, Cylinder, Plane
from .specs import BodySpec, EmitterSpec
from .validation import choice, fail, integer, matrix, number, section, vector

SHAPES = ("box", "disk", "sphere", "points", "mesh")
SAMPLINGS = ("regular", "jittered", "random")
COLLIDER_SHAPES = ("plane", "box", "disk", "sphere", "cylinder")
EMITTER_KEYS = {"shape", "material", "center", "radius", "velocity", "ppc", "sampling", "seed", "start", "interval",
                "until"}
BODY_KEYS = {
    "shape", "material", "lower", "upper", "center", "radius", "positions", "file", "ppc", "sampling",
    "seed", "count", "particle_volume", "velocity", "angular_velocity", "rotation_center", "velocity_gradient",
}


def parse_bodies(bodies, dim, materials):
    """The ``[[bodies]]``: a :class:`BodySpec` each (shape, material and sampling parameters)."""
    if not isinstance(bodies, list) or not bodies:
        fail("bodies", bodies, "a non-empty array of tables, e.g. [[bodies]]")
    return [_parse_body(b, i, dim, materials) for i, b in enumerate(bodies)]


def _parse_body(b, i, dim, materials):
    path = f"bodies[{i}]"
    section(b, path, BODY_KEYS)
    shape = choice(b, "shape", path, SHAPES, required=True)
    material = choice(b, "material", path, tuple(materials), required=True)
    p = {"velocity": vector(b, "velocity", path, dim, default=[0.0] * dim)}
    p.update(_body_geometry(b, path, shape, dim))
    p["ppc"] = integer(b, "ppc", path, default=2**dim, lo=1, hi=64)
    p["sampling"] = choice(b, "sampling", path, SAMPLINGS, default="regular")
    samples = shape != "points"  # for given points, ppc only sets the particle volume
    if samples and p["sampling"] == "regular" and round(p["ppc"] ** (1.0 / dim)) ** dim != p["ppc"]:
        power = "square" if dim == 2 else "cube"
        fail(f"{path}.ppc", p["ppc"], f"a perfect {power} (1, {2**dim}, {3**dim}, ...) for regular sampling")
    p["seed"] = integer(b, "seed", path, default=0, lo=0)
    p["count"] = integer(b, "count", path, default=None, lo=1)
    if p["count"] is not None and p["sampling"] != "random":
        fail(f"{path}.count", p["count"], "only with sampling = 'random'")
    p["particle_volume"] = number(b, "particle_volume", path, default=None, lo=0.0, lo_open=True)
    if dim == 2:
        p["angular_velocity"] = number(b, "angular_velocity", path, default=0.0)
    else:
        p["angular_velocity"] = vector(b, "angular_velocity", path, 3, default=[0.0, 0.0, 0.0])
    p["rotation_center"] = vector(b, "rotation_center", path, dim)
    p["velocity_gradient"] = matrix(b, "velocity_gradient", path, dim, default=np.zeros((dim, dim)))
    return BodySpec(index=i, shape=shape, material=material, params=p)


def _body_geometry(b, path, shape, dim):
    """The parameters of a body's ``shape``: box corners, disk or sphere, given points or a file."""
    if shape == "box":
        lower, upper = _corners(b, path, dim)
        return {"lower": lower, "upper": upper}
    if shape in ("disk", "sphere"):
        want = 2 if shape == "disk" else 3
        if dim != want:
            fail(f"{path}.shape", shape, f"'{'disk' if dim == 2 else 'sphere'}' in a {dim}D scene")
        return {"center": vector(b, "center", path, dim, required=True),
                "radius": number(b, "radius", path, required=True, lo=0.0, lo_open=True)}
    if shape == "points":
        return {"positions": _points_array(b, path, dim)}
    if not isinstance(b.get("file"), str):
        fail(f"{path}.file", b.get("file"), "the path of a mesh or point cloud readable by meshio")
    return {"file": b["file"]}


def _corners(data, path, dim):
    """The ``lower`` and ``upper`` corners of a box, ``upper`` above ``lower`` on every axis."""
    lower, upper = vector(data, "lower", path, dim, required=True), vector(data, "upper", path, dim, required=True)
    if np.any(upper <= lower):
        fail(f"{path}.upper", upper.tolist(), f"greater than lower = {lower.tolist()} on every axis")
    return lower, upper


def _points_array(b, path, dim):
    pos = b.get("positions")
    try:
        arr = np.asarray(pos, dtype=np.float64)
    except (TypeError, ValueError):
        arr = None
    if arr is None or arr.ndim != 2 or arr.shape[1] != dim or arr.shape[0] == 0 or not np.all(np.isfinite(arr)):
        fail(f"{path}.positions", pos if arr is None else f"array of shape {arr.shape}",
             f"a finite array of shape (n, {dim}) with n >= 1")
    return arr


def parse_emitters(emitters, dim, materials, grid, kernel, time):
    """The ``[[emitters]]``: validated particle sources (synchronous stepping only; docs/scenes.md)."""
    if not isinstance(emitters, list):
        fail("emitters", emitters, "an array of tables, e.g. [[emitters]]")
    if emitters and time.stepping != "sync":
        fail("time.stepping", time.stepping, "'sync' in a scene with [[emitters]] (particles are added between "
             "synchronous steps)")
    return [_parse_emitter(e, i, dim, materials, grid, kernel, time) for i, e in enumerate(emitters)]


def _parse_emitter(e, i, dim, materials, grid, kernel, time):
    path = f"emitters[{i}]"
    section(e, path, EMITTER_KEYS)
    shape = "disk" if dim == 2 else "sphere"
    choice(e, "shape", path, (shape,), default=shape)
    p = {"material": choice(e, "material", path, tuple(materials), required=True),
         "center": vector(e, "center", path, dim, required=True),
         "radius": number(e, "radius", path, required=True, lo=0.0, lo_open=True),
         "velocity": vector(e, "velocity", path, dim, required=True),
         "ppc": integer(e, "ppc", path, default=2**dim, lo=1, hi=64),
         "sampling": choice(e, "sampling", path, SAMPLINGS, default="regular"),
         "seed": integer(e, "seed", path, default=0, lo=0), "count": None, "particle_volume": None,
         "angular_velocity": 0.0 if dim == 2 else np.zeros(3), "rotation_center": None,
         "velocity_gradient": np.zeros((dim, dim))}
    if p["sampling"] == "regular" and round(p["ppc"] ** (1.0 / dim)) ** dim != p["ppc"]:
        fail(f"{path}.ppc", p["ppc"], f"a perfect {'square' if dim == 2 else 'cube'} for regular sampling")
    lo = grid.origin + kernel.low_margin * grid.dx
    hi = grid.origin + (np.array(grid.cells) - kernel.high_margin) * grid.dx
    if np.any(p["center"] - p["radius"] < lo) or np.any(p["center"] + p["radius"] >= hi):
        fail(f"{path}.center", p["center"].tolist(), f"a {shape} of radius {p['radius']} inside the grid's valid "
             f"region {lo.tolist()} .. {hi.tolist()}")
    speed = float(np.linalg.norm(p["velocity"]))
    if speed == 0.0:
        fail(f"{path}.velocity", p["velocity"].tolist(), "a nonzero velocity (releases at rest would overlap)")
    clear = 2.0 * p["radius"] / speed
    interval = number(e, "interval", path, default=clear, lo=0.0, lo_open=True)
    if interval < clear * (1.0 - 1e-12):
        fail(f"{path}.interval", interval, f"at least 2 radius / |velocity| = {clear:.6g} s (a release must have "
             "cleared the previous one, which moved interval |velocity| since)")
    if time.dt is not None and interval < time.dt:
        fail(f"{path}.interval", interval, f"at least time.dt = {time.dt} (one release per step)")
    start = number(e, "start", path, default=0.0, lo=0.0)
    until = number(e, "until", path, required=True, lo=start, lo_open=True)
    body = BodySpec(index=i, shape=shape, material=p.pop("material"), params=p)
    return EmitterSpec(index=i, body=body, start=start, interval=interval, until=until)


def parse_colliders(colliders, dim):
    """The ``[[colliders]]``: a level-set :class:`~mpmref.physics.colliders.Collider` each."""
    if not isinstance(colliders, list):
        fail("colliders", colliders, "an array of tables, e.g. [[colliders]]")
    out = []
    for i, c in enumerate(colliders):
        path = f"colliders[{i}]"
        section(c, path, {"shape", "type", "friction", "velocity", "point", "normal", "center", "radius",
                          "lower", "upper", "axis"})
        shape = choice(c, "shape", path, COLLIDER_SHAPES, required=True)
        if shape in ("disk", "sphere") and shape != ("disk" if dim == 2 else "sphere"):
            fail(f"{path}.shape", shape, f"'{'disk' if dim == 2 else 'sphere'}' in a {dim}D scene")
        if shape == "cylinder" and dim != 3:
            fail(f"{path}.shape", shape, "'cylinder' only in 3D (use 'disk' in 2D)")
        out.append(Collider(shape=_collider_shape(c, path, shape, dim),
                            type=choice(c, "type", path, BOUNDARY_TYPES, default="separate"),
                            friction=number(c, "friction", path, default=0.0, lo=0.0),
                            velocity=vector(c, "velocity", path, dim, default=[0.0] * dim)))
    return out


def _collider_shape(c, path, shape, dim):
    if shape == "plane":
        normal = vector(c, "normal", path, dim, required=True)
        if np.linalg.norm(normal) == 0:
            fail(f"{path}.normal", normal.tolist(), "a non-zero vector")
        return Plane(point=vector(c, "point", path, dim, required=True), normal=normal)
    if shape == "box":
        lower, upper = _corners(c, path, dim)
        return Box(lower=lower, upper=upper)
    radius = number(c, "radius", path, required=True, lo=0.0, lo_open=True)
    if shape == "cylinder":
        axis = vector(c, "axis", path, dim, required=True)
        if np.linalg.norm(axis) == 0:
            fail(f"{path}.axis", axis.tolist(), "a non-zero vector")
        return Cylinder(point=vector(c, "point", path, dim, required=True), axis=axis, radius=radius)
    return Ball(center=vector(c, "center", path, dim, required=True), radius=radius)
