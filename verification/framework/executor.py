"""One executor for every parameter sweep: local processes by default, a Dask cluster on request.

Sweeps (convergence levels, stability bisections, speed-vs-accuracy grids, the runs of ``mpmref study``) are
lists of independent runs. ``Executor.map(fn, items)`` runs ``fn(item)`` for each item and returns the results in
the order of ``items`` (and can report each result as it arrives). ``fn`` must be a module-level function and ``items``
picklable, so the same sweep runs unchanged in a local process pool or on a ``dask.distributed`` cluster. An exception
inside ``fn`` reaches the caller with the scene and the backend's stage where it was raised
(:func:`~verification.framework.failure.locate`, found where it happened, before it leaves the worker).

Ctrl-C stops a sweep at once, whether the terminal sends SIGINT to the whole process group or only to the main
process: the local workers ignore SIGINT (:func:`worker_signals`, as does the other process a command starts, the
background compilation of :mod:`.warmup`), so the main process alone takes it, and on the way out of
:meth:`Executor.map` it cancels the runs not started and ends the running ones (:func:`stop_pool`; a Dask client
cancels its futures). The ``KeyboardInterrupt`` then reaches
the command, which says what is kept and how to resume, and exits with status 130. The results already handed to
``on_result`` are the caller's to keep.
"""

import contextlib
import multiprocessing
import os
import signal
from concurrent.futures import ProcessPoolExecutor, as_completed
from functools import partial

from .failure import locate

#: Local workers start from a fork server, a clean process started once: forking the main process is
#: unsafe after it has run a parallel Numba kernel (GNU OpenMP aborts the child), and spawning a fresh
#: interpreter per pool would import NumPy, SciPy and Numba again every time.
_CONTEXT = multiprocessing.get_context("forkserver")
_CONTEXT.set_forkserver_preload(["numpy", "scipy.linalg", "mpmref", "verification.framework.registry"])


class Executor:
    """Run independent sweep points.

    Parameters
    ----------
    scheduler : str or None
        Address of a running ``dask.distributed`` scheduler (``tcp://host:port``); ``None`` runs in local
        processes.
    workers : int or None
        Local process count (default: the number of CPU cores). ``1`` runs in this process, which is what
        tests and debugging want.
    """

    def __init__(self, scheduler=None, workers=None):
        self.scheduler = scheduler
        self.workers = workers if workers is not None else (os.cpu_count() or 1)

    def map(self, fn, items, on_result=None):
        """``[fn(item) for item in items]``, evaluated where this executor runs work.

        ``on_result(index, result)``, if given, is called in this process as each result arrives (in the order
        they finish: a progress bar, or saving what is done before the whole sweep is)."""
        items = list(items)
        results = [None] * len(items)
        with contextlib.closing(self._completed(fn, items)) as completed:  # an exception here stops the workers
            for index, result in completed:
                results[index] = result
                if on_result is not None:
                    on_result(index, result)
        return results

    def _completed(self, fn, items):
        """``(index, fn(items[index]))`` pairs as the runs finish."""
        fn = partial(located_call, fn)
        if self.scheduler is not None:
            from dask.distributed import Client
            from dask.distributed import as_completed as arrived

            with Client(self.scheduler) as client:
                futures = client.map(fn, items, pure=False)
                index = {future.key: i for i, future in enumerate(futures)}
                try:
                    for future in arrived(futures):
                        yield index[future.key], future.result()
                except BaseException:  # Ctrl-C, or the caller stopped: nothing more runs for this sweep
                    client.cancel(futures, force=True)
                    raise
            return
        if self.workers <= 1 or len(items) <= 1:
            yield from ((i, fn(item)) for i, item in enumerate(items))
            return
        with local_pool(min(self.workers, len(items))) as pool:
            futures = {pool.submit(fn, item): i for i, item in enumerate(items)}
            for future in as_completed(futures):
                yield futures[future], future.result()

    def describe(self):
        """Where the work runs, for reports."""
        if self.scheduler is not None:
            return f"dask.distributed scheduler {self.scheduler}"
        return "this process" if self.workers <= 1 else f"{self.workers} local processes"


@contextlib.contextmanager
def local_pool(workers):
    """A process pool of ``workers`` processes from the fork server, ignoring SIGINT; left by an exception
    (``KeyboardInterrupt``, a failed run, the caller closing the sweep), it is stopped at once (:func:`stop_pool`)
    instead of waiting for the runs still queued, as ``ProcessPoolExecutor``'s own exit would."""
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=_CONTEXT, initializer=worker_signals)
    try:
        yield pool
    except BaseException:
        stop_pool(pool)
        raise
    pool.shutdown()


def stop_pool(pool, grace_s=2.0):
    """Cancel the runs of ``pool`` not yet started and end its worker processes: SIGTERM (a worker exits as from
    ``sys.exit``, :func:`worker_signals`), then SIGKILL for one still alive after ``grace_s`` seconds; returns once the
    pool's own threads and queues are closed, so that no process and no semaphore is left.
    ``shutdown(cancel_futures=True)`` alone would wait for the running ones."""
    processes = list(pool._processes.values())  # the running workers: the pool has no public handle on them
    pool.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        process.terminate()
    for process in processes:
        process.join(grace_s)
        if process.is_alive():
            process.kill()
            process.join()
    pool.shutdown(wait=True)


def worker_signals():
    """How a worker process (a pool's, the background compilation's) takes signals. SIGINT is ignored: Ctrl-C is the
    main process's to handle, which ends its workers (:func:`stop_pool`); a worker that took it would stop one run
    and start the next, or print a traceback while it waits for one. SIGTERM ends it at once, as a process of
    :mod:`multiprocessing` ends (:func:`_terminated`), so that what it made (a progress bar's semaphore) does not
    leak."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _terminated)


def _terminated(signum, frame):
    """End this process now, after :mod:`multiprocessing`'s exit finalizers (which unlink the semaphores it made;
    they are what ``Process`` runs when its target returns). Raising :class:`SystemExit` instead would not end a pool
    worker: it reports the exception as the run's result and takes the next run. A second SIGTERM (the pool sends
    one to every worker when it sees one gone) is ignored: it would cut the finalizers short."""
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    multiprocessing.util._exit_function()
    os._exit(128 + signum)


@contextlib.contextmanager
def interrupts_held():
    """Hold SIGINT back from this thread while a process is started in the block: a spawned interpreter inherits the
    blocked signal (Ctrl-C stays the main process's from its first instruction on, before :func:`worker_signals` runs
    there), and a SIGINT that arrives meanwhile is taken here when the block ends, not lost."""
    held = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, held)


def located_call(fn, item):
    """``fn(item)``; an exception is located (:func:`~verification.framework.failure.locate`) where it is raised."""
    try:
        return fn(item)
    except Exception as exc:
        locate(exc)
        raise
