"""Timing helpers: thread counts per backend, and the median of repeats with the first call kept apart."""

import statistics
import time

from ..errors import MpmrefError


def thread_counts(backend, threads):
    """The thread counts a backend runs at: all of ``threads`` for Numba, whose threads mpmref sets; only 1 for the
    NumPy reference (single-threaded) and for any other backend (which sets its own threads)."""
    return list(threads) if backend == "numba" else [1]


def check_threads(backends, threads):
    """Refuse, before any work, thread counts that a backend cannot run (more than Numba started with)."""
    if "numba" not in backends:
        return
    import numba

    limit = numba.config.NUMBA_NUM_THREADS
    if max(threads) > limit:
        raise MpmrefError(f"--threads {max(threads)}: Numba was started with at most {limit} threads "
                          "(set NUMBA_NUM_THREADS before starting mpmref to allow more)")


def set_threads(backend, threads):
    """Make ``backend`` use ``threads`` worker threads (``numba.set_num_threads``; NumPy runs on one)."""
    if backend == "numba":
        import numba

        numba.set_num_threads(threads)


def measure(run, repeats, setup=tuple, first=None):
    """Time ``first(*setup())`` once, then ``run(*setup())`` ``repeats`` times; ``setup`` is not timed.

    The first call (``first`` defaults to ``run``) includes any JIT compilation and is reported
    apart as ``first_call_s``; ``median_s`` is the median of the repeats, ``times_s`` all of them.
    Returns ``(record, result of the last run)``.
    """
    first_s, _ = _timed(first or run, setup)
    times, result = [], None
    for _ in range(repeats):
        elapsed, result = _timed(run, setup)
        times.append(elapsed)
    return {"first_call_s": first_s, "times_s": times, "median_s": statistics.median(times)}, result


def _timed(call, setup):
    args = setup()
    start = time.perf_counter()
    result = call(*args)
    return time.perf_counter() - start, result
