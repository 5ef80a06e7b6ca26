"""Domain-study executors when the study is stopped: a Ctrl-C sent to the whole process group
(as a terminal sends it) does not end a local worker's run, a task that failed because the
study is stopping is not an error, and a Dask executor waiting for results sees the stop.
The command's way out (exit 130, the finished runs written) is in
``integration/test_domains_interrupts.py``."""

from __future__ import annotations

import os
import signal
import threading
import time

import pytest

from deploy.experiments.domains.run import DaskExecutor, LocalExecutor, gather, settle


def interrupted_worker() -> int:
    """In a worker: the Ctrl-C a terminal sends to every process of its group, then a moment
    for its handler to run; this worker's pid."""
    os.kill(os.getpid(), signal.SIGINT)
    time.sleep(0.2)
    return os.getpid()


def test_a_local_workers_run_outlives_a_ctrl_c_to_its_group() -> None:
    stop = threading.Event()
    try:
        out = gather(LocalExecutor(1), interrupted_worker, [()], stop)
    except KeyboardInterrupt:  # raised in the worker, re-raised here by its future
        pytest.fail("the worker's Ctrl-C reached the main process as an exception")
    assert list(out) == [0] and out[0] != os.getpid()
    assert not stop.is_set()


def broken() -> None:
    raise RuntimeError("worker lost")


def test_a_task_failed_by_the_stop_is_dropped_any_other_failure_raised() -> None:
    stop = threading.Event()
    assert settle(lambda: 3, stop) == (True, 3)
    with pytest.raises(RuntimeError, match="worker lost"):
        settle(broken, stop, grace_s=0.01)
    # The stop set a moment after the task failed (the signal's relay thread comes later than
    # the workers' death): still the stop's doing.
    threading.Timer(0.1, stop.set).start()
    assert settle(broken, stop, grace_s=5.0) == (False, None)
    assert settle(broken, stop, grace_s=0.0) == (False, None)


RELEASE = threading.Event()


def held() -> None:
    """A run that ends when the test says (or after 3 s: long past the stop's moment)."""
    RELEASE.wait(3.0)


def test_a_dask_executor_waiting_for_results_sees_the_stop() -> None:
    """Its workers gone or a run long, it waited for the next result before looking at the
    stop: for ever when none would come."""
    import distributed  # the cluster extra, which make installs

    cluster = distributed.LocalCluster(
        n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None
    )
    executor = DaskExecutor.__new__(DaskExecutor)  # in threads of this process, not processes
    executor.cluster, executor.client = cluster, distributed.Client(cluster)
    stop = threading.Event()
    RELEASE.clear()
    try:
        threading.Timer(0.5, stop.set).start()
        started = time.monotonic()
        out = gather(executor, held, [(), ()], stop)
        waited = time.monotonic() - started
    finally:
        RELEASE.set()
        executor.close()
    assert out == {}
    assert waited < 2.0, waited
