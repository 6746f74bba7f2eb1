r"""The MPM step, written once: the stages of a backend composed in order.

.. math::

    \text{prepare} \to \text{P2G} \to [\text{hooks on } (m_i, (mv)_i, f_i)] \to \text{grid update}
    \to \text{G2P} \to \text{return map}

Every stepper advances particles with :func:`substep` (the synchronous one for all particles at once, the
asynchronous one for the particles of a group of blocks plus their ghosts). :class:`Hooks` let a caller
add what a special step needs without rewriting it: a body force per unit mass, and grid folds applied to
the grid state before the grid update (e.g. the symmetry planes of the convergence case).
"""

from dataclasses import dataclass

import numpy as np

from ..physics.kernels import compute_stencil


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


def substep(backend, particles, dt, time, hooks=NO_HOOKS):
    """One symplectic-Euler MPM step of ``particles`` from ``time`` with step ``dt``; returns new particles.

    The only place the stages are composed: prepare, P2G, the hooks, grid update (gravity, walls and
    colliders at ``time``), G2P and the return map. ``particles`` is not modified.
    """
    scene = backend.scene
    with backend.running(particles.n):
        prepared = backend.prepare(particles)  # the stencil is shared: particles do not move until G2P
        grid_state = backend.p2g(particles, prepared)
        if hooks.body_force is not None:
            f = nodal_body_force(particles, scene.grid, scene.kernel, hooks.body_force(particles, time))
            grid_state.force += f.astype(grid_state.force.dtype)
        for fold in hooks.grid_folds:
            fold(grid_state, scene.grid)
        v_grid, v_tilde = backend.grid_update(grid_state, dt, time)
        return backend.return_map(backend.g2p(particles, v_grid, v_tilde, dt, prepared))
