r"""The MPM step, written once: the stages of a backend composed in order.

.. math::

    \text{prepare} \to [\text{CPIC contact}] \to \text{P2G} \to [\text{hooks on } (m_i, (mv)_i, f_i)]
    \to \text{grid update} \to \text{G2P} \to \text{return map} \to [\text{rigid step}]

Every stepper advances particles with :func:`substep` (the synchronous one for all particles at once, the
asynchronous one for the particles of a group of blocks plus their ghosts). :class:`Hooks` let a caller
add what a special step needs without rewriting it: a body force per unit mass, and grid folds applied to
the grid state before the grid update (e.g. the symmetry planes of the convergence case). A scene with
rigid bodies couples them by CPIC (Hu et al. 2018 §4–5; docs/cpic.md) in the same step: the bracketed
stages, and P2G and G2P that respect compatibility.
"""

from dataclasses import dataclass

import numpy as np

from ..backends.base import FUSED_BACKEND_STAGES
from ..physics.interface import momentum_share
from ..physics.kernels import compute_stencil
from ..physics.rigid_dynamics import apply_impulses, begin_step, end_step


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


def substep(backend, particles, dt, time, hooks=NO_HOOKS, rigid=None, ledger=None):
    """One symplectic-Euler MPM step of ``particles`` from ``time`` with step ``dt``; returns new particles.

    The only place the stages are composed: prepare, P2G, the hooks, grid update (gravity, walls and
    colliders at ``time``), G2P and the return map. ``particles`` is not modified.

    With rigid bodies (``rigid``, a :class:`~mpmref.physics.rigid_dynamics.RigidState`), the step couples
    them by CPIC and returns ``(particles, rigid)``: the colored distance field of the bodies where they
    are and the particles' sticky tags (``cpic_contact``), P2G to compatible nodes only, the impulses of
    incompatible nodes on the bodies, G2P with ghost velocities and the penalty (``cpic_g2p``), then the
    rigid step (docs/cpic.md of the reference code, written up in docs/cpic.md).

    A ``ledger`` (:class:`~mpmref.ledger.EnergyLedger`) observes the stages' outputs and books the step's
    energy change by stage (docs/energy_ledger.md); it changes nothing the stages compute.
    """
    scene = backend.scene
    with backend.running(particles.n):
        if ledger is not None:
            ledger.start(particles, rigid)
        prepared = backend.prepare(particles)  # the stencil is shared: particles do not move until G2P
        contact = None
        if rigid is not None:
            rigid = begin_step(scene.rigid_bodies, rigid, time, dt)
            particles, contact = backend.cpic_contact(particles, prepared, rigid, dt)
        if contact is not None:
            grid_state = backend.p2g(particles, prepared, contact)
        elif folds_force(backend, hooks, ledger):
            grid_state = backend.p2g_fused(particles, dt, prepared)
        else:
            grid_state = backend.p2g(particles, prepared)
        if hooks.body_force is not None or hooks.grid_folds:
            apply_hooks(hooks, grid_state, particles, scene, time)
        v_grid, v_tilde = backend.grid_update(grid_state, dt, time)
        if ledger is not None:
            ledger.grid(grid_state, v_grid, dt, time)
        if contact is None:
            new = _observed(ledger, backend.g2p(particles, v_grid, v_tilde, dt, prepared), backend.return_map)
        else:
            new, rigid = _coupled_g2p(backend, particles, prepared, contact, grid_state, v_grid, rigid, dt, time,
                                      ledger)
        if ledger is not None:
            ledger.finish(new, rigid)
        return new if contact is None else (new, rigid)


def folds_force(backend, hooks, ledger):
    """Whether a step folds the internal force into P2G (the backend's ``p2g_fused``, the optional stage of
    :class:`~mpmref.backends.base.FusedBackend`; looked up by name, as an ``isinstance`` test of the protocol costs
    tens of microseconds a step): when the backend can, the scheme's G2P does not need the grid
    velocity before the force (not FLIP), and nothing reads the force apart (no hook, no energy ledger; CPIC's
    coupled P2G is never fused). The result is the same up to round-off (docs/performance.md#the-fused-p2g)."""
    return (callable(getattr(backend, FUSED_BACKEND_STAGES[0], None)) and not backend.scene.transfer.flip
            and ledger is None and hooks.body_force is None and not hooks.grid_folds)


def _observed(ledger, trial, return_map):
    """``return_map(trial)``, with the ledger shown the G2P output ``trial`` first (a backend may reuse its arrays)."""
    if ledger is not None:
        ledger.g2p(trial)
    return return_map(trial)


def interface_substep(backend, particles, classes, dt, time, kicks=True, ledger=None):
    r"""One level update of asynchronous stepping by classes: :func:`substep` of ``particles`` (active, finer ghosts
    and coarser shadows, by ``classes``; :mod:`mpmref.physics.interface`) with P2G summing each class apart, which
    with conservative interfaces (``kicks``) also returns the impulses of impulse refluxing.

    P2G sums each class apart in the same pass; the grid update uses their totals; the node kicks
    (the backend's ``interface_kicks``, :func:`~mpmref.physics.interface.interface_kicks`) are gathered in the
    same G2P pass. Returns
    ``(particles, dP, dL)``: the new particles, and for each one the impulse :math:`\delta P_p` and its moment
    :math:`\delta L_p` about the origin ((n, 1) in 2D, (n, 3) in 3D; zero for the finer ghosts), or ``None`` for
    both without ``kicks``. A ``ledger`` (:class:`~mpmref.ledger.LevelLedger`) books the active particles' energy
    change from the per-class sums. No hooks, no rigid bodies (asynchronous stepping takes neither).
    """
    scene = backend.scene
    with backend.running(particles.n):
        if ledger is not None:
            ledger.start(particles, classes)
        prepared = backend.prepare(particles)
        grid_state = backend.p2g(particles, prepared, classes=classes)
        v_grid, v_tilde = backend.grid_update(grid_state, dt, time)
        if ledger is not None:
            ledger.grid(grid_state, v_grid, dt, time)
        dP = dL = None
        if kicks:
            node_kicks = backend.interface_kicks(grid_state, dt, momentum_share(scene.transfer))
            trial, (dP, dL) = backend.g2p(particles, v_grid, v_tilde, dt, prepared, kicks=(classes, node_kicks))
        else:
            trial = backend.g2p(particles, v_grid, v_tilde, dt, prepared)
        if ledger is not None:
            ledger.g2p(trial)
        new = backend.return_map(trial)
        if ledger is not None:
            ledger.finish(new)
        return new, dP, dL


def apply_hooks(hooks, grid_state, particles, scene, time):
    """The body force and grid folds of ``hooks``, applied to ``grid_state`` in place.

    Hooks see dense C-ordered node arrays; a sparse grid state (one with a ``layout``) is handed to them as
    :meth:`~mpmref.state.GridState.dense` and takes the result back on its active nodes (the only ones G2P
    reads).
    """
    dense = grid_state.dense()
    if hooks.body_force is not None:
        f = nodal_body_force(particles, scene.grid, scene.kernel, hooks.body_force(particles, time))
        dense.force += f.astype(dense.force.dtype)
    for fold in hooks.grid_folds:
        fold(dense, scene.grid)
    grid_state.assign_dense(dense)


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
