"""The one sweep executor: this process, local processes, and a Dask distributed scheduler."""

import math
import time

import psutil
import pytest

from verification.framework.executor import Executor

ITEMS = [3, 7, 1, 12, 5]
EXPECTED = [math.factorial(k) for k in ITEMS]


@pytest.mark.parametrize("workers", [1, 2])
def test_local_executor_keeps_the_order_of_items(workers):
    assert Executor(workers=workers).map(math.factorial, ITEMS) == EXPECTED


def test_dask_scheduler_runs_the_same_sweep_in_order():
    import distributed
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster:
        executor = Executor(scheduler=cluster.scheduler_address)
        assert executor.map(math.factorial, ITEMS) == EXPECTED
        assert "dask.distributed" in executor.describe()


@pytest.mark.parametrize("workers", [1, 2])
def test_each_result_is_reported_as_it_arrives_with_its_index(workers):
    seen = []
    results = Executor(workers=workers).map(math.factorial, ITEMS, on_result=lambda i, r: seen.append((i, r)))
    assert results == EXPECTED and sorted(seen) == list(enumerate(EXPECTED))


def pool_workers():
    """The processes this process's fork server started (the executor's local workers)."""
    servers = [c for c in psutil.Process().children() if "forkserver" in " ".join(c.cmdline())]
    return [w for s in servers for w in s.children()]


def test_a_sweep_stopped_by_its_caller_ends_its_running_workers_at_once():
    """Ctrl-C while a result is handed over (``on_result`` raises ``KeyboardInterrupt``): ``map`` raises it at once,
    the two runs of a minute left running are ended, not waited for."""
    def interrupt(index, result):
        raise KeyboardInterrupt

    start = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        Executor(workers=2).map(time.sleep, [0, 60, 60], on_result=interrupt)
    assert time.monotonic() - start < 20
    assert psutil.wait_procs(pool_workers(), timeout=5)[1] == []
