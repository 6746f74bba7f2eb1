r"""CPIC stages of the Numba backend: the colored distance field, the particles' tags and distance,
P2G to compatible nodes, the bodies' impulses and G2P with ghost velocities, compiled.

Modules: :mod:`.stages` (the stages the backend calls, one code path for 2D and 3D), over the kernels of each
dimension, chosen once per step (:data:`.stages.KERNELS`): :mod:`.field2d` and :mod:`.field3d` (the field, the
tags, the least-squares fits), :mod:`.transfer2d` and :mod:`.transfer3d` (ghost velocities, P2G, impulses,
G2P); :mod:`.common` holds the kernel helpers that are the same in both.

The equations are those of the NumPy reference (:mod:`mpmref.backends.numpy.cpic`,
:mod:`mpmref.physics.cdf`, :func:`mpmref.rigid.dynamics.friction_projection`); Hu et al. 2018,
SIGGRAPH, §4–5, as the authors' reference implementation does (docs/cpic.md). What differs is only how
the work is laid out:

* the field is rasterised body by body, sample by sample, in the reference's order (so that its
  deterministic tie rules — the nearest element decides a node's side, the lower body id wins a tie in
  distance — give the same bits);
* the tagging runs over the particles' blocks and skips a block whose particles' stencils reach no node of
  any body's band (most blocks), and writes only the particles near a body;
* per particle, the contact keeps a bit mask of the incompatible nodes of its transfer stencil instead of
  ``(K, n)`` arrays; ghost velocities are formed inside P2G and G2P from the node's nearest body, the
  particle's normal and friction, and the bodies' velocities of that stage;
* P2G runs block-parallel by colour (:mod:`mpmref.backends.numba.blocks`), so each node receives its contributions, the
  rejected momentum and force included, in a fixed order for any thread count;
* impulses are reduced in a fixed order: P2G's serially node by node; the penalty's particle by particle
  within each block by the parallel G2P, then block by block: the same bits for any thread count, no
  atomics.

Only the posing of the bodies' polylines and their surface samples (a few points per body, not per node or
particle) stay in NumPy (:func:`mpmref.rigid.dynamics.current_shapes`,
:func:`mpmref.rigid.polyline.surface_samples`).
"""

from .stages import Contact, contact, g2p, impulses, p2g, warm_up

__all__ = ["Contact", "contact", "g2p", "impulses", "p2g", "warm_up"]
