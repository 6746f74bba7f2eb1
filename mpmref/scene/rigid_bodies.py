"""The ``[[rigid_bodies]]`` of CPIC coupling (docs/cpic.md), parsed once for 2D and 3D.

A body is the same in both dimensions (motion, contact, scripted or dynamic motion) but for its geometry and
its rotation: in 2D a polyline (``vertices``, ``segments``) that turns by an angle, in 3D a triangle mesh
(``vertices``, ``triangles``, or a ``mesh`` file read by meshio) that turns by a rotation vector. Those parts
are chosen once by dimension (:data:`GEOMETRY_KEYS`, :func:`_geometry`, :func:`_rotation`).
"""

import math
from dataclasses import replace

import numpy as np

from ..rigid.dynamics import (
    CONTACT_TYPES,
    MOTIONS,
    RigidBody,
    area_mass_properties,
    encode_friction,
    line_mass_properties,
)
from ..rigid.polyline import validate_polyline
from ..rigid.trimesh import mass_properties, read_trimesh, validate_trimesh
from .validation import choice, fail, flag, integer, number, section, vector

RIGID_COMMON_KEYS = {"closed", "motion", "type", "friction"}
#: the geometry of a body in each dimension: a polyline (2D); a triangle mesh inline (vertices, triangles) or
#: from a file read by meshio (mesh) (3D)
GEOMETRY_KEYS = {2: {"vertices", "segments"}, 3: {"vertices", "triangles", "mesh"}}
#: dynamic-body keys of the 2D sand wheel (a pin, angular damping, welds) that 3D bodies do not have yet
PINNED_KEYS_2D = {"pinned", "angular_damping", "welded_to"}
#: keys each rigid-body motion accepts besides the common ones
RIGID_MOTION_KEYS = {
    "fixed": set(),
    "scripted": {"velocity", "angular_velocity", "center", "keyframes"},
    "dynamic": {"density", "velocity", "angular_velocity", "gravity", *PINNED_KEYS_2D},
}
#: the keyframe key of a scripted body's rotation: an angle (2D) or a rotation vector (3D)
ROTATION_KEY = {2: "angle", 3: "rotation"}


def parse_rigid_bodies(bodies, dim, grid, cpic, time, base_dir=None):
    """The ``[[rigid_bodies]]``: validated 2D polylines or 3D triangle meshes with their motion and contact.

    ``cpic`` is the scene's :class:`~mpmref.scene.specs.CpicSpec` (``None`` without coupling): bodies need it.
    """
    if not isinstance(bodies, list):
        fail("rigid_bodies", bodies, "an array of tables, e.g. [[rigid_bodies]]")
    if bodies and cpic is None:
        fail("method.coupling", "none", "'cpic' when the scene has [[rigid_bodies]]")
    if cpic is not None and not bodies:
        fail("method.coupling", "cpic", "'none' in a scene without [[rigid_bodies]]")
    if bodies and time.stepping != "sync":
        fail("time.stepping", time.stepping, "'sync' in a scene with [[rigid_bodies]] (CPIC runs in the synchronous "
             "step)")
    parsed = [_parse_rigid_body(b, i, dim, grid, base_dir) for i, b in enumerate(bodies)]
    return _welds(parsed, bodies, grid) if dim == 2 else parsed


def _parse_rigid_body(b, i, dim, grid, base_dir):
    """One ``[[rigid_bodies]]`` entry: its geometry, motion and contact."""
    path = f"rigid_bodies[{i}]"
    if not isinstance(b, dict):
        fail(path, b, "a table")
    motion = choice(b, "motion", path, MOTIONS, default="fixed")
    if dim == 3:
        for key in PINNED_KEYS_2D & set(b):
            fail(f"{path}.{key}", b[key], "absent in 3D (pinned, damped and welded bodies are 2D only for now)")
    section(b, path, RIGID_COMMON_KEYS | GEOMETRY_KEYS[dim] | RIGID_MOTION_KEYS[motion])
    closed = flag(b, "closed", path, default=False)
    shape = _geometry(b, path, i, dim, grid, closed, base_dir)
    params = {"shape": shape, "motion": motion, "friction": _contact_sides(b, path),
              "center": shape.vertices.mean(axis=0), "velocity": np.zeros(dim),
              "angular_velocity": 0.0 if dim == 2 else np.zeros(3)}
    if motion == "scripted":
        params.update(_script(b, path, shape, dim))
    elif motion == "dynamic":
        params.update(_dynamic(b, path, shape, dim))
    return RigidBody(**params)


def _geometry(b, path, i, dim, grid, closed, base_dir):
    """A 2D body's polyline or a 3D body's triangle mesh (inline or read by meshio), inside the domain."""
    lo, hi = grid.origin, grid.origin + np.array(grid.cells) * grid.dx
    if dim == 3:
        if "mesh" not in b:
            return validate_trimesh(b.get("vertices"), b.get("triangles"), closed=closed, index=i, domain=(lo, hi))
        inline = sorted({"vertices", "triangles"} & set(b))
        if inline:
            fail(f"{path}.{inline[0]}", b[inline[0]], "absent when mesh = \"file\" gives the geometry")
        if not isinstance(b["mesh"], str):
            fail(f"{path}.mesh", b["mesh"], "a file name (a triangle mesh meshio can read)")
        return read_trimesh(b["mesh"], closed=closed, index=i, domain=(lo, hi), base_dir=base_dir or ".")
    shape = validate_polyline(b.get("vertices"), b.get("segments"), closed=closed, index=i)
    outside = np.nonzero(np.any((shape.vertices < lo) | (shape.vertices > hi), axis=1))[0]
    if outside.size:
        k = int(outside[0])
        fail(f"{path}.vertices", shape.vertices[k].tolist(), f"inside the domain [{lo.tolist()}, {hi.tolist()}] "
             f"(vertex {k} is outside)")
    return shape


def _rotation(data, key, path, dim):
    """An angle or angular velocity, 0 when absent: a number in 2D, a rotation vector in 3D."""
    if dim == 2:
        return number(data, key, path, default=0.0)
    return vector(data, key, path, 3, default=[0.0] * 3)


def _script(b, path, shape, dim):
    """A scripted body: constant ``velocity`` and ``angular_velocity`` about ``center``, or keyframes of offset
    and rotation."""
    center = vector(b, "center", path, dim, default=shape.vertices.mean(axis=0))
    if "keyframes" not in b:
        return {"center": center, "velocity": vector(b, "velocity", path, dim, default=[0.0] * dim),
                "angular_velocity": _rotation(b, "angular_velocity", path, dim)}
    for key in ("velocity", "angular_velocity"):
        if key in b:
            fail(f"{path}.{key}", b[key], "absent when keyframes are given (the keyframes set the motion)")
    turn = ROTATION_KEY[dim]
    frames = b["keyframes"]
    if not isinstance(frames, list) or len(frames) < 2:
        fail(f"{path}.keyframes", frames, f"a list of at least two tables {{time, offset, {turn}}}")
    out = []
    for k, f in enumerate(frames):
        where = f"{path}.keyframes[{k}]"
        section(f, where, {"time", "offset", turn})
        t = number(f, "time", where, required=True, lo=0.0)
        if out and t <= out[-1][0]:
            fail(f"{where}.time", t, f"greater than the previous keyframe's time {out[-1][0]}")
        out.append((t, vector(f, "offset", where, dim, default=[0.0] * dim), _rotation(f, turn, where, dim)))
    return {"center": center, "keyframes": tuple(out)}


def _dynamic(b, path, shape, dim):
    """A dynamic body: mass, centre and inertia from ``density``; in 2D also a pin, damping and a weld."""
    density = number(b, "density", path, required=True, lo=0.0, lo_open=True)
    gravity = flag(b, "gravity", path, default=True)
    mass, center, inertia = _polyline_mass(b, path, shape, density) if dim == 2 else mass_properties(shape, density)
    pinned = _pinned(b, path) if dim == 2 else False
    out = {"mass": mass, "center": center, "inertia": inertia, "gravity": gravity,
           "velocity": vector(b, "velocity", path, dim, default=[0.0] * dim),
           "angular_velocity": _rotation(b, "angular_velocity", path, dim)}
    if dim == 2:
        out.update(pinned=pinned, angular_damping=number(b, "angular_damping", path, default=0.0, lo=0.0),
                   welded_to=integer(b, "welded_to", path, default=-1, lo=0))
    return out


def _polyline_mass(b, path, shape, density):
    """Mass, centre and inertia of a 2D body: of the area a closed polyline bounds (its segments consistently
    oriented), or of an open polyline's length."""
    if not shape.closed:
        return line_mass_properties(shape, density)
    starts = np.bincount(shape.segments[:, 0], minlength=len(shape.vertices))
    if np.any(starts != 1):
        fail(f"{path}.segments", shape.segments.tolist(), "consistently oriented segments for a closed dynamic "
             "body (each vertex starts exactly one segment)")
    return area_mass_properties(shape, density)


def _pinned(b, path):
    """Whether a 2D dynamic body is pinned at its centre of mass (then it has no ``velocity``)."""
    pinned = flag(b, "pinned", path, default=False)
    if pinned and "velocity" in b:
        fail(f"{path}.velocity", b["velocity"], "absent for a pinned body (its centre of mass does not move)")
    return pinned


def _contact_sides(b, path):
    """The encoded friction of side 0 and side 1 from ``type`` and ``friction`` (each one value or two)."""
    kinds = b.get("type", "separate")
    kinds = [kinds, kinds] if isinstance(kinds, str) else kinds
    if not isinstance(kinds, list) or len(kinds) != 2 or any(k not in CONTACT_TYPES for k in kinds):
        fail(f"{path}.type", b.get("type"), f"one of {list(CONTACT_TYPES)}, or a list of two (side 0, side 1)")
    mu = b.get("friction", 0.0)
    mu = [mu, mu] if not isinstance(mu, list) else mu
    if len(mu) != 2 or any(isinstance(c, bool) or not isinstance(c, (int, float)) or not math.isfinite(c) or c < 0
                           for c in mu):
        fail(f"{path}.friction", b.get("friction"), "a number >= 0, or a list of two (side 0, side 1)")
    return np.array([encode_friction(k, c) for k, c in zip(kinds, mu)])


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
            fail(path, k, f"the index of an earlier dynamic body that is not itself welded (0 .. {i - 1})")
        if not (body.pinned and parsed[k].pinned):
            fail(path, k, f"a weld of two pinned bodies (set pinned = true on rigid_bodies[{i}] and "
                 f"rigid_bodies[{k}]; welds of free bodies are not built)")
        gap = float(np.linalg.norm(body.center - parsed[k].center))
        if gap > 1e-6 * grid.dx:
            fail(path, k, f"a body pinned at the same centre (centres of mass {body.center.tolist()} and "
                 f"{parsed[k].center.tolist()} differ by {gap:.3g})")
        if "angular_velocity" in declared[i]:
            fail(f"rigid_bodies[{i}].angular_velocity", declared[i]["angular_velocity"],
                 "absent on a welded body (it turns with the body it is welded to)")
        out[i] = replace(body, angular_velocity=parsed[k].angular_velocity)
    return out
