"""The Numba backend object: the reference's stages, compiled for one scene and run in parallel."""

from functools import cached_property

import numba
import numpy as np

from ...physics.interface import N_CLASSES
from ...physics.materials import material_groups
from ...physics.polypic import higher_modes
from ...state import GridState
from ..base import MaterialTable, wall_table
from ..pointwise.grid import collider_table
from ..pointwise.laws import parameter_table
from ..residency import ArrayPool
from . import cpic, materials, transfers
from .blocks import block_keys, colour_classes, counting_sort, slab_colours
from .grid_update import block_grid_velocity, collider_velocity, grid_velocity
from .kernel_args import Groups, SparseLayout
from .kicks import class_first_rows, class_totals, node_kicks
from .rows import NO_ROWS, RowStages
from .sparse import BlockLayout
from .threads import describe_threads, threads_for


def dense_with_classes(state):
    """:meth:`~mpmref.state.GridState.dense` that carries ``class_sums`` over too (dense, per class)."""
    dense = state.dense()
    if state.class_sums is not None:
        dense.class_sums = np.stack([state.layout.to_dense(c) for c in state.class_sums])
    return dense

def _or_empty(array, dtype, *shape):
    return array if array is not None else np.empty(shape, dtype=dtype)


#: P2G hands out slabs when each of their two colours has at least this many, else single blocks in
#: :math:`2^d` colours: a compact body spans few slabs, too few to keep two threads busy (fluid3d: 5 slabs,
#: P2G at 2 threads 4.46 ms by slabs, 3.75 ms by blocks), while many slabs cost fewer passes (262 144
#: particles in 2D, 52 slabs: 10.3 against 10.9 ms). A count of the geometry, never of the threads, so
#: the choice, and the bits, are the same for any thread count.
MIN_SLABS_PER_COLOUR = 16


class Blocks:
    """Particles sorted into the grid's blocks, the groups P2G hands to the threads colour by colour
    (``p2g_groups``: slabs, or single blocks when slabs are too few, see :data:`MIN_SLABS_PER_COLOUR`), the
    sparse grid's :class:`~.sparse.BlockLayout` of these particles, and the :math:`2^d` colour classes of
    blocks (see :mod:`.blocks`); of every particle, or of the particles ``rows`` only."""

    def __init__(self, order, block_start, blocks_per_axis, layout, rows=None):
        self.order, self.block_start, self.blocks_per_axis = order, block_start, blocks_per_axis
        #: the particles sorted (an index array), or ``None`` for every particle (:meth:`NumbaBackend.prepare_rows`)
        self.rows = rows
        slab_start, slabs, colour_start = slab_colours(block_start, blocks_per_axis)
        enough = min(colour_start[1] - colour_start[0], colour_start[2] - colour_start[1]) >= MIN_SLABS_PER_COLOUR
        #: ``(group_start, groups, colour_start)``: ``order[group_start[g]:group_start[g + 1]]`` are group ``g``'s
        #: particles; ``groups[colour_start[c]:colour_start[c + 1]]`` the groups of colour ``c``
        self.p2g_groups = (slab_start, slabs, colour_start) if enough else (block_start, *self.block_colours)
        self.layout = layout

    @cached_property
    def block_colours(self):
        """``(colour_blocks, colour_start)`` of :func:`.blocks.colour_classes`."""
        return colour_classes(self.block_start, self.blocks_per_axis)


class NumbaBackend(RowStages):
    """Optimised implementation of the reference stages for ``scene`` (same methods as ``NumpyBackend``).

    Only what the scene declares is compiled: the transfer kernels for its dimension, kernel, scheme and
    force (:func:`~.transfers.make_p2g`, :func:`~.transfers.make_g2p`), and the stress and return-map
    kernels of its materials' declared laws (:mod:`mpmref.backends.numba.materials`). Walls and level-set
    colliders are the pointwise ones of :mod:`mpmref.backends.pointwise.grid`, compiled.

    The grid is sparse (:mod:`.sparse`): P2G, the grid update and G2P store and visit only the blocks that
    the particles' stencils reach. Node arrays come in two forms. A stage given the ``prepared`` sort of
    :meth:`prepare` exchanges them in that sort's :class:`~.sparse.BlockLayout` (P2G returns a
    :class:`~mpmref.state.GridState` whose ``layout`` says so, the grid update keeps its input's form, G2P
    reads velocities in ``prepared.layout``): that is how the step pipeline runs. Without ``prepared``, they
    are the dense C-ordered arrays of every node, the stage contract of :mod:`mpmref.backends.base` that the
    conformance harness checks; the sparse kernels run all the same, with a scatter or gather at the edge.
    CPIC's stages (:mod:`mpmref.backends.numba.cpic`) use the dense grid.
    """

    name = "numba"

    def __init__(self, scene):
        self.scene = scene
        grid = scene.grid
        self.dtype = scene.dtype
        self.transfer = scene.transfer
        #: the one law of J of every material, which P2G computes the stress by (:func:`.transfers.inline_stress_law`)
        self.stress_law = transfers.inline_stress_law(scene.material_list)
        self._p2g = transfers.make_p2g(self.transfer, grid.block, self.stress_law)
        self._p2g_fused = transfers.make_p2g(self.transfer, grid.block, self.stress_law, fused=True)
        self._g2p = transfers.make_g2p(self.transfer, grid.block)
        self.origin = np.asarray(grid.origin, dtype=np.float64)
        self.dx = float(grid.dx)
        self.inertia = 0.0 if scene.kernel.inertia_factor is None else scene.kernel.inertia_factor * self.dx**2
        self.strides = grid.strides
        self.node_shape = np.array(grid.node_shape, dtype=np.int64)
        modes = higher_modes(scene.dim, scene.kernel.support) if self.transfer.polypic else np.zeros((0, scene.dim))
        self.mode_index = np.ascontiguousarray(modes, dtype=np.int64)
        self.shift = scene.kernel.base_shift
        self.block = grid.block
        self.blocks_per_axis = grid.blocks_per_axis
        self.wall_type, wall_friction = wall_table(scene.boundary, scene.dim)
        self.wall_friction = wall_friction.astype(self.dtype)
        self.colliders = collider_table(scene.colliders)
        self.gravity = np.asarray(scene.gravity, dtype=self.dtype)
        self.params = parameter_table(scene.material_list)
        kernels = materials.material_kernels(scene.material_list, self.params)
        self.materials = MaterialTable(scene.material_list, kernels)
        self.buffers = ArrayPool(np.empty, self.dtype)
        self.n_blocks = int(np.prod(grid.blocks_per_axis))
        #: ``(keys, Blocks)`` of the last sort: a step whose particles all stay in their blocks reuses it
        self._last_sort = (None, None)
        #: ``[(rows, keys, Blocks)]`` of the last sorts of rows, the latest first (:meth:`prepare_rows`)
        self._row_sorts = []
        self._held_class_rows = NO_ROWS  # the class rows of a P2G of some rows (:meth:`_class_rows`), reused

    running = staticmethod(threads_for)

    @staticmethod
    def describe_execution():
        """How the kernels run, for summaries: ``"2 threads (tbb)"`` (:func:`.threads.describe_threads`)."""
        return describe_threads()

    # ------------------------------------------------------------------ helpers
    def _or_empty(self, array, *shape):
        return _or_empty(array, self.dtype, *shape)

    # ------------------------------------------------------------------ stages
    @cached_property
    def node_x(self):
        """Positions of every node of the dense grid (for colliders on a dense grid state)."""
        return self.scene.grid.node_positions()

    def prepare(self, particles):
        """Sort the particles into the grid's blocks and P2G's colour classes of slabs or blocks, and the
        sparse grid's active blocks (:meth:`.sparse.BlockLayout.from_sort`). The sort is a function of the
        particles' blocks alone (:func:`.blocks.counting_sort`), so when every particle is in the block it was in at
        the last sort, that sort is returned as it is (the particles' blocks are computed every time, in parallel:
        :func:`.blocks.block_keys`)."""
        keys = self._keys(particles, NO_ROWS)
        last_keys, last_blocks = self._last_sort
        if last_keys is not None and np.array_equal(keys, last_keys):
            return last_blocks  # the sort depends on the blocks alone (counting_sort): the last one still holds
        blocks = self._sorted(keys, None)
        self._last_sort = (keys, blocks)
        return blocks

    def _keys(self, particles, rows):
        """Each particle's block (:func:`.blocks.block_keys`), of every particle or of ``rows``."""
        return block_keys(particles.x, rows, self.origin, self.dx, self.shift, self.block, self.blocks_per_axis)

    def _sorted(self, keys, rows):
        """:class:`Blocks` of a counting sort of ``keys`` (those of ``rows``, or of every particle)."""
        order, block_start = counting_sort(keys, self.n_blocks)
        layout = BlockLayout.from_sort(block_start, self.blocks_per_axis, self.block, self.scene.grid.node_shape)
        return Blocks(order if rows is None else rows[order], block_start, self.blocks_per_axis, layout, rows)

    def wave_speeds(self, particles, idx):
        """Current wave speed (the CFL rule's :math:`c_p`) of the particles ``idx``, float64, each by its material's
        law (:func:`.materials.wave_speeds`)."""
        return materials.wave_speeds(self.materials, self.params, particles, idx)

    def stress(self, particles):
        """Kirchhoff stress (n, d, d) of every particle, material by material."""
        return self.materials.stress(particles)

    def return_map(self, particles, wave_speed=None):
        """Plastic projection of every plastic material's particles (a new state; others untouched); with
        ``wave_speed`` (float64, (n,)), each particle's current wave speed in its new state written there too, a
        plastic law's in the loop of its projection (:func:`.materials.material_kernels`; the reference and its
        equations: :meth:`mpmref.backends.numpy.backend.NumpyBackend.return_map`)."""
        return self.materials.return_map(particles, wave_speed)

    def p2g(self, particles, prepared=None, contact=None, classes=None):
        """Node mass, momentum and internal force (parallel by colour over slabs or blocks; bitwise
        thread-count independent);
        with a CPIC ``contact``, only to compatible nodes (:func:`mpmref.backends.numba.cpic.p2g`, dense).

        The stress comes from the stress stage (:meth:`stress`), run here first, except in a scene of fluids
        only: a fluid's stress is a function of :math:`J` alone, and P2G computes it per particle instead of
        storing it (:func:`mpmref.backends.numba.transfers2d.p2g_kernel`). The node rows of the active
        blocks live in one (rows, 1 + 2d) array from the backend's :class:`~mpmref.backends.residency.ArrayPool` (mass,
        momentum and force of a node share a cache line); the returned
        :class:`~mpmref.state.GridState` holds views of it and the layout, or, without ``prepared``, dense
        copies (see the class doc). With ``classes`` (:mod:`mpmref.physics.interface`), each class is summed
        into its own block of rows in the same pass: the state's ``class_sums`` (K, rows, 1 + 2d), whose sum
        over the classes gives its mass, momentum and force.
        """
        blocks = prepared or self.prepare(particles)
        if contact is not None:
            return cpic.p2g(self, particles, blocks, contact)
        return self._grid_state(self._p2g, particles, blocks, prepared, classes, 0.0, 2)

    def _grid_state(self, kernel, particles, blocks, prepared, classes, dt, vectors):
        """Run the P2G ``kernel`` (1 + ``vectors`` d values per node) and give its :class:`~mpmref.state.GridState`,
        with the classes' sums apart when ``classes`` is given; in ``blocks``' layout, or dense without ``prepared``."""
        n_classes = 1 if classes is None else N_CLASSES
        class_rows = NO_ROWS if classes is None else self._class_rows(particles, blocks, classes)
        grid = self._scatter(kernel, particles, blocks, n_classes, class_rows, dt, vectors)
        layout, d = blocks.layout, particles.dim
        width = 1 + vectors * d
        class_sums = None
        if classes is not None:
            class_sums = grid.reshape(N_CLASSES, layout.n_rows, width)
            grid, = self.buffers.take(f"grid_totals_{vectors}", (layout.n_rows, width))
            class_totals(class_sums, grid)
        state = GridState(mass=grid[:, 0], momentum=grid[:, 1:1 + d], force=grid[:, 1 + d:] if vectors == 2 else None,
                          layout=layout, class_sums=class_sums)
        return state if prepared is not None else dense_with_classes(state)

    def _class_rows(self, particles, blocks, classes):
        """The first grid row of each particle's class, indexed by particle (of the sorted rows only, when
        ``blocks`` sorts some rows: the kernel reads no other; :func:`.kicks.class_first_rows`)."""
        classes = np.asarray(classes, dtype=np.int64)
        if blocks.rows is None:
            out = np.empty(particles.n, dtype=np.int64)
        else:
            out = self._held_class_rows
            if out.shape[0] < particles.n:
                out = self._held_class_rows = np.empty(particles.n, dtype=np.int64)
        class_first_rows(classes, NO_ROWS if blocks.rows is None else blocks.rows, blocks.layout.n_rows, out)
        return out

    def p2g_fused(self, particles, dt, prepared=None, classes=None):
        """P2G with the internal force folded into the momentum (:func:`.transfers2d.p2g_kernel` with ``FUSED``; the
        reference is :func:`mpmref.backends.numpy.transfers.p2g_fused`): node rows of mass and momentum after the
        force, (1 + d) values where :meth:`p2g` scatters (1 + 2d); a :class:`~mpmref.state.GridState` with
        ``force = None``, in ``prepared``'s layout or, without it, dense. With ``classes``, each class's sums apart
        as in :meth:`p2g` (``class_sums`` (K, rows, 1 + d)): what the kicks of conservative interfaces need when the
        G2P takes the whole node momentum (:meth:`interface_kicks`)."""
        blocks = prepared or self.prepare(particles)
        return self._grid_state(self._p2g_fused, particles, blocks, prepared, classes, dt, 1)

    def _scatter(self, kernel, particles, blocks, n_classes, class_rows, dt, vectors):
        """Run a P2G ``kernel`` over the particles by colour into zeroed pool rows of 1 + ``vectors`` d values per
        node (and per class); returns the rows."""
        layout = blocks.layout
        n, d = particles.x.shape
        if self.stress_law is not None:
            stress = self._or_empty(None, 0, d, d)
        elif blocks.rows is None:
            stress = self.stress(particles)
        else:  # the stress of the sorted rows only: the kernel reads no other
            stress, = self.buffers.take("stress", (n, d, d))
            self.materials.stress_into(particles, blocks.rows, stress)
        grid, = self.buffers.take("grid" if vectors == 2 else "grid_fused",
                                  (n_classes * layout.n_rows, 1 + vectors * d))
        grid.fill(0.0)  # a memset: memory-bound, so a parallel loop's launch costs more than its second thread gains
        chunk = numba.set_parallel_chunksize(1)  # groups hold unequal numbers of particles: one at a time
        try:
            kernel(particles.x, particles.v, self._or_empty(particles.C, 0, d, d),
                   self._or_empty(particles.modes, 0, 0, d), particles.mass, particles.vol0, stress,
                   self._or_empty(particles.J, 0), particles.material, self.params, self.sparse_layout(layout),
                   self.mode_index, Groups(blocks.order, *blocks.p2g_groups), class_rows, dt, grid)
        finally:
            numba.set_parallel_chunksize(chunk)
        return grid

    def sparse_layout(self, layout):
        """The grid's layout as the transfer kernels read it (:class:`.kernel_args.SparseLayout`), for the
        block layout ``layout`` of this step's particles."""
        return SparseLayout(self.origin, self.dx, self.inertia, layout.slot_of, layout.table_strides)

    @cached_property
    def _kick_gather(self):
        """The kick gather of conservative level interfaces (compiled on first use)."""
        return transfers.make_kick_gather(self.transfer, self.block)

    def interface_kicks(self, grid_state, dt, kappa):
        """The node kicks of impulse refluxing from a P2G by classes (2, rows, d), compiled
        (:func:`.kicks.node_kicks`; the reference is :func:`mpmref.physics.interface.interface_kicks`), also from a
        fused P2G by classes (``kappa`` then 1: the folded momentum is what the G2P hands out)."""
        sums = grid_state.class_sums
        kicks = np.empty((2, sums.shape[1], grid_state.momentum.shape[1]))
        node_kicks(sums, dt, kappa, kicks)
        return kicks

    def grid_update(self, grid_state, dt, time=0.0):
        """Grid velocity after forces, gravity, walls and colliders; returns ``(v, v_tilde)`` (pool arrays) in
        the form of ``grid_state``: the rows of its ``layout``, or dense when it has none."""
        folded = grid_state.force is None  # a fused P2G's state: no v_tilde (see grid_update.node_velocity)
        shape = grid_state.momentum.shape
        v, v_tilde = (self.buffers.take("grid_velocity_folded", shape, (0, shape[1])) if folded
                      else self.buffers.take("grid_velocity", shape, shape))
        force = self._or_empty(grid_state.force, 0, shape[1])
        layout = grid_state.layout
        walls = (self.scene.boundary.width, self.wall_type, self.wall_friction, v, v_tilde)
        if layout is None:
            grid_velocity(grid_state.mass, grid_state.momentum, force, dt, self.gravity, self.node_shape, self.strides,
                          *walls)
        else:
            block_grid_velocity(grid_state.mass, grid_state.momentum, force, dt, self.gravity, self.node_shape,
                                self.block, layout.blocks, *walls)
        if self.scene.colliders:
            node_x = self.node_x if layout is None else self.origin + layout.node_index * self.dx
            collider_velocity(grid_state.mass, node_x, self.colliders, len(self.scene.colliders), float(time), v)
        return v, None if folded else v_tilde

    def g2p(self, particles, v_grid, v_tilde, dt, prepared=None, kicks=None):
        """New particle state from the grid velocities (a parallel gather).

        A gather needs no sort: it runs over the particles in their storage order; it reads ``v_grid`` and
        ``v_tilde`` as rows of ``prepared.layout`` or, without ``prepared``, as dense node arrays (gathered
        into the rows of the particles' layout first; see the class doc). The new arrays come from the backend's
        :class:`~mpmref.backends.residency.ArrayPool`: a run that keeps only the current and the previous state swaps
        two sets of them instead of allocating a state per step. With ``kicks`` = ``(classes, kick)``
        (conservative interfaces; see :func:`mpmref.backends.numpy.transfers.g2p`) a second gather collects
        each particle's impulse and its moment about the origin (:func:`.transfers2d.kick_gather_kernel`: its
        own pass, so that no other run's G2P compiles it), and the result is ``(particles, (dP, dL))``.
        """
        n, d = particles.x.shape
        if prepared is None:
            layout = self.prepare(particles).layout
            v_grid, v_tilde = layout.from_dense(v_grid), None if v_tilde is None else layout.from_dense(v_tilde)
            if kicks is not None:
                kicks = (kicks[0], np.stack([layout.from_dense(k) for k in kicks[1]]))
        else:
            layout = prepared.layout
        impulses = None if kicks is None else self._impulses(particles, NO_ROWS, layout, kicks)

        def shape(name, *full):
            return full if getattr(particles, name) is not None else (0,) * len(full)

        modes_shape = particles.modes.shape if particles.modes is not None else (0, 0, d)
        x_new, v_new, C_new, F_new, J_new, modes_new = self.buffers.take(
            "particles", (n, d), (n, d), shape("C", n, d, d), shape("F", n, d, d), shape("J", n), modes_shape)
        new = particles.with_(x=x_new, v=v_new)
        for name, array in (("C", C_new), ("F", F_new), ("J", J_new), ("modes", modes_new)):
            if getattr(particles, name) is not None:
                setattr(new, name, array)
        self._gather(particles, NO_ROWS, layout, v_grid, v_tilde, dt, new)
        return new if kicks is None else (new, impulses)

    # ------------------------------------------------------------------ CPIC stages (:mod:`mpmref.backends.numba.cpic`)
    def cpic_contact(self, particles, prepared, rigid, dt):
        return cpic.contact(self, particles, prepared or self.prepare(particles), rigid, dt)

    def cpic_impulses(self, grid_state, contact, rigid, dt):
        return cpic.impulses(grid_state, contact, rigid, dt)

    def cpic_g2p(self, particles, v_grid, dt, prepared, contact, rigid):
        return cpic.g2p(self, particles, v_grid, dt, prepared or self.prepare(particles), contact, rigid)

    # ------------------------------------------------------------------ warm-up
    def compiled_kernels(self):
        """What :meth:`warm_up` compiles for this scene, as a set: the transfer kernels (one per configuration,
        shared by every scene that has it), and per dtype the step's other stages, each material law's
        stress and return map, and the CPIC kernels where there are rigid bodies. A scene whose set lies
        inside what earlier warm-ups compiled finds all of it in the cache."""
        dtype = np.dtype(self.dtype).str
        laws = {(dtype, type(m).__name__) for m in self.scene.material_list}
        cpic = self.scene.cpic
        cpic_kernels = {(dtype, "cpic", self.scene.dim, cpic.fit)} if cpic is not None else set()
        return {self._p2g, self._p2g_fused, self._g2p, dtype} | laws | cpic_kernels

    def warm_up(self, particles, step, per_material=2):
        """Compile (or load from Numba's cache) every kernel a step of this scene uses, before a timed run.

        Runs ``step(backend, particles, dt, time)`` — the steppers' composition of the stages,
        :func:`mpmref.steppers.pipeline.substep`, passed in by the caller so that backends do not import
        the steppers built on them — on a copy of the first ``per_material`` particles of each material,
        with Δt = 0, so that compilation is not counted in a run's timings, and with rigid bodies the CPIC
        stages too (:func:`mpmref.backends.numba.cpic.warm_up`). ``particles`` is not modified.
        """
        keep = np.zeros(particles.n, dtype=bool)
        for _, idx in material_groups(self.materials.materials, particles):
            keep[idx[:per_material]] = True
        step(self, particles.select(keep), 0.0, 0.0)
        if self.scene.rigid_bodies:
            cpic.warm_up(self, particles.select(keep))
