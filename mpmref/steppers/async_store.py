"""The particle arrays that asynchronous stepping keeps from update to update, ordered by step.

A level update of :mod:`mpmref.steppers.asynchronous` advances the particles of one level, plus ghosts. When the
particles are stored ordered by their current step (finest first), the particles of a level are one contiguous run
of rows, and the particles due at a tick (those whose step divides it: the finest levels) are a prefix of the rows.
A :class:`RowStore` holds every field of the particles with **spare rows** after them: an update copies its ghosts
there, and the stages then advance the level's rows and the ghost rows where they are, in place
(:class:`~mpmref.backends.base.RowBackend`), so an update gathers its ghosts and nothing else. When particles change
their step, only the rows out of their level's run move (:func:`~.async_kernels.misplaced_rows`).

An interval of asynchronous stepping copies the state it starts from into a store once (a state is never
modified: it is the last good state a failed step falls back to), and the state it returns holds views of the
store's rows. So that the next interval does not write into the state it reads, a :class:`StorePool` hands out a
store that nothing outside the pool refers to: two of them alternate, as the two sets of a double buffer.
"""

import numpy as np

from ..backends.residency import unreferenced
from ..state import Particles

#: references to a store's array that the store itself holds: its dict and its :class:`Particles`
_HELD = 2


class RowStore:
    """Every field of ``n`` particles in arrays of ``capacity`` rows (the rows past ``n`` are spare, for ghosts).

    Attributes
    ----------
    n : int                 the particles' rows, ``0 .. n - 1``
    capacity : int          rows of every array
    particles : Particles   the arrays at their full capacity (what the stages of an update read and write)
    """

    def __init__(self, like, n, capacity):
        self.n, self.capacity = n, capacity
        self.spec = spec_of(like)
        self.arrays = {k: np.empty((capacity,) + shape, dtype) for k, shape, dtype in self.spec}
        self.particles = Particles(**self.arrays)

    def live(self):
        """The particles' rows, as a :class:`Particles` of views (what a state holds)."""
        return Particles(**{k: a[:self.n] for k, a in self.arrays.items()})

    def fill(self, particles):
        """Copy ``particles`` (same fields, ``n`` rows) into the first rows."""
        for k, a in particles.arrays().items():
            self.arrays[k][:self.n] = a

    def free(self):
        """Whether nothing but the store refers to its arrays (no state holds a view of them)."""
        return all(unreferenced(a, _HELD) for a in self.arrays.values())

    def fits(self, particles, capacity):
        """Whether the store holds the fields of ``particles`` and at least ``capacity`` rows."""
        return self.spec == spec_of(particles) and self.capacity >= capacity


def spec_of(particles):
    """The fields of ``particles`` as ``(name, row shape, dtype)``, what a store of them must match."""
    return tuple((k, a.shape[1:], a.dtype) for k, a in particles.arrays().items())


class StorePool:
    """At most ``keep`` :class:`RowStore` objects, handed out again when nothing outside refers to them."""

    def __init__(self, keep=2):
        self.keep, self.stores = keep, []

    def take(self, particles, spare):
        """A free store holding a copy of ``particles`` in its first rows, with at least ``spare`` spare rows; kept
        while fewer than ``keep`` are."""
        n = particles.n
        for store in self.stores:
            if store.fits(particles, n + spare) and store.free():
                store.n = n
                break
        else:
            store = RowStore(particles, n, n + max(spare, n // 4, 64))
            self.stores = [s for s in self.stores if s.fits(particles, 0)][-(self.keep - 1):] + [store]
        store.fill(particles)
        return store

    def grown(self, store, spare):
        """A store like ``store`` with at least ``spare`` spare rows, holding its particles' rows (``store`` itself if
        it has them); it replaces ``store`` in the pool."""
        if store.capacity >= store.n + spare:
            return store
        bigger = RowStore(store.particles, store.n, store.n + max(spare, store.capacity - store.n) * 3 // 2)
        bigger.fill(store.live())
        self.stores = [bigger if s is store else s for s in self.stores]
        return bigger
