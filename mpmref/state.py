"""Particle and grid state (structure of arrays).

Only the fields a scene needs are allocated: ``C`` for schemes that carry an affine velocity, ``modes``
for PolyPIC, ``F`` for materials that track the deformation gradient, ``J`` for materials that track only
the volume ratio, ``Jp`` for plastic materials.
"""

from dataclasses import dataclass, fields, replace

import numpy as np



@dataclass
class Particles:
    """Particle arrays; ``n`` particles in ``d`` dimensions.

    Attributes
    ----------
    x, v : (n, d)        position and velocity
    mass, vol0 : (n,)    mass and initial (reference) volume
    material : (n,) int  index into the scene's material list
    C : (n, d, d)        affine velocity matrix (APIC / MLS only) or ``None``
    F : (n, d, d)        deformation gradient (solids only) or ``None``
    J : (n,)             volume ratio (fluid only) or ``None``
    Jp : (n,)            plastic volume ratio (plastic materials only) or ``None``
    modes : (n, M, d)    PolyPIC coefficients of the modes beyond constant and linear, or ``None``
    """

    x: np.ndarray
    v: np.ndarray
    mass: np.ndarray
    vol0: np.ndarray
    material: np.ndarray
    C: np.ndarray | None = None
    F: np.ndarray | None = None
    J: np.ndarray | None = None
    Jp: np.ndarray | None = None
    modes: np.ndarray | None = None

    @property
    def n(self):
        return self.x.shape[0]

    @property
    def dim(self):
        return self.x.shape[1]

    def arrays(self):
        """Mapping of field name to array, for the fields that are allocated."""
        return {f.name: getattr(self, f.name) for f in fields(self) if getattr(self, f.name) is not None}

    def copy(self):
        return Particles(**{k: a.copy() for k, a in self.arrays().items()})

    def select(self, keep):
        """The particles where the boolean mask ``keep`` is true (a new object)."""
        return Particles(**{k: a[keep] for k, a in self.arrays().items()})

    def with_(self, **changes):
        """A shallow copy with some arrays replaced."""
        return replace(self, **changes)


@dataclass(frozen=True)
class Grid:
    """A regular grid of ``cells`` cells per axis, nodes at ``origin + i * dx`` (``i = 0 .. cells``)."""

    origin: np.ndarray
    dx: float
    cells: tuple

    @property
    def dim(self):
        return len(self.cells)

    @property
    def node_shape(self):
        return tuple(c + 1 for c in self.cells)

    @property
    def n_nodes(self):
        return int(np.prod(self.node_shape))

    @property
    def strides(self):
        """Linear-index strides of the C-ordered node array."""
        shape = self.node_shape
        return np.array([int(np.prod(shape[a + 1:])) for a in range(len(shape))], dtype=np.int64)

    def node_indices(self):
        """Integer multi-index of every node, shape (n_nodes, d), C order."""
        grids = np.meshgrid(*[np.arange(s) for s in self.node_shape], indexing="ij")
        return np.stack([g.ravel() for g in grids], axis=1)

    def node_positions(self):
        return self.origin + self.node_indices() * self.dx


@dataclass
class GridState:
    """Grid quantities after P2G: node mass (N,), momentum (N, d) and internal force (N, d)."""

    mass: np.ndarray
    momentum: np.ndarray
    force: np.ndarray
