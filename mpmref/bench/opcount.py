r"""Floating-point operations and bytes per particle of the Numba P2G (fused) and G2P kernels, read off their code,
and the ratio of classic MPM to MLS-MPM they predict for the talk's Table 2.

The counts follow :func:`mpmref.backends.numba.transfers3d.p2g_kernel` (``FUSED``) and
:func:`~mpmref.backends.numba.transfers3d.g2p_kernel` line by line for the Table-2 set-up (quadratic B-spline,
:math:`S = 3` nodes per axis, :math:`S^d` per particle; "mpm" is APIC with the classic force and velocity gradient,
"mls" MLS-MPM), one operation per addition, subtraction, multiplication or division and two per fused multiply-add
(the kernels' ``fastmath={"contract"}`` turns a product and a sum into one instruction, which counts as the two
operations it performs). Per particle:

* **set-up of each axis** (``axis_stencil``, ``quadratic_axis``): the position in cells (2), ``fx`` (2), the three
  weights (9), the three node offsets :math:`(k - f)\Delta x` (6) — and for the classic force and gradient the three
  weight derivatives (4) and their scaling by :math:`1/\Delta x` (3);
* **P2G, per particle**: the force matrix :math:`Q_p` (:math:`d^2` products and its scale, 3), :math:`m_p v_p`
  (:math:`d`), and the affine matrix — MLS: :math:`A_p = m_p C_p + \Delta t Q_p` (:math:`3d^2`), classic:
  :math:`m_p C_p` (:math:`d^2`); **per node**: the weight (1, and in 3D one product per :math:`(i, j)` pair shared by
  the :math:`S` nodes of a line), the mass (2), and per component the momentum :math:`m v_a + \sum_b A_{ab} d_b`
  (:math:`2d`) and its weighted sum into the node (2); classic adds the gradient weight (3D 5 products, 2D 2) and
  per component the force :math:`\sum_b Q_{ab} \nabla w_b` (:math:`2d - 1`) and its sum (1);
* **G2P, per node**: the weight as in P2G, :math:`v^{PIC} \mathrel{+}= w v_i` (:math:`2d`),
  :math:`B \mathrel{+}= (w v_i) d^T` (:math:`d + 2d^2`); classic adds the gradient weight and
  :math:`\sum_i v_i \nabla w^T` (:math:`2d^2`); **per particle**: :math:`C_p = B_p / D_p` (:math:`d^2`),
  :math:`x \mathrel{+}= \Delta t v` (:math:`2d`) and :math:`F \leftarrow F + \Delta t\,\nabla v\,F`
  (:math:`d^2 (3d + 1)`: per term a product by :math:`\Delta t` and a multiply-add, with MLS's :math:`\nabla v = B/D`
  divided once more per term, :math:`d^3`).

**Bytes per particle** are the particle arrays a kernel reads and writes (the grid rows a particle scatters into or
gathers from are shared by its neighbours and stay in cache at 8 particles per cell): the same for both methods, so
the ratio of their times is the ratio of their arithmetic where the kernels are compute-bound. The prediction of a
time ratio that includes the stress (the same work for both methods, timed apart) adds the measured stress to the
MLS kernel's measured transfer time and to the classic count scaled by the MLS kernel's measured rate:
:func:`predicted_ratio`.
"""

from dataclasses import dataclass

#: nodes per axis of the Table-2 kernel (quadratic B-spline)
S = 3


@dataclass(frozen=True)
class KernelCount:
    """Operations and particle bytes of one kernel per particle."""

    flops: int
    bytes: int


def axis_setup(method):
    """Operations of one axis's stencil set-up (``axis_stencil``): position, weights, offsets, and for the classic
    method the weight derivatives and their scaling."""
    return 2 + 2 + 9 + 2 * S + (4 + S if method == "mpm" else 0)


def weight_ops(dim):
    """Operations of the nodes' weights, per particle: one product per node, and in 3D one per pair ``(i, j)``."""
    return S**dim + (S * S if dim == 3 else 0)


def p2g_flops(dim, method):
    """Operations per particle of the fused P2G (module docstring)."""
    d, nodes = dim, S**dim
    particle = dim * axis_setup(method) + (d * d + 3) + d + (3 * d * d if method == "mls" else d * d)
    node = 2 + d * (2 * d + 2)
    if method == "mpm":
        node += d * 2 * d + (5 if dim == 3 else 2)
    return particle + weight_ops(dim) + nodes * node


def g2p_flops(dim, method):
    """Operations per particle of G2P with the F update (module docstring)."""
    d, nodes = dim, S**dim
    node = 2 * d + d + 2 * d * d
    if method == "mpm":
        node += 2 * d * d + (5 if dim == 3 else 2)
    particle = dim * axis_setup(method) + d * d + 2 * d + d * d * (3 * d + 1) + (d**3 if method == "mls" else 0)
    return particle + weight_ops(dim) + nodes * node


def particle_bytes(dim, itemsize, stage):
    """Bytes of particle arrays a kernel reads and writes per particle: P2G reads ``x, v, C`` and the stress
    (:math:`d^2` each for the matrices), ``mass``, ``vol0`` and its index in the sort (8 bytes); G2P reads ``x, v, F``
    and writes ``x, v, C, F``."""
    d = dim
    if stage == "p2g":
        return itemsize * (2 * d + 2 * d * d + 2) + 8
    return itemsize * (2 * d + d * d) + itemsize * (2 * d + 2 * d * d)


def counts(dim, itemsize=4):
    """``{(stage, method): KernelCount}`` for P2G and G2P of both Table-2 methods."""
    flops = {"p2g": p2g_flops, "g2p": g2p_flops}
    return {(stage, method): KernelCount(flops[stage](dim, method), particle_bytes(dim, itemsize, stage))
            for stage in flops for method in ("mpm", "mls")}


def predicted_ratio(dim, stage, mls_time=None, stress_time=0.0):
    r"""Classic over MLS-MPM time of ``stage`` that the operation counts predict.

    Without times, the ratio of the counts. With the MLS kernel's measured time ``mls_time`` (the stress included
    for P2G) and the stress's ``stress_time``:

    .. math:: \frac{t_\tau + (t_{MLS} - t_\tau)\, n_{MPM} / n_{MLS}}{t_{MLS}}

    the classic transfer at the MLS kernel's measured operation rate, plus the same stress.
    """
    c = counts(dim)
    ratio = c[(stage, "mpm")].flops / c[(stage, "mls")].flops
    if mls_time is None:
        return ratio
    transfer = mls_time - stress_time
    return (stress_time + transfer * ratio) / mls_time
