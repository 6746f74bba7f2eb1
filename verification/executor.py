"""One executor for every parameter sweep: local processes by default, a Dask cluster on request.

Sweeps (convergence levels, stability bisections, speed-vs-accuracy grids) are lists of independent
runs. ``Executor.map(fn, items)`` runs ``fn(item)`` for each item and returns the results in the order
of ``items``. ``fn`` must be a module-level function and ``items`` picklable, so the same sweep runs
unchanged in a local process pool or on a ``dask.distributed`` cluster.
"""

import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor

#: Local workers start from a fork server, a clean process started once: forking the main process is
#: unsafe after it has run a parallel Numba kernel (GNU OpenMP aborts the child), and spawning a fresh
#: interpreter per pool would import NumPy, SciPy and Numba again every time.
_CONTEXT = multiprocessing.get_context("forkserver")
_CONTEXT.set_forkserver_preload(["numpy", "scipy.linalg", "mpmref", "verification.registry"])


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

    def map(self, fn, items):
        """``[fn(item) for item in items]``, evaluated where this executor runs work."""
        items = list(items)
        if self.scheduler is not None:
            from dask.distributed import Client

            with Client(self.scheduler) as client:
                return client.gather(client.map(fn, items, pure=False))
        if self.workers <= 1 or len(items) <= 1:
            return [fn(item) for item in items]
        with ProcessPoolExecutor(max_workers=min(self.workers, len(items)), mp_context=_CONTEXT) as pool:
            return list(pool.map(fn, items))

    def describe(self):
        """Where the work runs, for reports."""
        if self.scheduler is not None:
            return f"dask.distributed scheduler {self.scheduler}"
        return "this process" if self.workers <= 1 else f"{self.workers} local processes"
