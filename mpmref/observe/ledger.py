r"""The energy ledger: where in the step each joule of the total energy change went.

The total energy of a run is :math:`E = K_p + \Psi + U\ (+ E_{bodies})`: the particles' kinetic energy (velocity,
affine and PolyPIC-mode parts, :func:`mpmref.observe.diagnostics.diagnostics`), their stored elastic energy, their
gravitational potential :math:`U = -\sum_p m_p\, g \cdot x_p`, and with CPIC the rigid bodies' kinetic and
gravitational energy. A step (:func:`mpmref.steppers.pipeline.substep`) changes it stage by stage; the ledger
observes the stages' outputs and books each change to the stage that made it, in float64 whatever the run's
dtype (docs/energy_ledger.md derives each term):

.. math::

    \Delta E = \underbrace{(K_g^0 - K_p^n)}_{\texttt{p2g\_transfer}}
    + \underbrace{\textstyle\sum_{i \in \partial} B_i}_{\texttt{boundary}}
    + \underbrace{(K_p^{n+1}(x^n) - K_g^1)}_{\texttt{g2p\_transfer}}
    + \underbrace{(K_p^{n+1} - K_p^{n+1}(x^n))}_{\texttt{advection}}
    + \underbrace{(\Psi^{n+1} - \Psi^{tr})}_{\texttt{plastic}}
    + \underbrace{\Delta E_{bodies}}_{\texttt{rigid\_bodies}}
    + \texttt{integration},

    \texttt{integration} = (\Psi^{tr} - \Psi^n + W_{int}) + (U^{n+1} - U^n + W_g)
    + \textstyle\sum_{i \notin \partial} B_i,

with the grid's kinetic energy :math:`K_g^0 = \tfrac12 \sum_i |(mv)_i|^2 / m_i` after P2G and
:math:`K_g^1 = \tfrac12 \sum_i m_i |v_i|^2` after the grid update; :math:`K_p^{n+1}(x^n)` the particles'
kinetic energy after G2P with their PolyPIC modes' norms taken where G2P projected the grid's velocity
(``advection`` is the change of those norms as the particles move: zero for every other scheme); the force work at the
velocity the nodes then move with, :math:`W_{int} = \Delta t \sum_i f_i \cdot v_i` and
:math:`W_g = \Delta t \sum_i m_i\, g \cdot v_i` (flows from the stored energies into kinetic energy: reported, and
cancelling in :math:`\Delta E`); and per node what the velocity change does that this work does not,

.. math::

    B_i = \tfrac12 m_i |v_i|^2 - \tfrac12 m_i |\tilde v_i|^2 - \Delta t\,(f_i + m_i g) \cdot v_i
        = R_i \cdot v_i - \tfrac12 m_i |v_i - \tilde v_i|^2, \qquad R_i = m_i (v_i - v_i^*),

where :math:`v_i^* = \tilde v_i + \Delta t (f_i / m_i + g)` is the velocity before the walls and colliders and
:math:`R_i` the impulse they apply. Nodes a wall band or a collider acts on (:math:`\partial`) book :math:`B_i` as
``boundary``: :math:`R_i \cdot v_i \le 0` for every static projection of talk Eq. 25, so it is never positive for
static walls and colliders, and a moving collider can add energy. Elsewhere :math:`R_i = 0` and
:math:`B_i = -\tfrac12 m_i |\Delta t\, a_i|^2`, the symplectic Euler step's own kinetic error, which joins
``integration``. The terms telescope: their sum is :math:`\Delta E` identically (``closure`` records the
round-off). ``plastic`` and ``advection`` are sums over the particles: the ledger also keeps each particle's share
of the last step (:attr:`EnergyLedger.shares`).

A run's ledger (the cumulative one a stepper keeps in the run's state, :data:`RUN_COLUMNS`) has two more terms, booked
between steps by the run (:func:`book_exchange`), for the particles that enter it and leave it:

.. math::

    E(t) - E_0 = \sum_{\text{steps}} \Delta E + \underbrace{\textstyle\sum_{p \in \text{in}} e_p}_{\texttt{inflow}}
    \underbrace{- \textstyle\sum_{p \in \text{out}} e_p}_{\texttt{outflow}},

with :math:`e_p` a particle's kinetic, stored and gravitational energy (the diagnostics' ``total_energy`` of that
particle alone): ``inflow`` what the particles an emitter releases bring (:mod:`mpmref.run.emitters`, at their
release, before the step they join), ``outflow`` what the particles deleted at the domain's edge take away
(:mod:`mpmref.run.domain`, in the state after the step that took them out).
"""

import numpy as np

from ..backends.numpy.transfers import wall_bands
from ..rigid import dynamics as rigid_dynamics
from .diagnostics import elastic_energies, gravitational_energy, kinetic_parts, mode_energies, polypic_mode_norms

#: the ledger's terms, in step order: their sum is the change of total energy
TERMS = ("p2g_transfer", "boundary", "g2p_transfer", "advection", "plastic", "rigid_bodies", "integration")
#: flows between stored energies, reported beside the terms (they cancel in the total)
FLOWS = ("internal_work", "gravity_work")
#: what a step's entry holds: the terms, the flows, the measured change of total energy and the closure
COLUMNS = (*TERMS, *FLOWS, "energy_change", "closure")
#: the terms that are sums over the particles, whose per-particle shares the ledger keeps
PER_PARTICLE = ("plastic", "advection")
#: what the run books between steps (:func:`book_exchange`): the energy of the particles that entered (released by an
#: emitter) and, negative, of those that left (deleted at the domain's edge)
EXCHANGE_TERMS = ("inflow", "outflow")
#: the terms of a synchronous run's cumulative ledger: its steps' and the particles it exchanged
RUN_TERMS = (*TERMS, *EXCHANGE_TERMS)
#: what a synchronous run's cumulative ledger holds (:func:`accumulate`; ``diagnostics.csv``'s ``ledger_<column>``)
RUN_COLUMNS = (*RUN_TERMS, *FLOWS, "energy_change", "closure")


class EnergyLedger:
    r"""Observer of :func:`~mpmref.steppers.pipeline.substep` that books each step's energy change by stage.

    The step calls :meth:`start`, :meth:`grid`, :meth:`g2p` and :meth:`finish` in that order; :meth:`finish`
    returns the step's entry (a dict over :data:`COLUMNS`), kept as ``last``. What accumulates over a run lives
    in the run's state (:func:`accumulate`), so that checkpoints carry it.

    Attributes
    ----------
    last : dict
        The last step's entry.
    shares : dict
        The last step's per-particle terms (:data:`PER_PARTICLE`), float64 (n,) arrays over the particles the step
        returned, whose stable ids are ``shares["id"]``: ``plastic`` :math:`V_p^0 (\Psi_p^{n+1} - \Psi_p^{tr})`,
        ``advection`` :math:`\tfrac12 m_p \sum_r |c_{pr}|^2 (N_{pr}(x_p^{n+1}) - N_{pr}(x_p^n))` (zero without
        PolyPIC modes). Each adds up to its term, to round-off.
    scale : float
        :func:`energy_scale` of the step's input state: the size of the energies its terms are differences of.

    Parameters
    ----------
    scene : Scene
        Its materials, gravity, kernel, grid, walls, colliders and rigid bodies define the energies and the
        boundary nodes.

    Docs: docs/energy_ledger.md#p2g, docs/energy_ledger.md#rigid-bodies-and-the-integration-error
    """

    #: the columns of the run's cumulative ledger (what :func:`book_exchange` books into)
    columns = RUN_COLUMNS

    def __init__(self, scene):
        self.scene = scene
        kernel, grid = scene.kernel, scene.grid
        self.inertia = None if kernel.inertia_factor is None else kernel.inertia_factor * grid.dx**2
        self.gravity = np.asarray(scene.gravity, dtype=np.float64)
        self.wall_nodes = np.zeros(grid.n_nodes, dtype=bool)  # C-ordered nodes of every wall band that acts
        for name, band, _ in wall_bands(grid, scene.boundary.width):
            if scene.boundary.walls[name].type != "open":
                self.wall_nodes |= band
        self.dense_index = grid.node_indices() if scene.colliders else None  # node of each dense row
        self.last, self.shares, self.scale = None, None, None
        self._open = {}

    # ------------------------------------------------------------------ the stages
    def start(self, particles, rigid=None, exchange=None):
        """Record the energies of the step's input state (and their :func:`energy_scale`). A synchronous step has no
        level ``exchange`` (a level update's is booked by :class:`LevelLedger`)."""
        if exchange is not None:
            raise ValueError("a level update by particle classes is booked by LevelLedger, not EnergyLedger")
        norms = self.mode_norms(particles)
        o = {"norms": norms, "K": self.kinetic(particles, norms), "Psi": float(np.sum(self.elastic(particles))),
             "U": self.potential(particles), "bodies": self.bodies_energy(rigid)}
        self._open = o
        self.scale = energy_scale(o["K"], o["Psi"], o["U"], o["bodies"])

    def grid(self, grid_state, v_grid, dt, time):
        r"""Book P2G (the grid's kinetic energy against the particles'), the force work and the boundary.

        ``grid_state`` is the grid after P2G (and the hooks); ``v_grid`` the velocity after the grid update, in
        the same rows (dense, or the rows of a sparse ``layout``).
        """
        m = np.asarray(grid_state.mass, dtype=np.float64)
        has = m > 0
        m = m[has]
        p = np.asarray(grid_state.momentum, dtype=np.float64)[has]
        f = np.asarray(grid_state.force, dtype=np.float64)[has]
        v = np.asarray(v_grid, dtype=np.float64)[has]
        v_tilde = p / m[:, None]
        v_star = v_tilde + dt * (f / m[:, None] + self.gravity)
        per_node = node_kinetic_remainder(m, v_tilde, v_star, v)
        on_boundary = self.boundary_nodes(grid_state.layout, time)[has]
        o = self._open
        o["K_g0"] = 0.5 * float(np.sum(np.einsum("nd,nd->n", p, p) / m))
        o["K_g1"] = 0.5 * float(np.sum(m * np.einsum("nd,nd->n", v, v)))
        o["internal_work"] = dt * float(np.sum(f * v))
        o["gravity_work"] = dt * float(np.sum(m * (v @ self.gravity)))
        o["boundary"] = float(np.sum(per_node[on_boundary]))
        o["kinetic_error"] = float(np.sum(per_node[~on_boundary]))

    def g2p(self, trial):
        """Record the state after G2P and before the return map (kinetic energy where G2P projected the grid's
        velocity, at the step's start positions, and where the particles moved to; trial elastic energy)."""
        o = self._open
        norms = self.mode_norms(trial)
        o["K_new"] = self.kinetic(trial, norms)
        o["K_projected"] = self.kinetic(trial, o["norms"]) if norms is not None else None  # only the norms move
        o["advection"] = (mode_energies(trial, norms) - mode_energies(trial, o["norms"]) if norms is not None
                          else np.zeros(trial.n))
        o["psi_trial"] = self.elastic(trial)
        o["Psi_trial"] = float(np.sum(o["psi_trial"]))

    def finish(self, new, rigid=None):
        """Book the return map and the bodies; close the step and return its entry."""
        o = self._open
        psi_new_p = self.elastic(new)
        psi_new, u_new, bodies_new = float(np.sum(psi_new_p)), self.potential(new), self.bodies_energy(rigid)
        entry = {
            "p2g_transfer": o["K_g0"] - o["K"],
            "boundary": o["boundary"],
            "g2p_transfer": (o["K_projected"] if o["K_projected"] is not None else o["K_new"]) - o["K_g1"],
            "advection": o["K_new"] - o["K_projected"] if o["K_projected"] is not None else 0.0,
            "plastic": psi_new - o["Psi_trial"],
            "rigid_bodies": bodies_new - o["bodies"],
            "integration": ((o["Psi_trial"] - o["Psi"] + o["internal_work"]) + (u_new - o["U"] + o["gravity_work"])
                            + o["kinetic_error"]),
            "internal_work": o["internal_work"],
            "gravity_work": o["gravity_work"],
            "energy_change": (o["K_new"] - o["K"]) + (psi_new - o["Psi"]) + (u_new - o["U"])
            + (bodies_new - o["bodies"]),
        }
        entry["closure"] = entry["energy_change"] - sum(entry[t] for t in TERMS)
        self.last = entry
        self.shares = {"id": new.id.copy(), "plastic": psi_new_p - o["psi_trial"], "advection": o["advection"]}
        self._open = {}
        return entry

    # ------------------------------------------------------------------ energies
    def kinetic(self, particles, norms):
        """Kinetic energy of the particles' velocity fields, float64: the sum of
        :func:`mpmref.observe.diagnostics.kinetic_parts` (velocity, affine and PolyPIC-mode parts), the modes' with the
        stencil norms ``norms`` (:meth:`mode_norms`)."""
        return sum(kinetic_parts(particles, self.inertia, norms))

    def mode_norms(self, particles):
        """The PolyPIC modes' stencil norms at the particles' positions
        (:func:`mpmref.observe.diagnostics.polypic_mode_norms`), or ``None`` for particles without modes."""
        return None if particles.modes is None else polypic_mode_norms(particles, self.scene.kernel, self.scene.grid)

    def elastic(self, particles):
        """Each particle's stored energy, float64 (n,) (:func:`mpmref.observe.diagnostics.elastic_energies`)."""
        return elastic_energies(particles, self.scene.material_list)

    def potential(self, particles):
        """Gravitational potential of the particles (:func:`mpmref.observe.diagnostics.gravitational_energy`)."""
        return gravitational_energy(particles, self.gravity)

    def bodies_energy(self, rigid):
        """The rigid bodies' kinetic and gravitational energy (0 without bodies)."""
        if rigid is None:
            return 0.0
        return float(np.sum(rigid_dynamics.mechanical_energy(self.scene.rigid_bodies, rigid, self.gravity)))

    def boundary_nodes(self, layout, time):
        """Mask over the rows of a grid state with sparse ``layout`` (dense C order when ``None``) of the nodes a
        wall band or a collider acts on at ``time``."""
        grid = self.scene.grid
        if layout is None:
            mask, index = self.wall_nodes.copy(), self.dense_index
        else:
            index = layout.node_index
            inside = np.all(index < np.array(grid.node_shape), axis=1)  # padding rows lie beyond the grid
            mask = inside & self.wall_nodes[np.where(inside[:, None], index, 0) @ grid.strides]
        for collider in self.scene.colliders:
            mask |= collider.shape.sdf(grid.origin + index * grid.dx - collider.velocity * time) <= 0.0
        return mask


def energy_scale(kinetic, elastic, potential, bodies=0.0):
    r"""The size of the energies a step's terms are differences of:
    :math:`S = K_p + \Psi + |U| + |E_{bodies}|`.

    Each term is a difference of such energies, each a float64 sum over particles or nodes, so its round-off is a
    multiple of the unit round-off times :math:`S` (Higham 2002, §4.2), whatever the term's own size: a term that
    theory puts at zero (PolyPIC's ``g2p_transfer``) is round-off of :math:`S`, not of itself. :math:`U`, whose
    zero is where the coordinates' origin is, enters with its magnitude.
    """
    return kinetic + elastic + abs(potential) + abs(bodies)


def accumulate(total, entry):
    """The cumulative ledger ``total`` (an array over :data:`RUN_COLUMNS`, or None before the first step) plus a
    step's ``entry`` (over :data:`COLUMNS`: a step exchanges no particles, the run books those,
    :func:`book_exchange`)."""
    step = np.array([0.0 if c in EXCHANGE_TERMS else entry[c] for c in RUN_COLUMNS])
    return step if total is None else np.asarray(total) + step


def book_exchange(total, columns, entered=0.0, left=0.0):
    r"""The cumulative ledger ``total`` (an array over ``columns``, or None before the first step) with the particles
    exchanged between two steps booked: the energy :math:`\sum_{p \in \text{in}} e_p` of those that ``entered`` to
    ``inflow``, minus the energy :math:`\sum_{p \in \text{out}} e_p` of those that ``left`` to ``outflow``, and both to
    ``energy_change``, which the diagnostics' :math:`E(t) - E_0` includes (``closure`` is unchanged: the terms still
    add up to it). float64; returns a new array.

    Docs: docs/energy_ledger.md#particles-that-enter-and-leave
    """
    booked = np.zeros(len(columns)) if total is None else np.array(total, dtype=np.float64)
    booked[columns.index("inflow")] += entered
    booked[columns.index("outflow")] -= left
    booked[columns.index("energy_change")] += entered - left
    return booked


def ledger_columns(total, columns=RUN_COLUMNS):
    """``diagnostics.csv`` columns ``ledger_<column>`` of a cumulative ledger over ``columns`` (zeros before the
    first step)."""
    values = np.zeros(len(columns)) if total is None else np.asarray(total)
    return {f"ledger_{c}": float(x) for c, x in zip(columns, values)}


def node_kinetic_remainder(m, v_tilde, v_star, v):
    r"""Per node, the kinetic energy change of the grid update that the force work at :math:`v_i` does not give.

    .. math::

        B_i = \tfrac12 m_i |v_i|^2 - \tfrac12 m_i |\tilde v_i|^2 - \Delta t\,(f_i + m_i g)\cdot v_i
            = R_i \cdot v_i - \tfrac12 m_i |v_i - \tilde v_i|^2, \qquad R_i = m_i (v_i - v_i^*)

    (the identity follows from :math:`m_i(v_i - \tilde v_i) = \Delta t (f_i + m_i g) + R_i`); written in the
    second form, which has no cancellation of kinetic energies. :math:`m_i` node mass, :math:`\tilde v_i`
    velocity after P2G, :math:`v_i^*` after the forces, :math:`v_i` after the walls and colliders, :math:`R_i`
    their impulse. Arrays (n,) and (n, d), float64; returns (n,).

    Docs: docs/energy_ledger.md#the-grid-update
    """
    R = m[:, None] * (v - v_star)
    jump = v - v_tilde
    return np.einsum("nd,nd->n", R, v) - 0.5 * m * np.einsum("nd,nd->n", jump, jump)



# ------------------------------------------------------------------------------------ asynchronous stepping
#: the terms of a level update: the synchronous step's, and what crosses level interfaces
LEVEL_TERMS = (*TERMS, "interface")
#: the terms of an asynchronous run's ledger: its level updates' and the particles it exchanged (:func:`book_exchange`)
ASYNC_TERMS = (*LEVEL_TERMS, *EXCHANGE_TERMS)
#: what an asynchronous run's entry holds (:class:`LevelLedger`)
ASYNC_COLUMNS = (*ASYNC_TERMS, *FLOWS, "energy_change", "closure")


class LevelLedger:
    r"""The energy ledger of asynchronous stepping: books the energy change of each level update's **active**
    particles, the only ones whose results count, and of the impulse registers of conservative interfaces.

    A level update (:func:`mpmref.steppers.pipeline.substep` with a level exchange) runs one substep over its active
    particles :math:`A` and their ghosts, with P2G summing each class apart (:mod:`mpmref.physics.interface`: node mass
    :math:`m^A_i`, momentum :math:`(mv)^A_i`, force :math:`f^A_i`, and the totals :math:`m_i, (mv)_i, f_i`). Each
    particle's state changes only in its own updates and when its register is applied, and its energy is its own,
    so the run's energy change between synchronised times is the sum of the active sets' changes and the
    registers'. :math:`A`'s change is split as a synchronous step's (:class:`EnergyLedger`), with every node
    quantity taken by :math:`A`'s share of the node mass, :math:`\mu^A_i = m^A_i / m_i`:

    .. math::

        \texttt{p2g\_transfer} = \tfrac12 \sum_i \frac{|(mv)^A_i|^2}{m^A_i} - K^A_p, \qquad
        \texttt{boundary} = \sum_{i \in \partial} \mu^A_i B_i, \qquad
        \texttt{g2p\_transfer} = K^{A,n+1}_p(x^n) - \tfrac12 \sum_i m^A_i |v_i|^2,

        \texttt{integration} = (\Psi^{A,tr} - \Psi^A + W^A_{int}) + (U^{A,n+1} - U^A + W^A_g)
            + \sum_{i \notin \partial} \mu^A_i B_i, \qquad
        W^A_{int} = \Delta t \sum_i f^A_i \cdot v_i, \quad W^A_g = \Delta t \sum_i m^A_i\, g \cdot v_i,

    ``advection`` and ``plastic`` over :math:`A`'s particles, and what :math:`A` takes from its ghosts:

    .. math::

        \texttt{interface} = \Big(\tfrac12 \sum_i m^A_i |\tilde v_i|^2 - \tfrac12 \sum_i \frac{|(mv)^A_i|^2}{m^A_i}\Big)
            + \Delta t \sum_i (\mu^A_i f_i - f^A_i) \cdot v_i \;+\; \sum_{\text{registers}} \Delta K_p,

    the kinetic energy :math:`A` gains by sharing the nodes' momentum with the ghosts (the averaging of the
    classes' velocities), the work of the ghosts' share of the node forces on :math:`A`, and the kinetic energy
    change of every register applied (:func:`mpmref.physics.interface.apply_registers`). Without ghosts the first
    two vanish and the entry is the synchronous step's. The terms telescope to :math:`A`'s measured change
    (``closure`` records the round-off), and :math:`\texttt{p2g\_transfer} \le 0` for PIC, APIC and PolyPIC class
    by class (Cauchy–Schwarz on :math:`A`'s own sums).

    A level update calls :meth:`start`, :meth:`grid`, :meth:`g2p` and :meth:`finish` in that order; :meth:`kicks`
    books a register application. Both add to :attr:`interval`, the entry of the synchronised interval under way
    (a dict over :data:`ASYNC_COLUMNS`, emptied by :meth:`begin`), which :meth:`close` keeps as ``last`` and adds to
    the run's cumulative ledger.

    Docs: docs/energy_ledger.md#asynchronous-runs
    """

    #: the columns of the run's cumulative ledger (what :func:`book_exchange` books into)
    columns = ASYNC_COLUMNS

    def __init__(self, scene):
        self.scene = scene
        self.nodes = EnergyLedger(scene)  # the boundary nodes, gravity and affine inertia, as a synchronous step's
        self.last = None
        self.interval = dict.fromkeys(ASYNC_COLUMNS, 0.0)
        self._open = {}

    # ------------------------------------------------------------------ a level update
    def start(self, particles, rigid, exchange):
        """Record the energies of the update's active particles (rows of ``particles`` whose class in ``exchange``, a
        :class:`~mpmref.steppers.pipeline.LevelExchange`, is active; ``rigid`` is ``None``: asynchronous stepping
        couples no rigid bodies)."""
        from ..physics.interface import ACTIVE

        rows = np.flatnonzero(np.asarray(exchange.classes) == ACTIVE)
        active = particles.select(rows)
        self._open = {"rows": rows, "x": active.x.copy(), "K": self.kinetic(active), "Psi": self.elastic(active),
                      "U": self.nodes.potential(active)}

    def grid(self, grid_state, v_grid, dt, time):
        r"""Book P2G, the boundary, the force work and the exchange with the ghosts, from the per-class node sums of
        ``grid_state`` (``class_sums``) and the node velocity ``v_grid`` after the grid update (same rows)."""
        from ..physics.interface import ACTIVE

        m = np.asarray(grid_state.mass, dtype=np.float64)
        has = m > 0
        m = m[has]
        d = grid_state.momentum.shape[1]
        own = np.asarray(grid_state.class_sums[ACTIVE], dtype=np.float64)[has]
        m_a, p_a, f_a = own[:, 0], own[:, 1:1 + d], own[:, 1 + d:]
        p = np.asarray(grid_state.momentum, dtype=np.float64)[has]
        f = np.asarray(grid_state.force, dtype=np.float64)[has]
        v = np.asarray(v_grid, dtype=np.float64)[has]
        v_tilde = p / m[:, None]
        g = self.nodes.gravity
        share = m_a / m
        remainder = share * node_kinetic_remainder(m, v_tilde, v_tilde + dt * (f / m[:, None] + g), v)
        on_boundary = self.nodes.boundary_nodes(grid_state.layout, time)[has]
        reached = m_a > 0
        own_kinetic = 0.5 * float(np.sum(np.einsum("nd,nd->n", p_a[reached], p_a[reached]) / m_a[reached]))
        o = self._open
        o["K_g0_own"] = own_kinetic
        o["mixing"] = 0.5 * float(np.sum(m_a * np.einsum("nd,nd->n", v_tilde, v_tilde))) - own_kinetic
        o["exchange_work"] = dt * float(np.sum((share[:, None] * f - f_a) * v))
        o["K_g1"] = 0.5 * float(np.sum(m_a * np.einsum("nd,nd->n", v, v)))
        o["internal_work"] = dt * float(np.sum(f_a * v))
        o["gravity_work"] = dt * float(np.sum(m_a * (v @ g)))
        o["boundary"] = float(np.sum(remainder[on_boundary]))
        o["kinetic_error"] = float(np.sum(remainder[~on_boundary]))

    def g2p(self, trial):
        """Record the active particles after G2P, before the return map (``trial``, every row of the update)."""
        o = self._open
        active = trial.select(o["rows"])
        o["K_projected"] = self.kinetic(active.with_(x=o["x"])) if active.modes is not None else None
        o["K_new"] = self.kinetic(active)
        o["Psi_trial"] = self.elastic(active)

    def finish(self, new, rigid=None):
        """Book the return map, close the update and add its entry to :attr:`interval`; returns the entry (``rigid``
        is ``None``: asynchronous stepping couples no rigid bodies)."""
        o = self._open
        active = new.select(o["rows"])
        psi_new, u_new = self.elastic(active), self.nodes.potential(active)
        projected = o["K_projected"] if o["K_projected"] is not None else o["K_new"]
        entry = {
            "p2g_transfer": o["K_g0_own"] - o["K"],
            "boundary": o["boundary"],
            "g2p_transfer": projected - o["K_g1"],
            "advection": o["K_new"] - projected,
            "plastic": psi_new - o["Psi_trial"],
            "rigid_bodies": 0.0,
            "integration": ((o["Psi_trial"] - o["Psi"] + o["internal_work"]) + (u_new - o["U"] + o["gravity_work"])
                            + o["kinetic_error"]),
            "interface": o["mixing"] + o["exchange_work"],
            "internal_work": o["internal_work"],
            "gravity_work": o["gravity_work"],
            "energy_change": (o["K_new"] - o["K"]) + (psi_new - o["Psi"]) + (u_new - o["U"]),
        }
        entry["closure"] = entry["energy_change"] - sum(entry[t] for t in LEVEL_TERMS)
        self._add(entry)
        self._open = {}
        return entry

    # ------------------------------------------------------------------ registers and intervals
    def kicks(self, particles, idx, apply):
        """Book the registers of the particles ``idx`` of ``particles`` applied by ``apply()`` (in place): their
        kinetic energy change, to ``interface``. Only velocity and affine matrix change."""
        before = self.kinetic(particles.select(idx), modes=False)
        apply()
        change = self.kinetic(particles.select(idx), modes=False) - before
        self._add({"interface": change, "energy_change": change})

    def begin(self):
        """A synchronised interval begins: nothing is booked to it yet."""
        self.interval = dict.fromkeys(ASYNC_COLUMNS, 0.0)

    def close(self, total):
        """Close the synchronised interval just ended: its entry is kept as ``last``, and the cumulative ledger
        ``total`` (an array over :data:`ASYNC_COLUMNS`, or None before the first interval) plus it is returned."""
        self.last = self.interval
        self.begin()
        step = np.array([self.last[c] for c in ASYNC_COLUMNS])
        return step if total is None else np.asarray(total) + step

    def _add(self, entry):
        for key, value in entry.items():
            self.interval[key] += value

    def elastic(self, particles):
        """The particles' stored energy (:func:`mpmref.observe.diagnostics.elastic_energy`), float64."""
        from .diagnostics import elastic_energy

        return elastic_energy(particles, self.scene.material_list)

    def kinetic(self, particles, modes=True):
        """Kinetic energy of the particles' velocity fields (:func:`mpmref.observe.diagnostics.kinetic_parts`), float64;
        with ``modes=False`` without the PolyPIC modes' part."""
        from .diagnostics import kinetic_parts, polypic_mode_norms

        if not modes:
            particles = particles.with_(modes=None)
        norms = (polypic_mode_norms(particles, self.scene.kernel, self.scene.grid) if particles.modes is not None
                 else None)
        return sum(kinetic_parts(particles, self.nodes.inertia, norms))
