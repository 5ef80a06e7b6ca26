"""The scenario's ``[supervisor]`` table: how ``umay up`` keeps the services alive."""

from __future__ import annotations

from enum import StrEnum
from typing import Literal

from pydantic import Field

from common.config.base import Strict


class RestartPolicy(StrEnum):
    ALWAYS = "always"
    ON_FAILURE = "on-failure"  # restart after a non-zero exit or a signal only
    NEVER = "never"


class SupervisorConfig(Strict):
    """How ``umay up`` keeps the services alive (as systemd/supervisord would)."""

    restart: dict[Literal["sim", "vision", "controller", "actuation"], RestartPolicy] = Field(
        default_factory=dict, description="per service; unnamed services use default_restart"
    )
    default_restart: RestartPolicy = Field(
        RestartPolicy.ALWAYS,
        description="always, on-failure (after a non-zero exit or a signal) or never",
    )
    backoff_initial_s: float = Field(
        0.1, ge=0.0, le=10.0, description="wait before a restart (s), doubled per recent one"
    )
    backoff_max_s: float = Field(
        5.0, ge=0.0, le=300.0, description="the longest wait before a restart (s)"
    )
    max_restarts: int = Field(5, ge=0, description="in restart_window_s; then give up")
    restart_window_s: float = Field(
        60.0, gt=0.0, description="the window max_restarts counts in (s)"
    )
    stop_grace_s: float = Field(2.0, gt=0.0, le=30.0, description="SIGTERM → SIGKILL")
    hang_timeout_s: float = Field(
        5.0,
        ge=0.0,
        le=300.0,
        description="a service whose event loop is stuck in one step, or that stops answering "
        "status queries, this long is killed (then restarted by its policy); 0: never",
    )
    start_timeout_s: float = Field(
        20.0,
        ge=0.0,
        le=600.0,
        description="a service that has answered no status query this long after it started "
        "is taken as hung (a start that never ends, or a hang before its first answer) and "
        "killed; 0: never",
    )
    launch: Literal["fork", "exec"] = Field(
        "fork",
        description="fork: each service a fork of a process that imported the services once "
        "(deploy/service_process.py); exec: each a fresh `python -m services.NAME`",
    )
    cpu_wakeup_latency_us: int | None = Field(
        None,
        ge=0,
        le=100_000,
        description="while the supervisor runs the services (not in in-process runs, which "
        "have no hops), ask Linux for CPU wake-up latencies at most this long (PM QoS, "
        "/dev/cpu_dma_latency: needs write access); 0: idle CPUs poll instead of halting, so "
        "each hop's wake-up is fast but a core stays busy while idle; None: leave the host's "
        "power management alone",
    )

    def policy(self, service: str) -> RestartPolicy:
        return self.restart.get(service, self.default_restart)  # type: ignore[call-overload]
