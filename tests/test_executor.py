"""The one sweep executor: this process, local processes, and a Dask distributed scheduler."""

import math

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
