"""Particle and grid state (structure of arrays).

Only the fields a scene needs are allocated: ``C`` for schemes that carry an affine velocity, ``modes``
for PolyPIC, ``F`` for materials that track the deformation gradient, ``J`` for materials that track only
the volume ratio, ``Jp`` for plastic materials.
"""

from dataclasses import dataclass, field, fields
from functools import cached_property

import numpy as np

#: the roles a field of :class:`Particles` declares (its metadata ``"role"``, read by :func:`fields_with_role`):
#:
#: * ``evolving``: what a step changes, the state of the motion and deformation (``x``, ``v``, ``C``, ``F``, ``J``,
#:   ``Jp``, ``modes``);
#: * ``constant``: set when the particle is made, never changed by a step (``mass``, ``vol0``, ``material``);
#: * ``identity``: the stable ``id``;
#: * ``stepper``: a stepper's own per-particle state (the asynchronous ``level``);
#: * ``cpic``: CPIC's tags, kept from step to step, and its reconstructed distance, normal and ``near`` flag.
ROLES = ("evolving", "constant", "identity", "stepper", "cpic")


def _field(role, *, required=False, deformation=False):
    """A field of :class:`Particles` with its ``role`` (one of :data:`ROLES`) in its metadata; ``None`` by default
    unless ``required``. ``deformation``: a deformation field, carried by the particles whose material evolves it
    (:func:`mpmref.physics.materials.evolved_fields`)."""
    metadata = {"role": role, "deformation": deformation}
    return field(metadata=metadata) if required else field(default=None, metadata=metadata)


@dataclass
class Particles:
    """Particle arrays; ``n`` particles in ``d`` dimensions.

    Each field declares its role (:data:`ROLES`: evolving, constant, identity, stepper or CPIC) in its metadata;
    every list of fields by role derives from there (:func:`fields_with_role`, :data:`EVOLVING_FIELDS`, ...).

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
    id : (n,) int64      stable particle identity: kept through deletion, reordering and checkpoints
                         (default ``0 .. n-1``)
    level : (n,) int64   asynchronous stepping only: the exponent ``k`` of the particle's last step of
                         ``2^k`` ticks, or ``None``
    tag_A, tag_T : (n, nb) bool   CPIC (scenes with rigid bodies) only: the particle's affinity and side tag per
                         body, kept from step to step (:func:`mpmref.physics.cdf.update_tags`), or ``None``
    phi, normal, near : (n,), (n, d), (n,) bool   CPIC only: the particle's signed distance, normal and ``near``
                         flag reconstructed at the start of its last step (:func:`mpmref.physics.cdf.reconstruct`)
    """

    x: np.ndarray = _field("evolving", required=True)
    v: np.ndarray = _field("evolving", required=True)
    mass: np.ndarray = _field("constant", required=True)
    vol0: np.ndarray = _field("constant", required=True)
    material: np.ndarray = _field("constant", required=True)
    C: np.ndarray | None = _field("evolving")
    F: np.ndarray | None = _field("evolving", deformation=True)
    J: np.ndarray | None = _field("evolving", deformation=True)
    Jp: np.ndarray | None = _field("evolving", deformation=True)
    modes: np.ndarray | None = _field("evolving")
    id: np.ndarray | None = _field("identity")
    level: np.ndarray | None = _field("stepper")
    tag_A: np.ndarray | None = _field("cpic")
    tag_T: np.ndarray | None = _field("cpic")
    phi: np.ndarray | None = _field("cpic")
    normal: np.ndarray | None = _field("cpic")
    near: np.ndarray | None = _field("cpic")

    def __post_init__(self):
        if self.id is None:
            self.id = np.arange(self.x.shape[0], dtype=np.int64)

    @property
    def n(self):
        return self.x.shape[0]

    @property
    def dim(self):
        return self.x.shape[1]

    def arrays(self):
        """Mapping of field name to array, for the fields that are allocated."""
        return {name: a for name in PARTICLE_FIELDS if (a := getattr(self, name)) is not None}

    def copy(self):
        return Particles(**{k: a.copy() for k, a in self.arrays().items()})

    def select(self, keep):
        """The particles at ``keep`` (a boolean mask or an index array), as a new object."""
        return Particles(**{k: a[keep] for k, a in self.arrays().items()})

    def assign(self, where, other):
        """Write the rows of ``other`` into the rows ``where`` of this object (in place)."""
        for k, a in self.arrays().items():
            a[where] = getattr(other, k)

    @staticmethod
    def concatenate(parts):
        """One object holding the rows of every object in ``parts`` (same fields), in order."""
        names = parts[0].arrays().keys()
        return Particles(**{k: np.concatenate([getattr(p, k) for p in parts]) for k in names})

    def with_(self, **changes):
        """A shallow copy with some arrays replaced (the fields are set as given, unvalidated, as
        :func:`dataclasses.replace` would; a plain copy of the attribute dict is several times cheaper, which
        matters for the many small groups of asynchronous stepping)."""
        unknown = changes.keys() - PARTICLE_FIELD_SET
        if unknown:
            raise TypeError(f"Particles has no field(s) {sorted(unknown)}")
        new = object.__new__(Particles)
        new.__dict__.update(self.__dict__)
        new.__dict__.update(changes)
        return new


def fields_with_role(*roles):
    """The names of the fields of :class:`Particles` whose role (:data:`ROLES`) is one of ``roles``, in declaration
    order."""
    unknown = set(roles) - set(ROLES)
    if unknown:
        raise ValueError(f"unknown particle field role(s) {sorted(unknown)}; the roles are {list(ROLES)}")
    return tuple(f.name for f in fields(Particles) if f.metadata["role"] in roles)


#: every field of :class:`Particles`, in declaration order
PARTICLE_FIELDS = tuple(f.name for f in fields(Particles))
PARTICLE_FIELD_SET = frozenset(PARTICLE_FIELDS)
#: the fields of each role (:data:`ROLES`), in declaration order
EVOLVING_FIELDS = fields_with_role("evolving")
CONSTANT_FIELDS = fields_with_role("constant")
CPIC_FIELDS = fields_with_role("cpic")
#: the deformation fields (``F``, ``J``, ``Jp``): each carried by the particles whose material evolves it
DEFORMATION_FIELDS = tuple(f.name for f in fields(Particles) if f.metadata["deformation"])


@dataclass(frozen=True)
class Grid:
    """A regular grid of ``cells`` cells per axis, nodes at ``origin + i * dx`` (``i = 0 .. cells``).

    The nodes are grouped into cubic **blocks** of ``block`` cells per edge (a power of two, at least the
    kernel support). A particle's *owner block* is the block that holds its stencil's base node. Blocks
    are the unit of the Numba backend's coloured parallel P2G and of asynchronous time stepping.
    """

    origin: np.ndarray
    dx: float
    cells: tuple
    block: int = 4

    @property
    def blocks_per_axis(self):
        """Number of blocks along each axis (the base nodes ``0 .. cells`` are covered)."""
        return np.array([c // self.block + 1 for c in self.cells], dtype=np.int64)

    @property
    def n_blocks(self):
        return int(np.prod(self.blocks_per_axis))

    def owner_blocks(self, base):
        """Linear index (C order) of the block of each base node; ``base`` is (n, d) integer node indices."""
        coords = np.asarray(base, dtype=np.int64) // self.block
        strides = np.cumprod(self.blocks_per_axis[::-1])[::-1]
        strides = np.append(strides[1:], 1)
        return coords @ strides

    def block_coordinates(self):
        """Integer coordinates (n_blocks, d) of every block, C order."""
        grids = np.meshgrid(*[np.arange(b) for b in self.blocks_per_axis], indexing="ij")
        return np.stack([g.ravel() for g in grids], axis=1)

    @property
    def dim(self):
        return len(self.cells)

    @property
    def node_shape(self):
        return tuple(c + 1 for c in self.cells)

    @cached_property
    def n_nodes(self):
        return int(np.prod(self.node_shape))

    @cached_property
    def strides(self):
        """Linear-index strides of the C-ordered node array (computed once: every transfer of the NumPy
        reference indexes nodes with it; read-only)."""
        shape = self.node_shape
        strides = np.array([int(np.prod(shape[a + 1:])) for a in range(len(shape))], dtype=np.int64)
        strides.setflags(write=False)
        return strides

    def __getstate__(self):
        """The declared fields only: what is computed from them is computed again where the grid is unpickled
        (a pickled array comes back writable, and :attr:`strides` is read-only: a compiled kernel given one and the
        other is compiled twice)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def node_indices(self):
        """Integer multi-index of every node, shape (n_nodes, d), C order."""
        grids = np.meshgrid(*[np.arange(s) for s in self.node_shape], indexing="ij")
        return np.stack([g.ravel() for g in grids], axis=1)

    def node_positions(self):
        return self.origin + self.node_indices() * self.dx


@dataclass
class GridState:
    """Grid quantities after P2G: node mass (N,), momentum (N, d) and internal force (N, d); or, after a fused P2G
    (``p2g_fused`` of :mod:`mpmref.backends.base`), node mass and the momentum after the force
    (mv)_i + Δt f_i with ``force = None``.

    With CPIC, also what particles did not give incompatible nodes (N, d): ``rejected_momentum`` and
    ``rejected_force`` (:func:`mpmref.backends.numpy.transfers.p2g`); ``None`` otherwise. With particle
    classes (a level update of asynchronous stepping, :mod:`mpmref.physics.interface`), ``class_sums``
    (K, N, 1 + 2d): each class's node mass, momentum and force, of which ``mass``, ``momentum`` and
    ``force`` are the sums over the classes.

    ``layout`` is ``None`` for dense arrays over every node of the grid in C order. A backend with a sparse
    grid (the Numba backend's :class:`~mpmref.backends.numba.sparse.BlockLayout`) stores rows of its active
    blocks instead and says so here; :meth:`dense` gives the C-ordered arrays.
    """

    mass: np.ndarray
    momentum: np.ndarray
    force: np.ndarray | None = None  # None: a fused P2G's state, whose momentum is (mv)_i + dt f_i
    rejected_momentum: np.ndarray | None = None
    rejected_force: np.ndarray | None = None
    layout: object = None
    class_sums: np.ndarray | None = None

    def node_arrays(self):
        """Mapping of name to node array, for the arrays that are allocated."""
        names = ("mass", "momentum", "force", "rejected_momentum", "rejected_force")
        return {name: a for name in names if (a := getattr(self, name)) is not None}

    def dense(self):
        """This state with dense C-ordered arrays over every node (itself when it has no ``layout``)."""
        if self.layout is None:
            return self
        return GridState(**{name: self.layout.to_dense(a) for name, a in self.node_arrays().items()})

    def assign_dense(self, dense):
        """Write the values of ``dense`` (a dense state of the same grid, e.g. from :meth:`dense`) into this
        state's arrays, in place; nodes outside a sparse ``layout`` are not stored and are dropped."""
        if dense is self:
            return
        for name, a in self.node_arrays().items():
            if self.layout is None:
                a[...] = getattr(dense, name)
            else:
                self.layout.from_dense(getattr(dense, name), out=a)


@dataclass
class State:
    """Everything a run needs to continue: the particles, the clock, and the stepper's own state.

    Attributes
    ----------
    particles : Particles   the authoritative particle state (each with its stable ``id``)
    step : int              steps taken (synchronous) or synchronised intervals completed (asynchronous)
    time : float            simulated time of ``particles``
    tick : int              integer clock, in units of ``tick_length`` (asynchronous stepping counts every
                            block's step in ticks; the synchronous stepper counts one tick per step)
    tick_length : float or None   seconds per tick (``None`` when synchronous steps have no fixed length)
    deleted : int           particles removed at the domain edge so far
    clamped : int           particles clamped back inside at the domain edge so far (a particle each time)
    stepper : dict          the stepper's own arrays (e.g. block levels), saved with checkpoints
    rigid : RigidState or None   the rigid bodies' pose, velocity and received impulse (CPIC scenes only;
                            :class:`mpmref.rigid.dynamics.RigidState`), saved with checkpoints
    """

    particles: Particles
    step: int = 0
    time: float = 0.0
    tick: int = 0
    tick_length: float | None = None
    deleted: int = 0
    clamped: int = 0
    stepper: dict = field(default_factory=dict)
    rigid: object = None

    def clock(self):
        """The scalar fields as a JSON-ready dict (what a checkpoint stores besides arrays)."""
        return {"step": self.step, "time": self.time, "tick": self.tick, "tick_length": self.tick_length,
                "deleted": self.deleted, "clamped": self.clamped}
