"""The supervisor's hang checks with a child that takes a while to die after SIGKILL (one in
an uninterruptible call, or a forkserver slow to report it): killed once, not at every tick
until it is reaped. No process and no Zenoh session: stand-ins for both.

Its stop with children that ignore or honour SIGTERM: small real processes in place of the
services (the supervisor needs no Zenoh session to start and stop them)."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest

from common.config import SupervisorConfig
from deploy.service_process import exec_command
from deploy.supervisor import Heard, Supervisor

TICK_S = 0.05  # umay up's loop


class SlowToDie:
    """A child process that ends ``dies_after_s`` after its SIGKILL (clock: ``now_s``)."""

    pid = 4242

    def __init__(self, dies_after_s: float) -> None:
        self.dies_after_s = dies_after_s
        self.now_s = 0.0
        self.killed_at_s: float | None = None
        self.kills = 0

    def poll(self) -> int | None:
        killed = self.killed_at_s
        return -9 if killed is not None and self.now_s - killed >= self.dies_after_s else None

    @property
    def returncode(self) -> int | None:
        return self.poll()

    def kill(self) -> None:
        self.kills += 1
        if self.killed_at_s is None:
            self.killed_at_s = self.now_s

    def send_signal(self, _sig: int) -> None:
        pass

    def wait(self, timeout: float | None = None) -> int:
        return -9


class NoSession:
    def get(self, *_args: object, **_kwargs: object) -> None:  # status queries go nowhere
        pass


def test_a_hung_child_slow_to_die_is_killed_once(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(Supervisor, "start_child", lambda self, child: None)  # no restart
    sup = Supervisor(
        None, "test/x", "tcp/127.0.0.1:1", tmp_path, services=("vision",),
        config=SupervisorConfig(hang_timeout_s=5.0), session=NoSession(),  # type: ignore[arg-type]
    )  # fmt: skip
    child = sup.children["vision"]
    process = SlowToDie(dies_after_s=0.3)
    child.process = process  # type: ignore[assignment]
    sup._heard[("vision", process.pid)] = Heard(process.pid, 1.0, 0.0)  # its last answer
    events: list[str] = []
    now = 1.0
    while child.process is not None and now < 10.0:
        process.now_s = now
        events += sup.tick(now)
        now += TICK_S
    killed = [e for e in events if "hung" in e]
    assert len(killed) == 1 and killed[0].startswith("vision hung (no status answer for"), events
    assert process.kills == 1 and child.hang_kills == 1
    assert child.exit_codes == [-9]


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
    for child in sup.children.values():
        while "ready" not in child.log_path.read_text():  # its SIGTERM disposition is set
            assert child.process.poll() is None, child.log_path.read_text()
            assert time.monotonic() < deadline, f"{child.name} never started"
            time.sleep(0.05)
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
