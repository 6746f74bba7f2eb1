r"""The states ``mpmref conformance search`` draws (hypothesis strategies), biased toward the extremes of
:mod:`~mpmref.conformance.extremes`, and shrinking toward the simplest: fewer particles, fewer cells, the first rung
of a ladder, round numbers.

A state is drawn for one *template*, a case of the catalogue or of the user's scene, whose scene (method, materials,
walls, colliders, gravity) it keeps; it draws its own box (fewer cells than the template's, the same cell size and
origin), its particles or node states, and its Δt (:func:`search_cases`). Each draw is tagged with the region it comes
from ("F near-symmetric", "x on a face", "Δt at the stability limit"), which the search counts.

The states keep the harness's promises, so that a correct code agrees on every one of them: a particle's weights are
either zero or at least ``MIN_WEIGHT`` where the kernel's gradient does not vanish with its weight (the linear hat),
and all at least that for PolyPIC; in a step, a node that a particle reads through a gradient at zero weight has mass;
the deformation rungs are those where the reference is well-conditioned (:func:`.extremes.well_conditioned`).
"""

import math

import numpy as np
from hypothesis import assume
from hypothesis import strategies as st

from ..physics.kernels import compute_stencil
from ..physics.polypic import higher_modes
from ..run.stability import stable_cfl
from ..scene import Scene
from .case import GivenCase, completed
from .extremes import (
    COLLAPSE_VOLUMES,
    NEAR_SYMMETRIC,
    NEAR_SYMMETRIC_M,
    REST_VOLUME_OFFSETS,
    YIELD_STATES,
    collapse_gradients,
    edge_gap,
    exactly_at,
    rest_gradients,
    well_conditioned,
)
from .states import JP_RANGE, MIN_WEIGHT, catalogue_scales, draw_time, step_at

#: most particles a searched state has
MAX_PARTICLES = 6
#: grid coordinates' fractions a particle is drawn at besides any: on a node line, half-way, a quarter
SPECIAL_FRACTIONS = (0.0, 0.5, 0.25)
#: CFL numbers a searched Δt is drawn at besides the stability limit
SEARCH_CFL = (0.3, 1e-2, 1e-4)


def _unit():
    return st.floats(-1.0, 1.0, allow_nan=False)


def rotation(dim, angles):
    """A rotation: by ``angles[0]`` in 2D; in 3D about z, then y, then x by the three angles."""
    def about(axis, t):
        R = np.eye(3)
        i, j = [a for a in range(3) if a != axis]
        R[i, i] = R[j, j] = math.cos(t)
        R[i, j], R[j, i] = -math.sin(t), math.sin(t)
        return R

    if dim == 2:
        return about(2, angles[0])[:2, :2]
    return about(0, angles[2]) @ about(1, angles[1]) @ about(2, angles[0])


@st.composite
def gradients(draw, material, dim, return_map):
    """``(F, region)`` of a particle of ``material``: a rung of the rest or the collapse ladder (those where the
    reference's stress is well-conditioned for the material, :func:`ladders`), :math:`R(I + bM)` near symmetric, a drawn
    :math:`I + sG`, and for a return map a rung of the material's yield-surface ladder."""
    rungs = ladders(material, dim, return_map)
    kind = draw(st.sampled_from([*rungs, "near-symmetric", "drawn"]))
    if kind == "near-symmetric":
        b = draw(st.sampled_from(NEAR_SYMMETRIC))
        angles = draw(st.lists(st.floats(-math.pi, math.pi), min_size=3, max_size=3))
        return (rotation(dim, angles) @ (np.eye(dim) + b * NEAR_SYMMETRIC_M[:dim, :dim]),
                f"F near-symmetric (|S₀₁| = {b:.0e})")
    if kind == "drawn":
        s = draw(st.sampled_from((1e-3, 1e-2, 0.1)))
        G = np.array(draw(st.lists(_unit(), min_size=dim * dim, max_size=dim * dim))).reshape(dim, dim)
        return np.eye(dim) + s * G, "F drawn"
    F, note = draw(st.sampled_from(rungs[kind]))
    return F, f"F {kind} ({note})"


def ladders(material, dim, return_map):
    """``{kind: [(F, note)]}``: the rungs of the yield-surface (for a return map, where the material has one), rest and
    collapse ladders of :mod:`~mpmref.conformance.extremes` at which ``material``'s stress is well-conditioned
    (:func:`.extremes.well_conditioned`); a ladder with no such rung is left out."""
    rng = np.random.default_rng(dim)
    out = {"rest": rest_gradients(rng, dim), "collapse": collapse_gradients(rng, dim)}
    family = YIELD_STATES.get(type(material)) if return_map else None
    if family is not None:
        out = {"yield-surface": [(F, note) for F, _, note in family(material, rng, dim)], **out}

    def stress(G):
        with np.errstate(all="ignore"):
            return material.kirchhoff_stress(*((G, np.ones(len(G))) if material.plastic else (G,)))

    floor = stress(np.array([1.1 * np.eye(dim)]))
    kept = {}
    for kind, ladder in out.items():
        F = np.array([rung for rung, _ in ladder])
        ok = well_conditioned(stress, F, np.broadcast_to(floor, F.shape))
        kept[kind] = [rung for rung, good in zip(ladder, ok) if good]
    return {kind: rungs for kind, rungs in kept.items() if rungs}


def volumes():
    """``(J, region)``: rest and collapse rungs of the fluid, or a drawn :math:`J \\in [0.5, 1.5]`."""
    rungs = [1.0] + [1.0 + s * e for e in REST_VOLUME_OFFSETS for s in (1.0, -1.0)] + list(COLLAPSE_VOLUMES)
    return st.one_of(st.sampled_from(rungs).map(lambda j: (j, f"J rung (J = {j:g})")),
                     st.floats(0.5, 1.5).map(lambda j: (j, "J drawn")))


@st.composite
def coordinate(draw, kernel, cells, gap):
    """``(xi, region)``: a grid coordinate a kernel allows on an axis of ``cells`` cells: a whole cell plus a special
    fraction or any, or the lowest or highest allowed (moved in by ``gap``)."""
    low, high = kernel.low_margin + gap, cells - kernel.high_margin - gap
    kind = draw(st.sampled_from(("line", "any", "lower edge", "upper edge")))
    if kind == "lower edge":
        return low, "x at the lower edge"
    if kind == "upper edge":
        return ("below", high), "x at the upper edge"
    cell = draw(st.integers(0, cells - 1))
    fraction = draw(st.sampled_from(SPECIAL_FRACTIONS)) if kind == "line" else draw(
        st.floats(0.0, 1.0, exclude_max=True))
    xi = cell + fraction
    assume(low <= xi < high)
    return xi, f"x on a line (fraction {fraction:g})" if kind == "line" else "x drawn"


def _placed(xi, grid, dtype):
    """Positions (float64 representable in ``dtype``) of grid coordinates ``xi`` (``("below", t)``: the largest below
    ``t``), exactly as the reference computes them (:func:`.extremes.exactly_at`)."""
    return np.array([exactly_at(t[1], grid.origin[a], grid.dx, dtype, below=True) if isinstance(t, tuple)
                     else exactly_at(t, grid.origin[a], grid.dx, dtype) for a, t in enumerate(xi)])


def well_posed_positions(scene, x, stage):
    """Whether the positions ``x`` keep the harness's promises (module docstring): PolyPIC's weights all at least
    ``MIN_WEIGHT``; for a kernel whose gradient does not vanish with its weight, no weight between zero and
    ``MIN_WEIGHT``, and in a step no such zero weight on a node without mass."""
    grid, kernel = scene.grid, scene.kernel
    stencil = compute_stencil(kernel, x, grid.origin, grid.dx)
    if scene.transfer.polypic:
        return bool(stencil.w.min() >= MIN_WEIGHT)
    if not edge_gap(kernel):
        return True
    if np.any((stencil.w > 0) & (stencil.w < MIN_WEIGHT)):
        return False
    if stage not in ("step", "ledger"):
        return True
    nodes = np.stack([(stencil.base + o) @ grid.strides for o in stencil.offsets], axis=1)
    weights = stencil.node_weights().T
    massive = np.zeros(grid.n_nodes, dtype=bool)
    massive[nodes[weights > 0]] = True
    return bool(massive[nodes].all())


@st.composite
def particle_state(draw, scene, stage, dtype, scales):
    """``(flat, notes)``: 1 to :data:`MAX_PARTICLES` particles of ``scene`` at rest-of-the-catalogue masses, each its
    material, position, velocity, affine matrix, deformation, volume ratios and modes drawn, and its regions noted."""
    grid, dim = scene.grid, scene.dim
    n = draw(st.integers(1, MAX_PARTICLES))
    gap = edge_gap(scene.kernel)
    flat = {k: [] for k in ("x", "v", "mass", "vol0", "material", "C", "F", "J", "Jp", "modes")}
    notes = []
    for _ in range(n):
        index = draw(st.integers(0, len(scene.material_list) - 1))
        material = scene.material_list[index]
        placed = [draw(coordinate(scene.kernel, grid.cells[a], gap)) for a in range(dim)]
        flat["x"].append(_placed([xi for xi, _ in placed], grid, dtype))
        flat["v"].append(scales.speed * np.array(draw(st.lists(_unit(), min_size=dim, max_size=dim))))
        flat["C"].append(scales.affine * np.array(draw(st.lists(_unit(), min_size=dim * dim, max_size=dim * dim)))
                         .reshape(dim, dim))
        F, J, Jp, region = np.eye(dim), 1.0, 1.0, ""
        if material.tracks == "F":
            F, region = draw(gradients(material, dim, stage == "return_map"))
        else:
            J, region = draw(volumes())
        if material.plastic:
            Jp = draw(st.one_of(st.sampled_from(sorted({1.0, getattr(material, "Jp_min", 1.0)})),
                                st.floats(*JP_RANGE)))
        flat["material"].append(index)
        flat["F"].append(F)
        flat["J"].append(J)
        flat["Jp"].append(Jp)
        vol0 = grid.dx**dim / 2**dim
        flat["vol0"].append(vol0)
        flat["mass"].append(material.rho * vol0)
        notes.append("; ".join(dict.fromkeys([region] + [r for _, r in placed])))  # each region once
    out = _allocated(scene, {k: np.array(v) for k, v in flat.items() if v}, n, scales)
    assume(well_posed_positions(scene, out["x"], stage))
    return out, notes


def _allocated(scene, flat, n, scales):
    """``flat`` with only the fields ``scene`` allocates (:func:`~.states.random_particles`), PolyPIC modes at zero."""
    out = {k: flat[k] for k in ("x", "v", "mass", "vol0")}
    out["material"] = flat["material"].astype(np.int32)
    if scene.transfer.affine:
        out["C"] = flat["C"]
    for key in ("F", "J", "Jp"):
        if scene.tracks(key):
            out[key] = flat[key]
    if scene.transfer.polypic:
        out["modes"] = np.zeros((n, len(higher_modes(scene.dim, scene.kernel.support)), scene.dim))
    return out


@st.composite
def grid_state(draw, scene, scales):
    """``(flat, None)``: node states of ``scene``: each node empty, nearly empty (1e-12 of a cell's mass) or with a
    drawn mass, and a drawn velocity and force per unit mass."""
    n_nodes, dim = scene.grid.n_nodes, scene.dim
    cell_mass = scales.density * scene.grid.dx**dim
    masses = draw(st.lists(st.one_of(st.just(0.0), st.just(1e-12), st.floats(0.2, 1.5)), min_size=n_nodes,
                           max_size=n_nodes))
    mass = cell_mass * np.array(masses)
    velocity = scales.speed * np.array(draw(st.lists(_unit(), min_size=n_nodes * dim, max_size=n_nodes * dim)))
    force = scales.force_per_speed * scales.speed * np.array(
        draw(st.lists(_unit(), min_size=n_nodes * dim, max_size=n_nodes * dim)))
    return {"grid_mass": mass, "grid_momentum": mass[:, None] * velocity.reshape(n_nodes, dim),
            "grid_force": mass[:, None] * force.reshape(n_nodes, dim)}, None


def box_dict(template, cells):
    """The template's scene with its box cut to ``cells`` per axis (same origin and cell size), its one body inside."""
    declared = dict(template.scene_dict)
    grid = declared["grid"]
    size = (np.asarray(cells) * grid["dx"]).tolist()
    declared["grid"] = {"origin": list(grid["origin"]), "size": size, "dx": grid["dx"]}
    origin = np.asarray(grid["origin"])
    body = dict(declared["bodies"][0])
    body.update(lower=(origin + 0.25 * np.asarray(size)).tolist(), upper=(origin + 0.75 * np.asarray(size)).tolist())
    declared["bodies"] = [body]
    return declared


@st.composite
def searched_case(draw, template):
    """``(case, regions)``: a :class:`~.case.GivenCase` of ``template``'s stage and scene (its box from the smallest the
    walls allow to the template's own, per axis; a state; Δt the template's, at the scheme's stability limit, or at a
    CFL number of :data:`SEARCH_CFL`; the template's time; named ``<stage>-<d>d-search-<template variant>``), and the
    regions its draws came from (one per particle and quantity, and the Δt's)."""
    scene = template.scene()
    smallest = max(4, 2 * (scene.boundary.width + 1))
    cells = [draw(st.integers(min(smallest, c), c)) for c in scene.grid.cells]
    declared = box_dict(template, cells)
    boxed = Scene.from_dict(declared)
    scales = template.scales or catalogue_scales(boxed)
    kind = draw(st.sampled_from(("template", "limit", "cfl")))
    dt = template.step_dt(scene)
    if kind == "limit":
        dt = step_at(boxed, stable_cfl(boxed.method.scheme), scales.speed)
    elif kind == "cfl":
        cfl = draw(st.sampled_from(SEARCH_CFL))
        dt = step_at(boxed, cfl, scales.speed)
    if boxed.time.stepping == "sync":
        declared["time"] = {"dt": dt}
    state = grid_state(boxed, scales) if template.stage == "grid_update" else particle_state(
        boxed, template.stage, template.dtype, scales)
    flat, notes = draw(state)
    given = completed(template.stage, boxed, flat, dt, draw_time(template.seed, scales.time), template.dtype)
    region = {"template": "Δt drawn", "limit": "Δt at the stability limit", "cfl": "Δt at a set CFL number"}[kind]
    regions = [region] + ([part.split(" (")[0] for note in notes for part in note.split("; ")] if notes else
                          ["node states"])
    case = GivenCase(template.stage, template.dim, f"search-{template.variant}", declared, template.dtype,
                     template.scales, None if template.dt is None else dt, template.source, given=given,
                     given_notes=None if notes is None else tuple(notes))
    return case, regions
