"""Processes ending, with small real processes in place of the services: the supervisor's stop
with children that ignore or honour SIGTERM (it needs no Zenoh session to start and stop them),
and a service seeing its supervisor end."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest

from common.processes import ProcessEnd
from deploy.service_process import exec_command
from deploy.supervisor import Supervisor

IGNORES_SIGTERM = "import signal; signal.signal(signal.SIGTERM, signal.SIG_IGN); "
SLEEPS = "print('ready', flush=True); import time; time.sleep(120)"


def started(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, codes: dict[str, str]
) -> tuple[Supervisor, list[subprocess.Popen]]:
    """A started supervisor whose service ``name`` is ``python -c codes[name]`` (its
    environment and log a service's, forked or exec'd), once each has said "ready" in its
    log; the processes, for the test to clean up after."""
    processes: list[subprocess.Popen] = []

    def start(name: str, _args: list[str], env: dict[str, str], log_path: Path):
        processes.append(exec_command([sys.executable, "-c", codes[name]], env, log_path))
        return processes[-1]

    monkeypatch.setattr("deploy.supervisor.fork_service", start)
    monkeypatch.setattr("deploy.supervisor.exec_service", start)
    sup = Supervisor(None, "test/x", "tcp/127.0.0.1:1", tmp_path, services=tuple(codes))
    sup.start()
    deadline = time.monotonic() + 60
    try:
        for child in sup.children.values():
            while "ready" not in child.log_path.read_text():  # its SIGTERM disposition is set
                assert child.process.poll() is None, child.log_path.read_text()
                assert time.monotonic() < deadline, f"{child.name} never started"
                time.sleep(0.05)
    except BaseException:  # none left behind for the test that never gets them
        for process in processes:
            process.kill()
            process.wait(10)
        raise
    return sup, processes


def test_stop_kills_a_child_that_ignores_sigterm_once_the_grace_is_over(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Stopping escalates: SIGTERM to every child, then SIGKILL to one still alive after the
    grace. The child that ignores SIGTERM ends by SIGKILL (exit -9) no earlier than the grace
    and well within grace + 5 s; the one beside it that honours SIGTERM ends by it (-15)."""
    sup, processes = started(
        tmp_path, monkeypatch, {"sim": IGNORES_SIGTERM + SLEEPS, "vision": SLEEPS}
    )
    grace_s = 1.0
    try:
        began = time.monotonic()
        sup.stop(grace_s=grace_s)
        took_s = time.monotonic() - began
        assert sup.children["sim"].exit_codes == [-9], sup.children["sim"].exit_codes
        assert sup.children["vision"].exit_codes == [-15], sup.children["vision"].exit_codes
        assert grace_s <= took_s < grace_s + 5.0, took_s
        assert all(p.poll() is not None for p in processes)  # none left running
        assert sup.pids() == {"sim": None, "vision": None}
    finally:
        for process in processes:
            if process.poll() is None:
                process.kill()
                process.wait(10)


def test_stop_waits_no_grace_for_children_that_honour_sigterm(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Children that end at SIGTERM end by it (exit -15, no SIGKILL), and stop returns once
    they have, not after the grace: here well under a third of its 30 s."""
    sup, processes = started(tmp_path, monkeypatch, {"sim": SLEEPS, "vision": SLEEPS})
    try:
        began = time.monotonic()
        sup.stop(grace_s=30.0)
        took_s = time.monotonic() - began
        assert [c.exit_codes for c in sup.children.values()] == [[-15], [-15]]
        assert took_s < 10.0, took_s
    finally:
        for process in processes:
            if process.poll() is None:
                process.kill()
                process.wait(10)


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
