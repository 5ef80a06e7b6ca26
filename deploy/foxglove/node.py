"""``umay view``: the live Foxglove view, an observer beside the loop (the imperative shell).

A process of its own: it subscribes to the run's data keys over Zenoh, turns them into
Foxglove messages (:mod:`deploy.foxglove.convert`) and serves them with the official
``foxglove-sdk`` WebSocket server. It publishes nothing on Zenoh, so the loop never waits for
it:

- it shows at most ``rate_hz`` messages per key and second (``image_hz`` colour images,
  ``depth_hz`` depth images: JPEG encoding is its main cost, on the loop's cores), and none
  while no client listens: a sample it does not want is dropped in the Zenoh callback
  before it is copied or decoded; the rest are decoded there and kept newest-only per key,
  so a view that falls behind skips messages instead of queueing them (``dropped`` in its
  status);
- the SDK keeps a bounded queue per client and drops the oldest data for a slow one.

It answers ``<prefix>/view/status`` like a service, and once a second asks the services for
their status, shown as log lines (``/log``).
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import re
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import foxglove
from foxglove.websocket import Capability

from common.codec import (
    DEFAULT_MAX_BYTES,
    FRAME_MAX_BYTES,
)
from common.config import Scenario
from common.keys import DEPTH, JOINT_STATE, RGB, TWIST, Keys
from common.node import Node
from common.publishers import decode_or_fetch
from deploy.arguments import NOTHING_RUNNING_THERE
from deploy.exit_codes import EXIT_BAD_INPUT, EXIT_FAILED, EXIT_OK
from deploy.foxglove import convert, topics, transforms
from deploy.foxglove.channels import FoxgloveChannels
from deploy.foxglove.options import DEFAULT_HOST, check_view_options, view_arguments
from deploy.foxglove.rate import RateGate
from deploy.foxglove.status import ViewStatus
from deploy.interrupts import stop_requested
from deploy.queries import query_status

log = logging.getLogger("umay.view")

STATUS_PERIOD_S = 1.0
FRAME_KEYS = (RGB, DEPTH)
SILENT_AFTER_S = 10.0  # no message on any viewed key for this long from the start: say so
# Outgoing messages the SDK queues per client before it drops the oldest. By count, not
# bytes: its default of 1024 let a stalled client hold a gigabyte of depth images.
CLIENT_BACKLOG = 64
SERVER_STOP_S = 2.0  # how long stopping waits for the server (a stalled client holds it)


def listening_note(
    heard: int, listening_s: float, warned: bool, prefix: str, looked_on: str
) -> str | None:
    """What to tell a user about what the view hears (``heard`` messages in ``listening_s``
    seconds), or None: after :data:`SILENT_AFTER_S` of nothing, that nothing seems to run
    where it listens; once it has said so (``warned``), that it hears the system after all (a
    slow start)."""
    if warned:
        return f"hearing {prefix} now" if heard else None
    if heard or listening_s < SILENT_AFTER_S:
        return None
    return f"nothing heard under {prefix} at {looked_on} for {listening_s:.0f} s: " + (
        NOTHING_RUNNING_THERE
    )


class PortInUseError(OSError):
    """The WebSocket port cannot be bound; the message says which and what to do."""


def start_server(host: str, port: int, context: foxglove.Context) -> foxglove.WebSocketServer:
    """The SDK's WebSocket server on ``host:port`` (0: any free port), announcing the time
    (simulated) to clients. :class:`PortInUseError` when the port is taken."""
    try:
        return foxglove.start_server(
            name="umay",
            host=host,
            port=port,
            context=context,
            capabilities=[Capability.Time],
            message_backlog_size=CLIENT_BACKLOG,
        )
    except RuntimeError as exc:  # the SDK reports bind failures as RuntimeError
        text = str(exc)
        if "in use" in text.lower() or "bind" in text.lower():
            raise PortInUseError(
                f"cannot serve on {host}:{port}: {text.removeprefix('FoxgloveError: ')} "
                "(another umay view? choose another --port)"
            ) from None
        raise


class ViewNode:
    """Zenoh in, Foxglove out. Zenoh callbacks only admit (rate limit, someone listening),
    decode and keep the newest message per key; only :meth:`run`'s thread touches
    :attr:`state`."""

    def __init__(
        self,
        scenario: Scenario,
        keys: Keys,
        session: Any,
        server: foxglove.WebSocketServer,
        channels: FoxgloveChannels,
        rate_hz: float,
        image_hz: float,
        depth_hz: float,
        jpeg_quality: int,
        looked_on: str = "",
    ) -> None:
        self.scenario = scenario
        self.state = convert.ViewState(scenario)
        self.looked_on = looked_on  # where the session looks for the system, in words
        self.heard = 0  # samples on the viewed keys, wanted or not
        self.keys = keys
        self.session = session
        self.server = server
        self.channels = channels
        self.jpeg_quality = jpeg_quality
        self.shown = 0
        self.rejected = 0
        self.dropped: dict[str, int] = dict.fromkeys(convert.VIEWED_KEYS, 0)
        periods = {RGB: 1.0 / image_hz, DEPTH: 1.0 / depth_hz}
        self._gates = {  # each key's rate limit (the twists': in the event loop, below)
            suffix: RateGate(periods.get(suffix, 1.0 / rate_hz)) for suffix in convert.VIEWED_KEYS
        }
        self._latest: dict[str, Any] = {}
        # Twists a newer one would have replaced while the view was behind, kept because the
        # newer one's phase or hold reason differs: shown first, in order.
        self._phase_twists: list[Any] = []
        self._cond = threading.Condition()
        self.node = Node("view", keys, session, self.status_fields)  # status and liveliness
        self._subscribers = [
            session.declare_subscriber(f"{keys.prefix}/{suffix}", self._on_sample(suffix, model))
            for suffix, model in convert.VIEWED_KEYS.items()
        ]

    def status_fields(self) -> ViewStatus:
        return ViewStatus(
            port=self.server.port,
            messages_shown=self.shown,
            dropped=dict(self.dropped),
            rejected=self.rejected,
        )

    def _wanted(self, suffix: str) -> bool:
        if suffix == RGB:
            return self.channels.wanted(topics.COLOUR_IMAGE)
        if suffix == DEPTH:
            return self.channels.wanted(topics.DEPTH_IMAGE)
        return self.channels.any_wanted()

    def _on_sample(self, suffix: str, model: type) -> Any:
        max_bytes = FRAME_MAX_BYTES if suffix in FRAME_KEYS else DEFAULT_MAX_BYTES
        gate = self._gates[suffix]

        def on_sample(sample: Any) -> None:
            self.heard += 1
            # Twists are small: every one is decoded, so that a change of phase is never missed
            # (their rate is limited in on_event).
            over = suffix != TWIST and not gate.admit(time.monotonic())
            if over or not self._wanted(suffix):
                self.dropped[suffix] += 1  # before the copy and the decode: costs nothing
                return
            # A frame in a ring this process cannot map is asked whole from its publisher.
            decode_or_fetch(
                self.session,
                f"{self.keys.prefix}/{suffix}",
                sample.payload.to_bytes(),
                model,
                max_bytes,
                lambda message, _fetched_s: keep(message),
                on_reject,
            )

        def on_reject(_reason: str) -> None:
            self.rejected += 1

        def keep(message: Any) -> None:
            with self._cond:
                waiting = self._latest.pop(suffix, None)
                if waiting is not None:
                    if suffix == TWIST and convert.phase_key(waiting) != convert.phase_key(message):
                        self._phase_twists.append(waiting)  # a change of phase: shown all the same
                    else:
                        self.dropped[suffix] += 1  # the view is behind: the newer one wins
                self._latest[suffix] = message
                self._cond.notify()

        return on_sample

    def on_event(self, suffix: str, message: Any) -> None:
        state = self.state.continued(message)
        if state is None:  # sent before the sim restarted, come late
            self.dropped[suffix] += 1
            return
        if state is not self.state:
            log.info("a new run of the sim (at %.2f s simulated)", message.header.sim_time_s)
            self.state = state
        if suffix == TWIST and not (
            self.state.phase_changes(message) or self._gates[TWIST].admit(time.monotonic())
        ):
            self.state.note_goal(message)  # not shown, but its goal is the overlay's from now
            self.dropped[suffix] += 1  # over the rate, and the phase the same
            return
        outs = self.state.on_message(suffix, message, self.jpeg_quality)
        image = getattr(message, "rgb", None) or getattr(message, "depth_m", None)
        if suffix in FRAME_KEYS and image is not None and not image.intact():
            self.dropped[suffix] += 1  # a ring slot overwritten while it was converted
            return
        self.channels.log_all(outs)
        self.shown += len(outs)
        if suffix == JOINT_STATE:
            self.server.broadcast_time(transforms.time_ns(self.state.sim_time_s))

    def poll_status(self, stop: threading.Event) -> None:
        """Every second: the services' status as log lines (a thread of its own: a query
        waits for answers); on stderr, :func:`listening_note`'s notes."""
        started, warned, settled = time.monotonic(), False, False
        while not stop.wait(STATUS_PERIOD_S):
            if not settled:
                heard = self.heard
                note = listening_note(
                    heard, time.monotonic() - started, warned, self.keys.prefix, self.looked_on
                )
                if note is not None:
                    print(f"umay view: {note}", file=sys.stderr, flush=True)
                warned = warned or note is not None
                settled = heard > 0
            if not self.channels.wanted(topics.LOG):
                continue
            try:
                statuses = query_status(self.session, self.keys, 0.5)
            except Exception:  # the session closing under us at the end
                log.debug("status query failed", exc_info=True)
                continue
            self.channels.log_all(convert.status_logs(statuses, self.state.sim_time_s))

    def run(self, stop: threading.Event) -> None:
        threading.Thread(target=self.poll_status, args=(stop,), daemon=True).start()
        self.node.ready()
        try:
            while not stop.is_set():
                with self._cond:
                    if not self._latest and not self._phase_twists:
                        self._cond.wait(0.1)
                    # Twists first: the overlay of a frame drawn in this batch then has the goal
                    # of the newest twist heard, its own frame's when that has come.
                    latest = sorted(self._latest.items(), key=lambda item: item[0] != TWIST)
                    batch = [(TWIST, t) for t in self._phase_twists] + latest
                    self._phase_twists, self._latest = [], {}
                for suffix, message in batch:
                    self.on_event(suffix, message)
        finally:
            for sub in self._subscribers:
                sub.undeclare()
            self.node.close()  # also closes the session


def main(argv: list[str] | None = None) -> int:
    return serve(view_arguments(argv))


def serve(args: argparse.Namespace) -> int:
    """``umay view``: exit 0 when stopped (Ctrl-C, SIGTERM), 2 on bad options or scenario, 1
    when the port is taken or Zenoh cannot open."""
    from common.config import ScenarioError, load_scenario
    from common.keys import default_prefix
    from common.runtime import parse_overrides
    from common.session import open_session, where_connecting

    problem = check_view_options(args)
    if problem is not None:
        print(f"umay view: {problem}", file=sys.stderr)
        return EXIT_BAD_INPUT
    try:
        scenario = load_scenario(args.scenario, parse_overrides(args.set))
    except ScenarioError as exc:
        print(f"umay view: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    keys = Keys(args.prefix or default_prefix())
    context = foxglove.Context()
    channels = FoxgloveChannels(context)
    try:
        server = start_server(args.host, args.port, context)
    except PortInUseError as exc:
        print(f"umay view: {exc}", file=sys.stderr)
        return EXIT_FAILED
    with stop_requested() as stop:
        try:
            session = open_session(connect=args.connect)
            view = ViewNode(
                scenario, keys, session, server, channels,
                args.rate_hz, args.image_hz, args.depth_hz, args.jpeg_quality,
                looked_on=where_connecting(args.connect),
            )  # fmt: skip
            print(
                f"{SERVING}{args.host}:{server.port} for {keys.prefix}; layout {LAYOUT_PATH}",
                flush=True,
            )
            view.run(stop)  # closes the session on the way out
        finally:
            stop_server(server)
    return EXIT_OK


def stop_server(server: foxglove.WebSocketServer, timeout_s: float = SERVER_STOP_S) -> None:
    """Stop the server, waiting at most ``timeout_s``: a client that stopped reading holds
    its stop until it goes away, and Ctrl-C must not wait for a client."""
    stopping = threading.Thread(target=server.stop, name="foxglove-stop", daemon=True)
    stopping.start()
    stopping.join(timeout_s)
    if stopping.is_alive():
        print(
            f"umay view: a client still holds the server after {timeout_s:g} s; leaving it",
            file=sys.stderr,
            flush=True,
        )


LAYOUT_PATH = Path(__file__).resolve().parent / "layout.json"
SERVING = "umay view: Foxglove WebSocket at ws://"  # the line that says the view serves


# --- launching it beside `umay up` / `umay run` --------------------------------------------
def served_port(log_text: str) -> int | None:
    """The port the view says it serves on, in its log's text (None: not said yet)."""
    said = re.search(re.escape(SERVING) + r"\S+:(\d+) for ", log_text)
    return int(said.group(1)) if said else None


def wait_for_serving(
    log_path: Path, offset: int, proc: subprocess.Popen, timeout_s: float
) -> int | None:
    """The port the view serves on, once it says so in its log (after byte ``offset``); None
    if ``proc`` ends or time runs out. Its own line, not a probe connection: a connection that
    never completes a WebSocket handshake is logged by the server as a failed one, and the
    line also tells which port ``--port 0`` took."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        with log_path.open("rb") as log:
            log.seek(offset)
            port = served_port(log.read().decode(errors="replace"))
        if port is not None:
            return port
        if proc.poll() is not None:
            return None
        time.sleep(0.1)
    return None


@dataclass(frozen=True)
class ServedView:
    """A view process and the port it serves on."""

    proc: subprocess.Popen
    port: int


class ViewStartError(RuntimeError):
    """The view process did not start serving; the message has its last output."""


@contextlib.contextmanager
def view_process(
    prefix: str,
    endpoint: str,
    port: int,
    log_path: Path,
    scenario_path: str | None = None,
    overrides: list[str] | None = None,
    host: str = DEFAULT_HOST,
    extra: list[str] | None = None,
    startup_timeout_s: float = 30.0,
) -> Iterator[ServedView]:
    """``umay view`` as a child process for the run on ``prefix`` at ``endpoint``, its output
    in ``log_path``; stopped (SIGTERM, then SIGKILL) on the way out. :class:`ViewStartError`
    when it does not serve within ``startup_timeout_s``."""
    argv = [sys.executable, "-m", "deploy", "view", "--prefix", prefix, "--connect", endpoint,
            "--host", host, "--port", str(port)]  # fmt: skip
    if scenario_path:
        argv += ["--scenario", str(scenario_path)]
    for item in overrides or []:
        argv += ["--set", item]
    argv += extra or []
    log_path.parent.mkdir(parents=True, exist_ok=True)
    with log_path.open("ab") as out:
        offset = out.tell()  # the log of earlier runs stays; this run's lines follow it
        proc = subprocess.Popen(argv, stdout=out, stderr=subprocess.STDOUT, env=dict(os.environ))
    try:
        served = wait_for_serving(log_path, offset, proc, startup_timeout_s)
        if served is None:
            tail = log_path.read_text(errors="replace").strip().splitlines()[-3:]
            raise ViewStartError(
                f"the view did not start serving on {host}:{port}: " + " / ".join(tail)
            )
        yield ServedView(proc, served)
    finally:
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(5.0)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
