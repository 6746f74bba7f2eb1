r"""Kernel helpers of the Numba CPIC stages that are the same in 2D and 3D: how a body's rasterised pairs settle
the colored distance field, a particle's sticky tag, and whether a node enters a particle's least-squares fit
(Hu et al. 2018, SIGGRAPH, §4; :mod:`mpmref.physics.cdf`; docs/cpic.md)."""

import numpy as np
from numba import njit

from ....physics.cdf import TAG_THRESHOLD


def empty_field(n_nodes, n_bodies):
    """The arrays of a colored distance field before rasterising, ``(d, nearest, A, T, d_body)``: no node in a
    band (distances ``inf``, nearest body -1, no :math:`A_{ir}`, :math:`T_{ir}`)."""
    return (np.full(n_nodes, np.inf), np.full(n_nodes, -1, dtype=np.int64),
            np.zeros((n_nodes, n_bodies), dtype=np.bool_), np.zeros((n_nodes, n_bodies), dtype=np.bool_),
            np.full((n_nodes, n_bodies), np.inf))


@njit(cache=True, inline="always")
def add_pair(flat, h, r, count, pair_node, pair_h, d_r, A):
    r"""Record body ``r``'s ``count``-th rasterised pair (node ``flat``, signed offset :math:`h`): the body's
    distance :math:`d_{ir} = \min(d_{ir}, |h|)` and :math:`A_{ir} = 1`; returns the new count
    (:func:`settle_body` settles the pairs)."""
    pair_node[count] = flat
    pair_h[count] = h
    d_r[flat] = min(d_r[flat], abs(h))
    A[flat, r] = True
    return count + 1


@njit(cache=True, inline="always")
def node_incompatible(p, idx, A, T, A_p, T_p):
    r"""Whether node ``idx`` is incompatible with particle ``p``: some body :math:`r` has :math:`A_{ir} = A_{pr}
    = 1` and :math:`T_{ir} \ne T_{pr}` (Hu et al. 2018 §4; docs/cpic.md)."""
    for r in range(A_p.shape[1]):
        if A[idx, r] and A_p[p, r] and T[idx, r] != T_p[p, r]:
            return True
    return False


@njit(cache=True, inline="always")
def settle_body(r, count, pair_node, pair_h, d_r, d, nearest, T, d_body):
    r"""After body ``r``'s ``count`` rasterised (node, :math:`h`) pairs: the body's own distance
    :math:`d_{ir}` into ``d_body``, :math:`T_{ir} = [h < 0]` from the pairs at :math:`d_{ir}` (the last such pair
    wins), node :math:`i`'s nearest body is ``r`` if :math:`d_{ir} < d_i` (so the first body wins a tie), and
    ``d_r`` is reset to ``inf`` for the next body."""
    for c in range(count):
        d_body[pair_node[c], r] = d_r[pair_node[c]]
    for c in range(count):
        if abs(pair_h[c]) == d_r[pair_node[c]]:
            T[pair_node[c], r] = pair_h[c] < 0.0
    for c in range(count):
        flat = pair_node[c]
        if d_r[flat] < d[flat]:
            d[flat] = d_r[flat]
            nearest[flat] = r
    for c in range(count):
        d_r[pair_node[c]] = np.inf


@njit(cache=True, inline="always")
def sticky_tag(p, r, near_r, S0, S1, tag_A, tag_T, A_new, T_new):
    r"""Particle ``p``'s new tag of body ``r``: kept while the body stays near (``near_r[r]``), cleared otherwise; a
    newly near body tags it if :math:`S_0 + S_1 > 10^{-7}`, on side :math:`[S_1 > S_0]`. Returns :math:`A_{pr}`."""
    a = tag_A[p, r] and near_r[r]
    t = tag_T[p, r] and a
    if near_r[r] and not a and S0[r] + S1[r] > TAG_THRESHOLD:
        a, t = True, S1[r] > S0[r]
    A_new[p, r], T_new[p, r] = a, t
    return a


@njit(cache=True, inline="always")
def fit_target(p, flat, dx, d, A, T, A_p, T_p):
    r"""Whether node ``flat`` enters particle ``p``'s least-squares fit, and its target :math:`y_i`: the node carries a
    body and at most one body shared with the particle puts them on different sides; :math:`y_i = +d_i/\Delta x`
    if none does (compatible), :math:`-d_i/\Delta x` if one does (:func:`mpmref.physics.cdf.reconstruct`)."""
    has_body = False
    differing = 0
    for r in range(A_p.shape[1]):
        if A[flat, r]:
            has_body = True
            if A_p[p, r] and T[flat, r] != T_p[p, r]:
                differing += 1
    y = d[flat] / dx
    return has_body and differing <= 1, (-y if differing == 1 else y)


@njit(cache=True, inline="always")
def add_side_sums(flat, w, A, T, d, near_r, S0, S1):
    r"""Add stencil node ``flat`` (weight ``w``) to a particle's side sums of every body :math:`r` with
    :math:`A_{ir} = 1`: ``near_r[r]`` set, :math:`S_{T_{ir}} \mathrel{+}= w_{ip} d_i` (:func:`sticky_tags`)."""
    for r in range(near_r.shape[0]):
        if A[flat, r]:
            near_r[r] = True
            if T[flat, r]:
                S1[r] += w * d[flat]
            else:
                S0[r] += w * d[flat]


@njit(cache=True, inline="always")
def sticky_tags(p, near_r, S0, S1, tag_A, tag_T, A_new, T_new):
    """Particle ``p``'s new tags of every body (:func:`sticky_tag`, from the side sums of
    :func:`add_side_sums`); returns whether some body tags it."""
    tagged = False
    for r in range(near_r.shape[0]):
        tagged = sticky_tag(p, r, near_r, S0, S1, tag_A, tag_T, A_new, T_new) or tagged
    return tagged


@njit(cache=True, inline="always")
def tagged_by_several(p, A_p):
    """Whether two or more bodies tag particle ``p`` (``A_p[p, r]``): the per-body fit then gives it a fit per body."""
    tagged = 0
    for r in range(A_p.shape[1]):
        tagged += A_p[p, r]
    return tagged >= 2


@njit(cache=True, inline="always")
def body_target(p, flat, r, dx, d_body, T, T_p):
    r"""The per-body fit's target of node ``flat`` for body ``r``: :math:`y_{ir} = \pm d_{ir}/\Delta x`, ``+`` iff
    :math:`T_{ir} = T_{pr}` (:func:`mpmref.physics.cdf.reconstruct_per_body`)."""
    y = d_body[flat, r] / dx
    return -y if T[flat, r] != T_p[p, r] else y


@njit(cache=True, inline="always")
def crossed_body(p, idx, tag_T, fits):
    r"""With the per-body fit (``fits`` a :class:`~mpmref.backends.numba.kernel_args.BodyFits`), the body :math:`c`
    whose own fit gives the ghost velocity of incompatible node ``idx`` for particle ``p``: :math:`A_{ic} = A_{pc}
    = 1`, :math:`T_{ic} \ne T_{pc}`, the least :math:`d_{ic}`, the lowest id on a tie, if its per-body fit is
    accepted; otherwise -1 (the single fit then applies; :func:`mpmref.backends.numpy.cpic.ghost_frames`). The
    kernels call it only when compiled for the per-body fit (their ``PER_BODY``)."""
    A, T, d_body, tag_A, fit_near = fits.A, fits.T, fits.d_body, fits.tag_A, fits.near
    c, best = -1, np.inf
    for r in range(tag_A.shape[1]):
        if A[idx, r] and tag_A[p, r] and T[idx, r] != tag_T[p, r] and d_body[idx, r] < best:
            c, best = r, d_body[idx, r]
    return c if c >= 0 and fit_near[p, c] else -1
