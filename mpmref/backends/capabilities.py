"""What a backend implements: its declaration, and what a scene needs that a backend does not have.

Real MPM codes implement a part of what mpmref does: one scheme, one kernel, the materials they need (sometimes with
parameters fixed in the code), the walls they need, ``J`` without ``F``. A backend says what it implements with an
attribute ``implements``, an :class:`Implements`, on its class, on the object or on its factory function::

    from mpmref.backends.capabilities import Implements

    class Mpm88Backend:
        implements = Implements(dims=(2,), schemes=("mls",), forces=("mls",), kernels=("quadratic",),
                                materials=("fluid",), walls=("separate", "open"), friction=False, colliders=(),
                                evolves=("C", "J"), stepping=("sync",), rigid_bodies=False)

Every field defaults to everything mpmref has, so a backend without the attribute (or with ``Implements()``) claims
all of it. :meth:`Implements.missing` says, in words, what a scene needs that the backend lacks ("needs the cubic
kernel", "compares F: this backend evolves C, J only"); the conformance harness and ``mpmref verify`` run every check
on exactly what a backend implements and list the others as *not applicable* with those reasons, and
:func:`mpmref.backends.make_backend` refuses such a scene before any work (docs/checking_your_code.md, "Codes that
implement a part").

A backend may also find out for itself: a factory that raises :class:`NotImplementedError` for a scene declines it,
and its message is the reason given (:func:`declined`).
"""

from dataclasses import dataclass, field, fields
from types import MappingProxyType

from ..physics.boundary import BOUNDARY_TYPES
from ..physics.catalogue import MATERIALS
from ..physics.kernels import KERNELS
from ..physics.materials import evolved_fields
from ..physics.scheme import TRANSFER_OF

#: every value of each axis a backend may declare
SCHEMES = ("pic", "flip", "apic", "polypic", "mls")
FORCES = ("mls", "classic")
WALL_TYPES = BOUNDARY_TYPES + ("open",)
#: collider shapes as a scene names them (``disk`` in 2D, ``sphere`` in 3D: one shape, a ball)
COLLIDER_SHAPES = ("plane", "box", "ball", "cylinder")
DTYPES = ("float64", "float32")
#: the particle fields besides ``x`` and ``v`` that a scene may evolve: the affine matrix, PolyPIC's modes, the
#: deformation gradient, the volume ratio and the plastic volume ratio
EVOLVED = ("C", "modes", "F", "J", "Jp")
STEPPINGS = ("sync", "async")
STEPPING_WORDS = {"sync": "synchronous", "async": "asynchronous"}
#: the axes of a scene that :meth:`Implements.missing` examines, in the order of its reasons: dimension and dtype;
#: scheme, force and kernel (and the affine matrix or modes they carry); materials, their fixed parameters and
#: deformation fields; walls and colliders; time stepping and rigid bodies
PARTS = ("dims", "method", "materials", "boundary", "stepping")

_CHOICES = {"schemes": SCHEMES, "forces": FORCES, "kernels": tuple(KERNELS), "materials": tuple(MATERIALS),
            "walls": WALL_TYPES, "colliders": COLLIDER_SHAPES, "dtypes": DTYPES, "evolves": EVOLVED,
            "stepping": STEPPINGS, "dims": (2, 3)}


@dataclass(frozen=True)
class Implements:
    """The declaration of what a backend implements (each field defaults to everything mpmref has).

    Attributes
    ----------
    dims : tuple of int           dimensions, 2 and/or 3
    schemes : tuple of str        schemes: ``pic``, ``flip``, ``apic``, ``polypic``, ``mls`` (MLS-MPM is the APIC
                                  transfer with the MLS force, so ``mls`` and ``apic`` name one transfer; the force
                                  is declared in ``forces``)
    forces : tuple of str         force discretisations (and velocity gradients of the F/J update): ``mls``, ``classic``
    kernels : tuple of str        ``linear``, ``quadratic``, ``cubic``
    materials : tuple of str      material types: ``fixed_corotated``, ``neo_hookean``, ``fluid``, ``snow``, ``sand``
    parameters : mapping          material parameters the code fixes, ``{type: {name: value}}`` (e.g. a fluid with
                                  ``gamma = 1`` built in); a scene with other values is not applicable, and the
                                  built-in cases use these values
    walls : tuple of str          wall types: ``sticky``, ``slip``, ``separate``, ``open``
    friction : bool               Coulomb friction on ``separate`` walls and colliders (talk Eq. 25)
    colliders : tuple of str      level-set collider shapes: ``plane``, ``box``, ``ball`` (disk/sphere), ``cylinder``
    moving_colliders : bool       colliders with a velocity
    dtypes : tuple of str         ``float64``, ``float32``
    evolves : tuple of str        the particle fields the code evolves besides ``x`` and ``v``: ``C``, ``modes``,
                                  ``F``, ``J``, ``Jp``; the others are neither needed nor compared
    stepping : tuple of str       ``sync`` and/or ``async`` (asynchronous, regional steps)
    rigid_bodies : bool           CPIC coupling to rigid bodies
    """

    dims: tuple = (2, 3)
    schemes: tuple = SCHEMES
    forces: tuple = FORCES
    kernels: tuple = _CHOICES["kernels"]
    materials: tuple = _CHOICES["materials"]
    parameters: dict = field(default_factory=dict)
    walls: tuple = WALL_TYPES
    friction: bool = True
    colliders: tuple = COLLIDER_SHAPES
    moving_colliders: bool = True
    dtypes: tuple = DTYPES
    evolves: tuple = EVOLVED
    stepping: tuple = STEPPINGS
    rigid_bodies: bool = True

    def __post_init__(self):
        for name, allowed in _CHOICES.items():
            value = getattr(self, name)
            if isinstance(value, (str, int)):
                value = (value,)
            value = tuple(value)
            unknown = [v for v in value if v not in allowed]
            if unknown:
                raise ValueError(f"Implements.{name}: unknown {unknown}; allowed {list(allowed)}")
            object.__setattr__(self, name, value)
        unknown = sorted(set(self.parameters) - set(self.materials))
        if unknown:
            raise ValueError(f"Implements.parameters: {unknown} not among the declared materials "
                             f"{list(self.materials)}")
        frozen = {k: MappingProxyType(dict(v)) for k, v in self.parameters.items()}
        object.__setattr__(self, "parameters", MappingProxyType(frozen))

    # ------------------------------------------------------------------------------------------ scenes
    def missing(self, scene, parts=PARTS):
        """What ``scene`` needs that this backend does not implement, in words (``[]``: it implements the scene).

        Each reason reads "needs ..." (a dimension, dtype, scheme, force, kernel, material or parameter value, wall,
        friction, collider, asynchronous stepping or rigid bodies) or "compares F: this backend evolves C, J only".
        ``parts`` (a subset of :data:`PARTS`) limits the question to some axes of the scene: what one stage depends on
        (the conformance harness asks a stress case about ``("dims", "materials", "stepping")`` only; the walls of
        its scene are not the stress's business).
        """
        unknown = sorted(set(parts) - set(PARTS))
        if unknown:
            raise ValueError(f"unknown parts {unknown}: the parts are {list(PARTS)}")
        reasons = []
        for part in PARTS:
            if part in parts:
                reasons += getattr(self, f"_{part}_reasons")(scene)
        return reasons

    def implements(self, scene):
        """Whether this backend implements everything ``scene`` needs."""
        return not self.missing(scene)

    def _needs(self, axis, value, what):
        return [] if value in getattr(self, axis) else [f"needs {what}"]

    def _dims_reasons(self, scene):
        return self._needs("dims", scene.dim, f"{scene.dim}D") + self._needs("dtypes", scene.dtype.name,
                                                                              scene.dtype.name)

    def _method_reasons(self, scene):
        """The scheme, the force and velocity gradient, the kernel, and the affine matrix or PolyPIC modes the
        transfer carries."""
        method, reasons = scene.method, []
        if TRANSFER_OF[method.scheme] not in {TRANSFER_OF[s] for s in self.schemes}:  # "mls" is APIC + MLS force
            reasons.append(f"needs the {method.scheme} scheme")
        for force in dict.fromkeys((method.force, method.velocity_gradient)):
            reasons += self._needs("forces", force, f"the {force} force")
        reasons += self._needs("kernels", method.kernel, f"the {method.kernel} kernel")
        carried = [name for name, flag in (("C", scene.transfer.affine), ("modes", scene.transfer.polypic)) if flag]
        return reasons + self._evolved_reasons(carried)

    def _materials_reasons(self, scene):
        """The material types, the parameter values this backend fixes, and the deformation fields they carry."""
        reasons = [r for material in scene.material_list for r in self._type_reasons(material)]
        carried = dict.fromkeys(field for m in scene.material_list for field in evolved_fields(m))
        return list(dict.fromkeys(reasons)) + self._evolved_reasons(carried)

    def material_reasons(self, material):
        """What one material object needs that this backend lacks, in words (its type, a parameter value it fixes
        otherwise, the fields it evolves)."""
        return self._type_reasons(material) + self._evolved_reasons(evolved_fields(material))

    def _type_reasons(self, material):
        kind = material_type(material)
        if kind not in self.materials:
            return [f"needs the material {kind}"]
        return [f"needs {kind} {parameter} = {getattr(material, parameter):g} (this backend fixes {parameter} = "
                f"{fixed:g})" for parameter, fixed in self.parameters.get(kind, {}).items()
                if getattr(material, parameter) != fixed]

    def _evolved_reasons(self, needed):
        lacking = [f for f in needed if f not in self.evolves]
        own = ", ".join(self.evolves) if self.evolves else "x and v"
        return [f"compares {', '.join(lacking)}: this backend evolves {own} only"] if lacking else []

    def _boundary_reasons(self, scene):
        reasons = []
        walls = scene.boundary.walls.values()
        for kind in dict.fromkeys(w.type for w in walls):
            reasons += self._needs("walls", kind, f"{kind} walls")
        frictions = [w.friction for w in walls if w.type == "separate"]
        frictions += [c.friction for c in scene.colliders if c.type == "separate"]
        if not self.friction and any(mu > 0.0 for mu in frictions):
            reasons.append("needs friction (Coulomb, talk Eq. 25)")
        for kind in dict.fromkeys(collider_shape(c) for c in scene.colliders):
            reasons += self._needs("colliders", kind, f"a {kind} collider")
        for kind in dict.fromkeys(c.type for c in scene.colliders):
            reasons += self._needs("walls", kind, f"{kind} colliders")
        if not self.moving_colliders and any(bool(abs(c.velocity).max() > 0.0) for c in scene.colliders):
            reasons.append("needs a moving collider")
        return reasons

    def _stepping_reasons(self, scene):
        reasons = self._needs("stepping", scene.time.stepping, f"{STEPPING_WORDS[scene.time.stepping]} time stepping")
        if scene.rigid_bodies and not self.rigid_bodies:
            reasons.append("needs rigid bodies (CPIC coupling)")
        return reasons

    # --------------------------------------------------------------------------------------- reporting
    def describe(self):
        """The declaration as a JSON-ready dict (for reports and manifests)."""
        out = {f.name: getattr(self, f.name) for f in fields(self)}
        out["parameters"] = {k: dict(v) for k, v in self.parameters.items()}
        return {k: list(v) if isinstance(v, tuple) else v for k, v in out.items()}

    def summary(self):
        """One line: what differs from everything mpmref has (``"everything"`` for a full backend)."""
        full = Implements()
        parts = []
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name == "parameters":
                parts += [f"{kind} {', '.join(f'{k} = {v:g}' for k, v in fixed.items())}"
                          for kind, fixed in value.items()]
            elif value != getattr(full, f.name):
                parts.append(f"{f.name}: {_words(value)}")
        return "; ".join(parts) if parts else "everything"


def _words(value):
    if isinstance(value, bool):
        return "yes" if value else "no"
    return ", ".join(str(v) for v in value) if value else "none"


def material_type(material):
    """The scene name of a material object (``fluid``, ``snow``, ...)."""
    return next(name for name, cls in MATERIALS.items() if type(material) is cls)


def collider_shape(collider):
    """The shape of a collider as :data:`COLLIDER_SHAPES` names it (a disk or a sphere is a ``ball``)."""
    return type(collider.shape).__name__.lower()


#: what a backend that declares nothing implements: everything
EVERYTHING = Implements()


def declared(obj):
    """The :class:`Implements` that ``obj`` (a backend object, class or factory, or the object a backend reference
    resolves to) declares as its ``implements`` attribute, or :data:`EVERYTHING` if it declares none. A declaration
    of another type is a :class:`TypeError` naming what was found."""
    found = getattr(obj, "implements", None)
    if found is None:
        return EVERYTHING
    if not isinstance(found, Implements):
        raise TypeError(f"{getattr(obj, '__qualname__', type(obj).__name__)}.implements is a "
                        f"{type(found).__name__}; declare an mpmref.backends.capabilities.Implements")
    return found


def probe_scenes():
    """Small synchronous scenes that a factory declaring nothing is tried on to find its objects' declaration
    (:func:`probed`): an elastic and a fluid block, in 2D and 3D."""
    from ..scene import SceneBuilder

    return [(SceneBuilder(dim=dim, name="declaration_probe").grid(size=1.0, cells=8).material("m", **spec)
             .box("m", lower=[0.25] * dim, upper=[0.75] * dim).time(dt=1e-3).build())
            for dim in (2, 3) for spec in ({"type": "fixed_corotated", "E": 1e3, "nu": 0.3},
                                           {"type": "fluid", "K": 1e3})]


def probed(found, scenes):
    """What the backend ``found`` (a resolved backend reference) implements, where its declaration is on the objects
    it makes: :func:`declared` of ``found`` if it declares, else, for a factory function (not a class, which declares
    on itself), :func:`declared` of the first object it makes for one of ``scenes`` (a factory that raises for a scene
    is tried on the next); :data:`EVERYTHING` if none is made.

    A factory ``def factory(scene): return MyBackend(scene)`` need not repeat its class's declaration: the checks
    find it this way before they choose their cases (docs/checking_your_code.md, "Codes that implement a part").
    """
    found_declares = getattr(found, "implements", None) is not None
    if found_declares or isinstance(found, type) or not callable(found) or callable(getattr(found, "p2g", None)):
        return declared(found)
    for scene in scenes:
        try:
            made = found(scene)
        except Exception:  # a factory that cannot make this scene's backend: try the next scene
            continue
        return declared(made)
    return EVERYTHING


def declined(exc):
    """The reason of a factory that declined a scene by raising :class:`NotImplementedError` (its message)."""
    return str(exc) or "the backend's factory raised NotImplementedError for this scene"
