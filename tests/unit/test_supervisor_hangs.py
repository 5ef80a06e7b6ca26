"""The supervisor's hang checks with a child that takes a while to die after SIGKILL (one in
an uninterruptible call, or a forkserver slow to report it): killed once, not at every tick
until it is reaped. No process and no Zenoh session: stand-ins for both."""

from __future__ import annotations

from pathlib import Path

import pytest

from common.config import SupervisorConfig
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
