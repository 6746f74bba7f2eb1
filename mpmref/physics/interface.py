r"""Momentum exchange across level interfaces of asynchronous stepping, and its conservative treatment.

In a level update of asynchronous stepping (Fang et al. 2018; :mod:`mpmref.steppers.asynchronous`) one
ordinary MPM substep runs over three classes of particles: the **active** ones :math:`A` (the level's own,
whose results count), **finer** ghosts :math:`F` (finer particles at the same tick) and **coarser** shadows
:math:`S` (coarser particles mid-step, at their sub-cycled shadow state). P2G gives each class its node
sums :math:`m^X_i, (mv)^X_i, f^X_i`; the grid velocity comes from their totals. The change of :math:`A`'s
momentum in the update is then a sum over nodes of the pairwise exchanges

.. math::

    I_i(A \leftarrow Y) = \frac{\kappa\,(m^A_i (mv)^Y_i - m^Y_i (mv)^A_i)
                                + \Delta t\,(m^A_i f^Y_i - m^Y_i f^A_i)}{m_i},
    \qquad m_i = m^A_i + m^F_i + m^S_i,

for :math:`Y = F, S` (spec A6; :math:`A`'s own forces sum to zero over the nodes, and gravity and the
walls act on each class by its share of the node mass, so they are not exchanges). :math:`\kappa = 1`
for PIC, APIC, PolyPIC and MLS-MPM; FLIP(α) returns only the share :math:`1 - \alpha` of the
momentum part, :math:`\kappa = 1 - \alpha`. The exchange is antisymmetric, :math:`I(A \leftarrow Y) =
-I(Y \leftarrow A)`, so synchronous MPM conserves momentum: both sides take it in the same step.

Asynchronous stepping does not: the coarse side takes :math:`I(C \leftarrow F)` once per coarse step, the
fine side :math:`I(F \leftarrow S)` at every fine step, and neither reaction is applied. The
**conservative** treatment is impulse refluxing (spec A9), the particle version of the flux registers of
Berger & Colella (1989, *J. Comput. Phys.* 82, §4) for sub-cycled adaptive mesh refinement: the finer side
resolves each exchange in time, and the coarser side receives exactly minus what the finer side took.

* In an update, the reaction :math:`-I_i(A \leftarrow S)` goes to the coarser shadows' own particles,
  shared by their mass at the node, :math:`w_{ip} m_p / m^S_i`; and :math:`-I_i(A \leftarrow F)` goes to
  :math:`A`'s own particles by :math:`w_{ip} m_p / m^A_i`, which cancels the coarse side's once-sampled
  estimate of the exchange with its finer neighbours (:func:`interface_kicks`, then each backend's G2P
  gathers the kicks).
* Each particle keeps a register of what it received: an impulse :math:`\delta P_p` and its moment
  :math:`\delta L_p` about the origin (:math:`\sum_i` share :math:`\cdot\, x_i \times (-I_i)`). At the end of
  the particle's own step, before anything reads it, :func:`apply_registers` adds :math:`\delta P_p / m_p`
  to its velocity and puts what the kick does not carry of :math:`\delta L_p` into the skew part of
  :math:`C_p`.

Every node's exchange is then applied with both signs once, whatever the clocks: linear momentum is
conserved, and angular momentum wherever the affine matrix carries it (APIC, PolyPIC, MLS-MPM). The
derivation and what this does to energy are in docs/async.md, "Conservative interfaces".
"""

import numpy as np

#: particle classes of a level update: the level's own particles, finer ghosts, coarser shadows
ACTIVE, FINER, COARSER = 0, 1, 2
N_CLASSES = 3
#: the kick rows of :func:`interface_kicks`: what the active particles and what the coarser shadows receive
KICK_ROW = {ACTIVE: 0, COARSER: 1}


def momentum_share(spec):
    r""":math:`\kappa`, the share of the node momentum exchange a particle's G2P returns: :math:`1 - \alpha`
    for FLIP(α), 1 for the other transfers."""
    return 1.0 - spec.flip_alpha if spec.flip else 1.0


def exchange(sums, dt, kappa, a, y):
    r""":math:`I_i(A \leftarrow Y)` at every node (module docstring), from per-class sums ``sums`` (K, N, 1 + 2d)
    (mass, momentum, force per class ``a`` and ``y``); (N, d), 0 where a node has no mass.

    Docs: docs/async.md#what-is-conserved-at-level-interfaces
    """
    d = (sums.shape[-1] - 1) // 2
    m = sums[..., 0]
    total = m.sum(axis=0)
    p, f = sums[..., 1:1 + d], sums[..., 1 + d:]
    num = kappa * (m[a, :, None] * p[y] - m[y, :, None] * p[a]) + dt * (m[a, :, None] * f[y] - m[y, :, None] * f[a])
    return np.divide(num, total[:, None], out=np.zeros_like(num), where=total[:, None] > 0)


def interface_kicks(sums, dt, kappa):
    r"""Velocity kicks per unit mass at each node: row 0 for the active particles,
    :math:`-I_i(A \leftarrow F) / m^A_i`, row 1 for the coarser shadows, :math:`-I_i(A \leftarrow S) / m^S_i`
    (0 where the class has no mass). A particle of class :math:`X` receives the impulse
    :math:`m_p \sum_i w_{ip}\, k^X_i` and its moment :math:`m_p \sum_i w_{ip}\, x_i \times k^X_i`; summed over
    the class, exactly :math:`-\sum_i I_i` and :math:`-\sum_i x_i \times I_i`. Returns (2, N, d)."""
    def per_mass(impulse, cls):
        m = sums[cls, :, 0][:, None]
        return np.divide(impulse, m, out=np.zeros_like(impulse), where=m > 0)

    return np.stack([per_mass(-exchange(sums, dt, kappa, ACTIVE, FINER), ACTIVE),
                     per_mass(-exchange(sums, dt, kappa, ACTIVE, COARSER), COARSER)])


def moment(x, impulse):
    """Moment :math:`x \\times J` of impulses ``impulse`` at positions ``x``: (n,) in 2D, (n, 3) in 3D."""
    if x.shape[1] == 2:
        return x[:, 0] * impulse[:, 1] - x[:, 1] * impulse[:, 0]
    return np.cross(x, impulse)


def skew_from_axial(s):
    r"""The skew matrix :math:`W` with axial vector ``s`` in the sense of
    :func:`mpmref.observe.diagnostics.affine_spin`, :math:`\operatorname{spin}(W) = s`: (n, 2, 2) from (n,),
    (n, 3, 3) from (n, 3). In 2D :math:`W_{yx} = -W_{xy} = s/2`; in 3D :math:`W = \tfrac12 [s]_\times`."""
    if s.ndim == 1:
        W = np.zeros((s.shape[0], 2, 2))
        W[:, 1, 0], W[:, 0, 1] = 0.5 * s, -0.5 * s
        return W
    W = np.zeros((s.shape[0], 3, 3))
    W[:, 2, 1], W[:, 1, 2] = 0.5 * s[:, 0], -0.5 * s[:, 0]
    W[:, 0, 2], W[:, 2, 0] = 0.5 * s[:, 1], -0.5 * s[:, 1]
    W[:, 1, 0], W[:, 0, 1] = 0.5 * s[:, 2], -0.5 * s[:, 2]
    return W


def apply_registers(v, C, x, mass, dP, dL, inertia):
    r"""The particles' velocities and affine matrices after their registers (impulse ``dP``, its moment ``dL``
    about the origin) are applied at positions ``x``:

    .. math::

        v_p \leftarrow v_p + \frac{\delta P_p}{m_p}, \qquad
        C_p \leftarrow C_p + W\!\left(\frac{\delta L_p - x_p \times \delta P_p}{m_p D_p}\right)

    with :math:`D_p` = ``inertia`` and :math:`W` of :func:`skew_from_axial`, so that the particle's momentum
    grows by :math:`\delta P_p` and its angular momentum (:func:`mpmref.observe.diagnostics.angular_momentum`,
    :math:`x_p \times m_p v_p + m_p D_p \operatorname{spin}(C_p)`) by :math:`\delta L_p`. ``C`` is ``None`` for
    PIC and FLIP, which carry no affine matrix (and do not conserve angular momentum in any stepping).
    Returns ``(v, C)``, new arrays.

    Docs: docs/async.md#conservative-interfaces
    """
    v = v + dP / mass[:, None]
    if C is None:
        return v, None
    spin = (dL - moment(x, dP)) / (mass * inertia if dL.ndim == 1 else (mass * inertia)[:, None])
    return v, C + skew_from_axial(spin).astype(C.dtype)
