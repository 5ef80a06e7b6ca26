"""Launch the four services as separate OS processes, watch them, restart them, stop them.

The supervisor holds the Zenoh session the services connect to (its listening endpoint is
passed to them in ``UMAY_ZENOH_CONNECT``); the services then find each other through gossip and
talk directly. Each child appends its output to ``<log_dir>/<service>.log``.

Restart policy per service (``always`` / ``on-failure`` / ``never``) with exponential backoff
and at most ``max_restarts`` restarts in ``restart_window_s``, as in systemd or supervisord.

A process can also hang without exiting: a deadlock, a native call that never returns, a
``SIGSTOP``. Given a session, the supervisor asks every service for its status each second
and kills (SIGKILL) a child whose event loop has been busy in one step, or that has not
answered, for ``hang_timeout_s``; its restart policy then applies as to any other death.
A child that has not answered yet, or whose event loop has not started yet, is still starting,
so a slow start is not taken for a hang; one still starting ``start_timeout_s`` after it
started is (a start that never ends, or a hang before its loop runs). A restart that cannot
make a process counts as a death of its own (exit 127), judged by the same policy.

With ``cpu_wakeup_latency_us`` set, the supervisor holds that CPU wake-up latency request
(:mod:`deploy.cpu_latency`) from :meth:`Supervisor.start` to :meth:`Supervisor.stop`.
"""

from __future__ import annotations

import logging
import math
import os
import signal
import subprocess
import time
from dataclasses import dataclass, field
from pathlib import Path

import zenoh
from pydantic import Field

from common.codec import MessageError
from common.config import RestartPolicy, SupervisorConfig
from common.frame_ring import remove_segments_of
from common.keys import SERVICES, Keys
from common.messages import StatusFields
from common.runtime import ENV_SUPERVISOR_PID
from common.session import ENV_CONFIG, ENV_CONNECT
from deploy.cpu_latency import CpuWakeupLatency
from deploy.queries import status_from_reply
from deploy.service_process import ForkUnavailable, ServiceProcess, exec_service, fork_service

log = logging.getLogger("umay.supervisor")


def wants_restart(policy: RestartPolicy, exit_code: int) -> bool:
    """``on-failure``: a non-zero exit code or death by a signal (negative code)."""
    if policy is RestartPolicy.ALWAYS:
        return True
    return policy is RestartPolicy.ON_FAILURE and exit_code != 0


def backoff_s(recent_restarts: int, config: SupervisorConfig) -> float:
    """Exponential: initial, 2·initial, 4·initial, ... capped at backoff_max_s."""
    return min(config.backoff_initial_s * 2.0**recent_restarts, config.backoff_max_s)


_FORK_REFUSALS_SAID: set[str] = set()  # why services could not be forked, as logged

HEALTH_CHECK_S = 1.0  # how often the supervisor asks the services for their status
UNDECODABLE_SAY_EVERY_S = 10.0  # a status answer that cannot be read is logged at most this often
START_FAILED_EXIT = 127  # the exit code a start that made no process counts as (the shell's)
KILL_WAIT_S = 5.0  # how long stop() waits for a SIGKILLed child before leaving it


@dataclass(frozen=True)
class Heard:
    """A child's last status answer: its pid, when it came (monotonic s), its loop_busy_s."""

    pid: int
    at_s: float
    loop_busy_s: float | None


def hang_reason(
    heard: Heard | None,
    unanswered_since_s: float | None,
    now_s: float,
    hang_timeout_s: float,
    started_s: float | None = None,
    start_timeout_s: float = 0.0,
) -> str | None:
    """Why a running child counts as hung, else None. ``unanswered_since_s``: when the first
    status query it has not answered was sent (None: it answered the last one). A child that
    has not yet answered, or whose event loop has not yet started, is still starting: it is
    judged by ``start_timeout_s`` (0: never) since it started at ``started_s``, so that one
    that hangs during its start is not left hanging for good; ``hang_timeout_s`` (0: never)
    judges the rest. Each timeout turns its own check off."""
    starting_for_s = None if started_s is None else now_s - started_s
    start_overrun = starting_for_s is not None and 0 < start_timeout_s < starting_for_s
    if heard is None:
        if start_overrun:
            return f"no status answer in the {starting_for_s:.1f} s since it started"
        return None
    if hang_timeout_s > 0:
        if unanswered_since_s is not None and now_s - unanswered_since_s > hang_timeout_s:
            return f"no status answer for {now_s - unanswered_since_s:.1f} s"
        if heard.loop_busy_s is not None and heard.loop_busy_s > hang_timeout_s:
            return f"event loop stuck in one step for {heard.loop_busy_s:.1f} s"
    if heard.loop_busy_s is None and start_overrun:
        return f"its event loop not started in the {starting_for_s:.1f} s since it started"
    return None


@dataclass
class Child:
    name: str
    args: list[str]  # the service's own arguments
    log_path: Path
    process: ServiceProcess | None = None
    restarts: int = 0
    exit_codes: list[int] = field(default_factory=list)
    restart_times: list[float] = field(default_factory=list)
    restart_due_s: float | None = None  # monotonic time of a scheduled restart
    given_up: bool = False
    started_s: float = 0.0
    hang_kills: int = 0
    last_hang: str = ""  # why it was last killed as hung
    killed_as_hung: bool = False  # its current or last process was

    def describe_exit(self) -> str:
        """``vision (exit -9, hung: ...)``: its last exit, and the hang that caused it."""
        hung = f", hung: {self.last_hang}" if self.killed_as_hung else ""
        return f"{self.name} (exit {self.exit_codes[-1]}{hung})"


class ChildStatus(StatusFields):
    """One service as its supervisor sees it."""

    pid: int | None = Field(description="its current process (none: not running)")
    running: bool = Field(description="a process of it is running")
    answered: bool = Field(
        description="its current process has answered a status query: until then it is "
        "starting, and judged hung only after `supervisor.start_timeout_s`"
    )
    restarts: int = Field(description="times it was started again")
    last_exit_codes: list[int] = Field(
        description="its last five processes' exit codes (−9: killed)"
    )
    policy: str = Field(description="its restart policy (`supervisor.restart`)")
    given_up: bool = Field(description="restarted too often: no longer restarted")
    hang_kills: int = Field(description="processes killed as hung")
    last_hang: str = Field(description="why it was last killed as hung")
    log: str = Field(description="its log file")


class SupervisorStatus(StatusFields):
    cpu_wakeup_latency: str = Field(
        description="the CPU wake-up latency request it holds, or why not "
        "(`supervisor.cpu_wakeup_latency_us`)"
    )
    launch: str = Field(
        description="how the services are started: `fork`, `exec`, or `exec (fork refused: why)`"
    )
    children: dict[str, ChildStatus] = Field(description="each service by name")


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
        config: SupervisorConfig | None = None,
        env: dict[str, str] | None = None,
        session: zenoh.Session | None = None,
    ) -> None:
        """``env``: extra environment variables for the children (e.g. ``UMAY_ZENOH_SHM``).
        ``session``: one the children reach, for the hang checks (none without it)."""
        self.endpoint = endpoint
        self.session = session
        self.keys = Keys(prefix)
        self._heard: dict[tuple[str, int], Heard] = {}  # by (service, pid); Zenoh's thread
        # Send times of the status queries, oldest first, as far back as a hang can reach.
        self._queries_s: list[float] = []
        self._undecodable_said_s = -math.inf  # when a status that failed to decode was logged
        self.extra_env = dict(env or {})
        self.zenoh_config = zenoh_config
        self.config = config or SupervisorConfig()
        self.log_dir = log_dir
        self.cpu_wakeup = CpuWakeupLatency(None)  # the request is made by start()
        self.fork_refused = ""  # why the services are exec'd though launch is "fork"
        common_args = ["--prefix", prefix]
        if scenario_path:
            common_args += ["--scenario", str(scenario_path)]
        for item in overrides or []:
            common_args += ["--set", item]
        self.children = {
            name: Child(name, common_args, log_dir / f"{name}.log") for name in services
        }

    @property
    def launch(self) -> str:
        """How the services are started: ``fork``, ``exec``, or ``exec`` and why not forked."""
        if self.config.launch == "fork" and self.fork_refused:
            return f"exec (fork refused: {self.fork_refused})"
        return self.config.launch

    def _env(self) -> dict[str, str]:
        env = dict(os.environ)
        env[ENV_CONNECT] = self.endpoint
        if self.zenoh_config:
            env[ENV_CONFIG] = self.zenoh_config
        env.setdefault("PYTHONUNBUFFERED", "1")
        env[ENV_SUPERVISOR_PID] = str(os.getpid())  # the children stop if this process dies
        env.update(self.extra_env)
        return env

    def start_child(self, child: Child) -> None:
        env = self._env()
        process = None
        if self.config.launch == "fork" and not self.fork_refused:
            try:
                process = fork_service(child.name, child.args, env, child.log_path)
            except ForkUnavailable as exc:
                self.fork_refused = str(exc)
                if self.fork_refused not in _FORK_REFUSALS_SAID:  # once a process, not a run
                    _FORK_REFUSALS_SAID.add(self.fork_refused)
                    log.warning("cannot fork the services (%s); exec'ing them", exc)
        child.process = process or exec_service(child.name, child.args, env, child.log_path)
        # An answer an earlier process of it gave under the same (reused) pid is not this one's.
        self._heard.pop((child.name, child.process.pid), None)
        child.started_s = time.monotonic()
        child.restart_due_s = None
        child.killed_as_hung = False
        log.info("started %s (pid %d)", child.name, child.process.pid)

    def start(self) -> None:
        # Here, not in __init__: callers open their Zenoh session before making the
        # supervisor and start it inside the try that closes the session again.
        self.log_dir.mkdir(parents=True, exist_ok=True)
        self.cpu_wakeup.release()  # a start after a stop asks again
        self.cpu_wakeup = CpuWakeupLatency(self.config.cpu_wakeup_latency_us)
        for child in self.children.values():
            self.start_child(child)

    def exited(self) -> list[Child]:
        """Children whose process has ended since the last call (exit code recorded)."""
        out = []
        for child in self.children.values():
            if child.process is not None and child.process.poll() is not None:
                child.exit_codes.append(child.process.returncode)
                self._ended(child.process)
                child.process = None
                out.append(child)
        return out

    def check_hangs(self, now_s: float | None = None) -> list[str]:
        """Kill the children that :func:`hang_reason` finds hung, and ask every service for
        its status again if it is time; returns what happened, for the log."""
        if self.session is None:
            return []
        now = time.monotonic() if now_s is None else now_s
        events = []
        for child in self.children.values():
            if child.process is None or child.process.poll() is not None:
                continue
            if child.killed_as_hung:  # killed already, not reaped yet: once is enough
                continue
            heard = self._heard.get((child.name, child.process.pid))  # this process's
            after = heard.at_s if heard else now
            unanswered = next((t for t in self._queries_s if t > after), None)
            reason = hang_reason(
                heard, unanswered, now, self.config.hang_timeout_s,
                child.started_s, self.config.start_timeout_s,
            )  # fmt: skip
            if reason is not None:
                child.hang_kills += 1
                child.last_hang = reason
                child.killed_as_hung = True
                child.process.kill()  # works on a stopped process too; exited() sees it
                events.append(f"{child.name} hung ({reason}); killed")
        if not self._queries_s or now - self._queries_s[-1] >= HEALTH_CHECK_S:
            # Kept for as long as a hang takes to show: the first query a child left
            # unanswered must still be here once hang_timeout_s have passed since it.
            kept_s = self.config.hang_timeout_s + 2 * HEALTH_CHECK_S
            self._queries_s = [t for t in self._queries_s if now - t <= kept_s] + [now]
            # A late answer still shows the process alive: wait for it as long as a hang.
            timeout_s = max(HEALTH_CHECK_S, self.config.hang_timeout_s)
            self.session.get(self.keys.all_status, self._on_status, timeout=timeout_s)
        return events

    def _on_status(self, reply: zenoh.Reply) -> None:
        try:
            status = status_from_reply(reply)
        except MessageError as exc:  # a child whose answers fail will be taken for hung: say why
            now = time.monotonic()
            if now - self._undecodable_said_s > UNDECODABLE_SAY_EVERY_S:
                self._undecodable_said_s = now
                log.warning("a status answer could not be read: %s", exc)
            return
        if status is None:  # an error reply
            return
        heard = Heard(status.pid, time.monotonic(), status.loop_busy_s)
        self._heard[(status.service, status.pid)] = heard

    def tick(self, now_s: float | None = None) -> list[str]:
        """Apply the hang checks and the restart policy once; returns what happened."""
        now = time.monotonic() if now_s is None else now_s
        events = self.check_hangs(now)
        for child in self.exited():
            events.extend(self._after_exit(child, now))
        for child in self.children.values():
            if child.restart_due_s is not None and now >= child.restart_due_s:
                child.restarts += 1
                child.restart_times.append(now)
                try:
                    self.start_child(child)
                except OSError as exc:  # no process to start (its log gone, fork refused):
                    # a failed start, judged by the policy as a death; the others keep running.
                    child.restart_due_s = None
                    child.exit_codes.append(START_FAILED_EXIT)
                    events.append(f"{child.name} could not be restarted ({exc})")
                    events.extend(self._after_exit(child, now))
                    continue
                events.append(f"{child.name} restarted (pid {child.process.pid})")
        return events

    def _after_exit(self, child: Child, now: float) -> list[str]:
        """The restart policy for ``child``, whose process just ended with its last exit code:
        schedule a restart, or say why not."""
        code = child.exit_codes[-1]
        window = self.config.restart_window_s
        child.restart_times = [t for t in child.restart_times if now - t <= window]
        if not wants_restart(self.config.policy(child.name), code):
            return [f"{child.name} exited ({code}); policy says no restart"]
        if len(child.restart_times) >= self.config.max_restarts:
            child.given_up = True
            return [
                f"{child.name} exited ({code}); {len(child.restart_times)} restarts in "
                f"{window:.0f} s, giving up"
            ]
        delay = backoff_s(len(child.restart_times), self.config)
        child.restart_due_s = now + delay
        return [f"{child.name} exited ({code}); restarting in {delay:.2f} s"]

    def stop(self, grace_s: float | None = None) -> None:
        """SIGTERM every child, SIGKILL what is still alive after ``grace_s``."""
        grace = self.config.stop_grace_s if grace_s is None else grace_s
        running = [c for c in self.children.values() if c.process is not None]
        for child in self.children.values():
            child.restart_due_s = None
        for child in running:
            if child.process.poll() is None:
                child.process.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + grace
        for child in running:
            remaining = max(0.0, deadline - time.monotonic())
            try:
                child.process.wait(remaining)
            except subprocess.TimeoutExpired:
                log.warning("%s did not stop within %.1f s; killing it", child.name, grace)
                child.process.kill()
                try:  # a process in an uninterruptible call ends only when the call does
                    child.process.wait(KILL_WAIT_S)
                except subprocess.TimeoutExpired:
                    log.error(
                        "%s (pid %d) still there %.0f s after SIGKILL; left behind",
                        child.name, child.process.pid, KILL_WAIT_S,
                    )  # fmt: skip
                    child.process = None
                    continue
            child.exit_codes.append(child.process.returncode)
            self._ended(child.process)
            child.process = None
        self.cpu_wakeup.release()

    @staticmethod
    def _ended(process: ServiceProcess) -> None:
        """After a child's end: remove the frame rings it left in shared memory (a sim
        killed outright cannot unlink its own)."""
        removed = remove_segments_of(process.pid)
        if removed:
            log.info("removed the frame rings pid %d left: %s", process.pid, ", ".join(removed))

    def status_fields(self) -> SupervisorStatus:
        return SupervisorStatus(
            cpu_wakeup_latency=self.cpu_wakeup.state,
            launch=self.launch,
            children={name: self._child_status(name, c) for name, c in self.children.items()},
        )

    def _child_status(self, name: str, c: Child) -> ChildStatus:
        """On a Zenoh thread: ``c.process`` is read once, as exited() may clear it meanwhile."""
        process = c.process
        return ChildStatus(
            pid=process.pid if process else None,
            running=process is not None,
            answered=process is not None and (name, process.pid) in self._heard,
            restarts=c.restarts,
            last_exit_codes=c.exit_codes[-5:],
            policy=self.config.policy(name).value,
            given_up=c.given_up,
            hang_kills=c.hang_kills,
            last_hang=c.last_hang,
            log=str(c.log_path),
        )

    def pids(self) -> dict[str, int | None]:
        return {n: (p.pid if (p := c.process) else None) for n, c in self.children.items()}
