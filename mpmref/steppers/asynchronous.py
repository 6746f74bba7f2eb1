r"""Asynchronous (regional) time stepping: power-of-two steps per block (Fang, Hu, Hu & Jiang, SCA 2018).

Time is an integer count of ticks (``time.tick`` seconds each). Every block of the grid
(:class:`~mpmref.state.Grid`) has a step of :math:`2^k` ticks, :math:`0 \le k \le` ``time.levels``,
chosen from the stability limits of the particles it owns:

.. math::

    S_b = \left\lfloor s\, \min_{p \in b} \frac{\Delta x}{c_p + |v_p|} \Big/ \Delta t_u \right\rfloor, \quad
    A_b = \left\lfloor a\, \frac{\Delta x}{\max_{p \in b} |v_p|\, \Delta t_u} \right\rfloor, \quad
    L_b = \min(S_b, A_b, 2^{\text{levels}})

(:math:`s` = ``time.cfl``, :math:`a` = ``time.advection_cfl``, :math:`c_p` the particle's current wave
speed, :math:`\Delta t_u` the tick). At its own step boundaries a block halves its step while it exceeds
:math:`L_b` and doubles it while the double fits and is aligned (:math:`t \bmod 2\Delta t_b = 0`); empty
blocks follow the coarsest non-empty one (Fang et al. 2018 §4; the rules of their reference code).

**Who advances, when.** Each particle takes its owner block's step at its own step boundary (capped by the
alignment of the current tick, so that a particle arriving in a coarser block mid-step keeps stepping
finely until it is aligned). At every tick with work, levels run coarse first. A level-``D`` update is one
ordinary substep (:func:`~.pipeline.substep`) of Δt = D ticks over

* the particles stepping at that level (their results are authoritative),
* *ghosts* near them: finer particles at the same time (their own state), and coarser particles that are
  mid-step (their *shadow*: the state at the coarse step's start, sub-cycled by the finest update that
  used it). A ghost is every particle whose stencil base node lies within ``2 (S - 1)`` nodes of an
  active particle's (``S`` the kernel support): the first ``S - 1`` give the active particles' nodes
  their complete mass, momentum and force, the next ``S - 1`` give those ghosts a complete neighbourhood
  for their own (shadow) update. The reference code takes the 3^d neighbouring blocks instead; that
  holds these particles and more, and gives the active particles the same result.

Ghost results only refresh shadows. Every particle is stored exactly once, with its own clock, so no
particle can be lost or duplicated at a level interface — the hazard of block-owned particle pools
(a particle moved by the fine step into a coarse block that the coarse step kept in the fine block).
A census at every synchronised time checks it anyway.

A shadow that an update needs but that no earlier update brought to the current tick (possible only when
fine particles move next to a coarse block mid-step) is used as it is and counted as ``stale_shadows``.

**Level interfaces** (``time.interface``). With ``"reference"`` an update is the plain substep, as Fang et
al. publish it: the coarse side takes its exchange with finer neighbours once per coarse step, the fine
side its exchange with the coarse shadows at every fine step, and neither reaction is applied, so momentum
is not conserved across levels. With ``"conservative"`` (impulse refluxing, :mod:`mpmref.physics.interface`)
each update also returns the reaction impulses of its exchanges; they accumulate in per-particle
registers (``dP``, ``dL``) and are applied at the end of each particle's own step, before its state is
read again (at its next boundary tick, or when the interval ends).
"""

import inspect
from dataclasses import dataclass, field, fields, replace
from time import perf_counter

import numpy as np

from ..backends.base import gives_wave_speeds, steps_rows
from ..errors import AsyncCensusError, MpmrefError, TickTooLongError
from ..observe.ledger import ASYNC_COLUMNS, ledger_columns
from ..physics.interface import ACTIVE, COARSER, FINER
from ..state import EVOLVING_FIELDS, State
from .async_kernels import (
    add_impulses,
    apply_registers_at,
    blocks_by_level,
    boundary_steps,
    bucket_by_block,
    bucket_zone_members,
    gather_ghosts,
    levels_of,
    misplaced_rows,
    move_rows,
    permute_rows,
    row_views,
    same_ids,
    shadow_nodes,
    span,
    step_limits,
    zone,
)
from .async_store import StorePool
from .limits import particle_speeds, wave_speeds
from .pipeline import NO_HOOKS, LevelExchange, substep

#: the classes of a level update's rows, in their order: its own particles, the level ghosts, the shadow ghosts
CLASSES = np.array([ACTIVE, FINER, COARSER], dtype=np.int64)
#: no rows
NO_ROWS = np.empty(0, dtype=np.int64)
#: the longest step a particle may take whatever its speed (the reference code's cap)
MAX_STEP_S = 0.1
#: what :attr:`WorkRecord.counts` counts: ticks with work; particles at a step
#: boundary (their limits, blocks and steps); blocks due for relevelling; candidate ghosts examined (the
#: particles of the blocks near an update); nodes of the updates' ghost zones (their bounding boxes); rows of
#: the updates (particle updates, ghosts included); intervals, and the particles of each (the only
#: work over every particle: the copy into the store, the registers' last application and the census); rows
#: copied one by one (ghosts into spare rows, the shadows they propose and commit), rows copied as runs (the state's
#: particles into a store, a cohort's shadows kept at its step's start) and rows moved to keep the particles
#: ordered by step (:meth:`AsyncInterval.arrange`)
COUNTS = ("ticks", "boundary_particles", "due_blocks", "ghost_candidates", "zone_nodes",
          "group_rows", "intervals", "interval_particles", "ghost_rows_copied", "run_rows_copied", "moved_rows")


@dataclass(frozen=True)
class AsyncSchedule:
    """The asynchronous stepper's state at a synchronised time, kept in :attr:`mpmref.state.State.stepper` as one
    array per field (so checkpoints carry it bit for bit; :meth:`of` reads it back).

    Attributes
    ----------
    block_dt : ndarray of int64, (n_blocks,)
        Each block's step in ticks, a power of two.
    updates, own_updates : int
        Particle updates done so far, ghosts included, and the particles' own steps (no ghosts).
    sync_updates : float
        What synchronous stepping at each interval's finest step would have done over the same time.
    stale_shadows : int
        Shadows used by an update that no earlier update had brought to its tick.
    finest_dt : int
        The finest step the stability limits chose, in ticks (steps shortened to end at ``t_end`` not counted).
    sync_times : int
        Synchronised times reached (intervals done).
    """

    block_dt: np.ndarray
    updates: int
    own_updates: int
    sync_updates: float
    stale_shadows: int
    finest_dt: int
    sync_times: int

    @classmethod
    def start(cls, n_blocks, max_units):
        """The schedule of a run that has not stepped: every block at the coarsest step."""
        return cls(np.full(n_blocks, max_units, dtype=np.int64), 0, 0, 0.0, 0, max_units, 0)

    @classmethod
    def of(cls, state):
        """The schedule held in ``state.stepper``."""
        held = state.stepper
        return cls(np.asarray(held["block_dt"]), int(held["updates"]), int(held["own_updates"]),
                   float(held["sync_updates"]), int(held["stale_shadows"]), int(held["finest_dt"]),
                   int(held["sync_times"]))

    def arrays(self):
        """The fields as arrays, for :attr:`mpmref.state.State.stepper`."""
        return {name: np.asarray(getattr(self, name)) for name in SCHEDULE_FIELDS}


#: the fields of :class:`AsyncSchedule`, in order
SCHEDULE_FIELDS = tuple(f.name for f in fields(AsyncSchedule))


@dataclass(frozen=True)
class LevelUpdate:
    """One level update, as :attr:`WorkRecord.trace` records it: its tick and step (ticks), the blocks of its active
    particles and of its level ghosts, and its shadow ghosts' (block, shadow tick) pairs."""

    tick: int
    level: int
    active: list
    level_ghosts: list
    shadow_ghosts: list


@dataclass
class WorkRecord:
    """What asynchronous stepping did and what it cost: returned by each interval, summed by the stepper
    (:attr:`AsynchronousStepper.work`). The benchmark's split of an update's cost into stages and bookkeeping and
    the tests' measure of how the bookkeeping's work grows.

    Attributes
    ----------
    counts : dict
        What the bookkeeping visited (:data:`COUNTS`).
    level_updates, ghost_level_updates : int
        Level updates, in all and those with ghosts.
    stage_seconds, ghost_stage_seconds : float
        Wall time in the step's stages (the substeps), in all and in the updates with ghosts.
    seconds : float
        Wall time of the intervals (stages and bookkeeping).
    trace : list of LevelUpdate, or None
        Every level update, in order, when the stepper records a trace (``record_trace``).
    """

    counts: dict = field(default_factory=lambda: dict.fromkeys(COUNTS, 0))
    level_updates: int = 0
    ghost_level_updates: int = 0
    stage_seconds: float = 0.0
    ghost_stage_seconds: float = 0.0
    seconds: float = 0.0
    trace: list | None = None

    def add(self, other):
        """Add ``other``'s work to this record, in place."""
        for k, count in other.counts.items():
            self.counts[k] += count
        self.level_updates += other.level_updates
        self.ghost_level_updates += other.ghost_level_updates
        self.stage_seconds += other.stage_seconds
        self.ghost_stage_seconds += other.ghost_stage_seconds
        self.seconds += other.seconds
        if other.trace is not None:
            self.trace = (self.trace or []) + other.trace


def alignment(t, cap):
    """The largest power of two (at most ``cap``) that divides tick ``t`` (``cap`` for ``t = 0``)."""
    return cap if t == 0 else min(t & -t, cap)


def within(room):
    """The largest power of two at most ``room`` ticks (``room >= 1``)."""
    return 1 << (int(room).bit_length() - 1)


class _Cohort:
    """The particles in rows ``start .. stop - 1`` of the interval's arrays, which began a step of ``D`` ticks at
    the same tick and end it together at ``end``."""

    __slots__ = ("D", "end", "start", "stop", "_buckets")

    def __init__(self, D, end, start, stop):
        self.D, self.end, self.start, self.stop, self._buckets = D, end, start, stop, None

    @property
    def size(self):
        return self.stop - self.start

    def rows(self):
        """The cohort's rows, as an index array."""
        return np.arange(self.start, self.stop, dtype=np.int64)

    def buckets(self, owner):
        """The particles bucketed by their block ``owner[p]`` (:func:`~.async_kernels.bucket_by_block`), for the
        ghost searches of the updates that run while they are at this tick or mid-step; built at the first search
        (their blocks and rows do not change before their step ends)."""
        if self._buckets is None:
            self._buckets = bucket_by_block(self.rows(), owner)
        return self._buckets


class AsyncInterval:
    """The working state of one :meth:`AsynchronousStepper.advance`: particles with their own clocks, stored in the
    order of their steps.

    **Storage that follows the schedule.** The particles live in the rows of a :class:`~.async_store.RowStore`
    ordered by their current step, finest first (``P``, every field; the state the interval starts from is copied
    there once, at its first tick with more than one step). A particle's step changes only at its step boundary,
    and the particles at a boundary at tick ``t`` are those whose step divides ``t``: the finest levels, a prefix of
    the rows. At each tick the prefix is put back in order of the new steps, moving only the rows out of their
    level's run (:func:`~.async_kernels.misplaced_rows`), so each level's particles are one run of rows, a
    **cohort** (:class:`_Cohort`: the particles that began a step of the same length at the same tick, and end it
    together; at most one per level is under way). A level update advances its cohort's rows where they are and
    copies only its ghosts into the store's spare rows (:meth:`group`); the stages run on those rows in place
    (:func:`~.pipeline.substep` with ``rows``). The shadows (each particle's state at its step's start, where a finer
    update reads it) live in ``shadow``, the shadows proposed by the updates of the current tick in ``proposed``,
    rows for rows; both hold only the fields a step changes (:data:`mpmref.state.EVOLVING_FIELDS`).

    When every particle takes the same step at the interval's first tick, the interval is that one update with no
    ghost: it is the synchronous step (:func:`~.pipeline.substep` of the state's particles, the backend's sort of
    the last step reused), and nothing is copied.

    A cohort is bucketed by block when an update first looks among its particles for ghosts, so an update looks
    only in the blocks near its own particles, and it keeps a shadow only when finer steps begin at its tick (no
    other update runs before its step ends); the blocks are kept ordered by step, so a tick relevels only the
    blocks due at it. The work over every particle happens once per interval (the copy into the store, the
    registers' last application and the census): a tick and an update cost what their own particles, ghosts and
    blocks cost (:data:`COUNTS`).

    With an end tick ``deadline``, no particle steps past it: each step is capped at the largest power of two that
    fits before it, so the interval ends there at the latest; the finest step and the particles' levels it
    records are those the level rule chose, not the capped steps. What the interval did is its :attr:`work`
    (:class:`WorkRecord`), returned by :meth:`finish`. A subclass can change one part of the bookkeeping (the
    verification case's and the tests' broken variants do): give it to the stepper as ``interval_type``.
    """

    def __init__(self, stepper, state, deadline=None):
        self.s = stepper
        self.state = state
        self.deadline = deadline
        self.work = WorkRecord(trace=[] if stepper.record_trace else None)
        self.P = state.particles  # the state's particles until the store is taken (:meth:`arrange`)
        self.store = None
        n = self.n = self.P.n
        self.t0 = self.t = state.tick
        # each particle's current step (ticks), stencil base node and block at its last boundary, and its
        # shadow's base node and tick: rows of P, every row written at the first tick
        held = stepper.bookkeeping(n, self.P.dim)
        self.dt_p, self.base, self.owner, self.shadow_base, self.shadow_t = held
        #: each row's wave speed c_p from its last update (the return map's output ``wave_speed``), or ``None`` where
        #: the backend has no such output (the level rule then runs the backend's ``wave_speeds`` at each boundary)
        self.c = stepper.carried_speeds(self.P)
        self.cohorts = [_Cohort(0, self.t, 0, n)]  # all due at the first tick
        self.drift = 0  # the farthest a shadow has been from its particle's base node, nodes per axis
        self.schedule = AsyncSchedule.of(state)
        self.block_dt = self.schedule.block_dt.copy()
        self.order, self.level_start = blocks_by_level(self.block_dt, stepper.levels)
        self.updates = 0
        self.own_updates = 0
        self.stale = 0
        self.finest = stepper.max_units
        self.rows = None  # row views of the stores, once the store is taken (:meth:`arrange`)
        self._registers = None  # impulse refluxing's registers (dP, dL), allocated at their first use
        self.kicked = False  # whether an update of this interval has added to a register
        self.work.counts["intervals"] += 1
        self.work.counts["interval_particles"] += n
        if stepper.ledger is not None:
            stepper.ledger.begin()

    @property
    def dP(self):
        """Each particle's register of received impulse (n, d), zero until an update adds to it."""
        return self.registers()[0]

    @property
    def dL(self):
        """Each particle's register of the moment of its received impulse about the origin: (n, 1) in 2D, (n, 3) in
        3D."""
        return self.registers()[1]

    def registers(self):
        """``(dP, dL)``, allocated (zero) at the first use: an interval with no ghost never needs them."""
        if self._registers is None:
            d = self.P.dim
            self._registers = (np.zeros((self.n, d)), np.zeros((self.n, 1 if d == 2 else 3)))
        return self._registers

    def synchronised(self):
        return self.t > self.t0 and all(c.end == self.t for c in self.cohorts)

    def tick_once(self):
        """Everything that happens at the current tick: the particles due (a prefix of the rows) re-level, the prefix
        is put in order of their new steps, then each due level updates, coarse first."""
        t, s = self.t, self.s
        due = [c for c in self.cohorts if c.end == t]
        self.cohorts = [c for c in self.cohorts if c.end != t]  # mid-step: their shadows may be ghosts
        n_due = sum(c.size for c in due)
        at = np.arange(n_due, dtype=np.int64)
        self.close_registers(at)
        P = self.P
        limit = s.particle_limits(P, at) if self.c is None else s.particle_limits(P, at, speeds=self.c[:n_due])
        if limit.min() < 1:
            bad = int(np.argmin(limit))
            raise TickTooLongError(t, int(P.id[at[bad]]), float(limit[bad] + 1) * s.tick_s)
        align = alignment(t, s.max_units)
        room = align if self.deadline is None else min(align, within(self.deadline - t))
        taken, due_blocks = boundary_steps(P.x, at, *s.lattice, limit, t, align, room, s.max_units, self.block_dt,
                                           self.order, self.level_start, s.block_limit, self.base, self.owner,
                                           self.dt_p)
        self.work.counts["due_blocks"] += due_blocks
        chosen = None  # the levels the rule chose, where the deadline shortened the steps
        if room < align:
            own = np.exp2(np.floor(np.log2(limit))).astype(np.int64)
            chosen = np.log2(np.minimum(self.block_dt[self.owner[at]], own)).astype(np.int64)
            self.finest = min(self.finest, 1 << int(chosen.min()))
        else:
            self.finest = min(self.finest, taken & -taken)
        self.work.counts["ticks"] += 1
        self.work.counts["boundary_particles"] += n_due
        if t == self.t0 and taken & (taken - 1) == 0:  # one step for every particle: the synchronous step
            self.synchronous_step(taken, chosen)
            return
        started = self.arrange(n_due, taken, chosen)  # coarse first
        for cohort in started:
            # its shadow (the state at its step's start) can be a ghost only of a finer update, and every finer
            # update before its step ends is of particles that take a finer step now
            if taken & (cohort.D - 1):
                self.save_shadows(cohort)
        mid = list(self.cohorts)  # the cohorts mid-step, whose shadows may be ghosts; each update adds its own
        proposals = []  # (shadow indices, end tick) of each update, coarse first
        for k, cohort in enumerate(started):
            proposals.append(self.update_level(cohort, started[k + 1:], mid))
            mid.append(cohort)
        self.cohorts += started
        self.refresh_shadows(proposals)
        self.t = min(c.end for c in self.cohorts)

    def save_shadows(self, cohort):
        """The shadows of the ``cohort``'s particles: their state, base node and tick at their step's start."""
        rows = slice(cohort.start, cohort.stop)
        self.work.counts["run_rows_copied"] += cohort.size
        for k in self.evolving:
            self.shadow[k][rows] = self.P_arrays[k][rows]
        self.shadow_base[rows] = self.base[rows]
        self.shadow_t[rows] = self.t

    def synchronous_step(self, D, chosen):
        """The interval's one update when every particle takes the step ``D`` at its first tick: no ghost, nothing
        gathered or copied, the synchronous step of the state's particles (:func:`~.pipeline.substep`), whose
        arrays the backend may reuse from the step before (its block sort too, when no particle changed block)."""
        s, t, n = self.s, self.t, self.n
        exchange = None if s.ledger is None else LevelExchange(np.full(n, ACTIVE, dtype=np.int64), False)
        start = perf_counter()
        new = substep(s.backend, self.P, D * s.tick_s, t * s.tick_s, s.hooks, ledger=s.ledger, exchange=exchange,
                      wave_speed=self.c)
        self.count_update(perf_counter() - start, n, n)
        level = np.full(n, int(D).bit_length() - 1, dtype=np.int64) if chosen is None else chosen
        self.P = new.with_(level=level)
        if self.work.trace is not None:
            self.work.trace.append(LevelUpdate(t, D, sorted(set(self.owner.tolist())), [], []))
        self.cohorts = [_Cohort(D, t + D, 0, n)]
        self.t = t + D

    def arrange(self, n_due, taken, chosen):
        """Put the particles due (rows ``0 .. n_due - 1``) in order of their new steps, finest first, moving only those
        out of their step's run (at the first such tick, after copying the state's particles into a store of the
        stepper's: :meth:`take_store`); record the levels the rule chose. Returns the new cohorts, coarse first."""
        if self.store is None:
            self.take_store(0)
        level = self.P_arrays["level"]
        levels_of(self.dt_p, n_due, level)  # the steps' levels, which order the rows
        src, dst, level_start = misplaced_rows(level, n_due, self.s.levels)
        if src.size:
            permute_rows(self.rows["moving"], src, dst)
            self.work.counts["moved_rows"] += src.size
        if chosen is not None:  # the particles' levels are those the rule chose, not the shortened steps
            level[:n_due] = chosen if not src.size else self.unpermuted(chosen, src, dst)
        t = self.t
        return [_Cohort(1 << k, t + (1 << k), int(level_start[k]), int(level_start[k + 1]))
                for k in range(taken.bit_length() - 1, -1, -1) if taken >> k & 1]

    @staticmethod
    def unpermuted(values, src, dst):
        """``values`` (one per row of the prefix, in the rows' order before :func:`permute_rows`) in their order
        after it."""
        out = values.copy()
        out[dst] = values[src]
        return out

    def take_store(self, spare):
        """Copy the particles into a store of the stepper's with at least ``spare`` spare rows (or move them into a
        bigger one), and keep the row views of the stores that the compiled row copies take."""
        s = self.s
        if self.store is None:
            self.store = s.stores.take(self.P, spare)
            self.work.counts["run_rows_copied"] += self.n
        else:
            self.store = s.stores.grown(self.store, spare)
        self.P = self.store.particles
        arrays = self.P_arrays = self.store.arrays
        if self.c is not None and self.c.shape[0] < self.store.capacity:  # the ghosts' rows write theirs too
            c = np.empty(self.store.capacity)
            c[:self.n] = self.c[:self.n]
            self.c = c
        speeds = () if self.c is None else (self.c,)
        self.evolving = tuple(k for k in arrays if k in EVOLVING_FIELDS)
        self.shadow = s.store(self.P, self.evolving, "shadow", self.n)
        self.proposed = s.store(self.P, self.evolving, "proposed", self.n)
        constant = tuple(k for k in arrays if k not in EVOLVING_FIELDS)
        self.rows = {"P": row_views(arrays[k] for k in self.evolving), "shadow": row_views(self.shadow.values()),
                     "proposed": row_views(self.proposed.values()),
                     "P_constant": row_views(arrays[k] for k in constant),
                     "moving": row_views([*arrays.values(), self.dt_p, self.base, self.owner, *speeds])}

    def pairs(self, src, dst):
        """``(source, destination)`` row views of every field between two stores."""
        return tuple(zip(self.rows[src], self.rows[dst]))

    def close_registers(self, idx):
        """Conservative interfaces: apply and clear the registers of the particles ``idx`` (at their step end;
        :func:`mpmref.physics.interface.apply_registers`, compiled)."""
        if not self.s.conservative or idx.size == 0 or not self.kicked:
            return
        P = self.P
        C = P.C if P.C is not None else np.empty((0, P.dim, P.dim), dtype=P.x.dtype)

        def apply():
            apply_registers_at(idx, P.x, P.v, C, P.mass, self.dP, self.dL, self.s.inertia)

        if self.s.ledger is None:
            apply()
        else:
            self.s.ledger.kicks(P, idx, apply)

    def refresh_shadows(self, proposals):
        """Each shadow takes the result of the finest update that used it at this tick (if any).

        Updates ran coarse first and each wrote its proposals over the coarser ones in ``proposed``, so
        committing them in order leaves the finest one.
        """
        s = self.s
        for idx, end in proposals:
            move_rows(self.pairs("proposed", "shadow"), idx, idx)
            self.work.counts["ghost_rows_copied"] += idx.size
            drift = shadow_nodes(self.shadow["x"], idx, *s.lattice[:4], end, self.shadow_base, self.shadow_t, self.base)
            self.drift = max(self.drift, drift)

    def group(self, active, level_ghosts, shadow_ghosts):
        """The rows of a level update: its ``active`` rows, and its ghosts copied into the store's spare rows after
        the particles', the level ghosts (every field, from ``P``) then the shadow ghosts (from ``shadow``; their
        other fields from ``P``)."""
        n, n_level, n_shadow = self.n, level_ghosts.size, shadow_ghosts.size
        if n_level + n_shadow == 0:
            return active
        if self.store.capacity < n + n_level + n_shadow:
            self.take_store(n_level + n_shadow)
        tail = span(n, n_level + n_shadow)
        self.work.counts["ghost_rows_copied"] += n_level + n_shadow
        constant = self.pairs("P_constant", "P_constant")
        gather_ghosts(self.pairs("P", "P") + constant, self.pairs("shadow", "P") + constant, level_ghosts,
                      shadow_ghosts, n)
        return np.concatenate((active, tail))

    def ghosts(self, zone_, cohorts, node, drift):
        """The particles of ``cohorts`` whose node ``node[p]`` (base node, or their shadow's) lies in the ghost
        zone ``zone_`` (:func:`~.async_kernels.zone`), ascending; ``drift`` bounds, in nodes per axis, how far
        ``node`` lies from the base node that gave a particle its block."""
        s = self.s
        found = []
        for cohort in cohorts:
            members, examined = bucket_zone_members(*zone_, drift, s.grid.block, s.lattice[5],
                                                    *cohort.buckets(self.owner), node)
            self.work.counts["ghost_candidates"] += examined
            if members.size:
                found.append(members)
        if not found:
            return NO_ROWS
        return np.sort(found[0] if len(found) == 1 else np.concatenate(found))

    def update_level(self, cohort, waiting, mid):
        """One level update at the current tick: a substep of the ``cohort``'s particles and their ghosts.

        ``waiting`` are the cohorts of finer particles at this tick, not yet advanced (they may be ghosts at their
        own state); ``mid`` the cohorts mid-step (their shadows may be ghosts). Returns the shadow proposal
        ``(indices, end tick)`` of the coarser ghosts, whose results it wrote into ``proposed``.
        """
        s, t, D = self.s, self.t, cohort.D
        active = cohort.rows()
        if waiting or mid:
            zone_ = zone(active, self.base, s.reach, s.node_shape)
            self.work.counts["zone_nodes"] += zone_[2].size
            level_ghosts = self.ghosts(zone_, waiting, self.base, 0)
            shadow_ghosts = self.ghosts(zone_, mid, self.shadow_base, self.drift)
        else:  # one level at this tick and none mid-step: no ghost to look for
            level_ghosts = shadow_ghosts = NO_ROWS
        if shadow_ghosts.size:
            self.stale += int(np.count_nonzero(self.shadow_t[shadow_ghosts] != t))
        rows = self.group(active, level_ghosts, shadow_ghosts)
        n_active = active.size
        start = perf_counter()
        kicks = s.conservative and n_active < rows.size  # with no ghost there is no exchange to reflux
        exchange = None
        if kicks or s.ledger is not None:  # by classes: the registers' impulses, or the ledger's active particles
            classes = np.repeat(CLASSES, [n_active, level_ghosts.size, shadow_ghosts.size])
            exchange = LevelExchange(classes, kicks)
        substep(s.backend, self.P, D * s.tick_s, t * s.tick_s, s.hooks, ledger=s.ledger, exchange=exchange,
                rows=rows, wave_speed=self.c)
        if kicks:
            self.add_impulses(active, shadow_ghosts, n_active + level_ghosts.size, exchange.impulses)
        self.count_update(perf_counter() - start, rows.size, n_active)
        if shadow_ghosts.size:
            move_rows(self.pairs("P", "proposed"), span(self.n + level_ghosts.size, shadow_ghosts.size), shadow_ghosts)
            self.work.counts["ghost_rows_copied"] += shadow_ghosts.size
        if self.work.trace is not None:
            shadow_blocks = s.owner_blocks(self.shadow["x"][shadow_ghosts]).tolist()
            self.work.trace.append(LevelUpdate(t, D, sorted(set(self.owner[active].tolist())),
                                               sorted(set(self.owner[level_ghosts].tolist())),
                                               sorted(set(zip(shadow_blocks, self.shadow_t[shadow_ghosts].tolist())))))
        return shadow_ghosts, t + D

    def add_impulses(self, active, shadow_ghosts, first_shadow, impulses):
        """Add an update's impulses and moments (one row per row of the update, :class:`~.pipeline.LevelExchange`) to
        the registers of its ``active`` particles (a run of rows) and of its shadow ghosts' particles
        (:func:`~.async_kernels.add_impulses`)."""
        self.kicked = True
        add_impulses(*self.registers(), int(active[0]), active.size, shadow_ghosts, first_shadow, *impulses)

    def count_update(self, elapsed, rows, n_active):
        """Book a level update of ``rows`` rows, ``n_active`` of them its own particles, whose stages took
        ``elapsed`` seconds."""
        work = self.work
        work.stage_seconds += elapsed
        work.level_updates += 1
        work.counts["group_rows"] += rows
        if n_active < rows:
            work.ghost_stage_seconds += elapsed
            work.ghost_level_updates += 1
        self.updates += rows
        self.own_updates += n_active

    def finish(self):
        """The new :class:`~mpmref.state.State` at this synchronised tick, after the id census (and, with
        conservative interfaces, every register applied: each particle is at its step end), and the interval's
        :class:`WorkRecord`."""
        if self.kicked:
            self.close_registers(np.arange(self.n, dtype=np.int64))
        particles = self.P if self.store is None else self.store.live()
        census(self.state.particles.id, particles.id, self.t)
        if self.c is not None:  # each particle's wave speed from its last update, for the next interval's first tick
            self.s.carry_speeds(particles, self.c)
        n, ticks, old = self.n, self.t - self.t0, self.schedule
        schedule = AsyncSchedule(self.block_dt, old.updates + self.updates, old.own_updates + self.own_updates,
                                 old.sync_updates + n * ticks / self.finest, old.stale_shadows + self.stale,
                                 min(old.finest_dt, self.finest), old.sync_times + 1)
        stepper = schedule.arrays()
        if self.s.ledger is not None:
            stepper["energy_ledger"] = self.s.ledger.close(self.state.stepper.get("energy_ledger"))
        new = replace(self.state, particles=particles, step=self.state.step + 1, tick=self.t,
                      time=self.t * self.s.tick_s, stepper=stepper)
        return new, self.work


class AsynchronousStepper:
    """Regional power-of-two time steps over the grid's blocks; see the module docstring.

    A :class:`~mpmref.steppers.Stepper`. ``advance`` moves a :class:`~mpmref.state.State` from one synchronised
    time (every particle at the same tick) to the next, which is one step of the run; its state is an
    :class:`AsyncSchedule` (in ``state.stepper``, with, given a ``ledger``
    (:class:`~mpmref.observe.ledger.LevelLedger`), ``energy_ledger``, the cumulative ledger over
    :data:`~mpmref.observe.ledger.ASYNC_COLUMNS`). Each interval is an ``interval_type`` (:class:`AsyncInterval`); what
    they did and cost adds up in :attr:`work` (a :class:`WorkRecord`; set ``record_trace = True`` for its list of every
    level update).
    """

    name = "async"
    #: a step advances particles by different Δt: the synchronous step's velocity bound does not apply
    uniform_step = False
    compiles = True
    interval_type = AsyncInterval

    def __init__(self, scene, backend, hooks=NO_HOOKS, ledger=None):
        if hooks.grid_folds:
            raise MpmrefError("asynchronous stepping takes no grid folds: a fold changes the node totals of a level "
                              "update, not the sums of its particle classes that conservative interfaces exchange; "
                              "run with time.stepping = \"sync\" (a body force hook acts in every update)")
        self.scene, self.backend, self.hooks, self.ledger = scene, backend, hooks, ledger
        t = scene.time
        self.tick_s, self.max_units = t.tick, 2**t.levels
        self.strength, self.advection = t.cfl, t.advection_cfl
        self.grid, self.kernel = scene.grid, scene.kernel
        self.reach = 2 * (self.kernel.support - 1)
        self.node_shape = np.array(self.grid.node_shape, dtype=np.int64)
        #: what the compiled bookkeeping needs of the grid: origin, dx, the kernel's base-node shift, the node
        #: lattice, the block size and the block lattice
        self.lattice = (np.asarray(self.grid.origin, dtype=np.float64), float(self.grid.dx),
                        self.kernel.base_shift, self.node_shape, self.grid.block,
                        np.asarray(self.grid.blocks_per_axis, dtype=np.int64))
        self._stores = {}
        #: the stores of the particles' rows that the intervals take in turn (:mod:`.async_store`)
        self.stores = StorePool()
        self.conservative = t.interface == "conservative"
        self.inertia = 0.0 if self.kernel.inertia_factor is None else self.kernel.inertia_factor * self.grid.dx**2
        self.levels = t.levels
        self.block_limit = np.full(self.grid.n_blocks, np.inf)  # scratch of relevel_due: infinite between calls
        #: whether the intervals record every level update (:attr:`WorkRecord.trace`)
        self.record_trace = False
        #: what the intervals did and cost since construction, summed (:class:`WorkRecord`)
        self.work = WorkRecord()
        #: whether the level rule reads each particle's wave speed from its last update (the return map's output
        #: ``wave_speed``, :func:`~mpmref.backends.base.gives_wave_speeds`) rather than from a pass at each boundary;
        #: not for a subclass whose own :meth:`particle_limits` takes no ``speeds`` (a rule of its own)
        self.speeds_from_step = (gives_wave_speeds(backend)
                                 and "speeds" in inspect.signature(type(self).particle_limits).parameters)
        self._carried = None  # (particles, wave speeds) the last interval ended with (:meth:`carry_speeds`)

    # ------------------------------------------------------------------ state
    def initial_state(self, particles):
        if particles.level is None:
            particles = particles.with_(level=np.zeros(particles.n, dtype=np.int64))
        schedule = AsyncSchedule.start(self.grid.n_blocks, self.max_units)
        return State(particles=particles, tick_length=self.tick_s, stepper=schedule.arrays())

    def base_nodes(self, x):
        """Stencil base node (n, d) of each position (clipped to the node lattice)."""
        base = self.kernel.base_node((np.asarray(x, dtype=np.float64) - self.grid.origin) / self.grid.dx)
        return np.clip(base, 0, np.array(self.grid.node_shape) - 1)

    def owner_blocks(self, x):
        """Block of each position's stencil base node."""
        return self.grid.owner_blocks(self.base_nodes(x))

    # ------------------------------------------------------------------ limits
    def particle_limits(self, particles, idx=None, speeds=None):
        """Step limit in ticks, ``min(S_p, A_p, 2^levels)`` (float64; see the module docstring), of each particle
        of ``particles`` or of its particles ``idx``; ``speeds`` their wave speeds :math:`c_p` (one per particle of
        ``idx``), or ``None`` for the backend's pass (``wave_speeds``)."""
        dx = self.grid.dx
        idx = np.arange(particles.n) if idx is None else idx
        if speeds is None:
            speeds = self.backend.wave_speeds(particles, idx)
        return step_limits(particles.v, idx, speeds, dx, self.strength, self.advection, self.tick_s, MAX_STEP_S,
                           self.max_units)

    def carried_speeds(self, particles):
        """The wave speed :math:`c_p` of each particle of ``particles`` (float64, a row per particle, which the
        interval then owns and writes), at the start of an interval: the speeds the last interval's updates left
        (:meth:`carry_speeds`) when ``particles`` are the particles it returned, else (the first interval, a restart, a
        state replaced between intervals: emitters, the domain policy) the backend's pass, whose values are the same
        bits (:func:`~mpmref.backends.base.gives_wave_speeds`). ``None`` where the backend gives no speeds from its
        step."""
        if not self.speeds_from_step:
            return None
        held, self._carried = self._carried, None
        if held is not None and held[0] is particles:
            return held[1]
        return np.ascontiguousarray(self.backend.wave_speeds(particles, np.arange(particles.n)), dtype=np.float64)

    def carry_speeds(self, particles, speeds):
        """Keep ``speeds`` (a row per particle of ``particles``, and maybe spare rows) for the next interval, should it
        start from ``particles`` (:meth:`carried_speeds`)."""
        self._carried = (particles, speeds)

    def store(self, particles, names, key, n):
        """Arrays of ``n`` rows shaped like the fields ``names`` of ``particles`` (contents undefined), kept on the
        stepper and handed out again to the next interval while the particle count and fields stay the same."""
        arrays = particles.arrays()
        spec = tuple((k, (n,) + arrays[k].shape[1:], arrays[k].dtype) for k in names)
        held = self._stores.get(key)
        if held is None or held[0] != spec:
            held = (spec, {k: np.empty(shape, dtype) for k, shape, dtype in spec})
            self._stores[key] = held
        return held[1]

    def bookkeeping(self, n, d):
        """The per-particle arrays of an interval's bookkeeping (contents undefined: the first tick writes every row),
        kept on the stepper like :meth:`store`: each particle's step (ticks), base node, block, and its shadow's base
        node and tick."""
        held = self._stores.get("bookkeeping")
        if held is None or held[0] != (n, d):
            arrays = (np.empty(n, np.int64), np.empty((n, d), np.int64), np.empty(n, np.int64),
                      np.empty((n, d), np.int64), np.empty(n, np.int64))
            held = self._stores["bookkeeping"] = ((n, d), arrays)
        return held[1]

    def warm_up(self, particles):
        """Compile (or load from Numba's cache) the bookkeeping kernels for these particles' fields, on one particle,
        and with conservative interfaces the level update by classes on one particle and a copy of it as its ghost,
        at Δt = 0: ``particles`` is not modified."""
        carried = self._carried
        interval = self.interval_type(self, self.initial_state(particles.select(slice(0, 1))))
        self._carried = carried
        one = np.zeros(1, dtype=np.int64)
        step_limits(interval.P.v, NO_ROWS, np.empty(0), 1.0, 1.0, 1.0, 1.0, 1.0, 1.0)
        boundary_steps(interval.P.x, one, *self.lattice, np.ones(1), 0, 1, 1, self.max_units, interval.block_dt,
                       interval.order, interval.level_start, self.block_limit, interval.base, interval.owner,
                       interval.dt_p)
        interval.take_store(1)
        levels_of(interval.dt_p, 1, interval.P_arrays["level"])
        permute_rows(interval.rows["moving"], *misplaced_rows(interval.P_arrays["level"], 1, self.levels)[:2])
        move_rows(interval.pairs("P", "shadow"), NO_ROWS, NO_ROWS)
        shadow_nodes(interval.shadow["x"], NO_ROWS, *self.lattice[:4], 0, interval.shadow_base, interval.shadow_t,
                     interval.base)
        cohort = _Cohort(1, 1, 0, 1)
        interval.ghosts(zone(one, interval.base, self.reach, self.node_shape), [cohort], interval.base, 0)
        rows = interval.group(one, one, NO_ROWS)  # the particle and a copy of it as a level ghost
        same_ids(interval.store.live().id, interval.store.live().id)
        if interval.c is not None:  # the return map's wave speeds: of some rows, and of a whole step
            self.backend.return_map(interval.P.select(one), wave_speed=np.empty(1))
            if steps_rows(self.backend):
                self.backend.return_map_rows(interval.P, one, wave_speed=interval.c)
        if self.conservative:  # the backend's kernels of a level update by classes, and the registers
            exchange = LevelExchange(CLASSES[:2].copy(), kicks=True)
            substep(self.backend, interval.P, 0.0, 0.0, exchange=exchange, rows=rows)
            interval.add_impulses(one, NO_ROWS, 2, exchange.impulses)
            interval.close_registers(one)

    # ------------------------------------------------------------------ stepping
    def advance(self, state, dt=None, t_end=None):
        """The state at the next synchronised time (``dt`` must be ``None``), at ``t_end`` at the latest: no step
        passes the first tick at or after ``t_end`` (:meth:`end_tick`)."""
        if dt is not None:
            raise MpmrefError("asynchronous stepping chooses every block's step itself: call step() without dt")
        start = perf_counter()
        run = self.interval_type(self, state, None if t_end is None else self.end_tick(t_end, state.tick))
        while not run.synchronised():
            run.tick_once()
        new, work = run.finish()
        work.seconds = perf_counter() - start
        self.work.add(work)
        return new

    def end_tick(self, t_end, tick):
        """The tick a run to ``t_end`` ends at: ``t_end`` itself when it is a whole number of ticks (to 1e-9 of a
        tick), else the first tick after it (time is counted in whole ticks); after ``tick``, the current one."""
        return max(int(np.ceil(t_end / self.tick_s - 1e-9)), tick + 1)

    def time_step(self, particles):
        """``None``: every block chooses its own step."""
        return None

    def cfl_number(self, particles, dt):
        """The largest ``dt (c_p + |v_p|) / dx`` of a step of ``dt`` (the finest level's CFL number)."""
        signal = wave_speeds(self.scene.material_list, particles) + particle_speeds(particles)
        return dt * float(signal.max(initial=0.0)) / self.grid.dx

    def updates(self, old, new):
        """Particle steps done between two states: the particles' own updates (ghost updates not counted)."""
        return int(new.stepper["own_updates"]) - int(old.stepper["own_updates"])

    def diagnostics(self, state):
        """Columns of ``diagnostics.csv``: tick, updates so far, synchronised times and stale shadows; with a ledger,
        the cumulative ledger's (``ledger_<column>`` over :data:`~mpmref.observe.ledger.ASYNC_COLUMNS`)."""
        s = AsyncSchedule.of(state)
        out = {"tick": state.tick, "particle_updates": s.updates, "sync_times": s.sync_times,
               "stale_shadows": s.stale_shadows}
        if self.ledger is not None:
            out |= ledger_columns(state.stepper.get("energy_ledger"), ASYNC_COLUMNS)
        return out

    def summary(self, state):
        """Run-summary figures: the particle updates done, owned and ghost; what synchronous stepping at the finest
        step would have done (``sync_particle_updates``) and its ratio to the updates done (``update_ratio``, the
        work async saves) and to the owned ones (``own_update_ratio``, the ideal that ghosts cost a share of);
        the levels the particles took last (log2 of their steps in ticks). Ratios of work, not of wall time
        (``mpmref bench --only async`` measures that)."""
        s = AsyncSchedule.of(state)
        done, own, sync = s.updates, s.own_updates, s.sync_updates
        return {"particle_updates": done, "own_updates": own,
                "ghost_updates": done - own, "sync_particle_updates": sync,
                "update_ratio": sync / done if done else float("nan"),
                "own_update_ratio": sync / own if own else float("nan"),
                "finest_dt_ticks": s.finest_dt,
                "levels": sorted(set(state.particles.level.tolist())),
                "stale_shadows": s.stale_shadows}


def census(before, after, tick):
    """Check that the ids ``after`` are exactly the ids ``before``, each once, in any order (an interval may reorder
    the rows); raise :class:`AsyncCensusError`."""
    if after is before or same_ids(before, after):
        return
    ids, counts = np.unique(after, return_counts=True)
    duplicated = ids[counts > 1]
    lost = np.setdiff1d(before, ids)
    if lost.size or duplicated.size:
        raise AsyncCensusError(tick, lost, duplicated)
