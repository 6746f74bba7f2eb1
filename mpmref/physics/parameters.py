"""Material parameters declared once, on the material: each is a dataclass field carrying its default and range.

A material class lists its parameters as fields made by :func:`parameter`: the field's default is the
default a scene gets (no default: the scene must give it), and its metadata holds the allowed range. The scene
validator (:func:`mpmref.scene.materials.parse_materials`) derives the keys a ``[materials.NAME]`` table
accepts, their defaults and their bounds from :func:`declared`, so adding a material, or a parameter to one,
touches only the material's class (and each backend's kernel table; docs/materials.md, "Adding a material").
"""

from dataclasses import MISSING, dataclass, field, fields


@dataclass(frozen=True)
class Bounds:
    """The allowed range of a parameter: ``lo`` and ``hi`` (``None``: unbounded), each closed unless ``*_open``."""

    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False


@dataclass(frozen=True)
class Parameter:
    """A declared material parameter: its name, its scene default (``None``: required) and its :class:`Bounds`."""

    name: str
    default: float | None
    bounds: Bounds


def parameter(default=MISSING, lo=None, hi=None, lo_open=False, hi_open=False):
    """A material parameter: a keyword-only dataclass field with ``default`` (none: required) and its range.

    Keyword-only, so that a material may declare a required parameter after a base class's parameters
    with defaults (the density comes first, and is checked first, in every material).
    """
    return field(default=default, kw_only=True, metadata={"bounds": Bounds(lo, hi, lo_open, hi_open)})


def declared(material_class):
    """The :class:`Parameter` of each field of ``material_class`` made by :func:`parameter`, in declaration
    order (base classes first)."""
    return [Parameter(f.name, None if f.default is MISSING else f.default, f.metadata["bounds"])
            for f in fields(material_class) if "bounds" in f.metadata]
