"""The Numba backend's threads: how many a step uses, how a command chooses them, and what its summary says.

Numba starts its pool of ``NUMBA_NUM_THREADS`` threads (by default one per core) the first time a parallel kernel
runs, and that size cannot change afterwards. :func:`use_threads` chooses how many of them the backend's steps use,
here and in the worker processes started from then on (the local processes of ``mpmref verify`` and ``mpmref
study``, which read the environment variable :data:`THREADS_VARIABLE` when they import mpmref). Each step applies
the choice in the backend's ``running`` context (:func:`threads_for`), which also runs a scene too small to repay
a second thread on one. Which library runs the threads, and why the default one waits without spinning, is
:func:`mpmref._threads_that_wait_quietly` (docs/performance.md, "Threads on a shared machine").
"""

import os
from contextlib import contextmanager

import numba

from ...errors import ArgumentError

#: the environment variable that carries a command's ``--threads`` to the worker processes it starts
THREADS_VARIABLE = "MPMREF_NUMBA_THREADS"
#: below this many particles a step runs on one thread: each parallel region costs a fork and a join, which
#: small problems do not repay. Measured on mpm88 (2 cores, TBB, idle, median of 7 runs): two threads over one
#: 0.96x at 256 particles, 1.06x at 512, 1.11x at 1024, 1.30x at 4096 (docs/performance.md, "Threads on a shared
#: machine"). The answer is the same bits either way (see :mod:`.blocks`).
SERIAL_BELOW = 512


def thread_limit():
    """The most threads this process can use: the size of Numba's pool (``NUMBA_NUM_THREADS``)."""
    return numba.config.NUMBA_NUM_THREADS


def chosen_threads():
    """The thread count chosen by :func:`use_threads` here or in the process that started this one (capped at
    :func:`thread_limit`), or ``None``: Numba's own count (one per core)."""
    chosen = os.environ.get(THREADS_VARIABLE)
    return None if not chosen else min(int(chosen), thread_limit())


def use_threads(count):
    """Run the Numba backend's steps on ``count`` threads here and in the worker processes started from now on.

    Raises :class:`~mpmref.errors.ArgumentError` naming the limit when ``count`` is not between 1 and
    :func:`thread_limit` (the command line: exit status 2).
    """
    limit = thread_limit()
    if not 1 <= count <= limit:
        raise ArgumentError("threads", count, f"1 to {limit}: Numba was started with at most {limit} threads here "
                            "(set NUMBA_NUM_THREADS before starting mpmref to allow more)")
    os.environ[THREADS_VARIABLE] = str(count)
    numba.set_num_threads(count)


def threads_for(n_particles):
    """A context that runs the enclosed stages of a step of ``n_particles`` on the chosen threads
    (:func:`chosen_threads`), or on one when ``n_particles < SERIAL_BELOW`` (:func:`on_threads`)."""
    return on_threads(1 if n_particles < SERIAL_BELOW else chosen_threads())


@contextmanager
def on_threads(count):
    """Run the enclosed code on ``count`` Numba threads (``None``: as it is); the count before is restored after."""
    if count is None:
        yield
        return
    before = numba.get_num_threads()
    numba.set_num_threads(count)
    try:
        yield
    finally:
        numba.set_num_threads(before)


def describe_threads():
    """``"2 threads (tbb)"``: the count a step of many particles runs on and the threading layer that runs it."""
    count = chosen_threads() or numba.get_num_threads()
    return f"{count} thread{'s' if count != 1 else ''} ({threading_layer()})"


def threading_layer():
    """The name of Numba's threading layer: the one loaded, or the one it would load first."""
    try:
        return numba.threading_layer()
    except ValueError:  # no parallel kernel has run yet: ask for the pool (cheap; it is started once)
        numba.get_num_threads()
        return numba.threading_layer()
