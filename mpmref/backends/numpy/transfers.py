r"""Particle-grid transfers of the NumPy reference: P2G, grid update and G2P.

Notation (Jiang et al. 2015; Hu et al. 2018): particle :math:`p` with mass :math:`m_p`, initial volume
:math:`V_p^0`, velocity :math:`v_p`, affine matrix :math:`C_p`, Kirchhoff stress :math:`\tau_p`; node
:math:`i` at :math:`x_i`; weight :math:`w_{ip}`; :math:`D_p = \tfrac14\Delta x^2 I` for the quadratic
B-spline, held as the scalar ``stencil.inertia``.
"""

import numpy as np

from ...physics.boundary import project_velocity
from ...physics.interface import KICK_ROW, N_CLASSES, moment
from ...physics.kernels import compute_stencil
from ...physics.polypic import axis_basis, higher_modes, mode_norms, mode_values
from ...state import GridState


def node_index(stencil, offset, grid):
    """Linear index of node ``base + offset`` for every particle."""
    return (stencil.base + offset) @ grid.strides


def scatter(index, values, n_nodes):
    """Sum ``values`` (n,) or (n, k) into ``n_nodes`` bins by ``index`` (``np.bincount`` per column)."""
    if values.ndim == 1:
        return np.bincount(index, weights=values, minlength=n_nodes)
    return np.stack([np.bincount(index, weights=values[:, k], minlength=n_nodes) for k in range(values.shape[1])],
                    axis=1)


def mls_gradient_weight(stencil, w, dpos, offset):
    r"""MLS approximation of the kernel gradient, :math:`\nabla w_{ip} \approx w_{ip} D_p^{-1}(x_i - x_p)`.

    Hu et al. 2018 §4, leading to their Eq. 18: with it, the nodal force becomes
    :math:`f_i = -\sum_p V_p^0\, \tau_p\, w_{ip} D_p^{-1} (x_i - x_p)` and the velocity gradient
    :math:`\nabla v_p = \sum_i v_i\, (w_{ip} D_p^{-1}(x_i - x_p))^T = C_p`.

    Docs: docs/mls_vs_classic.md#from-mls-shape-functions-to-the-mls-mpm-step,
    docs/mls_vs_classic.md#two-gradient-weights,
    docs/mpm_cycle.md#p2g-particle-to-grid
    """
    return w[:, None] * dpos / stencil.inertia


def classic_gradient_weight(stencil, w, dpos, offset):
    r"""Classic MPM: the exact kernel gradient :math:`\nabla w_{ip}` (Sulsky et al. 1994; talk Table 2 "MPM").

    The nodal force is :math:`f_i = -\sum_p V_p^0 P(F_p) F_p^T \nabla w_{ip}` and the velocity gradient
    :math:`\nabla v_p = \sum_i v_i \nabla w_{ip}^T` (Stomakhin et al. 2013 §4).

    Docs: docs/mls_vs_classic.md#two-gradient-weights
    """
    return stencil.node_gradient(offset)


GRADIENT_WEIGHTS = {"mls": mls_gradient_weight, "classic": classic_gradient_weight}


def prepare(particles, grid, kernel, transfer):
    """Kernel stencil of the particles (and PolyPIC's basis): what P2G and G2P of one step share.

    Particles do not move between P2G and G2P, so one step computes this once and passes it to both.
    Returns ``(stencil, basis)``; ``basis`` is ``None`` unless the scheme is PolyPIC.
    """
    st = compute_stencil(kernel, particles.x, grid.origin, grid.dx)
    return st, (polypic_basis(st, grid) if transfer.polypic else None)


def p2g(particles, tau, grid, kernel, transfer, prepared=None, contact=None, classes=None):
    r"""Particle to grid: node mass, momentum and internal force.

    .. math::

        m_i = \sum_p w_{ip} m_p, \qquad
        (mv)_i = \sum_p w_{ip} m_p \left(v_p + C_p (x_i - x_p)\right), \qquad
        f_i = -\sum_p V_p^0\, \tau_p\, g_{ip}

    (Jiang et al. 2015 §5 for APIC momentum, :math:`C_p` omitted for PIC/FLIP; PolyPIC adds
    :math:`\sum_r c_{pr} s_r(x_i)` of its higher modes, Fu et al. 2017 §4; Hu et al. 2018 Eq. 18 for
    the MLS force). :math:`g_{ip}` is the force discretisation's gradient weight
    (:func:`mls_gradient_weight` or :func:`classic_gradient_weight`).

    Docs: docs/mls_vs_classic.md#from-mls-shape-functions-to-the-mls-mpm-step,
    docs/mls_vs_classic.md#two-gradient-weights,
    docs/mpm_cycle.md#p2g-particle-to-grid, docs/transfers.md#apic-and-the-transfer-of-mls-mpm, docs/transfers.md#pic,
    docs/transfers.md#polypic

    Parameters
    ----------
    particles : Particles
    tau : (n, d, d) array   Kirchhoff stress of each particle
    grid : Grid
    kernel : kernel object  (``mpmref.physics.kernels``)
    transfer : TransferSpec the resolved scheme (:mod:`mpmref.physics.scheme`)
    prepared : output of :func:`prepare` for these particles (computed here if ``None``)
    contact : CPIC only (:class:`mpmref.backends.numpy.cpic.NumpyContact`): particles give mass, momentum and
        force only to compatible nodes; what they would have given an incompatible node is collected there
        as ``rejected_momentum`` :math:`\sum_p m_p w_{ip}(v^*_p - \tilde v_i)` and ``rejected_force``
        :math:`-\sum_p V_p^0 \tau_p g_{ip}` (Hu et al. 2018 §4–5; docs/cpic.md)
    classes : (n,) int array or None
        each particle's class in a level update of asynchronous stepping
        (:mod:`mpmref.physics.interface`): the sums go to ``class_sums`` (K, N, 1 + 2d) per class, in the
        same pass, and the totals are their sums
    """
    st, basis = prepared or prepare(particles, grid, kernel, transfer)
    gradient_weight = GRADIENT_WEIGHTS[transfer.force]
    m, d = particles.mass, grid.dim
    n_bins = grid.n_nodes * (N_CLASSES if classes is not None else 1)
    stress_volume = particles.vol0[:, None, None] * tau
    sums = np.zeros((n_bins, 1 + 2 * d))  # per node: mass, momentum, force
    rejected = np.zeros((grid.n_nodes, 2 * d)) if contact is not None else None  # momentum, force
    for k, offset in enumerate(st.offsets):
        idx = node_index(st, offset, grid)
        w = st.node_weight(offset)
        dpos = st.node_offset_vector(offset)
        gw = gradient_weight(st, w, dpos, offset)
        if contact is not None:
            keep = contact.compatible[k]
            kept_out = (w * m * ~keep)[:, None] * (contact.v_star - contact.ghost[k])
            rejected += scatter(idx, np.concatenate(
                [kept_out, -np.einsum("nab,nb->na", stress_volume, gw * ~keep[:, None])], axis=1), grid.n_nodes)
            w, gw = w * keep, gw * keep[:, None]
        p_mom = particles.v
        if transfer.affine:
            p_mom = p_mom + np.einsum("nab,nb->na", particles.C, dpos)
        if basis is not None:
            p_mom = p_mom + np.einsum("nm,nmd->nd", mode_values(basis[0], offset, basis[1]), particles.modes)
        bins = idx if classes is None else classes * grid.n_nodes + idx  # each class has its own nodes
        wm = w * m
        sums += scatter(bins, np.concatenate(
            [wm[:, None], wm[:, None] * p_mom, -np.einsum("nab,nb->na", stress_volume, gw)], axis=1), n_bins)
    class_sums = None
    if classes is not None:
        class_sums = sums.reshape(N_CLASSES, grid.n_nodes, 1 + 2 * d)
        sums = class_sums[0] + class_sums[1] + class_sums[2]
    dtype = particles.x.dtype
    return GridState(mass=sums[:, 0].astype(dtype), momentum=sums[:, 1:1 + d].astype(dtype),
                     force=sums[:, 1 + d:].astype(dtype),
                     rejected_momentum=None if rejected is None else np.ascontiguousarray(rejected[:, :d]),
                     rejected_force=None if rejected is None else np.ascontiguousarray(rejected[:, d:]),
                     class_sums=class_sums)


def p2g_fused(particles, tau, grid, kernel, transfer, dt, prepared=None):
    r"""P2G with the step's internal force folded in: node mass and the momentum after the force,
    :math:`(mv)_i + \Delta t f_i`, in one scatter (no force array).

    .. math::

        m_i = \sum_p w_{ip} m_p, \qquad
        (mv)_i + \Delta t f_i = \sum_p w_{ip} \left(m_p v_p + A_p (x_i - x_p)\right)
        \;\Big[+ \sum_r w_{ip} m_p c_{pr} s_r(x_i)\Big], \qquad
        A_p = m_p C_p - \Delta t\, V_p^0\, \tau_p D_p^{-1}

    with the MLS force, whose gradient weight :math:`w_{ip} D_p^{-1}(x_i - x_p)` is the APIC momentum's
    :math:`w_{ip}(x_i - x_p)` times :math:`D_p^{-1}`: the stress joins the affine matrix once per particle (Hu et al.
    2018 §4, Eq. 18 with APIC's momentum of Jiang et al. 2015 §5; the fused P2G of MLS-MPM implementations, e.g.
    the 88-line program's ``affine = stress + p_mass * C``). Without an affine scheme (PIC) :math:`A_p` is the
    force term alone. With the classic force the stress cannot join :math:`A_p` (its weight is :math:`\nabla
    w_{ip}`, not proportional to :math:`x_i - x_p`), so each node takes :math:`-\Delta t V_p^0 \tau_p \nabla w_{ip}`
    beside the momentum, in the same scatter. The bracket is PolyPIC's higher modes (:func:`p2g`).

    Equal to :func:`p2g`'s momentum plus :math:`\Delta t` times its force up to round-off (the conformance stage
    ``p2g_fused`` holds it to 1e-12 relative in float64); not for FLIP, whose G2P needs the grid velocity before the
    force. Returns a :class:`~mpmref.state.GridState` with ``force = None``, which :func:`grid_update` reads as folded.

    Docs: docs/performance.md#the-fused-p2g
    """
    st, basis = prepared or prepare(particles, grid, kernel, transfer)
    m, d = particles.mass, grid.dim
    stress_volume = particles.vol0[:, None, None] * tau
    mls = transfer.force == "mls"
    A = -dt * stress_volume / st.inertia if mls else np.zeros_like(stress_volume)
    if transfer.affine:
        A = A + m[:, None, None] * particles.C
    sums = np.zeros((grid.n_nodes, 1 + d))  # per node: mass, momentum after the force
    for offset in st.offsets:
        w = st.node_weight(offset)
        p_mom = m[:, None] * particles.v + np.einsum("nab,nb->na", A, st.node_offset_vector(offset))
        if basis is not None:
            p_mom = p_mom + m[:, None] * np.einsum("nm,nmd->nd", mode_values(basis[0], offset, basis[1]),
                                                   particles.modes)
        node_momentum = w[:, None] * p_mom
        if not mls:
            node_momentum = node_momentum - dt * np.einsum("nab,nb->na", stress_volume, st.node_gradient(offset))
        sums += scatter(node_index(st, offset, grid), np.concatenate([(w * m)[:, None], node_momentum], axis=1),
                        grid.n_nodes)
    dtype = particles.x.dtype
    return GridState(mass=sums[:, 0].astype(dtype), momentum=sums[:, 1:].astype(dtype), force=None)


def polypic_basis(stencil, grid):
    """PolyPIC per-axis polynomials, their norms and the higher-mode list for these particles."""
    q, norm = axis_basis(stencil.w, stencil.fx, stencil.dx)
    return q, higher_modes(grid.dim, stencil.w.shape[2]), norm


def wall_bands(grid, width):
    """Node sets of each wall: ``[(name, node_mask, inward_normal)]`` for nodes within ``width`` cells."""
    idx = grid.node_indices()
    bands = []
    for a in range(grid.dim):
        for side, mask in (("min", idx[:, a] < width), ("max", idx[:, a] > grid.cells[a] - width)):
            normal = np.zeros(grid.dim)
            normal[a] = 1.0 if side == "min" else -1.0
            bands.append((f"{'xyz'[a]}_{side}", mask, normal))
    return bands


def grid_update(gs, grid, dt, gravity, walls, bands, colliders=(), time=0.0, node_x=None):
    r"""Grid velocity update: symplectic Euler with gravity, then Eq. 25 at the walls and colliders.

    .. math::

        \tilde v_i = \frac{(mv)_i}{m_i}, \qquad v_i = \tilde v_i + \Delta t \left(\frac{f_i}{m_i} + g\right)

    followed by :func:`mpmref.physics.boundary.project_velocity` on each wall's band of nodes and by
    each level-set collider at ``time`` (Hu et al. 2018 Alg. 1, grid operations). Returns
    ``(v, v_tilde)``; ``v_tilde`` (the velocity before forces) is what FLIP needs. Nodes without mass
    get zero velocity. A grid state of :func:`p2g_fused` (``force`` is ``None``: its momentum is
    :math:`(mv)_i + \Delta t f_i`) gives :math:`v_i = ((mv)_i + \Delta t f_i)/m_i + \Delta t g` and no ``v_tilde``
    (``None``).

    Docs: docs/mpm_cycle.md#from-the-continuum-to-the-cycle, docs/mpm_cycle.md#grid-update

    Parameters
    ----------
    gs : GridState, dt : float, gravity : (d,) array
    walls : dict name -> WallSpec;  bands : output of :func:`wall_bands`
    colliders : sequence of :class:`mpmref.physics.colliders.Collider`; time : float
    node_x : (N, d) node positions (needed only with colliders)
    """
    has_mass = gs.mass > 0
    inv_m = np.where(has_mass, 1.0 / np.where(has_mass, gs.mass, 1.0), 0.0)[:, None]
    folded = gs.force is None
    v_tilde = None if folded else gs.momentum * inv_m
    v = (gs.momentum if folded else gs.momentum + dt * gs.force) * inv_m + dt * gravity * has_mass[:, None]
    v = v.astype(gs.momentum.dtype)
    for name, mask, normal in bands:
        wall = walls[name]
        if wall.type == "open":
            continue
        sel = mask & has_mass
        v[sel] = project_velocity(v[sel], np.broadcast_to(normal, (int(sel.sum()), grid.dim)), wall.type, wall.friction)
    for collider in colliders:
        v = collider.apply(v, node_x, has_mass, time)
    return v, v_tilde


def g2p(particles, v_grid, v_tilde, grid, kernel, transfer, dt, prepared=None, ghost=None, kicks=None):
    r"""Grid to particle: new velocity, affine matrix, PolyPIC modes, deformation and position.

    Each gathers from the stencil's node velocities (:func:`stencil_velocities`) in a function of its own, which
    carries its equation: :func:`pic_velocity`, :func:`affine_matrix` (APIC, and the MLS velocity gradient),
    :func:`velocity_gradient`, :func:`flip_velocity` (FLIP only), :func:`polypic_modes` (PolyPIC only); then
    :func:`deform` and :func:`advect`. ``transfer.gradient`` chooses the velocity gradient, independently of the
    force (``method.velocity_gradient``; it follows ``method.force`` unless declared).

    Parameters
    ----------
    particles : Particles
    v_grid : (N, d) array
        Node velocities after the grid update, :math:`v_i`.
    v_tilde : (N, d) array or None
        Node velocities before forces and walls, :math:`\tilde v_i` (FLIP only).
    grid, kernel, transfer
        The scene's grid, kernel and transfer.
    dt : float
        The step :math:`\Delta t`.
    prepared : tuple, optional
        The output of :func:`prepare` (computed here if ``None``).
    ghost : tuple, optional
        CPIC only: ``(compatible (K, n), ghost velocities (K, n, d))`` (:func:`stencil_velocities`).
    kicks : tuple, optional
        A level update of asynchronous stepping with conservative interfaces: ``(classes, kick)``
        (:func:`interface_impulses`).

    Returns
    -------
    Particles
        A new state; the input is not modified. With ``kicks``, ``(particles, (dP, dL))``.
    """
    st, basis = prepared or prepare(particles, grid, kernel, transfer)
    dtype = v_grid.dtype

    def nodes():
        return stencil_velocities(st, grid, v_grid, ghost)

    v_pic = pic_velocity(st, nodes(), dtype)
    C = affine_matrix(st, nodes(), dtype) if transfer.affine or transfer.mls_gradient else None
    grad_v = velocity_gradient(st, nodes(), dtype, C if transfer.mls_gradient else None)
    v_new = v_pic
    if transfer.flip:
        v_new = flip_velocity(particles.v, v_pic, st, nodes(), v_tilde, transfer.flip_alpha, dtype)
    changes = {"x": advect(particles.x, v_pic, dt), "v": v_new, **deform(particles, grad_v, dt)}
    if transfer.affine:
        changes["C"] = C
    if basis is not None:
        changes["modes"] = polypic_modes(nodes(), basis, np.zeros_like(particles.modes))
    new = particles.with_(**changes)
    if kicks is None:
        return new
    return new, interface_impulses(st, nodes(), kicks, particles)


def stencil_velocities(stencil, grid, v_grid, ghost=None):
    r"""``(offset, idx, w, v)`` for each node of the particles' stencil, in the order of ``stencil.offsets``: the
    offset, the nodes' linear indices (n,), the weights :math:`w_{ip}` (n,) and the node velocities :math:`v_i`
    (n, d) that the particles gather. With CPIC's ``ghost``, ``(compatible (K, n), ghost velocities (K, n, d))``,
    a node incompatible with the particle gives its ghost velocity instead (Hu et al. 2018 §4; docs/cpic.md).

    The indices are :func:`node_index`'s, as the index of the stencil's lowest node plus the offset's (the same
    integers, without a product per offset), and the velocities are gathered with ``np.take``, which copies the same
    values as indexing, faster: each function of :func:`g2p` walks the stencil once."""
    lowest = stencil.base @ grid.strides
    for k, offset in enumerate(stencil.offsets):
        idx = lowest + offset @ grid.strides
        v = np.take(v_grid, idx, axis=0)
        if ghost is not None:
            v = np.where(ghost[0][k][:, None], v, ghost[1][k])
        yield offset, idx, stencil.node_weight(offset), v


def pic_velocity(stencil, nodes, dtype):
    r"""PIC's velocity: the weighted mean of the stencil's node velocities (Sulsky et al. 1994).

    .. math:: v_p^{PIC} = \sum_i w_{ip}\, v_i

    with :math:`w_{ip}` the weight of node :math:`i` at particle :math:`p` and :math:`v_i` the node's velocity
    after the grid update. It is the new velocity of every scheme but FLIP, and every particle moves with it
    (:func:`advect`). ``nodes``: :func:`stencil_velocities`; ``dtype``: the grid velocities'. Returns (n, d).

    Docs: docs/mpm_cycle.md#g2p-grid-to-particle, docs/transfers.md#pic,
    docs/transfers.md#apic-and-the-transfer-of-mls-mpm
    """
    v = np.zeros(stencil.fx.shape, dtype=dtype)
    for _, _, w, vi in nodes:
        v += w[:, None] * vi
    return v


def affine_matrix(stencil, nodes, dtype):
    r"""APIC's affine matrix, the least-squares fit of an affine field to the stencil's velocities (Jiang et al.
    2015 §5).

    .. math:: B_p = \sum_i w_{ip}\, v_i\, (x_i - x_p)^T, \qquad C_p = B_p D_p^{-1}

    with :math:`x_i - x_p` the offset of node :math:`i` from particle :math:`p` and :math:`D_p` the APIC inertia
    (``stencil.inertia`` :math:`\times I`: :math:`\tfrac14 \Delta x^2 I` for the quadratic B-spline). Also the MLS
    velocity gradient (:func:`velocity_gradient`). Returns :math:`C_p`, (n, d, d).

    Docs: docs/mpm_cycle.md#g2p-grid-to-particle, docs/transfers.md#apic-and-the-transfer-of-mls-mpm
    """
    d = stencil.fx.shape[1]
    B = np.zeros((len(stencil.fx), d, d), dtype=dtype)
    for offset, _, w, vi in nodes:
        B += np.einsum("na,nb->nab", w[:, None] * vi, stencil.node_offset_vector(offset))
    return B / stencil.inertia


def velocity_gradient(stencil, nodes, dtype, C=None):
    r"""The velocity gradient that deforms the particle, :math:`\nabla v_p = \sum_i v_i\, g_{ip}^T`.

    .. math::

        \nabla v_p = \sum_i v_i\, \nabla w_{ip}^T \;\text{(classic: Stomakhin et al. 2013 §4)}, \qquad
        \nabla v_p = C_p \;\text{(MLS: Hu et al. 2018 §4, with their Eq. 18)}

    with :math:`\nabla w_{ip}` the kernel's gradient (``stencil.node_gradient``) and :math:`C_p` APIC's affine
    matrix (:func:`affine_matrix`), the MLS gradient weight :math:`g_{ip} = w_{ip} D_p^{-1}(x_i - x_p)` summed.
    ``C`` given: the MLS gradient, ``C`` itself; otherwise the classic sum. Returns (n, d, d).

    Docs: docs/mpm_cycle.md#g2p-grid-to-particle, docs/mls_vs_classic.md#two-gradient-weights,
    docs/mls_vs_classic.md#consistency-with-apics-affine-field
    """
    if C is not None:
        return C
    d = stencil.fx.shape[1]
    grad_v = np.zeros((len(stencil.fx), d, d), dtype=dtype)
    for offset, _, _, vi in nodes:
        grad_v += np.einsum("na,nb->nab", vi, stencil.node_gradient(offset))
    return grad_v


def flip_velocity(v, v_pic, stencil, nodes, v_tilde, alpha, dtype):
    r"""FLIP's velocity, blended with PIC's (FLIP: Brackbill and Ruppel 1986).

    .. math::

        v_p^{FLIP} = v_p + \sum_i w_{ip}\,(v_i - \tilde v_i), \qquad
        v_p \leftarrow \alpha\, v_p^{FLIP} + (1 - \alpha)\, v_p^{PIC}

    with :math:`v_p` the particle's velocity before the step, :math:`\tilde v_i` the node's velocity before forces
    and walls (``v_tilde``, of :func:`grid_update`), :math:`v_p^{PIC}` of :func:`pic_velocity` (``v_pic``) and
    :math:`\alpha` = ``method.flip_alpha``. Returns the new :math:`v_p`, (n, d).

    Docs: docs/mpm_cycle.md#g2p-grid-to-particle, docs/transfers.md#flipα
    """
    change = np.zeros(stencil.fx.shape, dtype=dtype)
    for _, idx, w, vi in nodes:
        change += w[:, None] * (vi - np.take(v_tilde, idx, axis=0))
    return alpha * (v + change) + (1.0 - alpha) * v_pic


def polypic_modes(nodes, basis, modes):
    r"""PolyPIC's higher modes: the projection of the stencil's velocities on each (Fu et al. 2017).

    .. math:: c_{pr} = \frac{\sum_i w_{ip}\, s_r(x_i)\, v_i}{\sum_i w_{ip}\, s_r(x_i)^2}

    with :math:`s_r` the particle's mode :math:`r`, a product of per-axis polynomials orthogonal under its own
    weights (:mod:`mpmref.physics.polypic`; ``basis`` of :func:`polypic_basis`); the denominator is
    :func:`mpmref.physics.polypic.mode_norms`, and a mode of zero norm gets :math:`c_{pr} = 0`. ``modes``: zeros of
    the modes' shape (n, R, d), which the numerators are summed into. Returns (n, R, d).

    Docs: docs/mpm_cycle.md#polypic, docs/transfers.md#polypic
    """
    for offset, _, w, vi in nodes:
        modes += np.einsum("nm,nd->nmd", w[:, None] * mode_values(basis[0], offset, basis[1]), vi)
    norms = mode_norms(basis[2], basis[1])[..., None]
    return np.divide(modes, norms, out=np.zeros_like(modes), where=norms > 0)


def deform(particles, grad_v, dt):
    r"""The deformation the velocity gradient makes over the step, of each field the particles carry (``F``, ``J``).

    .. math::

        F_p \leftarrow (I + \Delta t\, \nabla v_p)\, F_p, \qquad
        J_p \leftarrow (1 + \Delta t \operatorname{tr} \nabla v_p)\, J_p

    with :math:`\nabla v_p` of :func:`velocity_gradient` (Hu et al. 2018 §4 for :math:`F`; the :math:`J` update is
    the first-order form of Taichi's mpm88). Returns ``{"F": ..., "J": ...}`` of those the particles carry.

    Docs: docs/mpm_cycle.md#g2p-grid-to-particle, docs/mls_vs_classic.md#consistency-with-apics-affine-field
    """
    changes = {}
    if particles.F is not None:
        changes["F"] = particles.F + dt * grad_v @ particles.F
    if particles.J is not None:
        changes["J"] = particles.J * (1.0 + dt * np.trace(grad_v, axis1=1, axis2=2))
    return changes


def advect(x, v_pic, dt):
    r"""The particles' new positions: every scheme, FLIP included, moves them with PIC's velocity (Hu et al. 2018
    Alg. 1).

    .. math:: x_p \leftarrow x_p + \Delta t\, v_p^{PIC}

    Docs: docs/mpm_cycle.md#g2p-grid-to-particle
    """
    return x + dt * v_pic


def interface_impulses(stencil, nodes, kicks, particles):
    r"""The impulse and its moment about the origin that each particle of the active and coarser classes collects
    from the node kicks of conservative interfaces (asynchronous stepping; docs/async.md).

    .. math:: \delta P_p = m_p \sum_i w_{ip}\, k_i, \qquad
              \delta L_p = m_p \sum_i w_{ip}\, x_i \times k_i
              = x_p \times \delta P_p + m_p \sum_i w_{ip}\, (x_i - x_p) \times k_i

    with :math:`k_i` the kick of node :math:`i` for the particle's class and :math:`m_p` its mass. ``kicks`` is
    ``(classes, kick)``: each particle's class and the node kicks (2, N, d) of
    :func:`mpmref.physics.interface.interface_kicks`. Returns ``(dP, dL)``, float64: (n, d) and (n, 1) in 2D,
    (n, 3) in 3D.
    """
    classes, kick = kicks
    kick_row = np.array([KICK_ROW.get(c, 0) for c in range(N_CLASSES)])[classes]
    kicked = np.isin(classes, list(KICK_ROW))
    n, d = stencil.fx.shape
    dP = np.zeros((n, d))
    dL = np.zeros(n if d == 2 else (n, 3))
    for offset, idx, w, _ in nodes:
        ki = kick[kick_row, idx] * (w * kicked)[:, None]
        dP += ki
        dL += moment(stencil.node_offset_vector(offset), ki)
    m = particles.mass[:, None]
    dP = dP * m
    return dP, dL.reshape(n, -1) * m + moment(particles.x.astype(np.float64), dP).reshape(n, -1)
