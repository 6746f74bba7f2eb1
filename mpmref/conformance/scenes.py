r"""Conformance cases drawn from a user's own scene: every stage its steps call, on its physics, at its scales.

``mpmref conformance check --backend B --scene SCENE.toml`` checks a code on the scene it is written for, not on the
catalogue's. Each case keeps what the scene declares that a stage computes with: its dimension and dtype, its method
(scheme, force, kernel, FLIP's α, CPIC coupling), its materials with their parameters, its gravity, its boundary
(the wall on each face, friction, band width), its colliders and rigid bodies, and its time stepping. What the case
draws (from a generator seeded by its stage and number, and the base seed, never by the scene's name: a scene checks
the same under any name) is

* **a small box** of :data:`SCENE_CELLS` cells per axis (at least two axes differ) at the scene's own cell size, placed
  at a random place in the scene's domain (the origin moves off the scene's by a non-whole number of cells);
* **the geometry** of the colliders and rigid bodies, mapped from the scene's domain into that box by one scale and
  shift (:class:`Compression`): a collider keeps its place relative to the walls, its shape and its velocity;
* **the state** at the scene's scales (:func:`scene_scales`): particle velocities of the size of its bodies' speeds
  (or of the free fall across its domain under its gravity), affine matrices of that speed over half a cell, node
  forces of its gravity or its stiffest material's (:math:`0.01\,c^2/\Delta x`), node masses of its densest material;
* **Δt** from a CFL number over nearly four decades inside the stable range (:func:`~.states.draw_step`, with the
  scene's wave speed and speed scale; CPIC's penalty bounds Δt by :math:`1/k`), and **the time** over three decades of
  the time in which its fastest collider or body crosses 8 cells.

Each stage has :data:`CASES_PER_STAGE` cases, so each sees that many Δt, boxes and origins. The stages are those the
scene's steps call (:func:`scene_stages`).
"""

import copy
import re
import zlib
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from ..run.stability import stable_cfl
from ..scene import Scene
from ..scene.builder import read_scene_file
from .case import ConformanceCase, seeded_label
from .cases import base_seed, distinct_cells
from .extremes import EXTREMES, REST_CFL, holds_for
from .states import Scales, draw_step, step_at

#: cases per stage: each its own box, origin, Δt, time and state
CASES_PER_STAGE = 5
#: the cells per axis of a case's box: from ``max(8, 2 (width + 1))`` (room for the wall bands on both sides, which
#: :mod:`mpmref.scene` asks for) to that plus 8
SCENE_CELLS = (8, 8)


def scene_stages(scene):
    """The conformance stages that ``scene``'s steps call, in stage order.

    Every scene: ``stress`` and ``grid_update``, and ``return_map`` with a plastic material (snow, sand). Without rigid
    bodies: ``p2g``, ``g2p``, the whole ``step`` and its ``ledger``, and ``p2g_fused`` without FLIP (the steppers fuse
    the force into P2G where a backend can). Asynchronous stepping adds ``wave_speeds`` and ``p2g_classes``, and with
    conservative interfaces ``interface_kicks`` and ``g2p_kicks``. Rigid bodies (CPIC) replace P2G, G2P and the step by
    the five CPIC stages.
    """
    stages = ["stress"]
    if scene.tracks("Jp"):
        stages.append("return_map")
    if scene.rigid_bodies:
        return stages + ["grid_update", "cpic_field", "cpic_tags", "cpic_p2g", "cpic_g2p", "cpic_step"]
    stages += ["p2g"] + ([] if scene.transfer.flip else ["p2g_fused"]) + ["grid_update", "g2p", "step", "ledger"]
    if scene.time.stepping == "async":
        stages += ["wave_speeds", "p2g_classes"]
        if scene.time.interface == "conservative":
            stages += ["interface_kicks", "g2p_kicks"]
    return stages


def scene_scales(scene):
    r"""The :class:`~.states.Scales` of a case drawn from ``scene``.

    * speed :math:`s`: the largest of the bodies' and emitters' speeds (velocity, plus angular velocity and velocity
      gradient times the half diagonal of the domain), the free-fall speed :math:`\sqrt{2 |g| L}` across the domain's
      largest extent :math:`L`, and a hundredth of the largest wave speed :math:`c` (so that a scene at rest without
      gravity still moves);
    * affine: :math:`s / (2\Delta x)`, a velocity change of :math:`s` over two cells;
    * node force per unit mass: the larger of :math:`|g|` and :math:`0.01\, c^2/\Delta x` (the internal force of a
      strain of a percent over a cell), over :math:`s`;
    * node mass density: the densest material's;
    * time: :math:`8\Delta x / v`, with :math:`v` the largest of :math:`s` and the colliders' and rigid bodies' speeds.
    """
    dx, c = scene.grid.dx, scene.max_wave_speed()
    extent = np.array(scene.grid.cells) * dx
    reach = 0.5 * float(np.linalg.norm(extent))
    g = float(np.linalg.norm(scene.gravity))
    bodies = [b.params for b in scene.bodies] + [e.body.params for e in scene.emitters]
    speeds = [float(np.linalg.norm(p["velocity"])) + reach * (float(np.linalg.norm(p["angular_velocity"]))
                                                              + float(np.linalg.norm(p["velocity_gradient"])))
              for p in bodies]
    speed = max([*speeds, np.sqrt(2.0 * g * extent.max()), 0.01 * c])
    movers = [float(np.linalg.norm(k.velocity)) for k in scene.colliders]
    movers += [float(np.linalg.norm(b.velocity)) + reach * float(np.linalg.norm(b.angular_velocity))
               for b in scene.rigid_bodies]
    return Scales(speed=float(speed), affine=float(speed / (2.0 * dx)),
                  force_per_speed=float(max(g, 0.01 * c * c / dx) / speed),
                  density=max(m.rho for m in scene.material_list), time=float(8.0 * dx / max([speed, *movers])))


@dataclass(frozen=True)
class Compression:
    r"""The map of the scene's domain into a case's box: :math:`x' = o' + k\,(x - o)` with one scale :math:`k` for
    every axis (the largest that fits the domain in the box), centred in the box."""

    scale: float
    source_center: tuple
    target_center: tuple

    @classmethod
    def between(cls, grid, box):
        size = np.array(grid.cells) * grid.dx
        box_size = np.asarray(box["size"])
        return cls(float(np.min(box_size / size)), tuple(grid.origin + 0.5 * size),
                   tuple(np.asarray(box["origin"]) + 0.5 * box_size))

    def point(self, x):
        return (np.asarray(self.target_center) + self.scale * (np.asarray(x, dtype=float)
                                                                - np.asarray(self.source_center))).tolist()

    def length(self, value):
        return self.scale * float(value)

    def vector(self, v):
        return (self.scale * np.asarray(v, dtype=float)).tolist()


#: collider keys that are points, and those that are lengths
COLLIDER_POINTS, COLLIDER_LENGTHS = ("point", "center", "lower", "upper"), ("radius",)


def _collider(declared, compression):
    out = copy.deepcopy(declared)
    for key in COLLIDER_POINTS:
        if key in out:
            out[key] = compression.point(out[key])
    for key in COLLIDER_LENGTHS:
        if key in out:
            out[key] = compression.length(out[key])
    return out


def _rigid_body(declared, parsed, compression):
    """A ``[[rigid_bodies]]`` entry mapped into the box: its vertices (a mesh file's read here and written inline),
    a scripted centre and its keyframes' offsets."""
    out = copy.deepcopy(declared)
    if "mesh" in out:
        out.pop("mesh")
        out["triangles"] = np.asarray(parsed.shape.triangles).tolist()
    out["vertices"] = [compression.point(v) for v in np.asarray(parsed.shape.vertices)]
    if "center" in out:
        out["center"] = compression.point(out["center"])
    for frame in out.get("keyframes", []):
        if "offset" in frame:
            frame["offset"] = compression.vector(frame["offset"])
    return out


def scene_box(label, scene):
    """The box of the case called ``label`` (``{"origin", "size", "dx"}``): the scene's cell size, each axis its own
    number of cells (:data:`SCENE_CELLS`), placed at a random place of the scene's domain."""
    rng = np.random.default_rng(zlib.crc32(f"grid-{label}".encode()))
    low = max(SCENE_CELLS[0], 2 * (scene.boundary.width + 1))
    cells = distinct_cells(rng, scene.dim, (low, low + SCENE_CELLS[1]))
    dx = scene.grid.dx
    size = cells * dx
    room = np.array(scene.grid.cells) * dx - size
    origin = scene.grid.origin + rng.uniform(0.0, 1.0, scene.dim) * room + rng.uniform(-0.5, 0.5, scene.dim) * dx
    return {"origin": origin.tolist(), "size": size.tolist(), "dx": dx}


def _time_section(declared_time, scene, dt):
    """A case's ``[time]``: its Δt (synchronous), or the scene's asynchronous settings (the case carries its Δt)."""
    if scene.time.stepping == "sync":
        return {"dt": dt}
    return {k: v for k, v in declared_time.items() if k not in ("steps", "t_end")}


def scene_case_dict(declared, scene, box, dtype):
    """The scene of a case: ``declared`` (the user's scene) in the box ``box``, with one body in it (the cases draw
    their own particles), its colliders and rigid bodies mapped in (:class:`Compression`), no emitters and no
    outputs, in ``dtype``; its ``[time]`` is set by the caller."""
    compression = Compression.between(scene.grid, box)
    dim = scene.dim
    first = next(iter(declared["materials"]))
    lower = (np.asarray(box["origin"]) + 0.25 * np.asarray(box["size"])).tolist()
    upper = (np.asarray(box["origin"]) + 0.75 * np.asarray(box["size"])).tolist()
    out = {"name": scene.name, "dim": dim, "dtype": dtype, "grid": box,
           "method": copy.deepcopy(declared.get("method", {})), "materials": copy.deepcopy(declared["materials"]),
           "bodies": [{"shape": "box", "material": first, "lower": lower, "upper": upper}],
           "gravity": copy.deepcopy(declared.get("gravity", [0.0] * dim)),
           "boundary": copy.deepcopy(declared.get("boundary", {})),
           "colliders": [_collider(c, compression) for c in declared.get("colliders", [])]}
    if declared.get("rigid_bodies"):
        out["rigid_bodies"] = [_rigid_body(d, p, compression)
                               for d, p in zip(declared["rigid_bodies"], scene.rigid_bodies, strict=True)]
    return out


def _scene_case(stage, k, declared, scene, scales, dtype, seed=0):
    """Case ``k`` of ``stage``, named after the scene (``stress-2d-jelly-3``) and seeded by the stage and ``k`` alone
    (and the base ``seed``): a scene checks the same under any name."""
    variant = f"{re.sub(r'[^A-Za-z0-9_.-]', '_', scene.name)}-{k}"  # file-name safe
    label = seeded_label(f"{stage}-{scene.dim}d-scene-{k}", seed)
    case_dict = scene_case_dict(declared, scene, scene_box(label, scene), dtype)
    penalty = scene.cpic.penalty if scene.cpic is not None else 0.0
    case_dict["time"] = {"dt": 1.0}  # a placeholder while Δt is drawn from the case's own box
    dt = draw_step(label, Scene.from_dict(case_dict), scales.speed, 1.0 / penalty if penalty else None)
    case_dict["time"] = _time_section(declared.get("time", {}), scene, dt)
    own_dt = dt if scene.time.stepping != "sync" else None
    return ConformanceCase(stage, scene.dim, variant, case_dict, dtype, scales, own_dt, scene.name, seed_label=label)


#: the extreme families (:mod:`~mpmref.conformance.extremes`) of each stage a scene's cases hold, where they apply
#: (:func:`scene_families`)
SCENE_FAMILIES = {
    "stress": ("rest", "near-symmetric-F", "collapse"),
    "return_map": ("yield-surface", "collapse"),
    "p2g": ("on-nodes-and-faces", "domain-edge"),
    "p2g_fused": ("on-nodes-and-faces", "domain-edge"),
    "g2p": ("on-nodes-and-faces", "domain-edge"),
    "grid_update": ("massless-neighbours",),
    "step": ("on-nodes-and-faces", "domain-edge", "cfl-limit", "from-rest", "pushed-from-rest"),
    "ledger": ("cfl-limit",),
}


def scene_families(stage, scene, dtype="float64"):
    """The extreme families of :data:`SCENE_FAMILIES` that ``stage`` of ``scene`` holds: the near-symmetric one with a
    solid; the particle positions not with PolyPIC (its G2P divides by mode norms that vanish where a weight does, and
    no code could be checked there); ``from-rest`` (on the floor) with gravity; in float32, the families that hold in it
    (:attr:`~.extremes.Extreme.float32`); those that hold for its kernel (:func:`~.extremes.holds_for`)."""
    families = SCENE_FAMILIES.get(stage, ())
    skip = set()
    if not scene.tracks("F"):
        skip.add("near-symmetric-F")
    if scene.transfer.polypic:
        skip |= {"on-nodes-and-faces", "domain-edge"}
    if not np.any(scene.gravity):
        skip.add("from-rest")
    return tuple(f for f in families if f not in skip and (dtype == "float64" or EXTREMES[f].float32)
                 and holds_for(EXTREMES[f], scene.kernel))


def extreme_box(label, scene, extreme):
    """The box of a case at ``extreme``: for the particle positions, on the scene's node lattice (a whole number of
    cells from its origin, so that a node of the box is a node of the scene), at the scene's lower corner for the
    domain's edge; else :func:`scene_box`."""
    box = scene_box(label, scene)
    if not extreme.exact_grid:
        return box
    dx, origin = scene.grid.dx, scene.grid.origin
    cells = np.round((np.asarray(box["origin"]) - origin) / dx)
    box["origin"] = (origin + (0.0 if extreme.name == "domain-edge" else cells) * dx).tolist()
    return box


def _extreme_step(extreme, label, case_scene, scales, penalty):
    """The Δt of a scene's case at ``extreme``: at the scheme's stability limit, at :data:`~.extremes.REST_CFL` at rest,
    else drawn (:func:`~.states.draw_step`)."""
    if extreme.cfl == "limit":
        return step_at(case_scene, stable_cfl(case_scene.method.scheme), scales.speed)
    if extreme.cfl == "rest":
        return step_at(case_scene, REST_CFL, 0.0)
    return draw_step(label, case_scene, scales.speed, 1.0 / penalty if penalty else None)


def _scene_extreme_case(stage, family, declared, scene, scales, dtype, seed=0):
    """The case of ``stage`` of the scene at the extreme ``family`` (``stress-2d-jelly-near-symmetric-F``), seeded by
    the stage and the family alone (and the base ``seed``)."""
    extreme = EXTREMES[family]
    variant = f"{re.sub(r'[^A-Za-z0-9_.-]', '_', scene.name)}-{family}"
    label = seeded_label(f"{stage}-{scene.dim}d-scene-{family}", seed)
    case_dict = scene_case_dict(declared, scene, extreme_box(label, scene, extreme), dtype)
    case_dict["time"] = {"dt": 1.0}  # a placeholder while Δt is found for the case's own box
    penalty = scene.cpic.penalty if scene.cpic is not None else 0.0
    dt = _extreme_step(extreme, label, Scene.from_dict(case_dict), scales, penalty)
    case_dict["time"] = _time_section(declared.get("time", {}), scene, dt)
    own_dt = dt if scene.time.stepping != "sync" else None
    return ConformanceCase(stage, scene.dim, variant, case_dict, dtype, scales, own_dt, scene.name, extreme=extreme,
                           seed_label=label)


def load_scene(scene):
    """``(declared, parsed)``: the declarations and the :class:`~mpmref.scene.Scene` of ``scene``, a TOML file's path,
    a dict of declarations or a :class:`~mpmref.scene.Scene`. A bad scene raises
    :class:`~mpmref.errors.SceneError`."""
    if isinstance(scene, Scene):
        return copy.deepcopy(scene.source), scene
    if isinstance(scene, dict):
        declared = copy.deepcopy(scene)
        return declared, Scene.from_dict(declared)
    declared = read_scene_file(scene)
    return declared, Scene.from_dict(declared, base_dir=Path(scene).parent)


def scene_cases(scene, stages=None, dtype=None, count=CASES_PER_STAGE, seed=0, extremes=True):
    """The conformance cases of the user's ``scene`` (a TOML file's path, a dict of declarations or a
    :class:`~mpmref.scene.Scene`): :data:`CASES_PER_STAGE` cases of every stage its steps call
    (:func:`scene_stages`), or of ``stages`` (each one of those), in the scene's dtype or ``dtype``.

    Each case's :attr:`~.case.ConformanceCase.source` is the scene's name: a case applies to a backend that implements
    the whole scene (:meth:`~mpmref.backends.capabilities.Implements.missing`). The draws are seeded by each case's
    stage and number and the base ``seed`` (:func:`~.case.seeded_label`), never by the scene's name. ``extremes`` adds,
    after each stage's drawn cases, one case at each extreme family the stage holds (:func:`scene_families`).
    """
    declared, parsed = load_scene(scene)
    called = scene_stages(parsed)
    if stages is not None:
        foreign = [s for s in stages if s not in called]
        if foreign:
            raise ValueError(f"stages {foreign}: scene {parsed.name!r} does not call them; its steps call "
                             f"{', '.join(called)}")
    scales = scene_scales(parsed)
    dtype = dtype or parsed.dtype.name
    seed = base_seed(seed)
    cases = []
    for stage in called if stages is None else [s for s in called if s in stages]:
        cases += [_scene_case(stage, k, declared, parsed, scales, dtype, seed) for k in range(1, count + 1)]
        if extremes:
            cases += [_scene_extreme_case(stage, family, declared, parsed, scales, dtype, seed)
                      for family in scene_families(stage, parsed, dtype)]
    return cases


def scene_record(scene):
    """What ``export --scene`` writes of the user's scene in the manifest: its name, its declarations, what they resolve
    to (:func:`.vectors.resolved`: every default filled in), the scales the states are drawn at, the stages checked and
    the box sizes (JSON-ready)."""
    from .vectors import resolved

    declared, parsed = load_scene(scene)
    return {"name": parsed.name, "declared": declared, "resolved": resolved(parsed, declared["materials"]),
            "scales": asdict(scene_scales(parsed)),
            "stages": scene_stages(parsed), "cases_per_stage": CASES_PER_STAGE,
            "cells_per_axis": [max(SCENE_CELLS[0], 2 * (parsed.boundary.width + 1)),
                               max(SCENE_CELLS[0], 2 * (parsed.boundary.width + 1)) + SCENE_CELLS[1]],
            "dx": parsed.grid.dx}
