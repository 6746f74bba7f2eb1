"""Arrays a backend writes its stage outputs into, reused from step to step instead of allocated anew.

A step's outputs (the new particle arrays of G2P, the node rows of P2G, the node velocities of the grid
update) have the same shapes every step. :class:`BufferPool` keeps up to ``keep`` sets of them per kind and
hands a set out again only when nothing outside the pool refers to any of its arrays any more (CPython's
reference count, which counts views through their ``base`` too). A run that keeps only the current state
and the one before it — the last good state a non-finite step rolls back to — therefore swaps between two
sets (a double buffer) and never copies, while a state that someone still holds (a list of states, a
checkpoint in progress, a test comparing two runs) is never overwritten: a new set is allocated instead.
"""

import sys

import numpy as np

#: references to a free set (or array) seen by :meth:`BufferPool.take`: the pool's list (or tuple), the loop
#: variable, and the argument of ``sys.getrefcount``
_FREE = 3


class BufferPool:
    """Sets of work arrays of one dtype, reused once nobody else holds them (see the module doc).

    At most ``keep`` sets are kept per kind and shapes, and sets of only the ``shapes_per_kind`` most
    recently asked-for shapes of a kind (a stepper that advances groups of varying size, such as the
    asynchronous one, asks for many shapes; older ones are let go rather than kept forever).
    """

    def __init__(self, dtype, keep=2, shapes_per_kind=2):
        self.dtype, self.keep, self.shapes_per_kind = np.dtype(dtype), keep, shapes_per_kind
        self._sets = {}

    def take(self, kind, *shapes):
        """A tuple of uninitialised arrays of ``shapes``: a kept set that is free, else a new one (kept while
        fewer than ``keep`` sets of this kind and shapes exist)."""
        key = (kind, shapes)
        kept = self._sets.pop(key, [])
        self._sets[key] = kept  # most recently used last
        same_kind = [k for k in self._sets if k[0] == kind]
        for old in same_kind[:-self.shapes_per_kind]:
            del self._sets[old]
        for arrays in kept:
            if sys.getrefcount(arrays) <= _FREE and all(sys.getrefcount(a) <= _FREE for a in arrays):
                return arrays
        arrays = tuple(np.empty(shape, dtype=self.dtype) for shape in shapes)
        if len(kept) < self.keep:
            kept.append(arrays)
        return arrays

    def holds(self, array):
        """Whether ``array`` is one of the kept arrays."""
        return any(array is a for sets in self._sets.values() for arrays in sets for a in arrays)

    def nbytes(self):
        """Bytes held by the kept sets."""
        return sum(a.nbytes for sets in self._sets.values() for arrays in sets for a in arrays)
