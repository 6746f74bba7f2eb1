"""The ``[materials.NAME]`` tables, validated against what each material declares.

The keys a material's table accepts, their defaults and their allowed ranges are not written here: they are
the fields each material class declares with :func:`~mpmref.physics.parameters.parameter` (read by
:func:`~mpmref.physics.parameters.declared`), so a new material needs no change in this module.
"""

import math
from dataclasses import asdict

from ..physics.catalogue import MATERIALS as MATERIAL_TYPES
from ..physics.materials import LameParameters
from ..physics.parameters import declared
from .validation import choice, fail, number, section


def parse_materials(mats):
    """The ``[materials]``: ``{name: material object}`` in the order declared (the order gives material ids)."""
    if not isinstance(mats, dict) or not mats:
        fail("materials", mats, "a table with at least one named material, e.g. [materials.jelly]")
    out = {}
    for name, spec in mats.items():
        out[name] = parse_material(spec, f"materials.{name}")
    return out


def parse_material(spec, path):
    """One material table: its ``type`` and the parameters that type declares, each within its declared range
    (a missing one takes its declared default; one declared without a default is required)."""
    if not isinstance(spec, dict):
        fail(path, spec, "a table")
    kind = MATERIAL_TYPES[choice(spec, "type", path, tuple(MATERIAL_TYPES), required=True)]
    parameters = declared(kind)
    section(spec, path, {"type", *(p.name for p in parameters)})
    material = kind(**{p.name: number(spec, p.name, path, default=p.default, required=p.default is None,
                                      **asdict(p.bounds)) for p in parameters})
    if isinstance(material, LameParameters) and not (math.isfinite(material.mu) and math.isfinite(material.lam)):
        fail(f"{path}.nu", material.nu, "a value for which the Lamé parameters are finite")
    return material
