"""What every service process does the same way: arguments, logging, signals, session."""

from __future__ import annotations

import argparse
import logging
import os
import sys
import threading
import tomllib
from collections.abc import Mapping
from typing import Any

import zenoh

from common.config import Scenario, ScenarioError, load_scenario
from common.keys import PREFIX_HELP, Keys, check_prefix, default_prefix
from common.node import setup_logging
from common.processes import ProcessEnd
from common.session import ZenohConfigError, check_endpoints, open_session
from common.stop_signals import stop_on_signals

# Set by the supervisor for its children: the PID they stop without (see ServiceContext).
ENV_SUPERVISOR_PID = "UMAY_SUPERVISOR_PID"
SUPERVISOR_CHECK_S = 0.5  # how often a supervised service looks for its supervisor

log = logging.getLogger("umay")


def prefix_argument(value: str) -> str:
    """argparse type of ``--prefix``: a valid key prefix, else a usage error saying why."""
    try:
        return check_prefix(value)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def endpoints_argument(value: str) -> list[str]:
    """argparse type of ``--connect``: comma-separated Zenoh endpoints, as a list, else a
    usage error naming the bad one."""
    try:
        return check_endpoints(value)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def endpoint_argument(value: str) -> str:
    """argparse type of ``--listen`` where one endpoint is meant."""
    if "," in value:
        raise argparse.ArgumentTypeError(f"{value!r}: one endpoint, not a list")
    return endpoints_argument(value)[0]


def service_arguments(service: str, argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog=f"umay service {service}")
    parser.add_argument("--scenario", default=None, help="scenario TOML (default: default.toml)")
    parser.add_argument("--prefix", type=prefix_argument, help=PREFIX_HELP)
    parser.add_argument(
        "--connect",
        type=endpoints_argument,
        default=None,
        help="Zenoh endpoint(s), comma-separated",
    )
    parser.add_argument("--zenoh-config", default=None, help="Zenoh JSON5 config file")
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="TABLE.FIELD=VALUE",
        help="override a scenario field, VALUE in TOML syntax (repeatable)",
    )
    return parser.parse_args(argv)


def parse_overrides(items: list[str]) -> dict[str, Any]:
    """``["run.clock='realtime'", "camera.kinect.enabled=true"]`` → nested tables
    ``{"run": {"clock": "realtime"}, "camera": {"kinect": {"enabled": True}}}``. VALUE is TOML
    (a bare word such as realtime is taken as a string); a top-level field takes no dot
    (``events=[{at_s = 1.0, action = "hide_target", duration_s = 1.0}]``)."""
    out: dict[str, Any] = {}
    for item in items:
        path, sep, value = item.partition("=")
        names = [n.strip() for n in path.split(".")]
        if not sep or not all(names):
            raise ScenarioError(f"--set {item!r}: expected TABLE.FIELD=VALUE")
        try:
            parsed = tomllib.loads(f"v = {value}")["v"]
        except tomllib.TOMLDecodeError:
            parsed = value.strip()
        table = out
        for name in names[:-1]:
            table = table.setdefault(name, {})
            if not isinstance(table, dict):
                raise ScenarioError(f"--set {item!r}: {name} is set as a value and as a table")
        table[names[-1]] = parsed
    return out


def supervisor_pid(env: Mapping[str, str]) -> int | None:
    """The PID in ``$UMAY_SUPERVISOR_PID`` (None: not supervised, or not a PID)."""
    value = env.get(ENV_SUPERVISOR_PID, "").strip()
    pid = int(value) if value.isdigit() else 0
    return pid if pid > 1 else None


class ServiceContext:
    """Parsed arguments, validated scenario, keys, an open Zenoh session and a stop event that
    SIGINT/SIGTERM set, and that the supervisor's end sets too: a service launched by one
    (``$UMAY_SUPERVISOR_PID``) stops when that process has ended, so a supervisor killed
    outright (SIGKILL, the OOM killer) leaves no service running. A forked service's parent
    is the forkserver, not the supervisor, so the supervisor itself is watched."""

    def __init__(self, service: str, argv: list[str] | None) -> None:
        args = service_arguments(service, argv)
        setup_logging(service)
        try:
            self.scenario: Scenario = load_scenario(args.scenario, parse_overrides(args.set))
        except ScenarioError as exc:
            print(exc, file=sys.stderr)
            raise SystemExit(2) from exc
        self.keys = Keys(args.prefix or default_prefix())
        try:
            self.session = open_session(args.zenoh_config, args.connect)
        except ZenohConfigError as exc:
            print(exc, file=sys.stderr)
            raise SystemExit(2) from exc
        except zenoh.ZError as exc:  # e.g. the router is unreachable or refuses the login
            print(f"{service}: cannot open the Zenoh session: {exc}", file=sys.stderr)
            raise SystemExit(1) from exc
        self.stop = threading.Event()
        stop_on_signals(self.stop)  # set from a thread: see common/stop_signals.py
        supervisor = supervisor_pid(os.environ)
        if supervisor is not None:
            threading.Thread(target=self._stop_without, args=(supervisor,), daemon=True).start()

    def __enter__(self) -> ServiceContext:
        return self

    def __exit__(self, *_exc: object) -> None:
        """Close the session however the service ended. An exception that skipped the
        service's own close left Zenoh's callback threads (not daemons) holding the process
        open: it neither exited nor could be stopped by SIGTERM, and its supervisor, which
        still heard it, never restarted it."""
        self.session.close()

    def _stop_without(self, supervisor: int) -> None:
        """Set ``stop`` once the process ``supervisor`` has ended."""
        ended = ProcessEnd(supervisor)
        while not self.stop.wait(SUPERVISOR_CHECK_S):
            if ended():
                log.warning("supervisor (pid %d) is gone; stopping", supervisor)
                self.stop.set()
