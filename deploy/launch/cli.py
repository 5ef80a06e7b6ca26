"""The launch commands of ``umay``: run, up, router, logs, service and status (their
parsers and handlers; :mod:`deploy.cli` puts them together)."""

from __future__ import annotations

import argparse
import contextlib
import importlib
import json
import logging
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path

import zenoh

from common.config import ClockMode, JacobianMode, Scenario, ScenarioError
from common.keys import PREFIX_HELP, SERVICES, Keys, default_prefix
from common.runtime import endpoint_argument, endpoints_argument, prefix_argument
from common.session import (
    DEFAULT_ENDPOINT,
    open_session,
    open_zenoh,
    where_connecting,
    zenoh_reason,
)
from deploy.arguments import positive_seconds, tcp_port
from deploy.exit_codes import (
    EXIT_BAD_INPUT,
    EXIT_CONVERGED,
    EXIT_INTERRUPTED,
    EXIT_NOT_CONVERGED,
)
from deploy.interrupts import stop_requested
from deploy.paths import check_output_dir, check_output_file


def _scenario_options(p: argparse.ArgumentParser, clock_default: str) -> None:
    p.add_argument("--scenario", default=None, help="scenario TOML (default: default.toml)")
    p.add_argument(
        "--mode", default=None, help="Jacobian strategy: constant|dynamic|pmj|mpj|points3d"
    )
    p.add_argument("--clock", default=clock_default, help="lockstep|realtime")
    p.add_argument("--prefix", type=prefix_argument, help=PREFIX_HELP)
    p.add_argument(
        "--listen",
        type=endpoint_argument,
        default=None,
        help="Zenoh endpoint the services connect to",
    )
    p.add_argument("--log-dir", default="out/logs", help="per-service log files (out/logs)")
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="TABLE.FIELD=VALUE",
        help="change one scenario field, the value in TOML (controller.gain=2.0, "
        "camera.kinect.enabled=true); repeatable; fields: docs/scenarios.md",
    )


def _overrides(args: argparse.Namespace) -> list[str]:
    """Command-line options as scenario overrides, checked here so the message names them."""
    out = list(args.set)
    if args.mode is not None:
        if args.mode not in {m.value for m in JacobianMode}:
            choices = ", ".join(m.value for m in JacobianMode)
            raise ScenarioError(f"--mode: unknown mode {args.mode!r} (choose from {choices})")
        out.append(f"controller.mode='{args.mode}'")
    if args.clock is not None:
        if args.clock not in {c.value for c in ClockMode}:
            raise ScenarioError(f"--clock: unknown clock {args.clock!r} (lockstep or realtime)")
        out.append(f"run.clock='{args.clock}'")
    if getattr(args, "timeout", None) is not None:
        out.append(f"run.timeout_s={float(args.timeout)}")
    return out


def _validated(args: argparse.Namespace, command: str) -> tuple[list[str], Scenario] | None:
    """(overrides, scenario), or None after saying what is wrong: nothing is launched."""
    from deploy.launch.run import prepare

    try:
        overrides = _overrides(args)
        return overrides, prepare(args.scenario, overrides)
    except ScenarioError as exc:
        print(f"umay {command}: {exc}", file=sys.stderr)
        return None


def cmd_run(args: argparse.Namespace) -> int:
    from rich.console import Console

    from deploy.launch.run import format_result, result_table, run_once, write_result

    if args.inprocess:
        args.clock = args.clock or "lockstep"  # an in-process run is lockstep
    validated = _validated(args, "run")
    if validated is None:
        return EXIT_BAD_INPUT
    overrides, scenario = validated
    if args.inprocess:
        from deploy.launch.run_inprocess import cmd_run_inprocess

        return cmd_run_inprocess(args, scenario)
    record = Path(args.record) if args.record else None
    record_frames = not args.record_without_frames
    if args.result:
        check_output_file("--result", args.result)
    if args.plot:
        check_output_dir("--plot", args.plot)
        if record is None:  # plotting needs a recording: one beside the figures, and no
            # camera frames in it (the figures draw none; with them it weighs tens of MB)
            record = check_output_file("--plot", Path(args.plot) / "run.mcap")
            record_frames = False
    if args.record:
        check_output_file("--record", args.record)
    check_output_dir("--log-dir", args.log_dir)
    prefix = args.prefix or default_prefix()
    listen = args.listen
    # Ctrl-C or SIGTERM ends the run as its end would: the services stopped, then the
    # summary, the result (detail "interrupted") and the figures of the run so far. A second
    # Ctrl-C while they stop interrupts as usual.
    with stop_requested(second_interrupts=True) as stop, contextlib.ExitStack() as stack:
        if args.view:
            from deploy.launch.run import default_listen_endpoint

            listen = listen or default_listen_endpoint()
            if not _start_view(stack, args, "run", prefix, listen, overrides):
                return 1
        result = run_once(
            args.scenario,
            scenario,
            overrides,
            prefix,
            Path(args.log_dir),
            listen=listen,
            quiet=args.quiet,
            record=record,
            record_frames=record_frames,
            stop=stop,
        )
    if args.quiet:
        print(format_result(result))
    else:
        Console().print(result_table(result))
    if args.result:
        write_result(result, args.result)
    if args.plot and record is not None and not record.exists():  # the recorder heard nothing
        print(f"umay run: no figures: nothing was recorded to {record}", file=sys.stderr)
    elif args.plot and record is not None:
        from deploy.recording.plots import plot_recording

        for path in plot_recording(record, Path(args.plot), scenario.controller.converged_px):
            print(f"figure: {path}")
    if stop.is_set() and result.detail == "interrupted":  # not a run that had ended already
        print("umay run: interrupted; what it started is stopped", file=sys.stderr)
        return EXIT_INTERRUPTED
    return EXIT_CONVERGED if result.converged else EXIT_NOT_CONVERGED


def cmd_up(args: argparse.Namespace) -> int:
    from deploy.launch.run import default_listen_endpoint
    from deploy.launch.up import run_up

    validated = _validated(args, "up")
    if validated is None:
        return EXIT_BAD_INPUT
    overrides, scenario = validated
    check_output_dir("--log-dir", args.log_dir)
    listen = args.listen or default_listen_endpoint()
    # Also join the well-known endpoint (or --connect), so a supervisor already running on
    # this prefix is seen even when this one had to listen elsewhere.
    connect = args.connect or [DEFAULT_ENDPOINT]
    connect = [e for e in connect if e != listen]
    prefix = args.prefix or default_prefix()
    with contextlib.ExitStack() as stack:
        if args.view and not _start_view(stack, args, "up", prefix, listen, overrides):
            return 1
        return run_up(
            args.scenario, scenario, overrides, prefix, listen, connect, Path(args.log_dir)
        )


def _start_view(
    stack: contextlib.ExitStack,
    args: argparse.Namespace,
    command: str,
    prefix: str,
    endpoint: str,
    overrides: list[str],
) -> bool:
    """``umay view`` beside ``umay up``/``run`` (stopped when ``stack`` closes), its output in
    ``<log-dir>/view.log``; False after saying why when it does not start serving."""
    from deploy.foxglove.node import ViewStartError, view_process
    from deploy.foxglove.options import DEFAULT_HOST

    log_path = Path(args.log_dir) / "view.log"
    try:
        view = stack.enter_context(
            view_process(
                prefix, endpoint, args.view_port, log_path, args.scenario, overrides,
                host=DEFAULT_HOST,
            )
        )  # fmt: skip
    except ViewStartError as exc:
        print(f"umay {command}: {exc} (see {log_path})", file=sys.stderr)
        return False
    print(f"umay {command}: Foxglove view at ws://{DEFAULT_HOST}:{view.port}", flush=True)
    return True


def _view_options(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--view", action="store_true", help="serve a live Foxglove view beside it (umay view)"
    )
    p.add_argument("--view-port", type=tcp_port, default=8765, help="its WebSocket port (8765)")


def cmd_router(args: argparse.Namespace) -> int:
    """A Zenoh router for multi-host setups, for users without zenohd."""

    if args.config:
        try:
            cfg = zenoh.Config.from_file(args.config)
        except Exception as exc:  # zenoh raises its own error type with the parser's message
            print(f"umay router: {args.config}: {zenoh_reason(exc)}", file=sys.stderr)
            return EXIT_BAD_INPUT
        # A credentials file named relative to the config is found wherever we run from.
        dictionary = json.loads(cfg.get_json("transport/auth/usrpwd/dictionary_file"))
        if dictionary and not Path(dictionary).is_absolute():
            resolved = (Path(args.config).parent / dictionary).resolve()
            cfg.insert_json5("transport/auth/usrpwd/dictionary_file", json.dumps(str(resolved)))
    else:
        cfg = zenoh.Config()
        cfg.insert_json5("mode", '"router"')
        cfg.insert_json5("scouting/multicast/enabled", "false")
    listen = args.listen or (None if args.config else ["tcp/0.0.0.0:7447"])
    if listen:
        cfg.insert_json5("listen/endpoints", json.dumps(listen))
    with stop_requested() as stop:
        try:
            session = open_zenoh(cfg)
        except Exception as exc:
            print(f"umay router: cannot start: {zenoh_reason(exc)}", file=sys.stderr)
            return 1
        endpoints = ",".join(listen or json.loads(cfg.get_json("listen/endpoints")))
        print(f"umay router: listening on {endpoints}", flush=True)
        try:
            stop.wait()
        finally:
            session.close()
    return 0


def cmd_logs(args: argparse.Namespace) -> int:
    path = Path(args.log_dir) / f"{args.name}.log"
    if args.lines < 0:
        print(f"umay logs: -n {args.lines}: a number of lines, 0 or more", file=sys.stderr)
        return EXIT_BAD_INPUT
    if not path.exists():
        started_by = (
            "`umay up --view` or `umay run --view` starts it"
            if args.name == "view"
            else "`umay run` and `umay up` write the services' logs there"
        )
        print(
            f"umay logs: no log for {args.name} in {args.log_dir} ({started_by})",
            file=sys.stderr,
        )
        return EXIT_BAD_INPUT
    lines = path.read_text(errors="replace").splitlines()
    if args.lines:  # lines[-0:] would be all of them
        print("\n".join(lines[-args.lines :]))
    if args.follow:
        with path.open(errors="replace") as f:
            f.seek(0, 2)
            try:
                while True:
                    line = f.readline()
                    if line:
                        print(line, end="", flush=True)
                    else:
                        time.sleep(0.2)
            except KeyboardInterrupt:
                pass
    return 0


def cmd_service(args: argparse.Namespace) -> int:
    # A service's own level (its log says what it runs and waits for), not the command's.
    logging.getLogger().setLevel(os.environ.get("UMAY_LOG_LEVEL", "INFO"))
    module = importlib.import_module(f"services.{args.name}.node")
    return int(module.main(args.service_options))


def cmd_status(args: argparse.Namespace) -> int:
    from rich.console import Console, RenderableType
    from rich.live import Live

    from deploy.launch.status import as_json, collect, status_display, verdict

    keys = Keys(args.prefix or default_prefix())
    session = open_session(connect=args.connect)
    try:
        time.sleep(0.3)  # let the session connect and learn the peers
        # Ctrl-C and SIGTERM end a watch after its current query: raised inside one, the
        # interrupt could leave the session's close waiting for good.
        if args.watch and args.json:  # one JSON document a line, every second (jq, a log)
            with stop_requested() as stop:
                while not stop.is_set():
                    print(json.dumps(as_json(collect(session, keys, args.timeout))), flush=True)
                    stop.wait(1.0)
            return 0
        if args.watch:

            def now() -> RenderableType:
                return status_display(collect(session, keys, args.timeout), keys)

            with stop_requested() as stop, Live(now(), console=Console()) as live:
                while not stop.wait(1.0):
                    live.update(now())
            return 0
        views = collect(session, keys, args.timeout)
    finally:
        session.close()
    if args.json:
        print(json.dumps(as_json(views), indent=2))
    else:
        Console().print(status_display(views, keys))
    code, why = verdict(views, keys, where_connecting(args.connect))
    if why:
        print(f"umay status: {why}", file=sys.stderr)
    return code


def add_run_parser(sub: argparse._SubParsersAction) -> None:
    """``umay run``: one bounded run."""
    p = sub.add_parser(
        "run",
        help="bounded run: servo until converged or timeout, then report",
        description="Launch the four services, servo until the run ends (converged, the "
        "timeout, or a named failure), print a summary, write the result JSON, stop them. "
        "Exit 0 converged, 1 not converged, 2 bad input (nothing launched), 130 interrupted.",
    )
    _scenario_options(p, clock_default=None)
    p.add_argument("--timeout", type=positive_seconds, default=None, help="simulated seconds")
    p.add_argument("--result", default=None, help="write the result JSON here")
    p.add_argument("--quiet", action="store_true", help="no live progress line")
    p.add_argument(
        "--plot",
        default=None,
        metavar="DIR",
        help="write the run's figures here (and, without --record, the recording they are "
        "drawn from, DIR/run.mcap, without camera frames)",
    )
    p.add_argument("--record", default=None, metavar="OUT.mcap", help="record the run to MCAP")
    p.add_argument(
        "--record-without-frames",
        action="store_true",
        help="with --record: leave the camera frames out (enough for umay plot; far smaller)",
    )
    p.add_argument(
        "--inprocess", action="store_true", help="lockstep in this process: no services, no Zenoh"
    )
    _view_options(p)
    p.set_defaults(func=cmd_run)


def add_up_parser(sub: argparse._SubParsersAction) -> None:
    """``umay up``: the four services, kept running."""
    p = sub.add_parser(
        "up",
        help="launch the four services and keep them running",
        description="Launch the four services and keep them running (servoing, then holding "
        "on the target) until Ctrl-C or SIGTERM; a service that dies or hangs is restarted. "
        "Watch it with `umay status --watch` or `umay view`.",
    )
    _scenario_options(p, clock_default="realtime")
    p.add_argument(
        "--connect",
        type=endpoints_argument,
        default=None,
        help="Zenoh endpoint(s) to join as well",
    )
    _view_options(p)
    p.set_defaults(func=cmd_up)


def add_router_parser(sub: argparse._SubParsersAction) -> None:
    """``umay router``: a Zenoh router."""
    p = sub.add_parser("router", help="run a Zenoh router (multi-host setups)")
    p.add_argument(
        "--listen",
        type=endpoints_argument,
        default=None,
        help="endpoint(s), comma-separated (default: the config's, else tcp/0.0.0.0:7447)",
    )
    p.add_argument(
        "--config", default=None, help="a Zenoh JSON5 config (router mode), e.g. with an ACL"
    )
    p.set_defaults(func=cmd_router)


def add_logs_parser(sub: argparse._SubParsersAction) -> None:
    """``umay logs``: a service's log file."""
    p = sub.add_parser("logs", help="show a service's log file (or the live view's: view)")
    p.add_argument("name", choices=(*SERVICES, "view"))
    p.add_argument("--log-dir", default="out/logs")
    p.add_argument("-n", "--lines", type=int, default=40)
    p.add_argument("-f", "--follow", action="store_true")
    p.set_defaults(func=cmd_logs)


def add_service_parser(sub: argparse._SubParsersAction) -> None:
    """``umay service``: one service alone."""
    p = sub.add_parser(
        "service",
        help="run one service alone",
        description="Run one service alone; its own options follow its name "
        "(umay service NAME --help lists them).",
    )
    p.add_argument("name", choices=SERVICES, metavar="NAME", help=", ".join(SERVICES))
    p.add_argument(
        "service_options",
        nargs=argparse.REMAINDER,
        metavar="...",
        help="the service's options: --scenario, --prefix, --connect, --zenoh-config, --set",
    )
    p.set_defaults(func=cmd_service)


def add_status_parser(sub: argparse._SubParsersAction) -> None:
    """``umay status``: every service's status."""
    p = sub.add_parser("status", help="ask every service for its status over Zenoh")
    p.add_argument("--prefix", type=prefix_argument, help=PREFIX_HELP)
    p.add_argument(
        "--connect",
        type=endpoints_argument,
        default=None,
        help="Zenoh endpoint(s) of the running system",
    )
    p.add_argument(
        "--timeout", type=positive_seconds, default=1.0, help="seconds to wait for replies"
    )
    p.add_argument(
        "--json",
        action="store_true",
        help="machine-readable output (with --watch: one JSON document a line, every second)",
    )
    p.add_argument("--watch", action="store_true", help="refresh every second until Ctrl-C")
    p.set_defaults(func=cmd_status)


# Command name -> what adds its parser; deploy.cli puts them in the help's order.
COMMANDS: dict[str, Callable[[argparse._SubParsersAction], None]] = {
    "run": add_run_parser,
    "up": add_up_parser,
    "router": add_router_parser,
    "logs": add_logs_parser,
    "service": add_service_parser,
    "status": add_status_parser,
}
