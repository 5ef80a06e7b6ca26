"""``umay up``: keep the four services running until Ctrl-C / SIGTERM.

The supervisor is itself a Zenoh node: it answers ``<prefix>/supervisor/status`` (children,
pids, restarts, last exit codes, the CPU wake-up latency request it holds) and holds
``<prefix>/alive/supervisor/<pid>``, which is also how a second ``umay up`` on the same prefix sees
that it must not start.
"""

from __future__ import annotations

import signal
import sys
import threading
from pathlib import Path

from common.config import Scenario
from common.keys import Keys
from common.node import Node
from common.queries import alive_services
from common.session import open_session
from common.stop_signals import SignalRelay
from deploy.exit_codes import EXIT_ALREADY_RUNNING
from deploy.supervisor import Supervisor


def run_up(
    scenario_path: str | None,
    scenario: Scenario,
    overrides: list[str],
    prefix: str,
    listen: str,
    connect: list[str],
    log_dir: Path,
    stop: threading.Event | None = None,
) -> int:
    keys = Keys(prefix)
    session = open_session(connect=connect, listen=[listen])
    try:
        if "supervisor" in alive_services(session, keys, 1.0):
            print(f"umay up: a supervisor is already running under {prefix}", file=sys.stderr)
            return EXIT_ALREADY_RUNNING
        sup = Supervisor(
            scenario_path, prefix, listen, log_dir, overrides, config=scenario.supervisor,
            session=session,
        )  # fmt: skip
        node = Node("supervisor", keys, session, sup.status_fields)
        return supervise(sup, node, prefix, listen, stop or threading.Event())
    finally:
        # Also when something above failed: an open session's threads (not daemons) would
        # keep this process from exiting. Closed twice when node.close did it: harmless.
        session.close()


def supervise(sup: Supervisor, node: Node, prefix: str, listen: str, stop: threading.Event) -> int:
    """Run the services until ``stop`` (Ctrl-C, SIGTERM), then stop them and say how each
    ended."""
    relay, previous = None, {}
    if threading.current_thread() is threading.main_thread():
        relay = SignalRelay(stop)  # set from a thread: see common/stop_signals.py
        previous = relay.install()
    try:
        sup.start()
        node.ready()
        print(f"umay up: services running under {prefix}, Zenoh at {listen}; Ctrl-C stops them")
        while not stop.wait(0.05):
            for event in sup.tick():
                print(f"umay up: {event}", file=sys.stderr, flush=True)
    finally:
        node.state = "stopping"
        sup.stop()
        node.close()  # also closes the session
        # Said last, so whoever pressed Ctrl-C knows nothing is left running, and how each ended.
        codes = [f"{n} {c.exit_codes[-1]}" for n, c in sup.children.items() if c.exit_codes]
        ended = ", ".join(codes)
        print(f"umay up: services stopped (exit codes: {ended or 'none started'})", flush=True)
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        if relay is not None:
            relay.close()
    return 0
