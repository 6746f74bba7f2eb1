"""The scenes that ``mpmref bench`` times, built with mpmref's own scene machinery.

* :func:`table2_scene`: the set-up of the talk's Table 2 (MPM versus MLS-MPM): a cube of
  ``n**3`` cells filled with 8 particles per cell at the cell centre ``± dx/4`` on every axis (regular
  sampling with ``ppc = 8``), quadratic B-spline, a fixed-corotated elastic solid; or its 2D
  counterpart, a square of ``n**2`` cells at 4 particles per cell.
* :func:`mpm88_scene`: the ``examples/mpm88.toml`` fluid with a chosen particle count and grid.
* :func:`fluid3d_scene`: the 3D counterpart: a block of the same fluid falling in a box.
"""

from dataclasses import dataclass

import numpy as np

from ..scene import SceneBuilder
from ..scene.sampling import sample_particles

#: the two columns of Table 2: classic MPM (APIC transfer, kernel-gradient force) and MLS-MPM
TABLE2_METHODS = {"mpm": {"scheme": "apic", "force": "classic"}, "mls": {"scheme": "mls"}}
#: the elastic law of the Table-2 block (its stress needs one SVD per particle)
TABLE2_MATERIAL = "fixed_corotated"
#: empty cells around the Table-2 block (the quadratic stencil reaches 1.5 cells)
TABLE2_PAD = 2
#: builder arguments of the throughput cases (the performance goals' scenes): ``(count, cells)`` in 2D, ``(cells,)`` for
#: the 3D fluid; tiny ones for ``--quick``
THROUGHPUT_SIZES = {"mpm88": (32768, 128), "fluid3d": (64,), "large2d": (262144, 512)}
QUICK_SIZES = {"mpm88": (512, 128), "fluid3d": (16,), "large2d": (2048, 64)}


def table2_cells(particles, dim=3):
    """Cells per side of the Table-2 block closest to ``particles`` particles (:math:`2^d` per cell), at least 2."""
    return max(2, int(round((particles / 2.0**dim) ** (1.0 / dim))))


def table2_scene(cells, method="mls", dtype="float64", dim=3):
    """The Table-2 block: ``cells**dim`` cells at :math:`2^d` particles per cell (``± dx/4`` on every axis),
    fixed-corotated (the talk's table is 3D; ``dim = 2`` is its 2D counterpart).

    The grid has :data:`TABLE2_PAD` empty cells on each side of the block; ``method`` is a key of
    :data:`TABLE2_METHODS`.
    """
    total = cells + 2 * TABLE2_PAD
    lower, upper = [TABLE2_PAD / total] * dim, [(TABLE2_PAD + cells) / total] * dim
    name = f"table2_{method}" + ("_2d" if dim == 2 else "")
    return (SceneBuilder(dim=dim, name=name, dtype=dtype).grid(size=1.0, cells=total)
            .method(**TABLE2_METHODS[method])
            .material("jelly", TABLE2_MATERIAL, E=1.0e4, nu=0.3, rho=1.0)
            .box("jelly", lower=lower, upper=upper, ppc=2**dim, sampling="regular").time(dt=1.0e-4).build())


def table2_particles(scene, seed=2018):
    """Sampled Table-2 particles with a generic state: small seeded random ``v``, ``C`` and ``F = I + E``.

    A generic ``F`` keeps the stress (an SVD per particle for fixed-corotated) from taking a shortcut.
    """
    p = sample_particles(scene)
    rng = np.random.default_rng(seed)
    n, d, dtype = p.n, p.dim, p.x.dtype
    v = 0.1 * rng.standard_normal((n, d))
    C = 0.1 * rng.standard_normal((n, d, d))
    F = np.eye(d) + 0.05 * rng.standard_normal((n, d, d))
    return p.with_(v=v.astype(dtype), C=C.astype(dtype), F=F.astype(dtype))


def mpm88_scene(count=32768, cells=128, dtype="float64"):
    """``examples/mpm88.toml`` with ``count`` random particles on a ``cells**2`` grid.

    The particle volume is the box area over the count (so the fluid's density stays ``rho``) and
    ``dt = 2e-4 * 128 / cells`` keeps the CFL number of the example.
    """
    return (SceneBuilder(dim=2, name="mpm88", dtype=dtype).grid(size=[1.0, 1.0], cells=cells).method("mls")
            .material("water", "fluid", K=400.0, gamma=1.0, rho=1.0)
            .box("water", lower=[0.2, 0.2], upper=[0.6, 0.6], sampling="random", count=count,
                 velocity=[0.0, -1.0], seed=88)
            .gravity([0.0, -9.8]).walls("separate", width=3).time(dt=2.0e-4 * 128 / cells).build())


def fluid3d_scene(cells=64, dtype="float64"):
    """The ``fluid3d`` fluid on a ``cells**3`` grid: a block of ``cells/4 x cells/2 x cells/4`` cells at
    8 particles per cell (65 536 particles at 64 cells), falling from rest; ``dt = 4e-4 * 32 / cells``."""
    start = cells // 8 + 2
    extent = (cells // 4, cells // 2, cells // 4)
    lower = [start / cells] * 3
    upper = [(start + e) / cells for e in extent]
    return (SceneBuilder(dim=3, name="fluid3d", dtype=dtype).grid(size=1.0, cells=cells).method("mls")
            .material("water", "fluid", K=400.0, gamma=1.0, rho=1.0)
            .box("water", lower=lower, upper=upper, ppc=8, sampling="regular")
            .gravity([0.0, -9.8, 0.0]).walls("separate", width=3).time(dt=4.0e-4 * 32 / cells).build())


@dataclass(frozen=True)
class ThroughputCase:
    """A throughput case: a scene builder and its arguments (the dtype is chosen per run)."""

    name: str
    build: object
    args: tuple

    def scene(self, dtype):
        return self.build(*self.args, dtype=dtype)


def throughput_cases(quick=False):
    """The three throughput cases of the performance goals: ``mpm88`` (32 768 particles, 128² grid), ``fluid3d`` (64³
    grid, 65 536 particles) and ``large2d`` (262 144 particles, 512² grid); tiny versions if ``quick``."""
    sizes = QUICK_SIZES if quick else THROUGHPUT_SIZES
    builders = {"mpm88": mpm88_scene, "fluid3d": fluid3d_scene, "large2d": mpm88_scene}
    return [ThroughputCase(name, builders[name], sizes[name]) for name in ("mpm88", "fluid3d", "large2d")]


def peer_cases(quick=False):
    """The cases compared with a peer code: ``mpm88`` and ``fluid3d`` (the fluid scenes of the performance goals)."""
    return [c for c in throughput_cases(quick) if c.name in ("mpm88", "fluid3d")]
