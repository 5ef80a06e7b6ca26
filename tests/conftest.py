"""Shared fixtures: the default scenario, a pybullet world on it, ``umay`` in this process for
the checks it makes before it starts anything, and a service's context with the default run's
first frames for tests that drive the services' handlers (tests/services_in_process.py)."""

from __future__ import annotations

import logging
import os
import signal
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest

from common.config import Scenario, load_scenario
from common.keys import ENV_PREFIX, ENV_ROBOT_ID
from common.session import ENV_CONFIG, ENV_CONNECT, ENV_SHM
from tests.prefixes import unique_keys

# The suite makes its own sessions: loopback, no multicast scouting, its own prefixes. A Zenoh
# config, endpoints, shared-memory switch or prefix from the shell that runs it would reach
# every test and every process it starts (a config file is used as is: scouting, endpoints).
for _name in (ENV_CONFIG, ENV_CONNECT, ENV_SHM, ENV_PREFIX, ENV_ROBOT_ID):
    os.environ.pop(_name, None)


@pytest.fixture(autouse=True)
def _signal_handlers_and_log_level_restored():
    """What ``deploy.cli.main`` sets for a command (SIGTERM as Ctrl-C, the root log level),
    put back after every test that calls it: the next test in this worker starts as the first."""
    term, level = signal.getsignal(signal.SIGTERM), logging.getLogger().level
    yield
    signal.signal(signal.SIGTERM, term)
    logging.getLogger().setLevel(level)


@pytest.fixture(scope="session")
def scenario() -> Scenario:
    return load_scenario()


@pytest.fixture()
def ctx():
    """A service's context on a loopback session of its own (tests/services_in_process.py)."""
    from tests.services_in_process import service_context

    with service_context() as context:
        yield context


@pytest.fixture(scope="session")
def pipeline_frames():
    """The default run's first frames as the services exchange them (run 0)."""
    from tests.services_in_process import first_frames

    return first_frames()


@pytest.fixture()
def world(scenario: Scenario):
    from services.sim.world import World

    w = World(scenario)
    yield w
    w.close()


@dataclass(frozen=True)
class CliResult:
    returncode: int
    stdout: str
    stderr: str


@pytest.fixture()
def umay_cli(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> Callable[..., CliResult]:
    """``umay ARGS`` run by ``deploy.cli.main`` in this process, for bad input: what it
    prints, and the exit code it would give (argparse's too). Starting a process or opening a
    Zenoh session fails the test, so "nothing was launched" is checked, not assumed; the
    signal handler and log level ``main`` sets are put back. A Python start per case would
    cost a second of CPU each; the exit code's way out of a process is tested by the runs."""
    import multiprocessing.util
    import subprocess

    import zenoh

    from deploy.cli import main

    def refuse(what: str) -> Callable[..., None]:
        def started(*args: object, **kwargs: object) -> None:
            raise AssertionError(f"bad input must start nothing, but it started {what}: {args}")

        return started

    for module, name in ((subprocess, "Popen"), (os, "fork"), (os, "posix_spawn"),
                         (multiprocessing.util, "spawnv_passfds"), (zenoh, "open")):  # fmt: skip
        monkeypatch.setattr(module, name, refuse(f"{module.__name__}.{name}"))

    def run(*args: str) -> CliResult:
        handler, level = signal.getsignal(signal.SIGTERM), logging.getLogger().level
        capsys.readouterr()
        try:
            code = main(list(args))
        except SystemExit as exc:  # argparse's own errors
            code = exc.code if isinstance(exc.code, int) else 1
        finally:
            signal.signal(signal.SIGTERM, handler)
            logging.getLogger().setLevel(level)
        out = capsys.readouterr()
        return CliResult(code, out.out, out.err)

    return run


def launch_umay_up(log_dir, clock: str, *extra: str, wrapper: tuple[str, ...] = ()):
    """``umay up`` as a child process under a unique prefix: (process, keys, endpoint).
    ``wrapper``: a command that runs it (it must exec its arguments)."""
    import subprocess
    import sys

    from common.session import free_tcp_endpoint

    endpoint = free_tcp_endpoint()
    keys = unique_keys()
    proc = subprocess.Popen(
        [*wrapper, sys.executable, "-m", "deploy", "up", "--clock", clock, "--prefix", keys.prefix,
         "--listen", endpoint, "--connect", endpoint, "--log-dir", str(log_dir), *extra],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    return proc, keys, endpoint


def processes_mentioning(text: str) -> list[int]:
    """PIDs of the processes (other than this one) whose command line contains ``text``."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            cmdline = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode()
        except OSError:
            continue
        if text in cmdline:
            found.append(int(entry.name))
    return found


# The slowest tests, slowest first (`pytest --durations=40`): `make test` hands whole tests to
# its two workers one at a time in collection order (`--dist loadgroup --no-loadscope-reorder`),
# so starting with the long ones lets the many short ones fill in behind them and both workers
# finish together, instead of one worker drawing the longest test last.
SLOW_FIRST = (
    "tests/integration/test_compare_run.py::test_small_comparison_outputs",
    "tests/integration/test_campaign_run.py::",
    "tests/integration/test_integration.py::test_neither_wall_clock",
    "tests/integration/test_domains_executors.py::",
    "tests/integration/test_realism_integration.py::",
    "tests/integration/test_pipeline_vs_distributed.py::",
    "tests/integration/test_recording.py::",
    "tests/integration/test_foxglove_view.py::",
    "tests/integration/test_bench_run.py::",
    "tests/integration/test_supervisor.py::",
    "tests/unit/test_campaign.py::test_each_start",
    "tests/unit/test_kinect_in_loop.py::",
)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    def rank(item: pytest.Item) -> int:
        found = (i for i, prefix in enumerate(SLOW_FIRST) if item.nodeid.startswith(prefix))
        return next(found, len(SLOW_FIRST))

    items.sort(key=rank)  # stable: the rest keep their order


_GROUP_LOST = pytest.StashKey[str]()


@pytest.hookimpl(trylast=True)  # after pytest-xdist's worker has named each test's group
def pytest_collection_finish(session: pytest.Session) -> None:
    """Under ``--dist loadgroup`` a worker sends each ``xdist_group`` test's id with its group
    (``…@bench``), which is how the tests that share a module-scoped run reach one worker.
    Some pytest/pytest-xdist pairs drop it silently (pytest-dev/pytest-xdist#1386): each
    such run would then be made once per worker. The grouped tests fail, saying why."""
    if not getattr(session.config.option, "loadgroup", False):
        return
    if any(
        item.get_closest_marker("xdist_group") and "@" not in item.nodeid for item in session.items
    ):
        session.config.stash[_GROUP_LOST] = (
            f"--dist loadgroup lost this test's xdist_group: pytest {pytest.__version__} with "
            "this pytest-xdist does not keep groups (pytest-dev/pytest-xdist#1386); see the "
            "pin in pyproject.toml"
        )


@pytest.hookimpl(tryfirst=True)  # before the test's fixtures are set up
def pytest_runtest_setup(item: pytest.Item) -> None:
    lost = item.config.stash.get(_GROUP_LOST, None)
    if lost and item.get_closest_marker("xdist_group"):
        pytest.fail(lost, pytrace=False)


def views_once_controller(proc, session, keys, field: str, timeout_s: float) -> dict:
    """Every service's status view, by name, polled from a running ``umay up`` until the
    controller's status field ``field`` is true (or ``timeout_s`` passes, or ``umay up``
    exits: the caller checks)."""
    import time

    from deploy.launch.status import collect

    deadline, views = time.monotonic() + timeout_s, {}
    while time.monotonic() < deadline and proc.poll() is None:
        views = {v.name: v for v in collect(session, keys, 0.5) if v.status}
        controller = views.get("controller")
        if controller and controller.status.fields.get(field):
            break
        time.sleep(0.5)
    return views
