r"""One mechanism that fits a scene to what a backend implements: every axis chosen from the declaration together.

A backend declares what it implements (:class:`~mpmref.backends.capabilities.Implements`). A check that holds for a
family of scenes (momentum is conserved whatever the material; a stage agrees with the reference whatever the
walls its case has) runs on the scene of that family closest to its own that the backend implements. What the
check lets change is an :class:`Allow`; :func:`fit` finds the scene:

* **dimension** (``dims``): a 2D scene becomes its 3D *slab* (:func:`lifted`): every body sampled as in 2D and
  extruded through :data:`SLAB_CELLS` cells along z, the same particles in every layer, open z faces that nothing
  reaches; disks become cylinders and planes stay planes among the colliders. The 2D motion is a solution of the
  slab's, so a claim that holds in any dimension (conservation, an energy bound, agreement with the reference)
  keeps its meaning.
* **method**: the scheme (``scheme``; a claim that is not about the scheme: a probe, a stage that does not see it),
  the force and velocity gradient (``force``), the kernel (``kernel``): any combination the scene validator accepts
  and the backend implements, the fewest changes first.
* **materials**: as declared; the same law with the parameters the backend fixes (for any claim that lets materials
  change), keeping the density and the rest P-wave speed; a hyperelastic material of another type
  (``"substitute"``) or any material the backend has (``"any"``), of the same density and rest P-wave speed (each
  material class makes its own parameters for a wave speed: ``with_wave_speed``); or the bodies of the materials the
  backend has (``"subset"``, a claim made material by material).
* **walls** (``"open"``: open walls become unreached walls of the backend's on a domain padded by their band;
  ``"static"``: and an acting wall becomes a static one the backend has), **friction** (dropped), **dtype**.

The search is joint: the dimension and the method are enumerated (the scene's own first, then the fewest
changes), the other axes are fitted to each, and the first scene that validates and that the backend implements
wins, so that no axis is chosen in a way that another then cannot accept (APIC keeps no linear hat). What no
combination gives is :class:`Inapplicable`, with the backend's reasons. A declaration that mpmref cannot model
at all (APIC with only the linear hat) is named by :func:`unmodelable`.

The verification cases (:mod:`verification.framework.applicable`) and the conformance catalogue
(:mod:`mpmref.conformance.cases`) both fit through this module.
"""

import copy
from dataclasses import dataclass
from functools import cache
from itertools import product

import numpy as np

from ..errors import SceneError
from ..physics.catalogue import MATERIALS
from ..physics.kernels import KERNELS
from ..physics.materials import evolved_fields
from ..physics.parameters import declared
from ..physics.scheme import TRANSFER_OF
from .capabilities import FORCES, SCHEMES, material_type

#: the kernel chosen when the scene's is lacking, first that the backend has
KERNEL_ORDER = ("quadratic", "cubic", "linear")
#: the static wall chosen for an acting wall the backend lacks, first that it has
STATIC_WALLS = ("slip", "separate", "sticky")
#: depth, in cells, of the slab a 2D scene is extruded through (:func:`lifted`)
SLAB_CELLS = 2
#: cells beyond the band on each side of the slab, enough for the widest stencil (cubic) to stay off it
SLAB_MARGIN = 3
AXES = "xyz"
MATERIAL_MODES = ("", "substitute", "any", "subset")
#: the kernels whose weights have a continuous gradient (:class:`Allow` ``kernel``): the linear hat's jumps at the
#: nodes make the force a discontinuous function of position, which the energy arguments of symplectic Euler do not
#: cover (a particle crossing a node feels a jump: the cell-crossing error)
SMOOTH_KERNELS = ("quadratic", "cubic")
WALL_MODES = ("", "open", "static", "any")


@dataclass(frozen=True)
class Allow:
    """What a check's claim lets :func:`fit` change in a scene (module docstring).

    Attributes
    ----------
    materials : str    ``""`` (as declared), ``"substitute"``, ``"any"`` or ``"subset"``; any but ``""`` also gives
                       a material the parameters the backend fixes
    walls : str        ``""``, ``"open"``, ``"static"`` or ``"any"`` (an acting wall may become any wall the backend
                       has, open ones too: a probe, which only has to run)
    friction : bool    drop Coulomb friction the backend lacks
    kernel : bool or tuple
                       another kernel the backend has (``True``), or one of these (a claim that holds for the
                       smooth B-splines only: :data:`SMOOTH_KERNELS`)
    force : bool       another force and velocity gradient
    scheme : bool      another scheme (a claim not about the scheme)
    dtype : bool       another precision
    dims : bool        the 3D slab of a 2D scene
    """

    materials: str = ""
    walls: str = ""
    friction: bool = False
    kernel: bool | tuple = False
    force: bool = False
    scheme: bool = False
    dtype: bool = False
    dims: bool = False

    def __post_init__(self):
        if self.materials not in MATERIAL_MODES:
            raise ValueError(f"Allow.materials = {self.materials!r}: allowed {', '.join(map(repr, MATERIAL_MODES))}")
        if self.walls not in WALL_MODES:
            raise ValueError(f"Allow.walls = {self.walls!r}: allowed {', '.join(map(repr, WALL_MODES))}")


#: everything a probe may change: a scene only has to make the backend's stages run
ANYTHING = Allow(materials="any", walls="any", friction=True, kernel=True, force=True, scheme=True, dtype=True,
                 dims=True)


@dataclass(frozen=True)
class Fitted:
    """A scene the backend implements, and what :func:`fit` changed to get it (sentences; none: as declared)."""

    scene: object
    changes: tuple = ()


class Inapplicable(Exception):
    """:func:`fit` found no scene the backend implements within what the claim allows; ``reasons`` say why."""

    def __init__(self, reasons):
        super().__init__(tuple(reasons))
        self.reasons = tuple(reasons)

    def __str__(self):
        return "; ".join(self.reasons)


# ---------------------------------------------------------------------------------------------------- fitting
def fit(scene, declaration, allow=Allow(), accept=None):
    """The scene closest to ``scene`` that ``declaration`` implements, within what ``allow`` lets change.

    Parameters
    ----------
    scene : Scene
    declaration : Implements
    allow : Allow
    accept : callable or None
        ``accept(scene)`` raises :class:`Inapplicable` for a scene the backend itself refuses (its factory
        declines it); the search then goes on to the next candidate.

    Returns
    -------
    Fitted
        ``scene`` itself when the backend implements it; else the fitted scene and its changes.

    Raises
    ------
    Inapplicable
        With the backend's reasons for ``scene`` (and what the closest candidate lacked).
    """
    from ..scene import Scene

    reasons = declaration.missing(scene)
    if not reasons:
        if accept is not None:
            accept(scene)
        return Fitted(scene)
    notes, closest = [], None
    for data, changes in _candidates(scene, declaration, allow, notes):
        try:
            fitted = Scene.from_dict(data, base_dir=scene.base_dir)
        except SceneError as exc:
            notes.append(f"(a fitted scene is invalid: {exc})")
            continue
        lacking = declaration.missing(fitted)
        closest = lacking if closest is None else closest
        if lacking:
            continue
        try:
            if accept is not None:
                accept(fitted)
        except Inapplicable as exc:
            notes += exc.reasons
            continue
        return Fitted(fitted, tuple(changes))
    raise Inapplicable(list(dict.fromkeys([*(closest or reasons), *notes[:1]])))


def _candidates(scene, declaration, allow, notes):
    """``(data, changes)`` of each candidate scene, the fewest changes of dimension and method first; the other axes
    fitted to each (:data:`_GREEDY`). Nothing when an axis has no option: its reasons stand."""
    from ..scene import Scene

    for dims_data, dims_changes in _dims_options(scene, declaration, allow, notes):
        base = scene if not dims_changes else Scene.from_dict(dims_data, base_dir=scene.base_dir)
        for method, method_changes in _method_options(base, declaration, allow):
            data = copy.deepcopy(dims_data)
            if method is not None:
                data["method"] = method
            changes = [*dims_changes, *method_changes]
            for step in _GREEDY:
                changes += step(data, base, declaration, allow)
            yield data, changes


# -------------------------------------------------------------------------------------------------- dimension
def _dims_options(scene, declaration, allow, notes):
    """The scene's own dimension, then (``allow.dims``, a 2D scene, a backend without 2D but with 3D) its slab."""
    if scene.dim in declaration.dims or not allow.dims or scene.dim != 2 or 3 not in declaration.dims:
        return [(copy.deepcopy(scene.source), [])]
    try:
        return [(lifted(scene), [f"the 2D scene extruded through a slab of {SLAB_CELLS} cells in z (3D): the claim "
                                 "holds in any dimension, and the 2D motion is a motion of the slab"])]
    except Inapplicable as exc:
        notes += exc.reasons
        return []


def lifted(scene):
    """The declaration (dict) of the 3D slab of the 2D ``scene``: each body sampled as in 2D and repeated in
    :data:`SLAB_CELLS` × (its particles per cell per axis) layers through a slab of :data:`SLAB_CELLS` cells centred
    on z = 0, with the 2D velocity field (``angular_velocity`` ω about z; a ``velocity_gradient`` padded with zeros);
    the grid grown in z by the band and :data:`SLAB_MARGIN` cells on each side, open z faces; gravity, colliders
    (planes with normals in the xy-plane, a disk as a cylinder along z, a box through the whole depth) as in 2D.

    Raises :class:`Inapplicable` for what has no slab: emitters, rigid bodies.
    """
    from ..scene.sampling import sample_body

    if scene.emitters or scene.rigid_bodies:
        raise Inapplicable([f"needs 2D: a scene with {'emitters' if scene.emitters else 'rigid bodies'} has no 3D "
                            "slab"])
    data, grid, width = copy.deepcopy(scene.source), scene.grid, scene.boundary.width
    depth_cells = SLAB_CELLS + 2 * (width + SLAB_MARGIN)
    data["dim"] = 3
    data["grid"] = {"origin": [*grid.origin.tolist(), -0.5 * depth_cells * grid.dx],
                    "size": [*(np.array(grid.cells) * grid.dx).tolist(), depth_cells * grid.dx], "dx": grid.dx,
                    **({"block": data["grid"]["block"]} if "block" in data.get("grid", {}) else {})}
    data["bodies"] = [_slab_body(b, sample_body(spec, 2, grid.dx, scene.base_dir), grid.dx)
                      for b, spec in zip(data["bodies"], scene.bodies)]
    if "gravity" in data:
        data["gravity"] = [*scene.gravity.tolist(), 0.0]
    data["colliders"] = [_slab_collider(c, depth_cells * grid.dx) for c in data.get("colliders", [])]
    walls = {name: {"type": w.type, "friction": w.friction} for name, w in scene.boundary.walls.items()}
    data["boundary"] = {**{k: v for k, v in data.get("boundary", {}).items() if k == "domain_exit"},
                        "width": width, "walls": {**walls, "z_min": {"type": "open"}, "z_max": {"type": "open"}}}
    return data


def _slab_body(body, sampled, dx):
    """A 2D body (its declaration and its sampled ``(points, volume)``) as a points body of the slab."""
    points, volume = sampled
    layers_per_cell = max(1, round(np.sqrt(body.get("ppc", 4))))
    spacing = dx / layers_per_cell
    z = (np.arange(SLAB_CELLS * layers_per_cell) + 0.5) * spacing - 0.5 * SLAB_CELLS * dx
    positions = np.concatenate([np.column_stack([points, np.full(len(points), zk)]) for zk in z])
    center = body.get("rotation_center", points.mean(axis=0).tolist())
    out = {"shape": "points", "material": body["material"], "positions": positions,
           "particle_volume": float(volume) * spacing, "velocity": [*body.get("velocity", [0.0, 0.0]), 0.0],
           "angular_velocity": [0.0, 0.0, float(body.get("angular_velocity", 0.0))],
           "rotation_center": [*center, 0.0]}
    if "velocity_gradient" in body:
        out["velocity_gradient"] = np.pad(np.asarray(body["velocity_gradient"], dtype=float), (0, 1)).tolist()
    return out


def _slab_collider(collider, depth):
    """A 2D collider of the slab: a plane with its normal in the xy-plane, a disk as a cylinder along z, a box
    through the slab's whole depth (and beyond)."""
    out = {k: v for k, v in collider.items() if k in ("type", "friction")}
    if "velocity" in collider:
        out["velocity"] = [*collider["velocity"], 0.0]
    shape = collider["shape"]
    if shape == "plane":
        return {**out, "shape": "plane", "point": [*collider["point"], 0.0], "normal": [*collider["normal"], 0.0]}
    if shape == "disk":
        return {**out, "shape": "cylinder", "point": [*collider["center"], 0.0], "axis": [0.0, 0.0, 1.0],
                "radius": collider["radius"]}
    return {**out, "shape": "box", "lower": [*collider["lower"], -depth], "upper": [*collider["upper"], depth]}


# ----------------------------------------------------------------------------------------------------- method
def _method_options(scene, declaration, allow):
    """``(method, changes)`` of each method the fit may give ``scene``: ``(None, [])`` (as declared) first, then each
    valid method the backend implements that ``allow`` permits, the fewest changed parts first (scheme, then force
    and gradient, then kernel, :data:`KERNEL_ORDER`)."""
    own = _method_key(scene.method)
    options = [(None, [])]
    for method in ranked_methods(own, [m for m in implemented_methods(declaration) if _allowed(own, m, allow)]):
        declared_method = {k: v for k, v in scene.source.get("method", {}).items() if k not in _METHOD_PARTS}
        if method[0] != "flip":
            declared_method.pop("flip_alpha", None)
        options.append(({**declared_method, **_method_dict(method)},
                        [f"the method {_label(own)} replaced by {_label(method)}, which the claim allows"]))
    return options


_METHOD_PARTS = ("scheme", "force", "velocity_gradient", "kernel")


def ranked_methods(own, methods):
    """``methods`` other than ``own`` (``(scheme, force, velocity_gradient, kernel)`` each), the fewest changed
    parts first, ties by the kernel's order (:data:`KERNEL_ORDER`), then the scheme's (:data:`SCHEMES`)."""
    return sorted((m for m in methods if m != own), key=lambda m: (sum(a != b for a, b in zip(own, m)), _rank(m)))


def closest_method(method, methods):
    """The method of ``methods`` closest to the :class:`~mpmref.scene.MethodSpec` ``method`` (itself if there)."""
    own = _method_key(method)
    return own if own in methods else ranked_methods(own, methods)[0]


def _method_key(method):
    """``(scheme, force, velocity_gradient, kernel)`` of a :class:`~mpmref.scene.MethodSpec`."""
    return method.scheme, method.force, method.velocity_gradient, method.kernel


def _method_dict(key):
    scheme, force, gradient, kernel = key
    out = {"scheme": scheme, "force": force, "kernel": kernel}
    return out if gradient == force else {**out, "velocity_gradient": gradient}


def _label(key):
    scheme, force, gradient, kernel = key
    return f"{scheme}-{force}-{kernel}" + ("" if gradient == force else f" (velocity gradient {gradient})")


def _allowed(own, other, allow):
    scheme, force, gradient, kernel = own
    return ((allow.scheme or TRANSFER_OF[other[0]] == TRANSFER_OF[scheme])
            and (allow.force or (other[1], other[2]) == (force, gradient))
            and (other[3] == kernel or allow.kernel is True or other[3] in (allow.kernel or ())))


def _rank(method):
    return KERNEL_ORDER.index(method[3]), SCHEMES.index(method[0]), method[1], method[2]


@cache
def valid_methods():
    """Every ``(scheme, force, velocity_gradient, kernel)`` the scene validator accepts."""
    from ..scene.parsers import parse_method

    out = []
    for scheme, force, gradient, kernel in product(SCHEMES, FORCES, FORCES, KERNELS):
        try:
            parse_method({"scheme": scheme, "force": force, "velocity_gradient": gradient, "kernel": kernel})
        except SceneError:
            continue
        out.append((scheme, force, gradient, kernel))
    return tuple(out)


def implemented_methods(declaration, carried=True):
    """The valid methods (:func:`valid_methods`) that ``declaration`` implements: its transfers, forces and
    kernels, and (``carried``) the affine matrix or PolyPIC modes the transfer carries among the fields it
    evolves."""
    transfers = {TRANSFER_OF[s] for s in declaration.schemes}
    fields = {"apic": {"C"}, "polypic": {"C", "modes"}}
    return tuple(m for m in valid_methods()
                 if TRANSFER_OF[m[0]] in transfers and m[1] in declaration.forces and m[2] in declaration.forces
                 and m[3] in declaration.kernels
                 and (not carried or fields.get(TRANSFER_OF[m[0]], set()) <= set(declaration.evolves)))


def unmodelable(declaration):
    """What of ``declaration`` mpmref cannot model, in words: each declared scheme that the scene validator joins with
    none of the declared kernels and forces, and each declared kernel that it joins with none of the declared schemes
    (``[]`` when each has a valid method: a declaration is a product of axes, not a claim that every combination
    exists). A declaration none of whose methods is valid cannot be checked for P2G, G2P or a step at all."""
    have = implemented_methods(declaration, carried=False)
    kernels, forces = " or ".join(declaration.kernels), " or ".join(declaration.forces)
    out = [f"mpmref cannot model the {scheme} scheme with the {kernels} kernel and the {forces} force "
           f"({_invalid_reason(scheme, declaration.forces[0], declaration.kernels[0])})"
           for scheme in declaration.schemes if not any(m[0] == scheme for m in have) and declaration.kernels
           and declaration.forces]
    schemes = " or ".join(declaration.schemes)
    out += [f"mpmref cannot model the {kernel} kernel with the {schemes} scheme and the {forces} force "
            f"({_invalid_reason(declaration.schemes[0], declaration.forces[0], kernel)})"
            for kernel in declaration.kernels if not any(m[3] == kernel for m in have) and declaration.schemes
            and declaration.forces and any(m[3] != kernel for m in have)]
    return out


def _invalid_reason(scheme, force, kernel):
    """The scene validator's reason for refusing ``scheme`` with ``force`` and ``kernel``."""
    from ..scene.parsers import parse_method

    try:
        parse_method({"scheme": scheme, "force": force, "kernel": kernel})
    except SceneError as exc:
        return str(exc)
    return "no valid combination"


# -------------------------------------------------------------------------------------------------- materials
def implements_material(material, declaration):
    """Whether the backend has ``material``'s type with the parameters it fixes and evolves its fields."""
    kind = material_type(material)
    fixed = declaration.parameters.get(kind, {})
    return (kind in declaration.materials and all(getattr(material, k) == v for k, v in fixed.items())
            and set(evolved_fields(material)) <= set(declaration.evolves))


def _materials(data, scene, declaration, allow):
    """Each material the backend lacks given the parameters the backend fixes, or replaced (:func:`stand_in`), or
    its bodies left out (``"subset"``)."""
    if not allow.materials:
        return []
    changes, kept = [], []
    for name, material in scene.materials.items():
        if implements_material(material, declaration):
            kept.append(name)
            continue
        spec = stand_in(material, declaration, allow.materials)
        if spec is not None:
            data["materials"][name] = spec
            kept.append(name)
            changes.append(_replaced(name, material, spec, declaration))
        elif allow.materials == "subset":
            why = "; ".join(declaration.material_reasons(material))
            changes.append(f"the bodies of '{name}' ({material_type(material)}) left out ({why}): the claim is "
                           "made material by material")
    if not kept:
        return []
    if len(kept) < len(scene.materials):
        data["materials"] = {name: data["materials"][name] for name in kept}
        data["bodies"] = [b for b in data["bodies"] if b["material"] in kept]
        data["emitters"] = [e for e in data.get("emitters", []) if e["material"] in kept]
    return changes


def _replaced(name, material, spec, declaration):
    """The sentence saying how material ``name`` became ``spec``."""
    kind = material_type(material)
    if spec["type"] == kind and all(spec[k] == getattr(material, k) for k in _parameters(spec)
                                    if k not in declaration.parameters.get(kind, {})):
        fixed = ", ".join(f"{k} = {v:g} for {getattr(material, k):g}" for k, v in declaration.parameters[kind].items()
                          if v != getattr(material, k))
        return f"material '{name}' ({kind}) given the parameters the backend fixes: {fixed}"
    return (f"material '{name}' ({describe(material)}) replaced by {describe_spec(spec)}, of the same density and rest "
            "P-wave speed where the backend fixes neither")


def stand_in(material, declaration, mode):
    """The declaration (a ``[materials.NAME]`` table) of the material the backend has that stands in for
    ``material`` under ``mode`` (:class:`Allow`), or ``None``.

    First the same law with the parameters the backend fixes; then (``"substitute"``, for a hyperelastic material)
    another hyperelastic type, solids for solids and the fluid for the fluid first; then (``"any"``) any type the
    backend has. Each keeps :math:`\\rho` and the rest P-wave speed :math:`c` (the same CFL step) through the class's
    own ``with_wave_speed``, unless the backend fixes the stiffness; a law's own parameters are kept where they
    are the same law's.
    """
    kind = material_type(material)
    candidates = [kind]
    if mode in ("substitute", "any") and material.hyperelastic:
        candidates += _family_order(material, declaration, hyperelastic_only=True)
    if mode == "any":
        candidates += _family_order(material, declaration, hyperelastic_only=False)
    for candidate in dict.fromkeys(candidates):
        if candidate not in declaration.materials:
            continue
        spec = _made_for(material, candidate, declaration.parameters.get(candidate, {}))
        if spec is not None and implements_material(MATERIALS[candidate](**_parameters(spec)), declaration):
            return spec
    return None


def _family_order(material, declaration, hyperelastic_only):
    """The backend's material types to try for ``material``: those that track what it tracks (F or J) first."""
    kinds = [k for k in declaration.materials if not hyperelastic_only or MATERIALS[k].hyperelastic]
    return sorted(kinds, key=lambda k: MATERIALS[k].tracks != material.tracks)


def _made_for(material, kind, fixed):
    """A ``kind`` material's declaration with ``material``'s density and rest P-wave speed and the ``fixed``
    parameters; ``material``'s own parameters carried over where ``kind`` is its law."""
    cls = MATERIALS[kind]
    own = {p.name: getattr(material, p.name) for p in declared(type(material))} if type(material) is cls else {}
    same = {**own, **fixed}
    if own and _speed_of(cls, same) == material.wave_speed():
        return {"type": kind, **same}
    stiffness = {"E", "K"} & set(own)
    given = {k: v for k, v in same.items() if k not in stiffness or k in fixed}
    given.pop("rho", None)
    try:
        return {"type": kind, **cls.with_wave_speed(material.rho, material.wave_speed(), given)}
    except (TypeError, ValueError):
        return None


def _speed_of(cls, parameters):
    try:
        return cls(**parameters).wave_speed()
    except (TypeError, ValueError):
        return None


def _parameters(spec):
    return {k: v for k, v in spec.items() if k != "type"}


def describe(material):
    """``type (name = value, ...)`` of a material object."""
    return describe_spec({"type": material_type(material),
                          **{p.name: getattr(material, p.name) for p in declared(type(material))}})


def describe_spec(spec):
    """``type (name = value, ...)`` of a ``[materials.NAME]`` table."""
    return f"{spec['type']} ({', '.join(f'{k} = {v:.4g}' for k, v in _parameters(spec).items())})"


# ------------------------------------------------------------------------------------------------------- walls
def _walls(data, scene, declaration, allow):
    """Replace the walls the backend lacks: open ones by unreached walls on a padded domain, acting ones by a static
    wall it has (``allow.walls == "static"``), or by any wall it has (``"any"``)."""
    if not allow.walls:
        return []
    boundary, walls = scene.boundary, scene.boundary.walls
    lacking = {name: w for name, w in walls.items() if w.type not in declaration.walls}
    if not lacking:
        return []
    unreached = _first(declaration.walls, ("open", *STATIC_WALLS))
    static = _first(declaration.walls, STATIC_WALLS + (("open",) if allow.walls == "any" else ()))
    changes, new, pad = [], {}, {}
    for name, wall in walls.items():
        if name not in lacking:
            new[name] = {"type": wall.type, "friction": wall.friction}
        elif wall.type == "open" and unreached is not None:
            new[name] = {"type": unreached, "friction": 0.0}
            pad[name] = boundary.width
        elif wall.type != "open" and allow.walls in ("static", "any") and static is not None:
            new[name] = {"type": static, "friction": wall.friction}
        else:
            return []
    data["boundary"] = {**{k: v for k, v in data.get("boundary", {}).items() if k in ("width", "domain_exit")},
                        "width": boundary.width, "walls": new}
    if pad:
        data["grid"] = _padded(scene.grid, pad, data.get("grid", {}).get("block"))
        sides = ", ".join(sorted(pad))
        changes.append(f"open walls ({sides}) replaced by frictionless {unreached} walls on a domain padded there by "
                       f"the {boundary.width}-node band they act on, which nothing reaches: the run is the open one")
    acting = sorted(n for n in lacking if n not in pad)
    if acting:
        kinds = ", ".join(dict.fromkeys(lacking[n].type for n in acting))
        why = ("a static wall's projection does no positive work" if static != "open" else
               "the backend has no acting wall, and the claim needs none")
        changes.append(f"{kinds} walls ({', '.join(acting)}) replaced by {static} walls, which the claim allows "
                       f"({why})")
    return changes


def _first(available, order):
    return next((w for w in order if w in available), None)


def _padded(grid, pad, block):
    """The ``[grid]`` of ``grid`` grown by ``pad[wall]`` cells on the side of each wall named (``x_min``, ...),
    with the same cell size and the same node positions."""
    lower = np.array([pad.get(f"{AXES[a]}_min", 0) for a in range(grid.dim)])
    upper = np.array([pad.get(f"{AXES[a]}_max", 0) for a in range(grid.dim)])
    cells = np.array(grid.cells) + lower + upper
    out = {"origin": (grid.origin - lower * grid.dx).tolist(), "size": (cells * grid.dx).tolist(), "dx": grid.dx}
    return out if block is None else {**out, "block": block}


def _friction(data, scene, declaration, allow):
    """Drop Coulomb friction (walls and colliders) that the backend lacks, when the claim allows."""
    walls = data.get("boundary", {}).get("walls") or {}
    frictions = [w.friction for w in scene.boundary.walls.values() if w.type == "separate"]
    frictions += [c.friction for c in scene.colliders if c.type == "separate"]
    if declaration.friction or not allow.friction or not any(mu > 0.0 for mu in frictions):
        return []
    for wall in walls.values():
        wall["friction"] = 0.0
    data.setdefault("boundary", {})["friction"] = 0.0
    for collider in data.get("colliders", []):
        collider["friction"] = 0.0
    return [f"Coulomb friction dropped (μ = {max(frictions):g} → 0): the backend has none, and the claim does not "
            "need it"]


def _dtype(data, scene, declaration, allow):
    dtype = scene.dtype.name
    if not allow.dtype or dtype in declaration.dtypes:
        return []
    data["dtype"] = declaration.dtypes[0]
    return [f"{dtype} replaced by {declaration.dtypes[0]}; the round-off bounds use its machine epsilon"]


#: the axes fitted to each candidate dimension and method, in this order
_GREEDY = (_materials, _walls, _friction, _dtype)
