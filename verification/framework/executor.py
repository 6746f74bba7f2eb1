"""One executor for every parameter sweep: local processes by default, a Dask cluster on request.

Sweeps (convergence levels, stability bisections, speed-vs-accuracy grids, the runs of ``mpmref study``) are
lists of independent runs. ``Executor.map(fn, items)`` runs ``fn(item)`` for each item and returns the results in
the order of ``items`` (and can report each result as it arrives). ``fn`` must be a module-level function and ``items``
picklable, so the same sweep runs unchanged in a local process pool or on a ``dask.distributed`` cluster. An exception
inside ``fn`` reaches the caller with the scene and the backend's stage where it was raised
(:func:`~verification.framework.failure.locate`, found where it happened, before it leaves the worker).
"""

import multiprocessing
import os
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
        for index, result in self._completed(fn, items):
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
                for future in arrived(futures):
                    yield index[future.key], future.result()
            return
        if self.workers <= 1 or len(items) <= 1:
            yield from ((i, fn(item)) for i, item in enumerate(items))
            return
        with ProcessPoolExecutor(max_workers=min(self.workers, len(items)), mp_context=_CONTEXT) as pool:
            futures = {pool.submit(fn, item): i for i, item in enumerate(items)}
            for future in as_completed(futures):
                yield futures[future], future.result()

    def describe(self):
        """Where the work runs, for reports."""
        if self.scheduler is not None:
            return f"dask.distributed scheduler {self.scheduler}"
        return "this process" if self.workers <= 1 else f"{self.workers} local processes"


def located_call(fn, item):
    """``fn(item)``; an exception is located (:func:`~verification.framework.failure.locate`) where it is raised."""
    try:
        return fn(item)
    except Exception as exc:
        locate(exc)
        raise
