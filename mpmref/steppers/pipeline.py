r"""The MPM step, written once: the stages of a backend composed in order.

.. math::

    \text{prepare} \to [\text{CPIC contact}] \to \text{P2G} \to [\text{hooks on } (m_i, (mv)_i, f_i)]
    \to \text{grid update} \to \text{G2P} \to \text{return map} \to [\text{rigid step}]

Every stepper advances particles with :func:`substep` (the synchronous one for all particles at once, the
asynchronous one for the particles of a level plus their ghosts: rows of arrays it keeps, advanced in place).
:class:`Hooks` let a caller add what a special step needs without rewriting it: a body force per unit mass, and
grid folds applied to the grid state before the grid update (e.g. the symmetry planes of the convergence case). A
scene with rigid bodies couples them by CPIC (Hu et al. 2018 §4–5; docs/cpic.md) in the same step: the bracketed
stages, and P2G and G2P that respect compatibility.
"""

import inspect
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from ..backends.base import FUSED_BACKEND_STAGES, steps_rows
from ..physics.interface import momentum_share
from ..physics.kernels import compute_stencil
from ..rigid.dynamics import apply_impulses, begin_step, end_step
from ..state import EVOLVING_FIELDS


@dataclass(frozen=True)
class Hooks:
    r"""Additions to the standard step.

    Attributes
    ----------
    body_force : callable or None
        ``body_force(particles, time) -> (n, d)``: force per unit mass :math:`b_p` at each particle. It
        enters the node force as :math:`f^{ext}_i = \sum_p w_{ip} m_p b_p` (:func:`nodal_body_force`).
    grid_folds : tuple of callables
        ``fold(grid_state, grid)``: modify node mass, momentum and force in place after P2G.
    """

    body_force: object = None
    grid_folds: tuple = ()


NO_HOOKS = Hooks()


@dataclass
class LevelExchange:
    r"""The particle classes of a level update of asynchronous stepping (:mod:`mpmref.physics.interface`): active
    particles, finer ghosts and coarser shadows, ``classes`` (n,) of :data:`~mpmref.physics.interface.ACTIVE`,
    ``FINER``, ``COARSER``.

    A :func:`substep` given one sums each class apart in P2G (never fused: the kicks and the ledger need each
    class's force), and with ``kicks`` (conservative interfaces, impulse refluxing) gathers the node kicks in G2P:
    it leaves each particle's impulse :math:`\delta P_p` and its moment :math:`\delta L_p` about the origin in
    ``impulses`` ((n, d) and (n, 1) in 2D or (n, 3) in 3D; zero for the finer ghosts).
    """

    classes: np.ndarray
    kicks: bool
    impulses: tuple | None = None


def nodal_body_force(particles, grid, kernel, b):
    r"""External node force :math:`f^{ext}_i = \sum_p w_{ip}\, m_p\, b_p` of a body force per unit mass ``b`` (n, d).

    The particle-carried external force of MPM (Sulsky, Chen & Schreyer 1994 §3). Returns (N, d) float64.
    """
    st = compute_stencil(kernel, particles.x.astype(np.float64), grid.origin, grid.dx)
    mb = particles.mass[:, None] * b
    f = np.zeros((grid.n_nodes, grid.dim))
    for offset in st.offsets:
        idx = (st.base + offset) @ grid.strides
        wmb = st.node_weight(offset)[:, None] * mb
        for a in range(grid.dim):
            f[:, a] += np.bincount(idx, weights=wmb[:, a], minlength=grid.n_nodes)
    return f


def substep(backend, particles, dt, time, hooks=NO_HOOKS, rigid=None, ledger=None, exchange=None, rows=None,
            out=None, wave_speed=None):
    """One symplectic-Euler MPM step of ``particles`` from ``time`` with step ``dt``; returns new particles.

    The only place the stages are composed, for every stepper: prepare, P2G, the hooks, grid update (gravity,
    walls and colliders at ``time``), G2P and the return map. ``particles`` is not modified. The extensions of
    the step are its arguments: ``hooks`` (a body force and grid folds), ``rigid`` (CPIC coupling), ``ledger``
    (an observer), ``exchange`` (a level update of asynchronous stepping by particle classes,
    :class:`LevelExchange`: P2G by classes, the body-force hook added class by class, and with conservative
    interfaces the kicks gathered in G2P, left in ``exchange.impulses``) and ``rows``.

    With ``rows`` (an int64 index array; no ``rigid``), the step advances the particles ``rows`` of ``particles``
    only, writes their new state into the same rows of ``out`` (default ``particles``: in place) and returns
    ``None`` (``exchange.classes`` and ``exchange.impulses`` then follow the order of ``rows``): a level update of
    asynchronous stepping on the arrays it keeps. A backend with the row stages
    (:class:`~mpmref.backends.base.RowBackend`) runs them where the particles are; any other backend, and a step
    with hooks or a ledger, goes through the adapter :func:`gathered_substep`, which gathers the rows into new
    particles, steps them as above and writes the results back (the same arithmetic, so the same bits).

    With rigid bodies (``rigid``, a :class:`~mpmref.rigid.dynamics.RigidState`), the step couples
    them by CPIC and returns ``(particles, rigid)``: the colored distance field of the bodies where they
    are and the particles' sticky tags (``cpic_contact``), P2G to compatible nodes only, the impulses of
    incompatible nodes on the bodies, G2P with ghost velocities and the penalty (``cpic_g2p``), then the
    rigid step (docs/cpic.md of the reference code, written up in docs/cpic.md).

    A ``ledger`` (:class:`~mpmref.observe.ledger.EnergyLedger`, or :class:`~mpmref.observe.ledger.LevelLedger` for a
    level update) observes the stages' outputs and books the step's energy change by stage (docs/energy_ledger.md); it
    changes nothing the stages compute.

    With ``wave_speed`` (a float64 array with a row per particle; no ``rigid``; a backend of which
    :func:`~mpmref.backends.base.gives_wave_speeds` holds), the return map's second output: each stepped particle's
    wave speed :math:`c_p` in its new state, written into its row (the rows ``rows``, or every row), what asynchronous
    stepping's level rule reads at the particle's next step boundary.
    """
    if rows is not None and (ledger is not None or hooks.body_force is not None or hooks.grid_folds
                             or not steps_rows(backend)):
        return gathered_substep(backend, particles, rows, dt, time, hooks, ledger, exchange, out, wave_speed)
    scene = backend.scene
    with backend.running(particles.n if rows is None else rows.size):
        if ledger is not None:
            ledger.start(particles, rigid, exchange)
        # the stencil is shared: particles do not move until G2P
        prepared = backend.prepare(particles) if rows is None else backend.prepare_rows(particles, rows)
        contact = None
        if rigid is not None:
            rigid = begin_step(scene.rigid_bodies, rigid, time, dt)
            particles, contact = backend.cpic_contact(particles, prepared, rigid, dt)
        grid_state = _p2g(backend, particles, prepared, dt, hooks, ledger, contact, exchange)
        if hooks.body_force is not None or hooks.grid_folds:
            apply_hooks(hooks, grid_state, particles, scene, time, exchange)
        v_grid, v_tilde = backend.grid_update(grid_state, dt, time)
        if ledger is not None:
            ledger.grid(grid_state, v_grid, dt, time)
        kicks = None
        if exchange is not None and exchange.kicks:
            kicks = (exchange.classes, backend.interface_kicks(grid_state, dt, momentum_share(scene.transfer)))
        if rows is not None:
            out = particles if out is None else out
            impulses = backend.g2p_rows(particles, v_grid, v_tilde, dt, prepared, out, kicks)
            if wave_speed is None:
                backend.return_map_rows(out, rows)
            else:
                backend.return_map_rows(out, rows, wave_speed=wave_speed)
            if kicks is not None:
                exchange.impulses = impulses
            return None
        return_map = backend.return_map
        if wave_speed is not None:
            def return_map(trial):
                return backend.return_map(trial, wave_speed=wave_speed)
        if kicks is not None:
            trial, exchange.impulses = backend.g2p(particles, v_grid, v_tilde, dt, prepared, kicks=kicks)
            new = _observed(ledger, trial, return_map)
        elif contact is None:
            new = _observed(ledger, backend.g2p(particles, v_grid, v_tilde, dt, prepared), return_map)
        else:
            new, rigid = _coupled_g2p(backend, particles, prepared, contact, grid_state, v_grid, rigid, dt, time,
                                      ledger)
        if ledger is not None:
            ledger.finish(new, rigid)
        return new if contact is None else (new, rigid)


def _p2g(backend, particles, prepared, dt, hooks, ledger, contact, exchange):
    """The P2G of :func:`substep`: CPIC's to compatible nodes, by classes for a level update, fused where
    :func:`folds_force` allows (for a level update, where also :func:`fuses_classes`), else plain."""
    if contact is not None:
        return backend.p2g(particles, prepared, contact)
    fused = folds_force(backend, hooks, ledger)
    if exchange is None:
        return backend.p2g_fused(particles, dt, prepared) if fused else backend.p2g(particles, prepared)
    if fused and fuses_classes(backend):
        return backend.p2g_fused(particles, dt, prepared, classes=exchange.classes)
    return backend.p2g(particles, prepared, classes=exchange.classes)


def gathered_substep(backend, particles, rows, dt, time, hooks=NO_HOOKS, ledger=None, exchange=None, out=None,
                     wave_speed=None):
    """:func:`substep` of the particles ``rows`` of ``particles`` through the plain stages: the rows gathered into
    new particles (in the order of ``rows``), one step of them, and their evolving fields (and with ``wave_speed``,
    their wave speeds) written into the same rows of ``out`` (default ``particles``) and of ``wave_speed``. The
    adapter that steps rows on a backend without the row stages (:class:`~mpmref.backends.base.RowBackend`); the
    particles it steps are the group such a backend would see, in the same order, so its results are the row
    stages' bit for bit."""
    speeds = None if wave_speed is None else np.empty(rows.size)
    new = substep(backend, particles.select(rows), dt, time, hooks, ledger=ledger, exchange=exchange,
                  wave_speed=speeds)
    out = particles if out is None else out
    for name in EVOLVING_FIELDS:
        if (array := getattr(new, name)) is not None:
            getattr(out, name)[rows] = array
    if wave_speed is not None:
        wave_speed[rows] = speeds


def folds_force(backend, hooks, ledger):
    """Whether a step folds the internal force into P2G (the backend's ``p2g_fused``, the optional stage of
    :class:`~mpmref.backends.base.FusedBackend`; looked up by name, as an ``isinstance`` test of the protocol costs
    tens of microseconds a step): when the backend can, the scheme's G2P does not need the grid
    velocity before the force (not FLIP), and nothing reads the force apart (no hook, no energy ledger; CPIC's
    coupled P2G is never fused). The result is the same up to round-off (docs/performance.md#the-fused-p2g)."""
    return (callable(getattr(backend, FUSED_BACKEND_STAGES[0], None)) and not backend.scene.transfer.flip
            and ledger is None and hooks.body_force is None and not hooks.grid_folds)


def fuses_classes(backend):
    """Whether ``backend``'s ``p2g_fused`` also sums particle classes apart (it takes ``classes``, as the Numba
    backend's does): then a level update by classes folds the force too when :func:`folds_force` allows, and the
    kicks of conservative interfaces come from the folded momentum (the scheme's G2P hands out all of it: not
    FLIP). Looked up once per backend class."""
    return _fused_takes_classes(type(backend))


@lru_cache(maxsize=None)
def _fused_takes_classes(cls):
    fused = getattr(cls, FUSED_BACKEND_STAGES[0], None)
    return callable(fused) and "classes" in inspect.signature(fused).parameters


def _observed(ledger, trial, return_map):
    """``return_map(trial)``, with the ledger shown the G2P output ``trial`` first (a backend may reuse its arrays)."""
    if ledger is not None:
        ledger.g2p(trial)
    return return_map(trial)


def apply_hooks(hooks, grid_state, particles, scene, time, exchange=None):
    """The body force and grid folds of ``hooks``, applied to ``grid_state`` in place.

    Hooks see dense C-ordered node arrays; a sparse grid state (one with a ``layout``) is handed to them as
    :meth:`~mpmref.state.GridState.dense` and takes the result back on its active nodes (the only ones G2P
    reads). In a level update by classes (``exchange``), the body force of each class's particles goes into that
    class's sums too (the kicks of conservative interfaces exchange every force), and the total is their sum;
    grid folds act on the node totals only, so the asynchronous stepper refuses them.
    """
    dense = grid_state.dense()
    if hooks.body_force is not None:
        b = hooks.body_force(particles, time)
        if exchange is None:
            f = nodal_body_force(particles, scene.grid, scene.kernel, b)
        else:
            f = add_class_body_forces(grid_state, particles, scene, b, exchange.classes)
        dense.force += f.astype(dense.force.dtype)
    for fold in hooks.grid_folds:
        fold(dense, scene.grid)
    grid_state.assign_dense(dense)


def add_class_body_forces(grid_state, particles, scene, b, classes):
    """Add each particle class's node body force (:func:`nodal_body_force` of its particles) to its rows of
    ``grid_state.class_sums`` (in the state's layout); returns their dense total."""
    d = particles.dim
    total = np.zeros((scene.grid.n_nodes, d))
    for k in range(grid_state.class_sums.shape[0]):
        rows = np.flatnonzero(classes == k)
        if rows.size == 0:
            continue
        f = nodal_body_force(particles.select(rows), scene.grid, scene.kernel, b[rows])
        total += f
        own = f if grid_state.layout is None else grid_state.layout.from_dense(f)
        grid_state.class_sums[k, :, 1 + d:] += own.astype(grid_state.class_sums.dtype)
    return total


def _coupled_g2p(backend, particles, prepared, contact, grid_state, v_grid, rigid, dt, time, ledger=None):
    r"""The CPIC end of :func:`substep`: impulses, G2P with ghosts, the rigid step; returns ``(particles, rigid)``.

    The impulses that incompatible nodes did not take in P2G change the dynamic bodies' velocities before
    G2P (the reference's order), or, with ``scene.cpic.momentum_exact``, after it: then the bodies' velocity
    is the same in P2G and G2P, and particles plus bodies keep their total linear momentum exactly
    (docs/cpic.md). The penalty's impulses are applied after G2P; then every body moves to ``time + dt``.
    """
    bodies, scene = backend.scene.rigid_bodies, backend.scene
    J, L = backend.cpic_impulses(grid_state, contact, rigid, dt)
    exact = scene.cpic.momentum_exact
    seen = rigid if exact else apply_impulses(bodies, rigid, J, L)  # the bodies G2P sees
    new, (J_pen, L_pen) = backend.cpic_g2p(particles, v_grid, dt, prepared, contact, seen)
    new = _observed(ledger, new, backend.return_map)
    after = (J + J_pen, L + L_pen) if exact else (J_pen, L_pen)
    return new, end_step(bodies, apply_impulses(bodies, seen, *after), time, dt, scene.gravity)
