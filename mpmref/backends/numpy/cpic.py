r"""CPIC stages of the NumPy reference: the contact of one step, the bodies' impulses, and G2P with ghosts.

One CPIC step (composed in :func:`mpmref.steppers.pipeline.substep`):

1. :func:`contact` — the colored distance field of the bodies where they are now, the particles' sticky
   tags and reconstructed distance/normal (:mod:`mpmref.physics.cdf`), and per particle and stencil node
   whether they are compatible, the node's nearest body and the particle's *ghost velocity* there;
2. P2G only to compatible nodes (:func:`mpmref.backends.numpy.transfers.p2g` with the contact), which also
   collects at each node what incompatible particles did not give it;
3. :func:`impulses` — that, as impulses on each node's nearest body;
4. :func:`g2p` — G2P that reads the ghost velocity at incompatible nodes, ``C_p := 0`` for ``near``
   particles, and the penalty.

Notation: particle :math:`p`, node :math:`i`, weight :math:`w_{ip}`, body :math:`r` with velocity field
:math:`\mathbf v_r(\mathbf x)`, the friction projection :math:`\Pi` of
:func:`mpmref.rigid.dynamics.friction_projection`. Source: Hu et al. 2018, SIGGRAPH, §4–5, as the
authors' reference implementation does (docs/cpic.md).
"""

from dataclasses import dataclass

import numpy as np

from ...physics.cdf import PENALTY_WINDOW, build_cdf, compatible, reconstruct, reconstruct_per_body, update_tags
from ...rigid.dynamics import body_impulses, current_shapes, friction_projection, point_velocity
from .transfers import g2p as plain_g2p
from .transfers import node_index


@dataclass
class NumpyContact:
    """What one CPIC step's transfers need, per stencil offset ``k`` (``K`` offsets) and particle.

    Attributes
    ----------
    cdf : ColoredDistanceField      the field of the bodies at the start of the step
    compatible : (K, n) bool        node ``base + offset_k`` is compatible with the particle
    node : (K, n) int               flat index of node ``base + offset_k``
    body : (K, n) int               that node's nearest body (``-1`` if none)
    node_x : (K, n, 2)              that node's position
    mu : (K, n)                     encoded friction of the particle's side of that body
    v_star : (n, 2)                 the particle's velocity with this step's gravity,
                                    :math:`\\mathbf v_p + \\mathbf g\\Delta t`
    force_velocity : (K, n, 2)      :math:`\\Delta t\\, \\mathbf f_{ip} / (m_p w_{ip})`, the velocity the particle's own
                                    internal force gives that node (zero unless ``method.ghost_force``)
    tau : (n, 2, 2)                 the particles' Kirchhoff stress (computed once for the step)
    ghost_body : (K, n) int         the body whose friction projection gives the ghost velocity there: the node's
                                    nearest body, or with the per-body fit the crossed body (:func:`ghost_frames`)
    ghost_normal : (K, n, 2)        the normal of that projection (:math:`\\mathbf n_p`, or :math:`\\mathbf n_{pr}`)
    ghost_mu : (K, n)               the friction of that projection
    ghost_near : (K, n) bool        whether the node projects (else the ghost velocity is :math:`\\mathbf v^*_p`)
    fit : tuple or None             the per-body fit ``(phi (n, nb), normal (n, nb, 2), near (n, nb))``
                                    (:func:`mpmref.physics.cdf.reconstruct_per_body`), None with the single fit
    ghost : (K, n, 2)               ghost velocities :math:`\\tilde{\\mathbf v}_i` with the bodies' velocities of P2G
    """

    cdf: object
    compatible: np.ndarray
    node: np.ndarray
    body: np.ndarray
    node_x: np.ndarray
    mu: np.ndarray
    v_star: np.ndarray
    force_velocity: np.ndarray
    tau: np.ndarray
    ghost_body: np.ndarray = None
    ghost_normal: np.ndarray = None
    ghost_mu: np.ndarray = None
    ghost_near: np.ndarray = None
    fit: tuple = None
    ghost: np.ndarray = None

    @property
    def per_body_fit(self):
        """The per-body fit ``(phi, normal, near)``, each ``(n, nb, ...)``, or None with the single fit."""
        return self.fit


def ghost_velocities(contact, rigid, particles):
    r"""Velocity an incompatible node :math:`i` shows particle :math:`p` (docs/cpic.md), without the pushing force.

    .. math:: \tilde{\mathbf v}_i = \begin{cases} \Pi(\mathbf v_p^* + \mathbf a_{ip};\ \mathbf v_r(\mathbf x_i),
              \mathbf n_p, \mu_{r,T_{pr}}) & p \text{ near} \\ \mathbf v_p^* & \text{otherwise,} \end{cases}

    with :math:`r` the node's nearest body (with the per-body fit, :func:`ghost_frames`: the crossed body and
    its own normal :math:`\mathbf n_{pr}` where that body's fit is accepted),
    :math:`\mathbf v_p^* = \mathbf v_p + \mathbf g \Delta t` (the
    reference adds gravity to the particle before P2G), and :math:`\mathbf a_{ip} = \Delta t\, \mathbf f_{ip}/
    (m_p w_{ip})` the velocity the particle's own internal force :math:`\mathbf f_{ip} = -V_p^0 \tau_p g_{ip}`
    would give the node (``method.ghost_force``, the default; the reference code uses
    :math:`\mathbf a_{ip} = 0`). With :math:`\mathbf a_{ip}` the friction projection sees the whole normal
    load a resting body carries, stress included, so Coulomb friction acts on it (docs/cpic.md, "Friction").
    P2G gives the body :math:`m_p w_{ip}(\mathbf v_p^* - \tilde{\mathbf v}_i) + \Delta t\, \mathbf f_{ip}` and
    G2P gives the particle :math:`\tilde{\mathbf v}_i`; with the same :math:`\tilde{\mathbf v}_i` on both
    sides the momentum balances exactly (docs/cpic.md). Returns (K, n, 2).
    """
    v_body = point_velocity(rigid, contact.ghost_body, contact.node_x)
    v_load = contact.v_star + contact.force_velocity
    projected = friction_projection(v_load, v_body, contact.ghost_normal, contact.ghost_mu)
    return np.where(contact.ghost_near[:, :, None], projected, contact.v_star)


def ghost_frames(contact, particles, friction, fit):
    r"""The body, normal, friction and ``near`` flag of each (stencil node, particle)'s ghost velocity.

    Single fit (``fit`` None, the paper's): the node's nearest body :math:`r`, the particle's normal
    :math:`\mathbf n_p`, the friction :math:`\mu_{r, T_{pr}}` of its side and its ``near`` flag.

    Per-body fit (docs/cpic.md, "Per-body fit"): at a node incompatible with a particle tagged by several bodies,
    the *crossed* body :math:`c` — of the bodies :math:`r` with :math:`A_{ir} = A_{pr} = 1` and
    :math:`T_{ir} \ne T_{pr}`, the one with the least :math:`d_{ir}` (the lowest id on a tie) — with its own
    normal :math:`\mathbf n_{pc}` and friction :math:`\mu_{c, T_{pc}}`, if its per-body fit is accepted; the
    single fit's choice otherwise. Returns ``(body (K, n), normal (K, n, d), mu (K, n), near (K, n))``.
    """
    K, n = contact.body.shape
    body = np.maximum(contact.body, 0)
    normal = np.broadcast_to(particles.normal, (K,) + particles.normal.shape)
    near = np.broadcast_to(particles.near, (K, n))
    if fit is None:
        return body, normal, contact.mu, near
    cdf, rows = contact.cdf, np.arange(n)
    A, T = particles.tag_A, particles.tag_T
    crossing = cdf.A[contact.node] & A[None] & (cdf.T[contact.node] != T[None])  # (K, n, nb)
    crossed = np.argmin(np.where(crossing, cdf.d_body[contact.node], np.inf), axis=2)
    own = crossing.any(axis=2) & fit[2][rows, crossed]
    mu_crossed = friction[crossed, T[rows, crossed].astype(int)]
    return (np.where(own, crossed, body), np.where(own[..., None], fit[1][rows, crossed], normal),
            np.where(own, mu_crossed, contact.mu), near | own)


def force_velocity(stencil, offset, gradient_weight, particles, tau, dt):
    r""":math:`\mathbf a_{ip} = -\Delta t\, V_p^0 \tau_p g_{ip} / (m_p w_{ip})` for one stencil offset (0 where
    :math:`w_{ip} = 0`)."""
    w = stencil.node_weight(offset)
    g = gradient_weight(stencil, w, stencil.node_offset_vector(offset), offset)
    f = -dt * np.einsum("nab,nb->na", particles.vol0[:, None, None] * tau, g)
    return np.where((w > 0.0)[:, None], f / np.where(w > 0.0, w * particles.mass, 1.0)[:, None], 0.0)


def contact(particles, prepared, bodies, rigid, grid, dt, gravity, tau, gradient_weight, ghost_force, per_body=False):
    r"""Build the step's :class:`NumpyContact` and return ``(particles with updated tags, contact)``.

    The field is rebuilt from the bodies' current pose (:func:`mpmref.physics.cdf.build_cdf`, docs/cpic.md); the
    tags are updated with sticky side memory and the distance :math:`\phi_p`, normal :math:`\mathbf n_p`
    and ``near`` flag reconstructed (:func:`~mpmref.physics.cdf.update_tags`,
    :func:`~mpmref.physics.cdf.reconstruct`, docs/cpic.md); node :math:`i` and particle :math:`p` are compatible
    iff they agree on the side of every body both are near (:func:`~mpmref.physics.cdf.compatible`, B4).
    ``tau`` is the particles' Kirchhoff stress, ``gradient_weight`` the force discretisation's
    :math:`g_{ip}`, ``ghost_force`` whether ghost velocities include :math:`\mathbf a_{ip}` (:func:`ghost_velocities`),
    ``per_body`` whether particles near several bodies also get a fit per body
    (:func:`~mpmref.physics.cdf.reconstruct_per_body`, ``method.cpic_fit``).
    """
    stencil = prepared[0]
    x = particles.x.astype(np.float64)
    cdf = build_cdf(current_shapes(bodies, rigid), grid.node_shape, grid.origin, grid.dx)
    A, T = update_tags(cdf, x, particles.tag_A, particles.tag_T)
    phi, normal, near = reconstruct(cdf, x, A, T)
    particles = particles.with_(tag_A=A, tag_T=T, phi=phi, normal=normal, near=near)
    friction = np.array([b.friction for b in bodies])  # (nb, 2): side 0, side 1
    compat, nodes, body, node_x, mu, a = [], [], [], [], [], []
    rows = np.arange(particles.n)
    for offset in stencil.offsets:
        idx = node_index(stencil, offset, grid)
        nodes.append(idx)
        compat.append(compatible(cdf.A[idx], cdf.T[idx], A, T))
        nearest = cdf.body[idx]
        body.append(nearest)
        node_x.append(grid.origin + (stencil.base + offset) * grid.dx)
        r = np.maximum(nearest, 0)
        mu.append(friction[r, T[rows, r].astype(int)])
        a.append(force_velocity(stencil, offset, gradient_weight, particles, tau, dt) if ghost_force
                 else np.zeros_like(particles.v))
    c = NumpyContact(cdf=cdf, compatible=np.array(compat), node=np.array(nodes), body=np.array(body),
                     node_x=np.array(node_x),
                     mu=np.array(mu), v_star=particles.v + dt * gravity, force_velocity=np.array(a), tau=tau)
    c.fit = reconstruct_per_body(cdf, x, A, T) if per_body else None
    c.ghost_body, c.ghost_normal, c.ghost_mu, c.ghost_near = ghost_frames(c, particles, friction, c.fit)
    c.ghost = ghost_velocities(c, rigid, particles)
    return particles, c


def impulses(grid_state, contact, rigid, dt):
    r"""Impulses on the bodies from what incompatible nodes did not receive in P2G (docs/cpic.md).

    At each node :math:`i` with nearest body :math:`r`,

    .. math:: \mathbf J_i = \sum_{p \text{ incompatible with } i} \left[ m_p w_{ip}
              (\mathbf v_p^* - \tilde{\mathbf v}_i)
              - \Delta t\, V_p^0 \tau_p\, g_{ip} \right],

    collected by P2G as ``grid_state.rejected_momentum`` and ``grid_state.rejected_force``; body :math:`r`
    receives :math:`\sum_i \mathbf J_i` and :math:`\sum_i (\mathbf x_i - \mathbf c_r)\times \mathbf J_i`.
    Returns ``(J (nb, 2), L (nb,))``.
    """
    J_node = grid_state.rejected_momentum + dt * grid_state.rejected_force
    nodes = np.nonzero(np.any(J_node != 0.0, axis=1))[0]
    cdf = contact.cdf
    x_node = cdf.origin + np.stack(np.unravel_index(nodes, cdf.shape), axis=1) * cdf.dx
    return body_impulses(rigid, cdf.body[nodes], x_node, J_node[nodes])


def g2p(particles, v_grid, grid, kernel, spec, dt, prepared, contact, rigid, pushing_force, penalty):
    r"""G2P with ghost velocities at incompatible nodes, then ``C_p := 0`` for near particles and the penalty.

    Incompatible node :math:`i` shows particle :math:`p` its ghost velocity
    (:func:`ghost_velocities`, with the bodies' velocities ``rigid`` of G2P) plus, for a near particle, the
    pushing force: :math:`\tilde{\mathbf v}_i + \mathbf n_p \Delta t\, \Delta x\, f_{push}`. G2P then proceeds
    as usual on these velocities (:math:`\mathbf v_p = \sum_i w_{ip}\tilde{\mathbf v}_i`,
    :math:`C_p`, :math:`F_p`, :math:`\mathbf x_p`). Afterwards, for near particles, :math:`C_p := 0`, and
    if :math:`-0.3\Delta x < \phi_p < -0.05\Delta x` the penalty :math:`\Delta\mathbf v = k \phi_p \mathbf n_p`
    is taken from the particle (:math:`\mathbf v_p \mathrel{-}= \Delta\mathbf v`) and given to its nearest
    body as the impulse :math:`m_p\Delta\mathbf v` at :math:`\mathbf x_p` (docs/cpic.md). With the per-body fit, a
    particle tagged by several bodies gets the penalty of each body instead (:func:`per_body_penalty`), and the
    pushing force along the normal of the ghost's body (:func:`ghost_frames`).

    Returns ``(new particles, (J (nb, 2), L (nb,)))``: the penalty's impulses on the bodies.
    """
    ghost = ghost_velocities(contact, rigid, particles)
    ghost = ghost + np.where(contact.ghost_near[:, :, None], contact.ghost_normal * (dt * grid.dx * pushing_force), 0.0)
    new = plain_g2p(particles, v_grid, None, grid, kernel, spec, dt, prepared, ghost=(contact.compatible, ghost))
    if new.C is not None:
        new = new.with_(C=np.where(particles.near[:, None, None], 0.0, new.C))
    several = _several(contact, particles)
    pushed = ~several & in_penalty_window(particles.near, particles.phi, grid.dx, penalty)
    dv = np.where(pushed[:, None], penalty * particles.phi[:, None] * particles.normal, 0.0)
    body = _nearest_tagged_body(contact, particles)[pushed]
    at, impulse = new.x[pushed], particles.mass[pushed, None] * dv[pushed]
    if contact.fit is not None:
        dv_r, pushed_r = per_body_penalty(contact.fit, several, grid.dx, penalty)
        dv = dv + dv_r.sum(axis=1)
        p, r = np.nonzero(pushed_r)
        body, at = np.concatenate([body, r]), np.concatenate([at, new.x[p]])
        impulse = np.concatenate([impulse, particles.mass[p, None] * dv_r[p, r]])
    new = new.with_(v=(new.v - dv).astype(new.v.dtype))
    J, L = body_impulses(rigid, body, at, impulse)
    return new, (J, L)


def in_penalty_window(near, phi, dx, penalty):
    """Where the penalty acts: ``near`` and :math:`-0.3\\Delta x < \\phi < -0.05\\Delta x`, with a penalty ``k > 0``."""
    lo, hi = PENALTY_WINDOW
    return near & (phi > lo * dx) & (phi < hi * dx) & (penalty > 0.0)


def per_body_penalty(fit, several, dx, penalty):
    r"""The penalty per body of particles tagged by several bodies (per-body fit, docs/cpic.md).

    For each body :math:`r` whose fit is accepted and :math:`-0.3\Delta x < \phi_{pr} < -0.05\Delta x`:
    :math:`\Delta\mathbf v_{pr} = k\phi_{pr}\mathbf n_{pr}`, taken from the particle and given to body :math:`r`
    as :math:`m_p\Delta\mathbf v_{pr}`. Returns ``(dv (n, nb, d), pushed (n, nb))``.
    """
    phi, normal, near = fit
    pushed = several[:, None] & in_penalty_window(near, phi, dx, penalty)
    return np.where(pushed[..., None], penalty * phi[..., None] * normal, 0.0), pushed


def _several(contact, particles):
    """Per particle, whether the per-body fit is on and it is tagged by two or more bodies."""
    return (contact.fit is not None) & (np.count_nonzero(particles.tag_A, axis=1) >= 2)


def _nearest_tagged_body(contact, particles):
    """Per particle, the nearest body of its stencil node closest to a body (``0`` where it has none)."""
    d = np.where(contact.body >= 0, contact.cdf.d[contact.node], np.inf)
    k = np.argmin(d, axis=0)
    return np.maximum(contact.body[k, np.arange(particles.n)], 0)
