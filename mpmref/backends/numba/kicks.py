r"""The node kicks of conservative level interfaces (impulse refluxing, :mod:`mpmref.physics.interface`), compiled:
the per-class node sums of a P2G by particle classes summed back (:func:`class_totals`) and the kicks of each
node (:func:`node_kicks`), written once for 2D and 3D (the loops run over the columns of the node rows). Each
dimension's kick gather, which hands the kicks to the particles, is its transfer kernels' ``kick_gather_kernel``
(:mod:`.transfers2d`, :mod:`.transfers3d`).
"""

import numpy as np
from numba import njit


@njit(cache=True)
def class_totals(class_sums, total):
    """``total[r] = class_sums[0, r] + class_sums[1, r] + class_sums[2, r]``: the node sums of a P2G by
    particle classes (:mod:`mpmref.physics.interface`), row by row (serial: a pass over memory, which a second
    thread hardly speeds up, and a parallel loop takes seconds longer to compile)."""
    for r in range(total.shape[0]):
        for c in range(total.shape[1]):
            total[r, c] = class_sums[0, r, c] + class_sums[1, r, c] + class_sums[2, r, c]


@njit(cache=True)
def node_kicks(class_sums, dt, kappa, kicks):
    r"""The node kicks of impulse refluxing, row by row (the equations of
    :func:`mpmref.physics.interface.interface_kicks`): ``kicks[0]`` :math:`= -I_i(A \leftarrow F)/m^A_i` for
    the active particles, ``kicks[1]`` :math:`= -I_i(A \leftarrow S)/m^S_i` for the coarser shadows, with
    :math:`I_i(A \leftarrow Y) = (\kappa (m^A (mv)^Y - m^Y (mv)^A) + \Delta t (m^A f^Y - m^Y f^A)) / m_i`;
    zero where the receiving class (or the node) has no mass. From a fused P2G by classes (rows of 1 + d values:
    mass and :math:`q = (mv) + \Delta t f`, and :math:`\kappa = 1`) the same exchange is
    :math:`(m^A q^Y - m^Y q^A) / m_i`.

    Docs: docs/async.md#what-is-conserved-at-level-interfaces
    """
    d = kicks.shape[2]
    folded = class_sums.shape[2] == 1 + d
    for r in range(kicks.shape[1]):
        mA, mF, mS = class_sums[0, r, 0], class_sums[1, r, 0], class_sums[2, r, 0]
        m = mA + mF + mS
        for k in range(2):
            y, receiver = (1, mA) if k == 0 else (2, mS)
            mY = class_sums[y, r, 0]
            for a in range(d):
                if m > 0 and receiver > 0:
                    exchange = kappa * (mA * class_sums[y, r, 1 + a] - mY * class_sums[0, r, 1 + a])
                    if not folded:
                        exchange += dt * (mA * class_sums[y, r, 1 + d + a] - mY * class_sums[0, r, 1 + d + a])
                    kicks[k, r, a] = -(exchange / m) / receiver
                else:
                    kicks[k, r, a] = 0.0


@njit(cache=True)
def kicked_blocks(kicks, block_nodes):
    """Whether each block of ``block_nodes`` rows of the node kicks ``kicks`` (rows, d) holds a non-zero kick (the
    kicks of both receiving classes, :func:`node_kicks`, one block of rows after the other): the blocks the kick
    gather (:func:`.transfers2d.kick_gather_kernel`) visits. One more entry, false, so that a block's next one
    always exists."""
    flags = np.zeros(kicks.shape[0] // block_nodes + 1, np.bool_)
    for r in range(kicks.shape[0]):
        for a in range(kicks.shape[1]):
            if kicks[r, a] != 0.0:
                flags[r // block_nodes] = True
                break
    return flags


@njit(cache=True)
def class_first_rows(classes, rows, n_rows, out):
    """The first grid row of each particle's class in a P2G by classes: ``out[rows[k]] = classes[k] * n_rows``
    (``out[k]`` when ``rows`` is empty: every particle, in order)."""
    some = rows.shape[0] > 0
    for k in range(classes.shape[0]):
        out[rows[k] if some else k] = classes[k] * n_rows


@njit(cache=True)
def kick_first_rows(classes, kick_row_of_class, n_rows):
    """The first row of each particle's kicks in the node kicks (classes' kick rows ``kick_row_of_class``, one block
    of ``n_rows`` rows each), or -1 for a class that receives none."""
    out = np.empty(classes.shape[0], np.int64)
    for k in range(classes.shape[0]):
        row = kick_row_of_class[classes[k]]
        out[k] = row * n_rows if row >= 0 else -1
    return out
