"""Processes ending, with small real processes in place of the services: the supervisor's stop
with children that ignore or honour SIGTERM (it needs no Zenoh session to start and stop them),
and a service seeing its supervisor end."""

from __future__ import annotations

import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from common.processes import ProcessEnd
from deploy.service_process import exec_command
from deploy.supervisor import Supervisor

IGNORES_SIGTERM = "import signal; signal.signal(signal.SIGTERM, signal.SIG_IGN); "
SLEEPS = "print('ready', flush=True); import time; time.sleep(120)"


@pytest.fixture()
def started(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> Iterator[Callable[[dict[str, str]], tuple[Supervisor, list[subprocess.Popen]]]]:
    """Starts a supervisor whose service ``name`` is ``python -c codes[name]`` (its environment
    and log a service's, forked or exec'd), once each has said "ready" in its log; gives it and
    the processes. Any of them still running after the test is killed."""
    processes: list[subprocess.Popen] = []

    def start(codes: dict[str, str]) -> tuple[Supervisor, list[subprocess.Popen]]:
        def launch(name: str, _args: list[str], env: dict[str, str], log_path: Path):
            processes.append(exec_command([sys.executable, "-c", codes[name]], env, log_path))
            return processes[-1]

        monkeypatch.setattr("deploy.supervisor.fork_service", launch)
        monkeypatch.setattr("deploy.supervisor.exec_service", launch)
        sup = Supervisor(None, "test/x", "tcp/127.0.0.1:1", tmp_path, services=tuple(codes))
        sup.start()
        deadline = time.monotonic() + 60
        for child in sup.children.values():
            while "ready" not in child.log_path.read_text():  # its SIGTERM disposition is set
                assert child.process.poll() is None, child.log_path.read_text()
                assert time.monotonic() < deadline, f"{child.name} never started"
                time.sleep(0.05)
        return sup, processes

    yield start
    for process in processes:
        if process.poll() is None:
            process.kill()
            process.wait(10)


def test_stop_kills_a_child_that_ignores_sigterm_once_the_grace_is_over(started) -> None:
    """Stopping escalates: SIGTERM to every child, then SIGKILL to one still alive after the
    grace. The child that ignores SIGTERM ends by SIGKILL (exit -9) no earlier than the grace
    and well within grace + 5 s; the one beside it that honours SIGTERM ends by it (-15)."""
    sup, processes = started({"sim": IGNORES_SIGTERM + SLEEPS, "vision": SLEEPS})
    grace_s = 1.0
    began = time.monotonic()
    sup.stop(grace_s=grace_s)
    took_s = time.monotonic() - began
    assert sup.children["sim"].exit_codes == [-9], sup.children["sim"].exit_codes
    assert sup.children["vision"].exit_codes == [-15], sup.children["vision"].exit_codes
    assert grace_s <= took_s < grace_s + 5.0, took_s
    assert all(p.poll() is not None for p in processes)  # none left running
    assert sup.pids() == {"sim": None, "vision": None}


def test_stop_waits_no_grace_for_children_that_honour_sigterm(started) -> None:
    """Children that end at SIGTERM end by it (exit -15, no SIGKILL), and stop returns once
    they have, not after the grace: here well under a third of its 30 s."""
    sup, _ = started({"sim": SLEEPS, "vision": SLEEPS})
    began = time.monotonic()
    sup.stop(grace_s=30.0)
    took_s = time.monotonic() - began
    assert [c.exit_codes for c in sup.children.values()] == [[-15], [-15]]
    assert took_s < 10.0, took_s


def test_a_watched_process_is_seen_to_end() -> None:
    """How a service notices its supervisor gone (a forked service is not its child)."""
    process = subprocess.Popen(
        [sys.executable, "-c", "import sys; sys.stdin.read()"], stdin=subprocess.PIPE
    )
    ended = ProcessEnd(process.pid)
    assert not ended() and not ended(0.05)
    process.stdin.close()  # it reads EOF and exits
    assert ended(10)
    process.wait(10)
    assert ProcessEnd(process.pid)()  # reaped: no such process any more
