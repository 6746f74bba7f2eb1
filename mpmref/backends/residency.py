"""Where a backend keeps the particles during a run, and what a run asks of one that keeps them elsewhere.

The stages of every backend take particles and return particles (:mod:`mpmref.backends.base`). The NumPy and
Numba backends work on the host's NumPy arrays, and a run holds those. A backend whose arrays live in another
memory, a GPU's, would lose most of its speed if every step copied the particles there and back: such a backend is
**resident**. It has three more methods (:class:`Resident`), and a run (:class:`mpmref.run.Simulation`) then

* moves the particles there once (``to_device``) and hands the backend's own arrays from stage to stage, step after
  step, through the one step :func:`mpmref.steppers.pipeline.substep`;
* checks each step where the particles are (``summarize``: a reduction that returns a few numbers, a
  :class:`Summary`): non-finite values, the particles' extent against the domain, the largest velocity change
  (the boundedness check of :mod:`mpmref.run.stability`) and the largest signal speed (the CFL rule's
  :math:`\\max_p(c_p + |v_p|)`). Only when one of them calls for it, or for an output, a diagnostics row, a
  checkpoint or a read of ``sim.x`` and the like, are the particles copied to the host (``to_host``), where the
  run's usual code acts on them (the same messages, the same last good state);
* lets host observers see host arrays: the energy ledger, which sums NumPy arrays, observes each stage's output
  through :class:`HostObserver`.

The stages of a resident backend also accept host particles (and return host arrays for them): that is how the
conformance harness, the verification cases that call the stages directly, and a run with step hooks (Python
functions of host arrays, :class:`mpmref.steppers.Hooks`) use it. A backend without these methods needs nothing:
:func:`resident` is false and the run keeps its particles on the host as before.
"""

from typing import NamedTuple, Protocol, runtime_checkable

import numpy as np

from ..state import GridState

#: the methods that make a backend resident
RESIDENT_METHODS = ("to_device", "to_host", "summarize")


class Summary(NamedTuple):
    """What a run checks of a state, as a resident backend reduces it where the particles are.

    Attributes
    ----------
    nonfinite : tuple of str    the particle fields holding a non-finite value (empty if none)
    lower, upper : (d,) arrays  the smallest and largest coordinate of the positions per axis (``inf`` and ``-inf``
                                without particles)
    velocity_change : float     the largest :math:`|v_{p,a} - v^{old}_{p,a}|` over particles and components (0
                                without a previous state)
    signal_speed : float        the largest :math:`c_p + |v_p|` (the CFL rule's, :mod:`mpmref.steppers.limits`)
    """

    nonfinite: tuple
    lower: np.ndarray
    upper: np.ndarray
    velocity_change: float
    signal_speed: float

    def inside(self, lo, hi):
        """Whether every position lies in ``[lo, hi)`` (the run's valid region)."""
        return bool(np.all(self.lower >= lo) and np.all(self.upper < hi))


@runtime_checkable
class Resident(Protocol):
    """A backend that keeps the particles in its own memory during a run (the module docstring)."""

    def to_device(self, particles):
        """-> the particles in the backend's memory (a :class:`~mpmref.state.Particles` of its arrays)"""

    def to_host(self, particles):
        """-> the particles as NumPy arrays (host particles are returned as they are)"""

    def summarize(self, particles, previous=None):
        """-> the :class:`Summary` of ``particles`` (and of their velocity change since ``previous``)"""


def resident(backend):
    """Whether ``backend`` keeps the particles in its own memory (has every method of :class:`Resident`)."""
    return all(callable(getattr(backend, name, None)) for name in RESIDENT_METHODS)


def is_device(array):
    """Whether ``array`` is a device array (numba-cuda's, or the simulator's)."""
    return hasattr(array, "copy_to_host")


def on_host(array):
    """``array`` as a NumPy array (a device array is copied; anything else is returned as it is)."""
    return array.copy_to_host() if is_device(array) else array


def host_grid(grid_state):
    """A grid state with NumPy arrays over every node in C order (:meth:`~mpmref.state.GridState.dense`)."""
    dense = grid_state.dense()
    if dense is grid_state and not any(is_device(a) for a in grid_state.node_arrays().values()):
        return grid_state
    return GridState(**{name: on_host(a) for name, a in dense.node_arrays().items()})


class HostObserver:
    """An observer of :func:`~mpmref.steppers.pipeline.substep` (the energy ledger) shown host copies of what a
    resident ``backend``'s stages hand on: the particles at the step's start, after G2P and at its end, and the grid
    state and velocity after the grid update. Every other attribute is the observer's own (``last``, ``shares``,
    ``scale``)."""

    def __init__(self, observer, backend):
        self.observer, self.backend = observer, backend

    def __getattr__(self, name):
        return getattr(self.observer, name)

    def start(self, particles, rigid=None, exchange=None):
        return self.observer.start(self.backend.to_host(particles), rigid, exchange)

    def grid(self, grid_state, v_grid, dt, time):
        return self.observer.grid(host_grid(grid_state), on_host(v_grid), dt, time)

    def g2p(self, trial):
        return self.observer.g2p(self.backend.to_host(trial))

    def finish(self, new, rigid=None):
        return self.observer.finish(self.backend.to_host(new), rigid)
