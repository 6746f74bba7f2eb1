"""Each case on what the backend implements: its scenes fitted to the backend's declaration, the rest not applicable.

A backend declares what it implements (:class:`mpmref.backends.capabilities.Implements`; everything when it declares
nothing) and may decline a scene by probing (its factory raises :class:`NotImplementedError`). A case builds every
scene it runs through :func:`fit` (or a :class:`Triage`), saying with an :class:`Allow` what its claim lets change:

* ``materials="substitute"``: a hyperelastic material the backend lacks becomes one it has, of the same density and
  P-wave speed (so the same CFL step), with the parameters the backend fixes. A claim that holds for any hyperelastic
  material (momentum conserved, no energy gain beyond the integrator's, a stability limit in CFL numbers) keeps its
  meaning, and every bound that depends on the material is computed from the scene, so from the substitute.
  ``materials="subset"``: only the bodies of the materials the backend has (a claim made material by material).
* ``walls="open"``: open walls the backend lacks become frictionless walls of a type it has, on a domain padded on
  their side by the band of nodes they act on. Nothing reaches that band: its nodes hold no mass, so no particle
  reads them, and the run is the open one. ``walls="static"``: that, and an acting wall the backend lacks becomes a
  static wall it has (for a claim that holds for every static wall: no energy gain, stability, agreement with the
  reference).
* ``friction``: Coulomb friction the backend lacks is dropped. ``kernel`` and ``dtype``: another kernel or precision
  the backend has, for a claim whose bounds the case computes from the scene's kernel and machine epsilon.

The scheme and the force are never changed: a claim about a scheme is checked on that scheme or not at all. What the
fit cannot give the backend is *not applicable*, with the reasons of
:meth:`~mpmref.backends.capabilities.Implements.missing` or of the backend's own refusal: a :class:`NotApplicable`
item of the case's result (``result["not_applicable"]``), never a failure, never an error. The changes of a fitted
scene are sentences (:class:`Adaptation`, ``result["adapted"]``) that the reports print. A backend that implements a
scene gets that scene unchanged, so a full backend runs every case exactly as the case declares it. A case none of
whose runs applies raises :class:`NothingApplicable` with its items; :func:`require` does so for a case that runs
only on backends implementing every scene it declares as declared.
"""

import copy
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from mpmref import Scene
from mpmref.backends import implements, make_backend
from mpmref.backends.capabilities import material_type
from mpmref.errors import NotImplementedByBackend, SceneError
from mpmref.physics.catalogue import MATERIALS
from mpmref.physics.materials import evolved_fields
from mpmref.physics.parameters import declared

#: the materials a substitution exchanges: hyperelastic, their stored energy a function of F (of J for the fluid)
HYPERELASTIC = ("fixed_corotated", "neo_hookean", "fluid")
SOLIDS = ("fixed_corotated", "neo_hookean")
#: the kernel chosen when the scene's is lacking, first that the backend has
KERNEL_ORDER = ("quadratic", "cubic", "linear")
#: the static wall chosen for an acting wall the backend lacks, first that it has
STATIC_WALLS = ("slip", "separate", "sticky")
#: Poisson's ratio of a solid standing in for a fluid (its Young's modulus then gives the fluid's P-wave speed)
SOLID_NU = 0.3
AXES = "xyz"


@dataclass(frozen=True)
class Allow:
    """What a case's claim lets :func:`fit` change in a scene (module docstring): ``materials`` ``""``,
    ``"substitute"`` or ``"subset"``; ``walls`` ``""``, ``"open"`` or ``"static"``; ``friction``, ``kernel`` and
    ``dtype`` switches."""

    materials: str = ""
    walls: str = ""
    friction: bool = False
    kernel: bool = False
    dtype: bool = False

    def __post_init__(self):
        if self.materials not in ("", "substitute", "subset"):
            raise ValueError(f"Allow.materials = {self.materials!r}: allowed '', 'substitute', 'subset'")
        if self.walls not in ("", "open", "static"):
            raise ValueError(f"Allow.walls = {self.walls!r}: allowed '', 'open', 'static'")


@dataclass(frozen=True)
class NotApplicable:
    """A check, or a run and the checks it carries, that the backend cannot do: its ``name`` and the ``reasons``
    (what the backend lacks, in words)."""

    name: str
    reasons: tuple

    @property
    def why(self):
        return "; ".join(self.reasons)


@dataclass(frozen=True)
class Adaptation:
    """The runs ``names`` of a case ran on a scene fitted to the backend: ``changes``, each a sentence."""

    names: tuple
    changes: tuple


@dataclass(frozen=True)
class Fitted:
    """A scene the backend implements, and what :func:`fit` changed to get it (sentences; none: as declared)."""

    scene: Scene
    changes: tuple = ()


class Inapplicable(Exception):
    """:func:`fit` found no scene the backend implements within what the claim allows; ``reasons`` say why."""

    def __init__(self, reasons):
        super().__init__(tuple(reasons))
        self.reasons = tuple(reasons)

    def __str__(self):
        return "; ".join(self.reasons)


class NothingApplicable(Exception):
    """No run of the case applies to the backend: the case is *not applicable*; ``items`` are its
    :class:`NotApplicable` items (picklable: the one argument is the tuple of items)."""

    def __init__(self, items):
        super().__init__(tuple(items))
        self.items = tuple(items)

    def __str__(self):
        return "; ".join(f"{i.name}: {i.why}" for i in self.items)


# ------------------------------------------------------------------------------------------------------ fitting
def fit(scene, backend, allow=Allow()):
    """The scene closest to ``scene`` that ``backend`` implements, within what ``allow`` lets change.

    Parameters
    ----------
    scene : Scene or dict
        The case's scene, or its declaration (the TOML structure; relative paths resolve from the current folder).
    backend : str, callable or backend object
        A backend reference (:mod:`mpmref.backends`).
    allow : Allow

    Returns
    -------
    Fitted
        ``scene`` itself when the backend implements it; else the fitted scene and its changes.

    Raises
    ------
    Inapplicable
        With the reasons the backend gives for the closest scene the claim allows.
    """
    scene = scene if isinstance(scene, Scene) else Scene.from_dict(scene)
    declaration = declaration_of(backend)
    reasons = declaration.missing(scene)
    if not reasons:
        _refuse_if_declined(backend, scene)
        return Fitted(scene)
    data, changes = copy.deepcopy(scene.source), []
    for step in (_materials, _walls, _friction, _kernel, _dtype):
        changes += step(data, scene, declaration, allow)
    if not changes:
        raise Inapplicable(reasons)
    try:
        fitted = Scene.from_dict(data, base_dir=scene.base_dir)
    except SceneError as exc:  # e.g. a kernel whose stencil does not fit the bodies: the original reasons stand
        raise Inapplicable([*reasons, f"(a fitted scene is invalid: {exc})"]) from None
    left = declaration.missing(fitted)
    if left:
        raise Inapplicable(left)
    _refuse_if_declined(backend, fitted)
    return Fitted(fitted, tuple(changes))


def declaration_of(backend):
    """What ``backend`` declares it implements (:func:`mpmref.backends.implements`: a factory function that declares
    nothing is asked through an object it makes for a small probe scene)."""
    return _declaration(backend) if isinstance(backend, str) else implements(backend)


@lru_cache(maxsize=None)
def _declaration(reference):
    return implements(reference)


def _refuse_if_declined(backend, scene):
    """:class:`Inapplicable` with the backend's own reasons if making it for ``scene`` refuses the scene (its
    factory declined it, or it lacks a stage only such scenes need)."""
    try:
        make_backend(backend, scene)
    except NotImplementedByBackend as exc:
        raise Inapplicable(exc.reasons) from None


# ---------------------------------------------------------------------------------------------------- materials
def _materials(data, scene, declaration, allow):
    """Substitute (or leave out) the materials the backend lacks, and give the ones it has the parameters it fixes."""
    if not allow.materials:
        return []
    changes = []
    lacking = [name for name, m in scene.materials.items() if not _implemented(m, declaration)]
    if allow.materials == "subset" and lacking:
        kept = [name for name in scene.materials if name not in lacking]
        if not kept:
            return []
        data["materials"] = {name: data["materials"][name] for name in kept}
        data["bodies"] = [b for b in data["bodies"] if b["material"] in kept]
        data["emitters"] = [e for e in data.get("emitters", []) if e["material"] in kept]
        changes.append(f"the bodies of {', '.join(_kinds(scene, lacking))} left out (the backend implements "
                       f"{', '.join(declaration.materials)}): the claim is made material by material")
    for name in data["materials"]:
        material = scene.materials[name]
        if name in lacking:  # another type, or this type with the parameters the backend fixes
            substitute = _substitute(material, declaration)
            if substitute is None:
                continue
            data["materials"][name] = substitute
            changes.append(f"material '{name}' ({_describe(material)}) replaced by {_describe_spec(substitute)}, "
                           "of the same density and P-wave speed where the backend fixes neither")
        else:
            fixed = _with_fixed(data["materials"][name], material_type(material), declaration)
            if fixed != data["materials"][name]:
                data["materials"][name] = fixed
                changes.append(f"material '{name}' given the parameters the backend fixes ({_describe_spec(fixed)})")
    return changes


def _implemented(material, declaration):
    """Whether the backend has ``material``'s type with the parameters it fixes and evolves its fields."""
    kind = material_type(material)
    fixed = declaration.parameters.get(kind, {})
    return (kind in declaration.materials and all(getattr(material, k) == v for k, v in fixed.items())
            and set(evolved_fields(material)) <= set(declaration.evolves))


def _kinds(scene, names):
    return [f"'{n}' ({material_type(scene.materials[n])})" for n in names]


def _substitute(material, declaration):
    """The declaration (a ``[materials.NAME]`` table) of a hyperelastic material the backend has, of ``material``'s
    density and P-wave speed (:func:`_stand_in`), or ``None`` when none fits."""
    kind = material_type(material)
    if kind not in HYPERELASTIC:
        return None
    order = SOLIDS + ("fluid",) if kind in SOLIDS else ("fluid",) + SOLIDS
    for candidate in order:
        if candidate not in declaration.materials:
            continue
        spec = _with_fixed(_stand_in(material, candidate, declaration.parameters.get(candidate, {})), candidate,
                           declaration)
        if set(evolved_fields(MATERIALS[candidate](**_parameters(spec)))) <= set(declaration.evolves):
            return spec
    return None


def _stand_in(material, kind, fixed):
    r"""A ``kind`` material with ``material``'s density :math:`\rho` and P-wave speed :math:`c`, given the parameters
    ``fixed`` that the backend fixes for ``kind``.

    A solid for a solid keeps :math:`E, \nu`. A fluid takes :math:`K = \rho c^2/\gamma` (its sound speed is
    :math:`\sqrt{\gamma K/\rho}`, :class:`~mpmref.physics.materials.WeaklyCompressibleFluid`) with the fixed
    :math:`\gamma` or its default; a solid for a fluid takes the fixed :math:`\nu` or :data:`SOLID_NU` and
    :math:`E = \rho c^2 (1+\nu)(1-2\nu)/(1-\nu)` (:math:`\lambda + 2\mu = \rho c^2`). A fixed stiffness (``K``,
    ``E``) then replaces the one computed, and the wave speed is the backend's.
    """
    rho, c = material.rho, material.wave_speed()
    if kind == "fluid":
        gamma = fixed.get("gamma", _default("fluid", "gamma"))
        return {"type": kind, "K": rho * c**2 / gamma, "gamma": gamma, "rho": rho}
    if material_type(material) in SOLIDS:
        return {"type": kind, "E": material.E, "nu": material.nu, "rho": rho}
    nu = fixed.get("nu", SOLID_NU)
    return {"type": kind, "E": rho * c**2 * (1 + nu) * (1 - 2 * nu) / (1 - nu), "nu": nu, "rho": rho}


def _default(kind, name):
    return next(p.default for p in declared(MATERIALS[kind]) if p.name == name)


def _with_fixed(spec, kind, declaration):
    """``spec`` with the parameters the backend fixes for ``kind``."""
    return {**spec, **declaration.parameters.get(kind, {})}


def _parameters(spec):
    return {k: v for k, v in spec.items() if k != "type"}


def _describe(material):
    return _describe_spec({"type": material_type(material), **{p.name: getattr(material, p.name)
                                                               for p in declared(type(material))}})


def _describe_spec(spec):
    return f"{spec['type']} ({', '.join(f'{k} = {v:.4g}' for k, v in _parameters(spec).items())})"


# -------------------------------------------------------------------------------------------------------- walls
def _walls(data, scene, declaration, allow):
    """Replace the walls the backend lacks: open ones by unreached walls on a padded domain, acting ones by a static
    wall it has (``allow.walls == "static"``)."""
    if not allow.walls:
        return []
    boundary, walls = scene.boundary, scene.boundary.walls
    lacking = {name: w for name, w in walls.items() if w.type not in declaration.walls}
    if not lacking:
        return []
    unreached = _first(declaration.walls, ("open", *STATIC_WALLS))
    static = _first(declaration.walls, STATIC_WALLS)
    changes, new, pad = [], {}, {}
    for name, wall in walls.items():
        if name not in lacking:
            new[name] = {"type": wall.type, "friction": wall.friction}
        elif wall.type == "open" and unreached is not None:
            new[name] = {"type": unreached, "friction": 0.0}
            pad[name] = boundary.width
        elif wall.type != "open" and allow.walls == "static" and static is not None:
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
        changes.append(f"{kinds} walls ({', '.join(acting)}) replaced by static {static} walls, which the claim "
                       "allows (a static wall's projection does no positive work)")
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
    if walls:
        for wall in walls.values():
            wall["friction"] = 0.0
    data.setdefault("boundary", {})["friction"] = 0.0
    for collider in data.get("colliders", []):
        collider["friction"] = 0.0
    return [f"Coulomb friction dropped (μ = {max(frictions):g} → 0): the backend has none, and the claim does not "
            "need it"]


# --------------------------------------------------------------------------------------------- kernel and dtype
def _kernel(data, scene, declaration, allow):
    kernel = scene.method.kernel
    if not allow.kernel or kernel in declaration.kernels:
        return []
    other = _first(declaration.kernels, KERNEL_ORDER)
    data.setdefault("method", {})["kernel"] = other
    return [f"the {kernel} kernel replaced by the {other} kernel; the bounds are computed from the kernel run"]


def _dtype(data, scene, declaration, allow):
    dtype = scene.dtype.name
    if not allow.dtype or dtype in declaration.dtypes:
        return []
    data["dtype"] = declaration.dtypes[0]
    return [f"{dtype} replaced by {declaration.dtypes[0]}; the round-off bounds use its machine epsilon"]


# ------------------------------------------------------------------------------------------------------ triage
class Triage:
    """Sorts a case's runs into those that run (on a fitted scene) and those not applicable, and keeps what it
    changed; ``record()`` gives the two lists for the case's result.

    Parameters
    ----------
    backend : str, callable or backend object
        The backend the case runs.
    """

    def __init__(self, backend):
        self.backend = backend
        self.not_applicable = []
        self._adapted = {}
        self._lacking = {}

    def fit(self, run, scene, allow=Allow()):
        """The scene of ``run`` fitted to the backend (:func:`fit`; its changes kept), or ``None`` when it is not
        applicable (its reasons kept for :meth:`reasons`, not listed: for a run that checks need, listed by
        :meth:`skip` under each check's name)."""
        try:
            fitted = fit(scene, self.backend, allow)
        except Inapplicable as exc:
            self._lacking[run] = exc.reasons
            return None
        if fitted.changes:
            self._adapted.setdefault(fitted.changes, []).append(run)
        return fitted.scene

    def scene(self, name, scene, allow=Allow(), run=None):
        """:meth:`fit`, listing ``name`` (the run and the checks it carries) with its reasons when it is not
        applicable. ``run`` names the run among the adapted ones (default ``name``)."""
        fitted = self.fit(run or name, scene, allow)
        if fitted is None:
            self.skip(name, self.reasons(run or name))
        return fitted

    def skip(self, name, reasons):
        """List ``name`` (a check that needs runs that are not applicable) with ``reasons``."""
        self.not_applicable.append(NotApplicable(name, tuple(dict.fromkeys(reasons))))

    def reasons(self, run):
        """The reasons run ``run`` was found not applicable (empty if it runs)."""
        return self._lacking.get(run, ())

    def record(self):
        """``{"not_applicable": [...], "adapted": [...]}`` for the case's result."""
        return {"not_applicable": list(self.not_applicable),
                "adapted": [Adaptation(tuple(names), changes) for changes, names in self._adapted.items()]}

    def nothing_ran(self):
        """:class:`NothingApplicable` with every item: raise it when no run of the case applies."""
        return NothingApplicable(self.not_applicable)


def require(backend, scenes, allow=Allow()):
    """Raise :class:`NothingApplicable` unless ``backend`` implements every scene of ``scenes`` (``[(name, scene)]``)
    within ``allow``: for a case whose claims need all of them."""
    triage = Triage(backend)
    for name, scene in scenes:
        triage.scene(name, scene, allow)
    if triage.not_applicable:
        raise triage.nothing_ran()

