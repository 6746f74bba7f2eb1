r"""The convergence case's step: the stepper's one pipeline with a boundary treatment and a body force as hooks.

The engine's walls project node velocities (sticky, slip, separate); none of them expresses a
*symmetry plane*, which the fixed end of the vibrating bar and the faces of the manufactured solution
need for second-order accuracy. So the case adds them through :class:`mpmref.steppers.Hooks`::

    P2G  ->  body force (hook)  ->  boundary treatment on (m_i, (mv)_i, f_i) (grid folds)  ->  grid update  ->  G2P

Two boundary treatments:

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

from functools import partial

import numpy as np

from mpmref.steppers import Hooks, substep

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


def hooks(planes, treatment, body_force=None):
    """The :class:`~mpmref.steppers.Hooks` of the boundary ``treatment`` on ``planes`` and a body force.

    ``body_force`` is ``None`` or ``body_force(particles, time) -> (n, d)``, force per unit mass.
    """
    folds = tuple(partial(_fold, BOUNDARY[treatment], plane) for plane in planes)
    return Hooks(body_force=body_force, grid_folds=folds)


def _fold(treatment, plane, gs, grid):
    treatment(gs, grid, plane)


def advance(backend, particles, dt, time, planes, treatment, body_force=None):
    """One MPM step from ``time`` with the boundary ``treatment`` on ``planes`` (see :func:`hooks`).

    Uses only the backend's stages through :func:`mpmref.steppers.substep`, so any backend runs it.
    Returns the new particles.
    """
    return substep(backend, particles, dt, time, hooks(planes, treatment, body_force))
