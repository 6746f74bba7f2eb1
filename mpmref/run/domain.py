"""Domain-exit policies: what happens to particles that leave the grid's valid region after a step.

* ``"error"``: nothing is changed; the caller raises :class:`~mpmref.errors.DomainExitError`.
* ``"clamp"``: each escaping particle is moved back just inside the region (by :data:`CLAMP_INSET` of
  the region's extent) and the velocity component along the outward normal of each face it crossed is
  zeroed when it points outward, so that it does not leave again at once. The count is returned.
* ``"delete"``: escaping particles are removed and counted.

Only the particle state is touched; the simulation keeps the counts.
"""

from dataclasses import dataclass

import numpy as np

from ..state import Particles

#: clamped particles are put this fraction of the region's extent inside its faces
CLAMP_INSET = 1e-6


@dataclass(frozen=True)
class DomainExit:
    """The outcome of a policy.

    Attributes
    ----------
    particles : Particles     the state after the policy
    outside : (k,) int array  indices (into the state before the policy) of the particles that left
    clamped : int             particles moved back inside (``"clamp"``)
    deleted : int             particles removed (``"delete"``)
    """

    particles: Particles
    outside: np.ndarray
    clamped: int = 0
    deleted: int = 0


def apply_domain_exit(particles, lo, hi, policy):
    """Apply ``policy`` (``"error"``, ``"clamp"`` or ``"delete"``) to the particles outside ``[lo, hi)``.

    Parameters
    ----------
    particles : Particles
    lo, hi : (d,) arrays   bounds of the valid region (``Scene.valid_region()``)
    policy : str

    Returns
    -------
    DomainExit
    """
    if all_inside(particles.x, lo, hi):  # every particle inside (or none left)
        return DomainExit(particles, np.empty(0, dtype=np.int64))
    below, above = particles.x < lo, particles.x >= hi
    left = np.any(below | above, axis=1)
    index = np.nonzero(left)[0]
    if index.size == 0 or policy == "error":
        return DomainExit(particles, index)
    if policy == "clamp":
        return DomainExit(clamp(particles, lo, hi, below, above), index, clamped=int(index.size))
    return DomainExit(particles.select(~left), index, deleted=int(index.size))


def all_inside(x, lo, hi):
    """Whether every position of ``x`` (n, d) lies in ``[lo, hi)``: each coordinate's smallest and largest value
    against its bounds (a column's reductions take a quarter of the time of comparing the (n, d) array with the
    bounds broadcast, measured at 8 192 particles in 2D: 13 µs against 48 µs a step)."""
    return all(x[:, a].min(initial=np.inf) >= lo[a] and x[:, a].max(initial=-np.inf) < hi[a] for a in range(x.shape[1]))


def outside(x, lo, hi):
    """Boolean mask of the positions ``x`` (n, d) outside the valid region ``[lo, hi)``."""
    return np.any((x < lo) | (x >= hi), axis=1)


def clamp(particles, lo, hi, below, above):
    """Particles moved just inside ``[lo, hi)``, their outward normal velocity zeroed where they crossed a face.

    ``below`` and ``above`` are the (n, d) masks of coordinates under ``lo`` and at or over ``hi``.
    """
    dtype = particles.x.dtype
    inset = np.asarray(CLAMP_INSET * (hi - lo), dtype=dtype)
    x = np.clip(particles.x, lo + inset, hi - inset).astype(dtype)
    v = particles.v.copy()
    v[below & (v < 0)] = 0
    v[above & (v > 0)] = 0
    return particles.with_(x=x, v=v)
