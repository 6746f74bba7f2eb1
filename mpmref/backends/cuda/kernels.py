"""Every kernel a scene's steps launch on the GPU, made for the scene's configuration.

A configuration (:class:`Config`) is what the kernels are specialised for at compile time: dtype, dimension, kernel,
the scheme's features (affine matrix, PolyPIC modes, FLIP), the force and the velocity gradient, the tracked
deformation, the material laws present and whether there are colliders. Each kernel factory is cached per
configuration, so scenes that share one share the compiled kernels. Grid geometry, walls, collider shapes, material
parameters and the time step are arguments: one compiled kernel serves every grid and every parameter value.
"""

from typing import NamedTuple

from ..pointwise.laws import laws_of
from .g2p import g2p_kernel
from .grid_update import grid_update_kernel
from .p2g import p2g_kernels
from .particles import particle_kernels
from .sort import sort_kernels


class Config(NamedTuple):
    """A scene's kernel configuration (the compile-time constants of its kernels)."""

    dtype: str
    dim: int
    kernel: str
    affine: bool
    poly: bool
    flip: bool
    mls_force: bool
    mls_gradient: bool
    tracks_F: bool
    tracks_J: bool
    laws: tuple
    colliders: bool

    @classmethod
    def of(cls, scene):
        """The configuration of ``scene``."""
        t = scene.transfer
        return cls(dtype=scene.dtype.name, dim=scene.dim, kernel=t.kernel, affine=t.affine, poly=t.polypic,
                   flip=t.flip, mls_force=t.mls_force, mls_gradient=t.mls_gradient, tracks_F=t.tracks_F,
                   tracks_J=t.tracks_J, laws=laws_of(scene.material_list)[0], colliders=bool(scene.colliders))


class Kernels:
    """The kernels of one configuration: the sort, P2G (plain and fused), the grid update (after either), G2P and the
    per-particle kernels (stress, return map, summary)."""

    def __init__(self, config):
        c = self.config = config
        self.sort = sort_kernels(c.dtype, c.dim, c.kernel)
        self.p2g = p2g_kernels(c.dtype, c.dim, c.kernel, c.affine, c.poly, c.mls_force, c.laws, False)
        self.p2g_fused = p2g_kernels(c.dtype, c.dim, c.kernel, c.affine, c.poly, c.mls_force, c.laws, True)
        self.grid_update = grid_update_kernel(c.dtype, c.dim, c.colliders).grid_update
        self.g2p = g2p_kernel(c.dtype, c.dim, c.kernel, c.affine, c.poly, c.flip, c.mls_gradient, c.tracks_F,
                              c.tracks_J).g2p
        self.particles = particle_kernels(c.dtype, c.dim, c.laws)

    def all(self, fused=True, atomic=False):
        """Every kernel a step may launch, by name: the fused P2G's too (where a fused step is possible: not FLIP) and
        the atomic scatter's if ``atomic``."""
        out = {f"sort.{k}": v for k, v in vars(self.sort).items()}
        for label, made in (("p2g", self.p2g), ("p2g_fused", self.p2g_fused)):
            if label == "p2g_fused" and not fused:
                continue
            out |= {f"{label}.{k}": v for k, v in vars(made).items()
                    if k != "row" and (atomic or k not in ("scatter", "clear"))}
        out["grid_update"] = self.grid_update
        out["g2p"] = self.g2p
        out |= {f"particles.{k}": v for k, v in vars(self.particles).items()}
        return out
