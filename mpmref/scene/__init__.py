"""Scenes: what a user declares, as a TOML file or through ``SceneBuilder``, validated before any work.

Every problem is reported as a :class:`~mpmref.errors.SceneError` naming the field (dotted path), the
value given and the allowed range. See ``docs/scenes.md`` for every field and its default.

The package, bottom up: :mod:`~mpmref.scene.validation` (the checks: numbers, integers, choices, vectors,
flags, tables), :mod:`~mpmref.scene.specs` (the validated sections: :class:`MethodSpec`, :class:`CpicSpec`,
...), the parsers of the sections (:mod:`~mpmref.scene.parsers` for grid, method, boundary, time and output;
:mod:`~mpmref.scene.materials`, derived from the materials' own declarations; :mod:`~mpmref.scene.bodies` for
bodies, emitters and colliders; :mod:`~mpmref.scene.rigid_bodies` for the CPIC rigid bodies, 2D and 3D), and
:mod:`~mpmref.scene.builder` (:class:`Scene`, which runs them all, and :class:`SceneBuilder`).
"""

from .bodies import COLLIDER_SHAPES, SAMPLINGS, SHAPES
from .builder import DTYPES, TOP_KEYS, Scene, SceneBuilder
from .materials import MATERIAL_TYPES
from .parsers import (
                      AXES,
                      COUPLINGS,
                      CPIC_FITS,
                      CPIC_SCHEMES,
                      DOMAIN_EXIT_POLICIES,
                      FORCES,
                      GRID_REGIONS,
                      INTERFACES,
                      OUTPUT_FIELDS,
                      SCHEMES,
                      STEPPINGS,
                      WALL_TYPES,
)
from .specs import BodySpec, BoundarySpec, CpicSpec, EmitterSpec, MethodSpec, OutputSpec, TimeSpec, WallSpec

__all__ = [
    "Scene", "SceneBuilder", "MethodSpec", "CpicSpec", "WallSpec", "BoundarySpec", "TimeSpec", "OutputSpec",
    "BodySpec", "EmitterSpec", "SCHEMES", "FORCES", "WALL_TYPES", "DOMAIN_EXIT_POLICIES", "DTYPES", "SHAPES",
    "SAMPLINGS", "OUTPUT_FIELDS", "GRID_REGIONS", "AXES", "STEPPINGS", "TOP_KEYS", "COUPLINGS", "CPIC_SCHEMES",
    "CPIC_FITS", "COLLIDER_SHAPES", "MATERIAL_TYPES", "INTERFACES",
]
