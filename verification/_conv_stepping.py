r"""The convergence case's own stepping loop: the backend's stages with a boundary treatment and a body force.

The engine's walls project node velocities (sticky, slip, separate); none of them expresses a
*symmetry plane*, which the fixed end of the vibrating bar and the faces of the manufactured solution
need for second-order accuracy. So the case steps the backend's stages itself::

    P2G  ->  add the body force  ->  boundary treatment on (m_i, (mv)_i, f_i)  ->  grid update  ->  G2P

and leaves the engine files untouched. Two boundary treatments:

``mirror`` (the odd ghost treatment)
    Every particle has a mirror image across the plane: position reflected, the normal components of
    velocity and affine matrix negated (:math:`v^* = Mv`, :math:`C^* = MCM`, :math:`M = I - 2nn^T`),
    the same stress up to the reflection. Its contributions to node :math:`i` are the reflections of the
    real particle's contributions to the mirror node :math:`i^*`, so after P2G

    .. math::

        m_i \leftarrow m_i + m_{i^*}, \qquad (mv)_i \leftarrow (mv)_i + M (mv)_{i^*}, \qquad
        f_i \leftarrow f_i + M f_{i^*}

    on the material side (the plane's own node adds its reflection once), and the ghost nodes take the
    reflected values, :math:`(m, mv, f)_{i^*} = (m_i, M(mv)_i, Mf_i)`. This is exactly the grid state of
    the domain doubled by reflection, with no boundary condition at all, so the normal velocity of the
    plane's nodes is zero and nothing else is constrained. (``tests/test_verify_convergence.py`` checks
    the equivalence against the doubled bar run by the engine.)

``zero`` (the crude treatment)
    Momentum and force are zeroed at every node on or beyond the plane, which is what a sticky wall band
    does. It pins the material over the stencil's half-width, an :math:`O(\Delta x)` shift of the
    boundary, and drops the convergence rate to one.
"""

import numpy as np

from mpmref.backends.numpy.transfers import node_index, scatter
from mpmref.physics.kernels import compute_stencil

TREATMENTS = ("mirror", "zero")


def _node_views(gs, grid):
    """Mass, momentum and force reshaped to the node lattice (views that write through)."""
    shape = grid.node_shape
    d = grid.dim
    return (gs.mass.reshape(shape), gs.momentum.reshape(shape + (d,)), gs.force.reshape(shape + (d,)))


def _reflection(axis, d):
    """Diagonal of :math:`M = I - 2nn^T` for the normal along ``axis``."""
    m = np.ones(d)
    m[axis] = -1.0
    return m


def mirror(gs, grid, plane):
    r"""Fold the grid state across a symmetry plane and fill its ghost nodes (the ``mirror`` treatment).

    ``gs`` (a :class:`~mpmref.state.GridState`) is modified in place. Node ``plane.node + s j`` (material
    side, :math:`s = \pm 1`) gains the reflection of node ``plane.node - s j`` for
    :math:`j = 0 \dots g`, then the ghost nodes ``plane.node - s j`` (:math:`j \ge 1`) are set to the
    reflection of their images; :math:`g` is the number of ghost layers.
    """
    s = 1 if plane.side == "low" else -1
    n_axis = grid.node_shape[plane.axis]
    layers = plane.node if s == 1 else n_axis - 1 - plane.node
    j = np.arange(layers + 1)
    real, ghost = plane.node + s * j, plane.node - s * j
    reflect = _reflection(plane.axis, grid.dim)
    for array, sign in zip(_node_views(gs, grid), (1.0, reflect, reflect)):
        lattice = np.moveaxis(array, plane.axis, 0)
        lattice[real] += sign * lattice[ghost]
        lattice[ghost[1:]] = sign * lattice[real[1:]]


def zero_beyond(gs, grid, plane):
    """Zero momentum and force at the plane's node and every node beyond it (the ``zero`` treatment)."""
    _, momentum, force = _node_views(gs, grid)
    n_axis = grid.node_shape[plane.axis]
    beyond = np.arange(plane.node + 1) if plane.side == "low" else np.arange(plane.node, n_axis)
    for array in (momentum, force):
        np.moveaxis(array, plane.axis, 0)[beyond] = 0.0


BOUNDARY = {"mirror": mirror, "zero": zero_beyond}


def body_force_on_grid(particles, grid, kernel, b):
    r"""External node force :math:`f^{ext}_i = \sum_p w_{ip}\, m_p\, b_p` of a body force per unit mass ``b`` (n, d).

    The usual particle-carried external force of MPM (Sulsky, Chen & Schreyer 1994 §3), as Uintah's MMS
    tests apply it: :math:`b_p = b(X_p, t^n)` at the particle's material point.
    """
    st = compute_stencil(kernel, particles.x, grid.origin, grid.dx)
    f = np.zeros((grid.n_nodes, grid.dim))
    mb = particles.mass[:, None] * b
    for offset in st.offsets:
        f += scatter(node_index(st, offset, grid), st.node_weight(offset)[:, None] * mb, grid.n_nodes)
    return f


def step(backend, particles, dt, time, planes, treatment, body_force=None):
    """One symplectic-Euler MPM step from ``time`` with the boundary ``treatment`` on ``planes``.

    ``body_force`` is ``None`` or the body force per unit mass (n, d) of each particle at ``time``.
    Uses only the backend's stages (``p2g``, ``grid_update``, ``g2p``, ``return_map``), so any backend
    with the reference's stage interface runs it. Returns the new particles.
    """
    grid = backend.scene.grid
    gs = backend.p2g(particles)
    if body_force is not None:
        gs.force += body_force_on_grid(particles, grid, backend.scene.kernel, body_force).astype(gs.force.dtype)
    for plane in planes:
        BOUNDARY[treatment](gs, grid, plane)
    v_grid, v_tilde = backend.grid_update(gs, dt, time)
    return backend.return_map(backend.g2p(particles, v_grid, v_tilde, dt))
