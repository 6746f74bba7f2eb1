"""Export the conformance cases as language-neutral test vectors: one ``.npz`` per case plus ``manifest.json``.

Each ``.npz`` (uncompressed, no pickled objects) holds flat named arrays: the stage's inputs prefixed ``in_``
and the reference's outputs prefixed ``out_`` (names of :mod:`mpmref.conformance.stages`; scalars as 0-d
arrays). ``manifest.json`` describes every case: its file, stage, dtype, tolerance, array shapes, the scene as
declared and as resolved (defaults filled in, Lamé parameters, wall table, PolyPIC mode order), and the
conventions below. It is written last, so a folder with a manifest is complete. See ``docs/conformance.md``.
"""

import json
from dataclasses import asdict
from pathlib import Path

import numpy as np

from ..io.atomic import atomic_path, write_text_atomic
from ..physics.materials import evolved_fields
from ..physics.polypic import higher_modes
from .cases import make_cases

FORMAT = "mpmref-conformance"
#: 2: per-axis cells, dt and time per case, in_tau, materials' "evolves"; 3: the ledger stage; 4: the stages of
#: asynchronous stepping, Δt and time of the CPIC cases per case, in_tau of p2g_fused, grid velocities compared on nodes
#: with mass only, cases drawn from a scene (``scene``, each case's ``source`` and ``scales``); 5: the cases at the
#: extremes (each case's ``extreme``, the multi-step cases' ``in_steps``), the error judged per particle too
FORMAT_VERSION = 5
MANIFEST = "manifest.json"
CONVENTIONS = {
    "nodes": "grid arrays have one row per node in C order: node (i_0, ..., i_{d-1}), 0 <= i_a <= cells_a, "
             "is row sum_a i_a * stride_a with stride_a = prod_{b > a} (cells_b + 1); it sits at origin + i * dx",
    "particles": "particle arrays have one row per particle, in the same order in inputs and outputs",
    "material": "in_material is an index into resolved.materials",
    "evolves": "resolved.materials[k].evolves lists the deformation fields (F, J, Jp) that material k's particles "
               "carry; out_F, out_J and out_Jp are compared only on the rows of particles whose material evolves them "
               "(a fluid's F, a solid's J mean nothing); x, v, C and modes on every row",
    "dt": "dt and time of a case are also in the manifest entry (dt: the scene's time.dt, or the case's own where the "
          "scene steps asynchronously); they vary from case to case (dt over nearly four decades of CFL number), so a "
          "stage that ignores its dt argument fails",
    "tau": "in_tau of a p2g, p2g_fused or p2g_classes case is the reference's Kirchhoff stress of the input particles: "
           "a P2G that takes the stress as an input can use it instead of computing it (outputs are the same)",
    "massless": "out_grid_v and out_grid_v_tilde are compared on the nodes with in_grid_mass > 0 only: G2P weights a "
                "node's velocity by w_ip, and a node without mass has w_ip = 0 for every particle, so no particle "
                "reads it and a code may leave anything there",
    "async": "the stages of asynchronous stepping: wave_speeds (in_idx, the particles asked; out_wave_speed), "
             "p2g_classes (in_classes: 0 active, 1 finer ghost, 2 coarser shadow; out_class_sums (K, N, 1 + 2d): each "
             "class's node mass, momentum and force, and their totals out_grid_*), interface_kicks (in_class_sums, "
             "in_kappa, in_dt; out_kicks (2, N, d): per unit mass, row 0 for the active particles, row 1 for the "
             "coarser shadows) and g2p_kicks (in_classes, in_grid_v, in_grid_v_tilde, in_kicks, in_dt; the particle "
             "fields and out_impulse_P (n, d), out_impulse_L (n, 1) in 2D or (n, 3) in 3D, about the origin); their "
             "scenes step asynchronously and have no time.dt: the case's dt is in_dt and the manifest's dt",
    "modes": "axis 1 of in_modes / out_modes follows resolved.polypic_modes (per-axis polynomial degrees)",
    "error": "max|candidate - reference| / max|reference| over every entry of an output array (denominator 1 "
             "where the reference is all zero), and per row (a particle, a node): max over rows of "
             "max|a_row - r_row| / max(max|r_row|, floor * S), S the output's largest entry or, for v and C, the "
             "larger natural scale of docs/conformance.md ('The error'), floor 0.227 in float64 and 1 in float32; an "
             "output's error is the larger of the two, and a case passes when its largest output error is <= rtol",
    "steps": "a step case with in_steps (a multi-step case at an extreme) runs that many steps from its inputs, step "
             "k at time in_time + k in_dt, and its outputs are the particles after the last",
    "extremes": "a case with an extreme holds states at an extreme by design (docs/conformance.md, 'Extremes'): its "
                "entry's extreme names the family and what it holds",
    "ledger": "a ledger case has the inputs of a step case; its outputs are 0-d float64: out_ledger_<column> the "
              "energy ledger of that step (docs/energy_ledger.md: the terms p2g_transfer, boundary, g2p_transfer, "
              "advection, plastic, rigid_bodies, integration, the flows internal_work and gravity_work, energy_change "
              "and closure) and out_energy_scale, K + Psi + |U| of the input state; a term's error is "
              "|a - r| / out_energy_scale, the scale's own the usual one",
    "scene": "cases drawn from a user's scene (export --scene) have a source (the scene's name) and the scales their "
             "states were drawn at; the manifest's scene holds that scene as declared, its scales and its stages",
    "cpic": "cpic_* cases (2D and 3D): in_tag_A / in_tag_T (n, nb) are the particles' previous tags; in_rigid_* the "
            "bodies' state (position of the reference point, angle, velocity, angular velocity, impulses received), "
            "body r being resolved.rigid_bodies[r] posed as x = position + R(angle) (x0 - center); out_cdf_d is 0 "
            "where out_cdf_body is -1; out_compatible (K, n) follows the transfer stencil's offsets in C order; "
            "booleans are compared as 0/1",
}


def jsonable(value):
    """``value`` with NumPy arrays and scalars turned into lists and Python numbers (recursively)."""
    if isinstance(value, dict):
        return {k: jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, (np.ndarray, np.generic)):
        return value.tolist()
    return value


def _material_entry(name, declared, material):
    lame = {"mu": material.mu, "lam": material.lam} if hasattr(material, "mu") else {}
    return {"name": name, "type": declared["type"], **asdict(material), **lame,
            "evolves": list(evolved_fields(material))}


def _collider_entry(collider):
    """A collider as a flat table: its shape's class name and parameters, type, friction and velocity."""
    return {"shape": type(collider.shape).__name__.lower(), **jsonable(asdict(collider.shape)),
            "type": collider.type, "friction": collider.friction, "velocity": collider.velocity.tolist()}


def resolved_scene(case):
    """What an implementation needs of ``case``'s scene, every default filled in (JSON-serialisable)."""
    return resolved(case.scene(), case.scene_dict["materials"])


def resolved(scene, declared):
    """What an implementation needs of ``scene`` (its materials ``declared`` as the scene file has them), every default
    filled in (JSON-serialisable)."""
    grid, kernel = scene.grid, scene.kernel
    return {
        "grid": {"origin": grid.origin.tolist(), "dx": grid.dx, "cells": list(grid.cells),
                 "node_shape": list(grid.node_shape), "n_nodes": grid.n_nodes},
        "method": asdict(scene.method),
        "cpic": None if scene.cpic is None else asdict(scene.cpic),
        "kernel": {"name": kernel.name, "support": kernel.support, "inertia_factor": kernel.inertia_factor},
        "materials": [_material_entry(name, declared[name], m) for name, m in scene.materials.items()],
        "gravity": scene.gravity.tolist(),
        "boundary": {"width": scene.boundary.width,
                     "walls": {name: asdict(w) for name, w in scene.boundary.walls.items()}},
        "colliders": [_collider_entry(c) for c in scene.colliders],
        "polypic_modes": higher_modes(scene.dim, kernel.support).tolist() if scene.transfer.polypic else None,
        "rigid_bodies": [_rigid_entry(b) for b in scene.rigid_bodies],
    }


def _rigid_entry(body):
    """A rigid body as a flat table: its polyline (``segments``) or triangle mesh (``triangles``) at time 0,
    reference point, motion, mass properties (3D: the inertia tensor, or ``"inf"``), script and encoded friction
    of side 0 and side 1 (see :func:`mpmref.rigid.dynamics.encode_friction`)."""
    cells = {"triangles": body.shape.triangles.tolist()} if hasattr(body.shape, "triangles") else {
        "segments": body.shape.segments.tolist()}
    inertia = np.asarray(body.inertia)
    return {"vertices": body.shape.vertices.tolist(), **cells,
            "closed": body.shape.closed, "motion": body.motion, "center": np.asarray(body.center).tolist(),
            "mass": _jsonable_number(body.mass),
            "inertia": inertia.tolist() if inertia.ndim else _jsonable_number(body.inertia),
            "velocity": np.asarray(body.velocity).tolist(),
            "angular_velocity": np.asarray(body.angular_velocity).tolist(),
            "keyframes": [[t, np.asarray(o).tolist(), np.asarray(a).tolist()] for t, o, a in body.keyframes],
            "gravity": body.gravity, "friction": np.asarray(body.friction).tolist()}


def _jsonable_number(value):
    """``value`` as a float, or the string ``"inf"`` (JSON has no infinity)."""
    return "inf" if np.isinf(value) else float(value)


def write_npz(path, arrays):
    """Write ``arrays`` as an uncompressed ``.npz`` at ``path``, atomically (a temporary name, then a rename)."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)


def write_case(out_dir, case):
    """Write ``case``'s inputs and reference outputs to ``out_dir/<name>.npz``; return its manifest entry."""
    inputs = case.inputs()
    outputs = case.reference(inputs)
    arrays = {**{f"in_{k}": np.asarray(a) for k, a in inputs.items()},
              **{f"out_{k}": np.asarray(a) for k, a in outputs.items()}}
    file = f"{case.name}.npz"
    write_npz(Path(out_dir) / file, arrays)
    steps = {k: float(inputs[k]) for k in ("dt", "time") if k in inputs}
    drawn = {"source": case.source, "scales": asdict(case.scales)} if case.source else {}
    extreme = {"extreme": {"name": case.extreme.name, "holds": case.extreme.holds}} if case.extreme else {}
    return {"name": case.name, "file": file, "stage": case.stage, "dim": case.dim, "dtype": case.dtype,
            "rtol": case.rtol, "seed": case.seed, **steps, **drawn, **extreme,
            "arrays": {k: {"shape": list(a.shape), "dtype": a.dtype.name} for k, a in arrays.items()},
            "scene": case.scene_dict, "resolved": resolved_scene(case)}


def export(out_dir, cases=None, scene=None):
    """Write every case (default: all float64 cases) to ``out_dir`` as ``.npz`` files and ``manifest.json``.

    ``scene`` is the record of the user's scene the cases were drawn from (:func:`.scenes.scene_record`), written
    as the manifest's ``scene``. Every file is written atomically (temporary name, then rename); the manifest comes
    last. Returns the path of the manifest.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    cases = make_cases() if cases is None else list(cases)
    manifest = {"format": FORMAT, "version": FORMAT_VERSION, "conventions": CONVENTIONS,
                **({"scene": jsonable(scene)} if scene is not None else {}),
                "cases": [write_case(out_dir, case) for case in cases]}
    write_text_atomic(out_dir / MANIFEST, json.dumps(manifest, indent=1))
    return out_dir / MANIFEST


def load_vectors(path):
    """Read one exported case: ``(inputs, outputs)``, two flat dicts with the ``in_`` / ``out_`` prefixes removed."""
    with np.load(path, allow_pickle=False) as data:
        inputs = {k[len("in_"):]: data[k] for k in data.files if k.startswith("in_")}
        outputs = {k[len("out_"):]: data[k] for k in data.files if k.startswith("out_")}
    return inputs, outputs
