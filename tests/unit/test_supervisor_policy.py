"""The supervisor's decisions on their own: restart policy and backoff, when a child counts as
hung, and which supervisor PID a service trusts."""

from __future__ import annotations

from pathlib import Path

import pytest

from common.config import RestartPolicy, SupervisorConfig
from common.runtime import ENV_SUPERVISOR_PID, supervisor_pid
from deploy.supervisor import Child, Heard, Supervisor, backoff_s, hang_reason, wants_restart


def test_restart_policy_and_backoff() -> None:
    assert wants_restart(RestartPolicy.ALWAYS, 0)
    assert wants_restart(RestartPolicy.ON_FAILURE, 1) and wants_restart(
        RestartPolicy.ON_FAILURE, -9
    )
    assert not wants_restart(RestartPolicy.ON_FAILURE, 0)
    assert not wants_restart(RestartPolicy.NEVER, -9)
    cfg = SupervisorConfig(backoff_initial_s=0.1, backoff_max_s=1.0)
    assert [backoff_s(n, cfg) for n in range(6)] == [0.1, 0.2, 0.4, 0.8, 1.0, 1.0]


def test_hang_reason_judges_only_a_child_that_has_answered() -> None:
    assert hang_reason(None, 0.0, 100.0, 5.0) is None  # never answered: still starting
    idle = Heard(pid=1, at_s=10.0, loop_busy_s=0.0)
    assert hang_reason(idle, None, 11.0, 5.0) is None
    assert hang_reason(idle, 11.0, 15.9, 5.0) is None  # one query unanswered for 4.9 s
    assert hang_reason(idle, 11.0, 16.5, 5.0) == "no status answer for 5.5 s"
    assert hang_reason(idle, 11.0, 16.5, 0.0) is None  # 0: hang checks off
    stuck = Heard(pid=1, at_s=10.0, loop_busy_s=6.25)
    assert hang_reason(stuck, None, 10.1, 5.0) == "event loop stuck in one step for 6.2 s"
    assert hang_reason(Heard(1, 10.0, 4.0), None, 10.1, 5.0) is None  # a long step, not a hang
    assert hang_reason(Heard(1, 10.0, None), None, 10.1, 5.0) is None  # loop not started


def test_supervisor_pid_is_read_only_when_it_is_a_pid() -> None:
    assert supervisor_pid({ENV_SUPERVISOR_PID: "4242"}) == 4242
    for value in ("", "abc", "-5", "1", "0"):  # 1: init, never a supervisor
        assert supervisor_pid({ENV_SUPERVISOR_PID: value}) is None
    assert supervisor_pid({}) is None


def test_a_child_that_never_answers_is_judged_after_the_start_timeout() -> None:
    """Frozen before its first answer (or a start that never ends): killed once
    ``start_timeout_s`` have passed since it started, not left hanging for good."""
    assert hang_reason(None, 1.0, 20.9, 5.0, started_s=1.0, start_timeout_s=20.0) is None
    reason = hang_reason(None, 1.0, 21.5, 5.0, started_s=1.0, start_timeout_s=20.0)
    assert reason == "no status answer in the 20.5 s since it started"
    assert hang_reason(None, 1.0, 99.0, 5.0, started_s=1.0, start_timeout_s=0.0) is None  # off
    # Each timeout turns only its own check off.
    reason = hang_reason(None, 1.0, 99.0, 0.0, started_s=1.0, start_timeout_s=20.0)
    assert reason == "no status answer in the 98.0 s since it started"


def test_a_child_whose_loop_never_starts_is_judged_after_the_start_timeout() -> None:
    """It answers (the node answers from its construction on) but hangs before its event
    loop's first wait: still starting until ``start_timeout_s``, then hung."""
    not_started = Heard(pid=1, at_s=20.5, loop_busy_s=None)
    assert hang_reason(not_started, None, 20.9, 5.0, started_s=1.0, start_timeout_s=20.0) is None
    reason = hang_reason(not_started, None, 21.5, 5.0, started_s=1.0, start_timeout_s=20.0)
    assert reason == "its event loop not started in the 20.5 s since it started"
    assert hang_reason(not_started, None, 99.0, 5.0, started_s=1.0, start_timeout_s=0.0) is None
    started = Heard(pid=1, at_s=20.5, loop_busy_s=0.0)
    assert hang_reason(started, None, 99.0, 5.0, started_s=1.0, start_timeout_s=20.0) is None


class _Process:
    """A child's process, running until the test or a kill ends it (``returncode`` set), and
    answering nothing (nothing answers here); its pid one no process can have (above Linux's
    PID_MAX_LIMIT), so no real process's leftovers are touched."""

    pids = iter(range(5_000_000, 6_000_000))

    def __init__(self) -> None:
        self.pid = next(self.pids)
        self.returncode: int | None = None

    def poll(self) -> int | None:
        return self.returncode

    def kill(self) -> None:
        self.returncode = -9


class _Session:
    def get(self, *_args, **_kwargs) -> None:  # the queries go nowhere
        pass


def test_a_child_silent_for_a_long_hang_timeout_is_still_killed(tmp_path) -> None:
    """The queries kept reach as far back as ``hang_timeout_s`` (up to the 300 s the config
    allows): a child that answered once and then fell silent is killed that long after."""
    from deploy.supervisor import Supervisor

    cfg = SupervisorConfig(hang_timeout_s=150.0, start_timeout_s=0.0)
    sup = Supervisor(
        None, "test/x", "tcp/127.0.0.1:1", tmp_path, services=("vision",), config=cfg,
        session=_Session(),
    )  # fmt: skip
    child = sup.children["vision"]
    process = child.process = _Process()
    sup._heard[("vision", process.pid)] = Heard(process.pid, at_s=0.5, loop_busy_s=0.0)
    killed_at = None
    for now in range(400):
        if sup.check_hangs(float(now)):
            killed_at = now
            break
    assert killed_at == 152 and child.last_hang == "no status answer for 151.0 s"
    assert len(sup._queries_s) <= 153


def _deaths(
    deaths_s: list[float], log_dir: Path, monkeypatch: pytest.MonkeyPatch
) -> tuple[Child, list[str]]:
    """A vision that dies (exit 1) at each of ``deaths_s`` (monotonic s, explicit: nothing
    sleeps), its supervisor ticking at each death and at the restart it then schedules
    (at most 3 restarts in 60 s; backoff 0.5 s, doubled per recent restart); the child and
    what the supervisor said."""
    monkeypatch.setattr("deploy.supervisor.fork_service", lambda *_args: _Process())
    monkeypatch.setattr("deploy.supervisor.exec_service", lambda *_args: _Process())
    cfg = SupervisorConfig(
        max_restarts=3, restart_window_s=60.0, backoff_initial_s=0.5, backoff_max_s=5.0
    )
    sup = Supervisor(None, "test/x", "tcp/127.0.0.1:1", log_dir, services=("vision",),
                     config=cfg)  # fmt: skip
    sup.start()
    child = sup.children["vision"]
    events: list[str] = []
    for now in deaths_s:
        if child.process is None:  # not restarted after the death before: given up
            break
        child.process.returncode = 1  # type: ignore[misc]
        events += sup.tick(now)
        if child.restart_due_s is not None:
            events += sup.tick(child.restart_due_s)
    return child, events


def test_deaths_further_apart_than_the_restart_window_never_exhaust_the_restarts(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``max_restarts`` counts the restarts of the last ``restart_window_s`` only: a service
    that dies now and then, each death more than the window after the restart before it, is
    restarted every time, each time after the first backoff again (no restart is recent);
    as many deaths close together exhaust the limit (3 restarts in 60 s), and it gives up."""
    spaced = [65.0 * k for k in range(12)]  # each 64.5 s after the restart (+0.5 s) before it
    child, events = _deaths(spaced, tmp_path / "spaced", monkeypatch)
    assert not child.given_up and child.restarts == 12, events
    assert child.process is not None and child.process.poll() is None  # the 13th, running
    exits = [e for e in events if e.startswith("vision exited")]
    assert exits == ["vision exited (1); restarting in 0.50 s"] * 12, events

    burst = [10.0 * k for k in range(4)]  # four deaths in 30 s: the fourth is one too many
    child, events = _deaths(burst, tmp_path / "burst", monkeypatch)
    assert child.given_up and child.restarts == 3 and child.process is None, events
    assert [e for e in events if e.startswith("vision exited")] == [
        "vision exited (1); restarting in 0.50 s",
        "vision exited (1); restarting in 1.00 s",
        "vision exited (1); restarting in 2.00 s",
        "vision exited (1); 3 restarts in 60 s, giving up",
    ], events
