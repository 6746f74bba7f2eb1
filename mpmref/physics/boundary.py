r"""Grid-node velocity projection at walls and colliders (talk Eq. 25).

For a boundary with outward-of-boundary unit normal :math:`n` (pointing into the material) moving
with velocity :math:`v_{co}`, the relative velocity :math:`v_{rel} = v - v_{co}` has normal part
:math:`v_n = v_{rel}\cdot n` and tangential part :math:`v_t = v_{rel} - v_n n`:

* ``sticky``:   :math:`v_{rel} \leftarrow 0`
* ``slip``:     :math:`v_{rel} \leftarrow v_t` (always)
* ``separate``: if :math:`v_n < 0` (approaching),
  :math:`v_{rel} \leftarrow 0` when :math:`\lVert v_t\rVert \le -\mu v_n`, otherwise
  :math:`v_{rel} \leftarrow v_t + \mu v_n\, v_t / \lVert v_t\rVert`; unchanged when separating.

Source: Hu, *Advances in the Material Point Method* (course talk) Eq. 25; Stomakhin et al. 2013 §8;
Jiang et al. 2016 (SIGGRAPH MPM course) §12.1. :math:`\mu` is the Coulomb friction coefficient.
"""

import numpy as np

BOUNDARY_TYPES = ("sticky", "slip", "separate")


def project_velocity(v, normal, kind, friction=0.0, v_collider=None):
    """Apply the Eq. 25 projection to node velocities ``v`` (m, d) with unit normals ``normal`` (m, d).

    ``kind`` is one of ``BOUNDARY_TYPES``; ``friction`` is the Coulomb coefficient (used by
    ``separate``); ``v_collider`` is the boundary's velocity (broadcastable to ``v``, default at rest).
    Returns the projected velocities (a new array).

    Docs: docs/mpm_cycle.md#boundary-conditions-talk-eq-25
    """
    v_co = 0.0 if v_collider is None else v_collider
    v_rel = v - v_co
    if kind == "sticky":
        return np.zeros_like(v) + v_co
    vn = np.einsum("md,md->m", v_rel, normal)
    vt = v_rel - vn[:, None] * normal
    if kind == "slip":
        return vt + v_co
    if kind != "separate":
        raise ValueError(f"unknown boundary type {kind!r}; allowed {BOUNDARY_TYPES}")
    approaching = vn < 0.0
    vt_norm = np.linalg.norm(vt, axis=1)
    sticks = approaching & (vt_norm <= -friction * vn)
    slides = approaching & ~sticks
    out = v_rel.copy()
    out[sticks] = 0.0
    scale = 1.0 + friction * vn[slides] / vt_norm[slides]
    out[slides] = vt[slides] * scale[:, None]
    return out + v_co
