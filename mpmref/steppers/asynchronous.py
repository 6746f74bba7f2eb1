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

from dataclasses import replace

import numpy as np
from scipy.ndimage import maximum_filter

from ..errors import AsyncCensusError, MpmrefError, TickTooLongError
from ..physics.interface import ACTIVE, COARSER, FINER, apply_registers
from ..state import State
from .limits import particle_speeds, wave_speeds
from .pipeline import NO_HOOKS, interface_substep, substep

#: the longest step a particle may take whatever its speed (the reference code's cap)
MAX_STEP_S = 0.1


def alignment(t, cap):
    """The largest power of two (at most ``cap``) that divides tick ``t`` (``cap`` for ``t = 0``)."""
    return cap if t == 0 else min(t & -t, cap)


def floor_power_of_two(limit):
    """The largest power of two ``<= limit`` for each entry of ``limit`` (an int64 array of values >= 1)."""
    return np.left_shift(1, np.floor(np.log2(limit)).astype(np.int64))


def relevel(dt, limit, t):
    """The block step rule at a block boundary (Fang et al. 2018 §4).

    Halve while ``dt > limit`` (stays aligned, as ``t`` is a multiple of the old step), then double while
    ``2 dt <= limit`` and ``t mod 2 dt == 0``. ``dt`` and ``limit`` are int64 arrays; returns the new steps.
    """
    dt = dt.copy()
    while (over := dt > limit).any():
        dt[over] //= 2
    while (grow := (2 * dt <= limit) & (t % (2 * dt) == 0)).any():
        dt[grow] *= 2
    return dt


class AsynchronousStepper:
    """Regional power-of-two time steps over the grid's blocks; see the module docstring.

    ``advance`` moves a :class:`~mpmref.state.State` from one synchronised time (every particle at the same
    tick) to the next. Its stepper state: ``block_dt`` (each block's step in ticks), ``updates`` (particle
    updates done, ghosts included), ``own_updates`` (the particles' own steps), ``sync_updates`` (what
    synchronous stepping at each interval's finest step would have done), ``finest_dt`` (the finest step
    taken, ticks), ``stale_shadows`` and ``sync_times``. Set ``trace = []`` to record every update as a dict
    (tick, level, active blocks, ghost blocks) for inspection.
    """

    name = "async"

    def __init__(self, scene, backend, hooks=NO_HOOKS):
        self.scene, self.backend, self.hooks = scene, backend, hooks
        t = scene.time
        self.tick_s, self.max_units = t.tick, 2**t.levels
        self.strength, self.advection = t.cfl, t.advection_cfl
        self.grid, self.kernel = scene.grid, scene.kernel
        self.reach = 2 * (self.kernel.support - 1)
        self.conservative = t.interface == "conservative"
        self.inertia = 0.0 if self.kernel.inertia_factor is None else self.kernel.inertia_factor * self.grid.dx**2
        self.trace = None

    # ------------------------------------------------------------------ state
    def initial_state(self, particles):
        if particles.level is None:
            particles = particles.with_(level=np.zeros(particles.n, dtype=np.int64))
        stepper = {"block_dt": np.full(self.grid.n_blocks, self.max_units, dtype=np.int64),
                   "updates": np.array(0), "own_updates": np.array(0), "sync_updates": np.array(0.0),
                   "stale_shadows": np.array(0), "finest_dt": np.array(self.max_units),
                   "sync_times": np.array(0)}
        return State(particles=particles, tick_length=self.tick_s, stepper=stepper)

    def base_nodes(self, x):
        """Stencil base node (n, d) of each position (clipped to the node lattice)."""
        base = self.kernel.base_node((np.asarray(x, dtype=np.float64) - self.grid.origin) / self.grid.dx)
        return np.clip(base, 0, np.array(self.grid.node_shape) - 1)

    def owner_blocks(self, x):
        """Block of each position's stencil base node."""
        return self.grid.owner_blocks(self.base_nodes(x))

    def ghost_zone(self, base):
        """Boolean lattice of base nodes within ``2 (S - 1)`` nodes (per axis) of the base nodes ``base``."""
        mask = np.zeros(self.grid.node_shape, dtype=bool)
        mask[tuple(base.T)] = True
        return maximum_filter(mask, size=2 * self.reach + 1, mode="constant")

    # ------------------------------------------------------------------ limits
    def particle_limits(self, particles):
        """Each particle's step limit in ticks, ``min(S_p, A_p, 2^levels)`` (float64; see the module docstring)."""
        dx = self.grid.dx
        speed = particle_speeds(particles)
        signal = wave_speeds(self.scene.material_list, particles) + speed
        strength = self.strength * np.minimum(dx / np.maximum(signal, 1e-300), MAX_STEP_S) / self.tick_s
        with np.errstate(divide="ignore"):
            advection = np.where(speed > 0, self.advection * dx / (np.maximum(speed, 1e-300) * self.tick_s), np.inf)
        return np.minimum(np.floor(np.minimum(strength, advection)), self.max_units)

    def relevel_blocks(self, block_dt, owner, limit, t):
        """New block steps at tick ``t`` from the particles at a boundary (``owner`` blocks, ``limit`` ticks).

        A block's limit is the smallest of the particles it owns (Fang et al. 2018). Taking instead every
        particle whose stencil touches the block's nodes was tried: it cost 15 % of the stork's savings and
        did not reduce the error of colliding balls (docs/async.md), so the reference rule stays.
        """
        block_limit = np.full(self.grid.n_blocks, np.inf)
        np.minimum.at(block_limit, owner, limit)
        nonempty = np.isfinite(block_limit)
        due = t % block_dt == 0
        new = block_dt.copy()
        sel = due & nonempty
        new[sel] = relevel(block_dt[sel], np.minimum(block_limit[sel], self.max_units).astype(np.int64), t)
        coarsest = new[nonempty].max() if nonempty.any() else self.max_units
        empty = due & ~nonempty
        new[empty] = relevel(block_dt[empty], np.full(int(empty.sum()), coarsest), t)
        return new

    # ------------------------------------------------------------------ stepping
    def advance(self, state, dt=None, t_end=None):
        """The state at the next synchronised time (``dt`` must be ``None``; ``t_end`` cannot shorten a step)."""
        if dt is not None:
            raise MpmrefError("asynchronous stepping chooses every block's step itself: call step() without dt")
        run = self.interval(self, state)
        while not run.synchronised():
            run.tick_once()
        return run.finish()

    def cfl_number(self, particles, dt):
        """The largest ``dt (c_p + |v_p|) / dx`` of a step of ``dt`` (the finest level's CFL number)."""
        signal = wave_speeds(self.scene.material_list, particles) + particle_speeds(particles)
        return dt * float(signal.max(initial=0.0)) / self.grid.dx

    def updates(self, old, new):
        """Particle updates (ghosts included) done between two states."""
        return int(new.stepper["updates"]) - int(old.stepper["updates"])

    def diagnostics(self, state):
        """Columns of ``diagnostics.csv``: tick, updates so far, synchronised times and stale shadows."""
        s = state.stepper
        return {"tick": state.tick, "particle_updates": int(s["updates"]), "sync_times": int(s["sync_times"]),
                "stale_shadows": int(s["stale_shadows"])}

    def summary(self, state):
        """Run-summary figures: updates done, what synchronous stepping at the finest step would have done."""
        s = state.stepper
        done = int(s["updates"])
        return {"particle_updates": done, "own_updates": int(s["own_updates"]),
                "ghost_updates": done - int(s["own_updates"]), "sync_particle_updates": float(s["sync_updates"]),
                "updates_saved": float(s["sync_updates"]) / done if done else float("nan"),
                "finest_dt_ticks": int(s["finest_dt"]),
                "stale_shadows": int(s["stale_shadows"])}


class _Interval:
    """The working state of one :meth:`AsynchronousStepper.advance`: particles with their own clocks."""

    def __init__(self, stepper, state):
        self.s = stepper
        self.state = state
        self.P = state.particles.copy()
        n = self.P.n
        self.t0 = self.t = state.tick
        self.t_p = np.full(n, self.t, dtype=np.int64)  # each particle's clock
        self.dt_p = np.zeros(n, dtype=np.int64)  # its current step (ticks)
        self.base = np.zeros((n, self.P.dim), dtype=np.int64)  # its stencil base node at its last boundary
        self.owner = np.zeros(n, dtype=np.int64)  # the block of that node
        self.shadow = self.P.copy()
        self.shadow_t = np.full(n, self.t, dtype=np.int64)
        self.shadow_base = np.zeros((n, self.P.dim), dtype=np.int64)  # base node of each shadow
        self.block_dt = np.asarray(state.stepper["block_dt"]).copy()
        self.updates = 0
        self.own_updates = 0
        self.stale = 0
        self.finest = stepper.max_units
        if stepper.conservative:  # impulse refluxing: each particle's received impulse and its moment
            self.dP = np.zeros((n, self.P.dim))
            self.dL = np.zeros(n if self.P.dim == 2 else (n, 3))

    def synchronised(self):
        return self.t > self.t0 and bool(np.all(self.t_p == self.t))

    def tick_once(self):
        """Everything that happens at the current tick: re-levelling, then each due level, coarse first."""
        t, s = self.t, self.s
        at = np.flatnonzero(self.t_p == t)
        self.apply_registers(at)
        here = self.P.select(at)
        self.base[at] = s.base_nodes(here.x)
        self.owner[at] = s.grid.owner_blocks(self.base[at])
        limit = s.particle_limits(here)
        if (limit < 1).any():
            bad = int(np.argmin(limit))
            raise TickTooLongError(t, int(here.id[bad]), float(limit[bad] + 1) * s.tick_s)
        self.block_dt = s.relevel_blocks(self.block_dt, self.owner[at], limit, t)
        self.dt_p[at] = np.minimum(np.minimum(self.block_dt[self.owner[at]], alignment(t, s.max_units)),
                                   floor_power_of_two(limit))
        self.finest = min(self.finest, int(self.dt_p[at].min()))
        self.shadow.assign(at, here)
        self.shadow_t[at] = t
        self.shadow_base[at] = self.base[at]
        proposals = []  # (shadow indices, their results, end tick) of each update, coarse first
        D = s.max_units
        while D >= 1:
            active = at[self.dt_p[at] == D] if t % D == 0 else at[:0]
            if active.size:
                proposals.append(self.update_level(D, active))
            D //= 2
        self.refresh_shadows(proposals)
        self.t = int(self.t_p.min())

    def apply_registers(self, idx):
        """Conservative interfaces: apply and clear the registers of the particles ``idx`` (at their step end)."""
        if not self.s.conservative or idx.size == 0:
            return
        P = self.P
        v, C = apply_registers(P.v[idx], None if P.C is None else P.C[idx], P.x[idx].astype(np.float64),
                               P.mass[idx], self.dP[idx], self.dL[idx], self.s.inertia)
        P.v[idx] = v
        if C is not None:
            P.C[idx] = C
        self.dP[idx] = 0.0
        self.dL[idx] = 0.0

    def refresh_shadows(self, proposals):
        """Each shadow takes the result of the finest update that used it at this tick (if any).

        Updates ran coarse first, so writing the proposals in order leaves the finest one.
        """
        for idx, rows, end in proposals:
            self.shadow.assign(idx, rows)
            self.shadow_t[idx] = end
            self.shadow_base[idx] = self.s.base_nodes(rows.x)

    def update_level(self, D, active):
        """One level-``D`` update at the current tick: a substep of the active particles and their ghosts.

        Returns the shadow proposal ``(indices, results, end tick)`` of the coarser ghosts.
        """
        s, t = self.s, self.t
        zone = s.ghost_zone(self.base[active])
        waiting = np.flatnonzero(self.t_p == t)  # the active particles and the finer ones, not yet advanced
        waiting = waiting[self.dt_p[waiting] < D]
        level_ghosts = waiting[zone[tuple(self.base[waiting].T)]]
        mid = np.flatnonzero(self.t_p > t)
        shadow_ghosts = mid[zone[tuple(self.shadow_base[mid].T)]]
        self.stale += int(np.count_nonzero(self.shadow_t[shadow_ghosts] != t))
        group = self.P.concatenate([self.P.select(active), self.P.select(level_ghosts),
                                    self.shadow.select(shadow_ghosts)])
        n_active = active.size
        first_shadow = n_active + level_ghosts.size
        if s.conservative:
            classes = np.repeat(np.array([ACTIVE, FINER, COARSER]), [n_active, level_ghosts.size, shadow_ghosts.size])
            result, dP, dL = interface_substep(s.backend, group, classes, D * s.tick_s, t * s.tick_s)
            self.dP[active] += dP[:n_active]
            self.dL[active] += dL[:n_active]
            self.dP[shadow_ghosts] += dP[first_shadow:]
            self.dL[shadow_ghosts] += dL[first_shadow:]
        else:
            result = substep(s.backend, group, D * s.tick_s, t * s.tick_s, s.hooks)
        self.P.assign(active, result.select(slice(0, n_active)))
        self.P.level[active] = int(D).bit_length() - 1
        self.t_p[active] = t + D
        self.updates += group.n
        self.own_updates += n_active
        if s.trace is not None:
            s.trace.append({"tick": t, "level": D, "active": sorted(set(self.owner[active].tolist())),
                            "level_ghosts": sorted(set(self.owner[level_ghosts].tolist())),
                            "shadow_ghosts": sorted(set(zip(s.owner_blocks(self.shadow.x[shadow_ghosts]).tolist(),
                                                            self.shadow_t[shadow_ghosts].tolist())))})
        return shadow_ghosts, result.select(slice(first_shadow, None)), t + D

    def finish(self):
        """The new :class:`~mpmref.state.State` at this synchronised tick, after the id census (and, with
        conservative interfaces, every register applied: each particle is at its step end)."""
        self.apply_registers(np.arange(self.P.n))
        census(self.state.particles.id, self.P.id, self.t)
        n, ticks = self.P.n, self.t - self.t0
        old = self.state.stepper
        stepper = {"block_dt": self.block_dt, "updates": np.array(int(old["updates"]) + self.updates),
                   "own_updates": np.array(int(old["own_updates"]) + self.own_updates),
                   "sync_updates": np.array(float(old["sync_updates"]) + n * ticks / self.finest),
                   "stale_shadows": np.array(int(old["stale_shadows"]) + self.stale),
                   "finest_dt": np.array(min(int(old["finest_dt"]), self.finest)),
                   "sync_times": np.array(int(old["sync_times"]) + 1)}
        return replace(self.state, particles=self.P, step=self.state.step + 1, tick=self.t,
                       time=self.t * self.s.tick_s, stepper=stepper)


AsynchronousStepper.interval = _Interval


def census(before, after, tick):
    """Check that the ids ``after`` are exactly the ids ``before``, each once; raise :class:`AsyncCensusError`."""
    ids, counts = np.unique(after, return_counts=True)
    duplicated = ids[counts > 1]
    lost = np.setdiff1d(before, ids)
    if lost.size or duplicated.size:
        raise AsyncCensusError(tick, lost, duplicated)
