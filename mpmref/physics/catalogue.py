"""Every material of the toolkit by its scene name (the ``type`` of a ``[materials.NAME]`` table)."""

from .materials import FixedCorotated, NeoHookean, WeaklyCompressibleFluid
from .plasticity import DruckerPragerSand, SnowPlasticity

MATERIALS = {
    "fixed_corotated": FixedCorotated,
    "neo_hookean": NeoHookean,
    "fluid": WeaklyCompressibleFluid,
    "snow": SnowPlasticity,
    "sand": DruckerPragerSand,
}
