"""Launch the four services as separate OS processes, watch them, stop them cleanly.

The supervisor holds the Zenoh session the services connect to (its listening endpoint is
passed to them in ``UMAY_ZENOH_CONNECT``); the services then find each other through gossip and
talk directly. Each child writes its log to ``<log_dir>/<service>.log``.
"""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from common.keys import SERVICES
from common.transport import ENV_CONFIG, ENV_CONNECT

log = logging.getLogger("umay.supervisor")

STOP_GRACE_S = 2.0


@dataclass
class Child:
    name: str
    argv: list[str]
    log_path: Path
    process: subprocess.Popen | None = None
    restarts: int = 0
    exit_codes: list[int] = field(default_factory=list)


class Supervisor:
    def __init__(
        self,
        scenario_path: str | None,
        prefix: str,
        endpoint: str,
        log_dir: Path,
        overrides: list[str] | None = None,
        services: tuple[str, ...] = SERVICES,
        zenoh_config: str | None = None,
    ) -> None:
        self.endpoint = endpoint
        self.zenoh_config = zenoh_config
        log_dir.mkdir(parents=True, exist_ok=True)
        common_args = ["--prefix", prefix]
        if scenario_path:
            common_args += ["--scenario", str(scenario_path)]
        for item in overrides or []:
            common_args += ["--set", item]
        self.children = {
            name: Child(
                name,
                [sys.executable, "-m", f"services.{name}", *common_args],
                log_dir / f"{name}.log",
            )
            for name in services
        }

    def _env(self) -> dict[str, str]:
        env = dict(os.environ)
        env[ENV_CONNECT] = self.endpoint
        if self.zenoh_config:
            env[ENV_CONFIG] = self.zenoh_config
        env.setdefault("PYTHONUNBUFFERED", "1")
        return env

    def start_child(self, child: Child) -> None:
        with child.log_path.open("ab") as out:
            child.process = subprocess.Popen(
                child.argv, stdout=out, stderr=subprocess.STDOUT, env=self._env()
            )
        log.info("started %s (pid %d)", child.name, child.process.pid)

    def start(self) -> None:
        for child in self.children.values():
            self.start_child(child)

    def exited(self) -> list[Child]:
        """Children whose process has ended since the last call (exit code recorded)."""
        out = []
        for child in self.children.values():
            if child.process is not None and child.process.poll() is not None:
                child.exit_codes.append(child.process.returncode)
                child.process = None
                out.append(child)
        return out

    def restart(self, child: Child) -> None:
        child.restarts += 1
        self.start_child(child)

    def stop(self, grace_s: float = STOP_GRACE_S) -> None:
        """SIGTERM every child, SIGKILL what is still alive after ``grace_s``."""
        running = [c for c in self.children.values() if c.process is not None]
        for child in running:
            if child.process.poll() is None:
                child.process.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + grace_s
        for child in running:
            remaining = max(0.0, deadline - time.monotonic())
            try:
                child.process.wait(remaining)
            except subprocess.TimeoutExpired:
                log.warning("%s did not stop within %.1f s; killing it", child.name, grace_s)
                child.process.kill()
                child.process.wait()
            child.exit_codes.append(child.process.returncode)
            child.process = None

    def pids(self) -> dict[str, int | None]:
        return {n: (c.process.pid if c.process else None) for n, c in self.children.items()}
