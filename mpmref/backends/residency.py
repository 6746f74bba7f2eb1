"""Where a run keeps the particles, and the arrays a backend reuses from step to step.

The stages of every backend take particles and return particles (:mod:`mpmref.backends.base`). The NumPy and
Numba backends work on the host's NumPy arrays, and a run holds those. A backend whose arrays live in another
memory, a GPU's, would lose most of its speed if every step copied the particles there and back: such a backend is
**resident**. It has four more methods (:class:`Resident`): it moves particles to its memory and back, copies one of
its arrays to the host, and reduces a state where it lives to the few numbers a run checks every step (a
:class:`Summary`). It alone knows which arrays are its own; nothing else asks.

A run (:class:`mpmref.run.Simulation`) asks every backend alike, through the :class:`Memory` of its particles: a
:class:`DeviceMemory` for a resident backend (the particles stay there from step to step, moved once, handed from
stage to stage through the one step :func:`mpmref.steppers.pipeline.substep`, copied to the host only for an output,
a diagnostics row, a checkpoint or a read of ``sim.x`` and the like), a :class:`HostMemory` for any other (the
particles are the host's arrays; the summary is computed from them). Each step the run checks the summary: non-finite
values, the particles' extent against the domain, the largest velocity change (the boundedness check of
:mod:`mpmref.run.stability`) and the largest signal speed (the CFL rule's :math:`\\max_p(c_p + |v_p|)`). Only when
one of them calls for it does it look closer, on the host, with the run's usual code (the same messages, the same
last good state). The energy ledger, which sums NumPy arrays, observes a resident run's stages through
:class:`HostObserver`.

The stages of a resident backend also accept host particles (and return host arrays for them): that is how the
conformance harness, the verification cases that call the stages directly, and a run with step hooks (Python
functions of host arrays, :class:`mpmref.steppers.Hooks`) use it.

The arrays a backend writes its stage outputs into come from one :class:`ArrayPool`, on the host or on the device.
"""

import sys
from dataclasses import replace
from typing import NamedTuple, Protocol, runtime_checkable

import numpy as np

#: the methods that make a backend resident
RESIDENT_METHODS = ("to_device", "to_host", "host_array", "summarize")


class Summary(NamedTuple):
    """What a run checks of a state each step, reduced where the particles are.

    Attributes
    ----------
    nonfinite : tuple of str    the particle fields holding a non-finite value (empty if none)
    lower, upper : (d,) arrays  the smallest and largest coordinate of the positions per axis (``inf`` and ``-inf``
                                without particles)
    velocity_change : float     the largest :math:`|v_{p,a} - v^{old}_{p,a}|` over particles and components (0
                                without a previous state)
    signal_speed : float        the largest :math:`c_p + |v_p|` (the CFL rule's, :mod:`mpmref.steppers.limits`);
                                ``None`` from a :class:`HostMemory` that was given no rule for it (a fixed Δt)
    """

    nonfinite: tuple
    lower: np.ndarray
    upper: np.ndarray
    velocity_change: float
    signal_speed: float | None

    def inside(self, lo, hi):
        """Whether every position lies in ``[lo, hi)`` (the run's valid region)."""
        return bool(np.all(self.lower >= lo) and np.all(self.upper < hi))


@runtime_checkable
class Resident(Protocol):
    """A backend that keeps the particles in its own memory during a run (the module docstring)."""

    def to_device(self, particles):
        """-> the host ``particles`` in the backend's memory (a :class:`~mpmref.state.Particles` of its arrays)"""

    def to_host(self, particles):
        """-> the backend's ``particles`` as NumPy arrays"""

    def host_array(self, array):
        """-> ``array`` as a NumPy array: a copy of one in the backend's memory, any other as it is"""

    def summarize(self, particles, previous=None):
        """-> the :class:`Summary` of ``particles`` (and of their velocity change since ``previous``)"""


def resident(backend):
    """Whether ``backend`` keeps the particles in its own memory (has every method of :class:`Resident`)."""
    return all(callable(getattr(backend, name, None)) for name in RESIDENT_METHODS)


class HostMemory:
    """The particles of a run on the host (its backend keeps none of its own, or its run has step hooks): the
    :class:`DeviceMemory` methods, for NumPy arrays.

    ``signal_speeds(particles)``, :math:`c_p + |v_p|` of each particle, is the CFL rule's (``None`` where the run's Δt
    is fixed or its stepper sets its own: the summary's ``signal_speed`` is then ``None``)."""

    def __init__(self, signal_speeds=None):
        self.signal_speeds = signal_speeds

    @staticmethod
    def host_state(state):
        """The state itself."""
        return state

    device_state = host_state

    @staticmethod
    def observer(ledger):
        """The ledger itself (it sums host arrays)."""
        return ledger

    def summarize(self, particles, previous=None):
        """The :class:`Summary` of the host ``particles``: a field is flagged when its sum is not finite (as a
        non-finite value makes it; an overflowing sum of finite values is flagged too, and the run's closer look
        clears it), every float field."""
        nonfinite = tuple(name for name, a in particles.arrays().items()
                          if a.dtype.kind == "f" and not np.isfinite(np.sum(a)))
        x = particles.x  # each coordinate's extent by a column's reductions (as mpmref.run.domain.all_inside)
        lower = np.array([x[:, a].min(initial=np.inf) for a in range(x.shape[1])])
        upper = np.array([x[:, a].max(initial=-np.inf) for a in range(x.shape[1])])
        change = 0.0 if previous is None else float(np.abs(particles.v - previous.v).max(initial=0.0))
        speed = None if self.signal_speeds is None else float(self.signal_speeds(particles).max(initial=0.0))
        return Summary(nonfinite, lower, upper, change, speed)


class DeviceMemory:
    """The particles of a run in a resident ``backend``'s memory (:class:`Resident`), as the run asks for them."""

    def __init__(self, backend):
        self.backend = backend

    def host_state(self, state):
        """``state`` with host copies of its particles."""
        return replace(state, particles=self.backend.to_host(state.particles))

    def device_state(self, state):
        """The host ``state`` with its particles in the backend's memory."""
        return replace(state, particles=self.backend.to_device(state.particles))

    def observer(self, ledger):
        """The ledger, shown host copies (:class:`HostObserver`)."""
        return HostObserver(ledger, self.backend)

    def summarize(self, particles, previous=None):
        """The backend's :class:`Summary`, reduced where the particles are."""
        return self.backend.summarize(particles, previous)


class HostObserver:
    """An observer of :func:`~mpmref.steppers.pipeline.substep` (the energy ledger) shown host copies of what a
    resident ``backend``'s stages hand on: the particles at the step's start, after G2P and at its end, and the grid
    state (dense, every node in C order) and velocity after the grid update. Every other attribute is the observer's
    own (``last``, ``shares``, ``scale``)."""

    def __init__(self, observer, backend):
        self.observer, self.backend = observer, backend

    def __getattr__(self, name):
        return getattr(self.observer, name)

    def start(self, particles, rigid=None, exchange=None):
        return self.observer.start(self.backend.to_host(particles), rigid, exchange)

    def grid(self, grid_state, v_grid, dt, time):
        dense = grid_state.dense()
        host = type(grid_state)(**{name: self.backend.host_array(a) for name, a in dense.node_arrays().items()})
        return self.observer.grid(host, self.backend.host_array(v_grid), dt, time)

    def g2p(self, trial):
        return self.observer.g2p(self.backend.to_host(trial))

    def finish(self, new, rigid=None):
        return self.observer.finish(self.backend.to_host(new), rigid)


def unreferenced(array, holders=1):
    """Whether nothing refers to ``array`` but its ``holders`` (CPython's reference count, which counts views through
    their ``base`` too; not counted: the caller's one name for it, this function's argument and ``sys.getrefcount``'s):
    the one test of every pool that hands arrays out again (:class:`ArrayPool`,
    :class:`mpmref.steppers.async_store.StorePool`)."""
    return sys.getrefcount(array) <= holders + 3


class ArrayPool:
    """Sets of arrays a backend writes its stage outputs into, reused from step to step instead of allocated anew.

    A step's outputs (the new particle arrays of G2P, the node rows of P2G, the node velocities of the grid update)
    have the same shapes every step. The pool keeps up to ``keep`` sets of them per kind, shapes and dtype, and hands
    a set out again only when nothing outside the pool refers to any of its arrays any more (CPython's reference
    count, which counts views through their ``base`` too). A run that keeps only the current state and the one before
    it — the last good state a non-finite step rolls back to — therefore swaps between two sets (a double buffer) and
    never copies, while a state that someone still holds (a list of states, a checkpoint in progress, a test comparing
    two runs) is never overwritten: a new set is allocated instead. Sets of only the ``shapes_per_kind`` most recently
    asked-for shapes of a kind are kept (a stepper that advances groups of varying size asks for many).

    ``allocate(shape, dtype)`` makes an array: ``np.empty`` on the host, a device array on a GPU.
    """

    def __init__(self, allocate, dtype, keep=2, shapes_per_kind=2):
        self.allocate, self.dtype = allocate, np.dtype(dtype)
        self.keep, self.shapes_per_kind = keep, shapes_per_kind
        self._sets = {}

    def take(self, kind, *shapes, dtype=None):
        """A tuple of uninitialised arrays of ``shapes`` (of ``dtype``, default the pool's): a kept set that is free,
        else a new one (kept while fewer than ``keep`` sets of this kind, shapes and dtype exist)."""
        dtype = self.dtype if dtype is None else np.dtype(dtype)
        key = (kind, shapes, dtype.str)
        kept = self._sets.pop(key, [])
        self._sets[key] = kept  # most recently used last
        same_kind = [k for k in self._sets if k[0] == kind]
        for old in same_kind[:-self.shapes_per_kind]:
            del self._sets[old]
        for arrays in kept:  # a set: held by the list; an array: by its set
            if unreferenced(arrays) and all(unreferenced(a) for a in arrays):
                return arrays
        arrays = tuple(self.allocate(shape, dtype) for shape in shapes)
        if len(kept) < self.keep:
            kept.append(arrays)
        return arrays

    def holds(self, array):
        """Whether ``array`` is one of the kept arrays."""
        return any(array is a for sets in self._sets.values() for arrays in sets for a in arrays)

    def nbytes(self):
        """Bytes held by the kept sets."""
        return sum(a.nbytes for sets in self._sets.values() for arrays in sets for a in arrays)


def memory_of(backend, keep_there, signal_speeds=None):
    """Where a run keeps its particles: the ``backend``'s own memory if it is :func:`resident` and the run lets it
    ``keep_there`` (a :class:`DeviceMemory`), else the host (a :class:`HostMemory` with the CFL rule's
    ``signal_speeds``)."""
    return DeviceMemory(backend) if keep_there and resident(backend) else HostMemory(signal_speeds)
