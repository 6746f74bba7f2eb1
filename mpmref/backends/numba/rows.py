"""The row stages of the Numba backend (:class:`~mpmref.backends.base.RowBackend`): a step of some rows of persistent
particle arrays, as asynchronous stepping's level updates run it (:mod:`mpmref.steppers.asynchronous`), and the G2P
and kick gather that the whole-step stages share with them.

The block sort of the rows (:meth:`RowStages.prepare_rows`) lists particle indices, so P2G reads the particles where
they are; G2P writes each row in place (its kernel reads a particle's state before writing it); a run of
consecutive rows, as a level update's own particles and its ghosts are, is handed to the G2P kernel as views, which
reads them without an index.
"""

import numpy as np

from ...physics.interface import KICK_ROW, N_CLASSES
from .blocks import runs_of
from .kicks import kick_first_rows, kicked_blocks

#: the empty row array that tells a kernel to visit every particle (and a transfer kernel that it has no particle
#: classes, or no kicks)
NO_ROWS = np.empty(0, dtype=np.int64)
#: G2P of some rows runs on views of each run of consecutive rows when they are at most this many runs (a level
#: update's rows are two: its level's and the ghosts'), through the index of the rows otherwise: the kernel reads
#: its particles through an index array about a quarter slower
MAX_RUNS = 4
#: block sorts of rows kept for reuse (:meth:`RowStages.prepare_rows`): a level update's rows, sorted again while
#: none of them changed block, as the levels of a run take turns
KEPT_ROW_SORTS = 8
#: the kick row of each particle class (-1: the class receives no kick)
KICK_ROW_OF_CLASS = np.array([KICK_ROW.get(c, -1) for c in range(N_CLASSES)], dtype=np.int64)


class RowStages:
    """The row stages of :class:`~.backend.NumbaBackend`, and the G2P and kick gather of every step (see the module
    doc). A mixin: it uses the backend's kernels, buffers and layout."""

    def prepare_rows(self, particles, rows):
        """:meth:`prepare` of the particles ``rows`` (an int64 index array) of ``particles``: their block sort, whose
        ``order`` lists particle indices, so P2G reads them where they are (the stage of
        :class:`~mpmref.backends.base.RowBackend`). The sort of the rows is the sort of a group holding them in
        the order of ``rows``, so the step gives the bits of that group's step.

        The sort is a function of the rows and their blocks alone (:func:`.blocks.counting_sort`), so the sort of the
        same rows in the same blocks, one of the last :data:`KEPT_ROW_SORTS`, is returned as it is, as
        :meth:`~.backend.NumbaBackend.prepare` does for a whole step (the rows' blocks are computed every time)."""
        keys = self._keys(particles, rows)
        kept = self._row_sorts
        for i, (kept_rows, kept_keys, blocks) in enumerate(kept):
            if np.array_equal(kept_rows, rows) and np.array_equal(kept_keys, keys):
                kept.insert(0, kept.pop(i))
                return blocks
        rows = rows.copy()  # the caller may reuse its array; the sort keeps its own
        blocks = self._sorted(keys, rows)
        kept.insert(0, (rows, keys, blocks))
        del kept[KEPT_ROW_SORTS:]
        return blocks

    def return_map_rows(self, particles, rows, wave_speed=None):
        """Plastic projection of the plastic materials' particles among ``rows``, in place (the stage of
        :class:`~mpmref.backends.base.RowBackend`); with ``wave_speed``, the rows' wave speeds in their new state into
        its rows ``rows`` (see :meth:`~.backend.NumbaBackend.return_map`)."""
        self.materials.return_map_rows(particles, rows, wave_speed)

    def g2p_rows(self, particles, v_grid, v_tilde, dt, prepared, out, kicks=None):
        """G2P of the particles ``prepared.rows`` (a :meth:`prepare_rows` sort) into the same rows of ``out``, which may
        be ``particles`` (in place: each particle reads its own state before writing it); with ``kicks`` (see
        :meth:`g2p`) the impulses and moments of the rows, in their order, gathered first (from the positions of
        P2G). The stage of :class:`~mpmref.backends.base.RowBackend`."""
        rows, layout = prepared.rows, prepared.layout
        impulses = None if kicks is None else self._impulses(particles, rows, layout, kicks)
        starts, stops = runs_of(rows)
        if starts.shape[0] > MAX_RUNS:
            self._gather(particles, rows, layout, v_grid, v_tilde, dt, out)
            return impulses
        for a, b in zip(starts.tolist(), stops.tolist()):  # a run of rows: the kernel on views, no index
            self._gather(particles, NO_ROWS, layout, v_grid, v_tilde, dt, out, slice(a, b))
        return impulses

    def _gather(self, particles, rows, layout, v_grid, v_tilde, dt, out, run=slice(None)):
        """Run the G2P kernel over ``rows`` (empty: every particle) of ``particles``, writing ``out``'s arrays; on
        the rows ``run`` of both (a slice) only."""
        d = particles.dim

        def arrays(p, name, *empty):
            a = getattr(p, name)
            return a[run] if a is not None else np.empty(empty, dtype=self.dtype)

        self._g2p(particles.x[run], particles.v[run], arrays(particles, "F", 0, d, d), arrays(particles, "J", 0),
                  rows, self.sparse_layout(layout), dt, self.transfer.flip_alpha, self.mode_index, v_grid,
                  v_grid if v_tilde is None else v_tilde,  # after a fused P2G (no FLIP): the kernel does not read it
                  out.x[run], out.v[run], arrays(out, "C", 0, d, d), arrays(out, "F", 0, d, d), arrays(out, "J", 0),
                  arrays(out, "modes", 0, 0, d))

    def _impulses(self, particles, rows, layout, kicks):
        """Each particle's impulse and moment from the node kicks ``kicks = (classes, kick)`` (see :meth:`g2p`), of
        every particle or of ``rows`` (empty: all), in that order (:func:`.transfers2d.kick_gather_kernel`)."""
        n, d = (rows.shape[0] or particles.n), particles.dim
        impulse, moment = np.zeros((n, d)), np.zeros((n, 1 if d == 2 else 3))
        node_kicks = kicks[1].reshape(-1, d)
        first = kick_first_rows(np.asarray(kicks[0], dtype=np.int64), KICK_ROW_OF_CLASS, layout.n_rows)
        self._kick_gather(particles.x, particles.mass, rows, self.sparse_layout(layout), first, node_kicks,
                          kicked_blocks(node_kicks, layout.block_nodes), impulse, moment)
        return impulse, moment
