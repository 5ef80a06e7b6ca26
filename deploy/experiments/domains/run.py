"""Executors of a convergence-domain study: thousands of independent lockstep runs.

A run is a plain picklable value (:class:`~deploy.experiments.domains.study.RunTask`) and a
module-level function (:func:`execute`): the pipeline runs inside whatever process the
executor hands the task to, and comes back as a
:class:`~deploy.experiments.domains.study.DomainRecord`. Two executors, neither a scheduler of
our own:

- :class:`LocalExecutor`: ``--jobs N`` processes of :class:`concurrent.futures.ProcessPoolExecutor`;
- :class:`DaskExecutor`: a Dask distributed cluster (``--cluster ADDRESS``, or
  ``--cluster local:N`` for a :class:`distributed.LocalCluster` of N worker processes). Dask
  retries a task whose worker died (the scheduler reschedules it; ``retries`` covers a task
  that raised) and hands results back as they finish. Dask is the optional extra ``cluster``
  of the package.

Ctrl-C reaches every process of the terminal's group: the local workers (either executor's)
ignore SIGINT, and the main process stops the study (``stop``), keeping what finished.

The pipeline (``--pipeline``): ``inprocess`` (the lockstep loop in one process,
:mod:`deploy.launch.run_inprocess`), ``distributed`` (the four service processes of ``umay
run``, each run under its own Zenoh key prefix and port), or ``module:function`` (a callable
taking the :class:`RunTask`, returning a :class:`~deploy.launch.evaluate.RunResult`; tests
use it). Drawing the starts is spread over the same executor (:func:`draw_one`).
"""

from __future__ import annotations

import importlib
import logging
import signal
import tempfile
import threading
import uuid
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from deploy.experiments.domains.study import (
    Cell,
    DomainRecord,
    DomainStart,
    RunTask,
    StudyDefinition,
    draw_domain_start,
    judge,
)
from deploy.launch.evaluate import RunResult

PIPELINES = ("inprocess", "distributed")
# A task that failed while no stop was set yet is given this long for one to come: a
# SIGTERM sent to the process group kills the workers, and their tasks can fail before the
# main process's own handler has set the stop (a thread sets it, common/stop_signals.py).
STOP_GRACE_S = 1.0
POLL_S = 0.5  # how often an executor waiting for results looks at ``stop``
# A task that raised (not one whose worker died: Dask reschedules those) is tried this many
# more times before the study reports it as an error.
DASK_RETRIES = 2


class ExecutorError(RuntimeError):
    """The executor could not be set up (e.g. Dask not installed, cluster unreachable)."""


# --- what runs in a worker -----------------------------------------------------------------
def ignore_interrupts() -> None:
    """A local worker's start: Ctrl-C, sent to the whole process group, must not end its run
    (the main process decides what stops, and when)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def dask_setup(_worker: object) -> None:
    """Dask's preload hook (this module is the preload of a ``local:N`` cluster's workers,
    restarted ones included): as :func:`ignore_interrupts`, and Dask's own logs at warnings."""
    ignore_interrupts()
    quiet_dask()


def quiet_dask() -> None:
    """Dask's INFO lines (workers starting and closing, a couple of dozen a study) buried the
    study's own on stderr: its warnings and errors only."""
    logging.getLogger("distributed").setLevel(logging.WARNING)


def run_inprocess(task: RunTask) -> RunResult:
    """The lockstep run in this worker's process (:mod:`services.pipeline`), equal to the
    distributed one frame for frame (tests/integration/test_pipeline_vs_distributed.py)."""
    from deploy.launch.run_inprocess import run_scenario_inprocess

    return run_scenario_inprocess(task.scenario())


def run_distributed(task: RunTask) -> RunResult:
    """The four-process lockstep pipeline under its own key prefix and port (a worker runs
    beside others on the same host), logs in a temporary folder."""
    from common.session import free_tcp_endpoint
    from deploy.launch.run import run_once

    prefix = f"umay/domains-{uuid.uuid4().hex[:8]}/{task.key}"
    with tempfile.TemporaryDirectory(prefix="umay-domains-") as logs:
        return run_once(
            task.scenario_path,
            task.scenario(),
            list(task.overrides),
            prefix=prefix,
            log_dir=Path(logs),
            listen=free_tcp_endpoint(),
            quiet=True,
        )


def resolve_runner(pipeline: str) -> Callable[[RunTask], RunResult]:
    if pipeline == "inprocess":
        return run_inprocess
    if pipeline == "distributed":
        return run_distributed
    module, sep, name = pipeline.partition(":")
    if not sep:
        raise ExecutorError(
            f"--pipeline: {pipeline!r}: one of {', '.join(PIPELINES)} or module:function"
        )
    try:
        return getattr(importlib.import_module(module), name)
    except (ImportError, AttributeError) as exc:
        raise ExecutorError(f"--pipeline: {pipeline!r}: {exc}") from exc


def execute(task: RunTask, pipeline: str) -> DomainRecord:
    """One run in this process, judged."""
    return judge(task, resolve_runner(pipeline)(task))


def draw_one(
    study: StudyDefinition,
    base_path: str,
    cell: Cell,
    draw: int,
    overrides: tuple[str, ...] = (),
) -> DomainStart:
    """One start, drawn in this process (the inverse kinematics is most of a plan's time), on
    the base scenario as its runs will see it: the study's overrides, then ``overrides`` (the
    command line's); e.g. with the orientation cue only the unturned goal is a goal."""
    from common.config import load_scenario
    from common.runtime import parse_overrides

    base = load_scenario(base_path, parse_overrides([*study.overrides, *overrides]))
    return draw_domain_start(study, base, cell, draw)


# --- executors -----------------------------------------------------------------------------
def settle(
    result: Callable[[], Any], stop: threading.Event, grace_s: float = STOP_GRACE_S
) -> tuple[bool, Any]:
    """``(True, value)`` of a finished task (``result``: its future's ``result``); ``(False,
    None)`` if it failed because the study is stopping (its worker ended by the same signal:
    the run is not done, and is run again by ``--resume``). Any other failure is raised."""
    try:
        return True, result()
    except BaseException:
        if stop.wait(grace_s):
            return False, None
        raise


class Executor(Protocol):
    name: str

    def run(
        self,
        fn: Callable[..., Any],
        items: Sequence[tuple[Any, ...]],
        on_done: Callable[[int, Any], None],
        stop: threading.Event,
    ) -> None:
        """Call ``fn(*item)`` for every item somewhere, ``on_done(index, value)`` in this
        thread as each finishes (any order); stop submitting and cancel what has not started
        when ``stop`` is set, and keep nothing that finishes after (a run the signal reached,
        e.g. a distributed pipeline's services, may have been cut short)."""

    def close(self) -> None: ...


@dataclass
class LocalExecutor:
    """``jobs`` worker processes on this machine (spawned: no state of this process, Zenoh
    sessions or GL contexts, is inherited)."""

    jobs: int

    @property
    def name(self) -> str:
        return f"--jobs {self.jobs}"

    def run(self, fn, items, on_done, stop) -> None:
        import multiprocessing

        context = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(
            max_workers=self.jobs, mp_context=context, initializer=ignore_interrupts
        ) as pool:
            pending = list(enumerate(items))
            running: dict[Future, int] = {}
            try:
                while (pending or running) and not stop.is_set():
                    # Keep only a few queued beyond the workers, so a stop leaves little to cancel.
                    while pending and len(running) < 2 * self.jobs:
                        i, item = pending.pop(0)
                        running[pool.submit(fn, *item)] = i
                    done, _ = wait(running, timeout=POLL_S, return_when=FIRST_COMPLETED)
                    for future in done:
                        i = running.pop(future)
                        kept, value = settle(future.result, stop)
                        if not kept or stop.is_set():
                            break
                        on_done(i, value)
            finally:
                for future in running:
                    future.cancel()

    def close(self) -> None:
        pass


class DaskExecutor:
    """A Dask distributed client: to the scheduler at ``address``, or to a new
    :class:`distributed.LocalCluster` of ``local_workers`` worker processes (one thread each:
    one pipeline per worker at a time)."""

    def __init__(self, address: str | None = None, local_workers: int | None = None) -> None:
        try:
            from distributed import Client, LocalCluster
        except ImportError as exc:
            raise ExecutorError(
                "--cluster needs Dask distributed: pip install -e '.[cluster]'"
            ) from exc
        self.cluster = None
        if address is None:
            quiet_dask()  # the scheduler and the nannies run in this process
            self.cluster = LocalCluster(
                n_workers=local_workers or 2,
                threads_per_worker=1,
                processes=True,
                dashboard_address=None,
                preload=[__name__],  # dask_setup: its workers are in our process group
            )
            self.client = Client(self.cluster)
            self.name = f"--cluster local:{local_workers or 2}"
        else:
            try:
                self.client = Client(address, timeout=30)
            except OSError as exc:
                raise ExecutorError(f"--cluster {address}: {exc}") from exc
            self.name = f"--cluster {address}"

    def run(self, fn, items, on_done, stop) -> None:
        from distributed import as_completed

        futures = [
            self.client.submit(fn, *item, pure=False, retries=DASK_RETRIES) for item in items
        ]
        index = {f.key: i for i, f in enumerate(futures)}
        completed = as_completed(futures, with_results=False)
        try:
            # Not a plain iteration: it waits for the next result without looking at ``stop``,
            # for ever if the workers are gone.
            while not completed.is_empty() and not stop.is_set():
                batch = completed.next_batch(block=False)
                if not batch:
                    stop.wait(POLL_S)
                for future in batch:
                    kept, value = settle(future.result, stop)
                    if not kept or stop.is_set():
                        break
                    on_done(index[future.key], value)
        finally:
            self.client.cancel([f for f in futures if not f.done()])

    def close(self) -> None:
        self.client.close()
        if self.cluster is not None:
            self.cluster.close()


def make_executor(jobs: int, cluster: str | None) -> Executor:
    """``--cluster local:N`` (a local Dask cluster), ``--cluster ADDRESS`` (an existing one),
    else ``--jobs N`` local processes."""
    workers = check_cluster(cluster)
    if cluster is None:
        return LocalExecutor(jobs)
    if workers:
        return DaskExecutor(local_workers=workers)
    return DaskExecutor(address=cluster)


def check_cluster(cluster: str | None) -> int:
    """A ``--cluster`` value checked by its form alone, before anything is made or connected
    to: the number of workers of ``local:N``, else 0; :class:`ExecutorError` naming it."""
    if cluster is None:
        return 0
    if cluster.startswith("local:"):
        n = cluster.removeprefix("local:")
        if not n.isdigit():
            raise ExecutorError(f"--cluster {cluster}: local:N, N a number of workers")
        if int(n) < 1:
            raise ExecutorError(f"--cluster {cluster}: at least one worker")
        return int(n)
    host, colon, port = cluster.split("://", 1)[-1].rpartition(":")
    if not (host and colon and port.isdigit()):
        raise ExecutorError(
            f"--cluster {cluster}: a scheduler's address, HOST:PORT (e.g. tcp://10.0.0.5:8786), "
            "or local:N"
        )
    return 0


def gather(
    executor: Executor,
    fn: Callable[..., Any],
    items: Iterable[tuple[Any, ...]],
    stop: threading.Event,
    on_done: Callable[[int, Any], None] = lambda _i, _v: None,
) -> dict[int, Any]:
    """Every value by its item's index (those finished before a stop), ``on_done`` as they
    come."""
    out: dict[int, Any] = {}

    def keep(i: int, value: Any) -> None:
        out[i] = value
        on_done(i, value)

    executor.run(fn, list(items), keep, stop)
    return out
