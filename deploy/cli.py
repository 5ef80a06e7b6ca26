"""The ``umay`` command: run, up, service, status, view, export."""

from __future__ import annotations

import argparse
import contextlib
import importlib
import json
import logging
import math
import os
import signal
import sys
import threading
import time
from pathlib import Path

import zenoh

from common.config import ClockMode, JacobianMode, ScenarioError
from common.keys import SERVICES, Keys, default_prefix
from common.runtime import endpoint_argument, endpoints_argument, prefix_argument
from common.transport import (
    DEFAULT_ENDPOINT,
    open_session,
    open_zenoh,
    setup_logging,
    zenoh_reason,
)
from deploy.exit_codes import EXIT_BAD_INPUT, EXIT_CONVERGED, EXIT_INTERRUPTED, EXIT_NOT_CONVERGED
from deploy.paths import FIGURE_SUFFIXES, OutputPathError, check_output_dir, check_output_file


def _positive_seconds(value: str) -> float:
    """argparse type of a duration: a finite number of seconds above 0."""
    try:
        seconds = float(value)
    except ValueError:
        seconds = math.nan
    if not (math.isfinite(seconds) and seconds > 0):
        raise argparse.ArgumentTypeError(f"{value!r}: seconds, a finite number above 0")
    return seconds


def _scenario_options(p: argparse.ArgumentParser, clock_default: str) -> None:
    p.add_argument("--scenario", default=None, help="scenario TOML (default: default.toml)")
    p.add_argument(
        "--mode", default=None, help="Jacobian strategy: constant|dynamic|pmj|mpj|points3d"
    )
    p.add_argument("--clock", default=clock_default, help="lockstep|realtime")
    p.add_argument("--prefix", type=prefix_argument, help="Zenoh key prefix (default: umay/<id>)")
    p.add_argument(
        "--listen",
        type=endpoint_argument,
        default=None,
        help="Zenoh endpoint the services connect to",
    )
    p.add_argument("--log-dir", default="out/logs", help="per-service log files")
    p.add_argument("--set", action="append", default=[], metavar="TABLE.FIELD=VALUE")


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


def _validated(args: argparse.Namespace, command: str):
    """(overrides, scenario), or None after saying what is wrong: nothing is launched."""
    from deploy.run import prepare

    try:
        overrides = _overrides(args)
        return overrides, prepare(args.scenario, overrides)
    except ScenarioError as exc:
        print(f"umay {command}: {exc}", file=sys.stderr)
        return None


def cmd_run(args: argparse.Namespace) -> int:
    from rich.console import Console

    from deploy.run import format_result, result_table, run_once, write_result

    validated = _validated(args, "run")
    if validated is None:
        return EXIT_BAD_INPUT
    overrides, scenario = validated
    record = Path(args.record) if args.record else None
    if args.result:
        check_output_file("--result", args.result)
    if args.plot:
        check_output_dir("--plot", args.plot)
        record = record or Path(args.plot) / "run.mcap"  # plotting needs a recording
    if args.record:
        check_output_file("--record", args.record)
    check_output_dir("--log-dir", args.log_dir)
    prefix = args.prefix or default_prefix()
    listen = args.listen
    with contextlib.ExitStack() as stack:
        if args.view:
            from deploy.run import default_listen_endpoint

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
        )
    if args.quiet:
        print(format_result(result))
    else:
        Console().print(result_table(result))
    if args.result:
        write_result(result, args.result)
    if args.plot:
        from deploy.plots import plot_recording

        for path in plot_recording(record, Path(args.plot), scenario.controller.converged_px):
            print(f"figure: {path}")
    return EXIT_CONVERGED if result.converged else EXIT_NOT_CONVERGED


def cmd_up(args: argparse.Namespace) -> int:
    from deploy.run import default_listen_endpoint
    from deploy.up import run_up

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
        stack.enter_context(
            view_process(
                prefix, endpoint, args.view_port, log_path, args.scenario, overrides,
                host=DEFAULT_HOST,
            )
        )  # fmt: skip
    except ViewStartError as exc:
        print(f"umay {command}: {exc} (see {log_path})", file=sys.stderr)
        return False
    print(f"umay {command}: Foxglove view at ws://{DEFAULT_HOST}:{args.view_port}", flush=True)
    return True


def _view_options(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--view", action="store_true", help="serve a live Foxglove view beside it (umay view)"
    )
    p.add_argument("--view-port", type=int, default=8765, help="its WebSocket port (8765)")


def cmd_view(args: argparse.Namespace) -> int:
    from deploy.foxglove.node import serve

    return serve(args)


def cmd_export(args: argparse.Namespace) -> int:
    from deploy.foxglove.export import export_foxglove
    from deploy.recording import NotARecordingError

    if not Path(args.file).is_file():
        print(f"umay export: {args.file}: no such file", file=sys.stderr)
        return EXIT_BAD_INPUT
    if not args.foxglove:
        print("umay export: say what to write: --foxglove OUT.mcap", file=sys.stderr)
        return EXIT_BAD_INPUT
    check_output_file("--foxglove", args.foxglove)
    if Path(args.foxglove).resolve() == Path(args.file).resolve():
        print("umay export: --foxglove must not overwrite the recording", file=sys.stderr)
        return EXIT_BAD_INPUT
    try:
        report = export_foxglove(args.file, args.foxglove, args.jpeg_quality)
    except (NotARecordingError, ScenarioError) as exc:
        print(f"umay export: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    for topic, n in sorted(report.written.items()):
        print(f"{n:8d}  {topic}")
    print(f"{sum(report.written.values()):8d}  messages in {args.foxglove}")
    for note in report.notes:
        print(f"note: {note}", file=sys.stderr)
    if report.rejected:
        print(f"note: {report.rejected} recorded payloads did not decode", file=sys.stderr)
    return 0 if report.written else EXIT_NOT_CONVERGED


def cmd_plot(args: argparse.Namespace) -> int:
    from deploy.plots import plot_recording
    from deploy.recording import NotARecordingError

    path = Path(args.file)
    if not path.is_file():
        print(f"umay plot: {path}: no such file", file=sys.stderr)
        return EXIT_BAD_INPUT
    check_output_dir("--out", args.out)
    try:
        written = plot_recording(path, Path(args.out))
    except NotARecordingError as exc:
        print(f"umay plot: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    for p in written:
        print(p)
    if not written:
        print(f"umay plot: {path} holds nothing to plot", file=sys.stderr)
        return EXIT_NOT_CONVERGED
    return 0


def cmd_router(args: argparse.Namespace) -> int:
    """A Zenoh router for multi-host setups, for users without zenohd."""

    if args.config:
        try:
            cfg = zenoh.Config.from_file(args.config)
        except Exception as exc:  # zenoh raises its own error type with the parser's message
            print(f"umay router: {args.config}: {exc}", file=sys.stderr)
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
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
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
        print(f"umay logs: no log for {args.name} in {args.log_dir}", file=sys.stderr)
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
    module = importlib.import_module(f"services.{args.name}.node")
    return int(module.main(args.rest))


def cmd_status(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.live import Live

    from deploy.status import as_json, collect, table

    keys = Keys(args.prefix or default_prefix())
    session = open_session(connect=args.connect)
    try:
        time.sleep(0.3)  # let the session connect and learn the peers
        if args.json:
            print(json.dumps(as_json(collect(session, keys, args.timeout)), indent=2))
        elif args.watch:
            with Live(table(collect(session, keys, args.timeout), keys), console=Console()) as live:
                try:
                    while True:
                        time.sleep(1.0)
                        live.update(table(collect(session, keys, args.timeout), keys))
                except KeyboardInterrupt:
                    pass
        else:
            Console().print(table(collect(session, keys, args.timeout), keys))
    finally:
        session.close()
    return 0


def cmd_record(args: argparse.Namespace) -> int:
    import signal
    import threading

    from deploy.recording import Recorder, run_metadata

    if args.keys is not None:
        try:
            zenoh.KeyExpr(args.keys)
        except zenoh.ZError as exc:
            print(f"umay record: --keys {args.keys!r}: {zenoh_reason(exc)}", file=sys.stderr)
            return EXIT_BAD_INPUT
    check_output_file("OUT.mcap", args.out)
    keys = Keys(args.prefix or default_prefix())
    metadata = {"prefix": keys.prefix, "recorded_by": "umay record"}
    if args.scenario or args.set:
        try:
            metadata = run_metadata(args.scenario, args.set, keys.prefix)
        except OSError as exc:
            print(f"umay record: {args.scenario}: {exc.strerror}", file=sys.stderr)
            return EXIT_BAD_INPUT
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    session = open_session(connect=args.connect)
    try:
        with Recorder(args.out, session, keys, args.keys, metadata) as recorder:
            print(f"recording {recorder.key_expr} to {args.out} (Ctrl-C to stop)", file=sys.stderr)
            stop.wait(args.duration)
        counts = recorder.message_counts()
    finally:
        session.close()
    for key, n in sorted(counts.items()):
        print(f"{n:8d}  {key}")
    print(f"{sum(counts.values()):8d}  messages in {args.out}")
    if recorder.lost:
        print(f"{recorder.lost:8d}  frames lost (last: {recorder.last_loss})")
    return 0


def cmd_info(args: argparse.Namespace) -> int:
    from deploy.recording import NotARecordingError, format_info, read_info

    try:
        info = read_info(args.file)
    except FileNotFoundError:
        print(f"umay info: {args.file}: no such file", file=sys.stderr)
        return EXIT_BAD_INPUT
    except NotARecordingError as exc:
        print(f"umay info: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except Exception as exc:  # the mcap reader raises several types for a bad file
        print(f"umay info: {args.file}: not a readable MCAP file ({exc})", file=sys.stderr)
        return EXIT_BAD_INPUT
    print(format_info(info))
    return 0


def cmd_replay(args: argparse.Namespace) -> int:
    from deploy.replay import REPLAYABLE, ReplayError, ReplayFailed, format_report, replay_service

    if args.service not in REPLAYABLE:
        choices = ", ".join(REPLAYABLE)
        print(
            f"umay replay: unknown service {args.service!r} (choose from {choices})",
            file=sys.stderr,
        )
        return EXIT_BAD_INPUT
    if not Path(args.file).is_file():
        print(f"umay replay: {args.file}: no such file", file=sys.stderr)
        return EXIT_BAD_INPUT
    if args.speed == "max":
        speed = None
    else:
        try:
            speed = float(args.speed)
        except ValueError:
            speed = -1.0
        if not (math.isfinite(speed) and speed > 0):
            print(f"umay replay: --speed {args.speed!r}: a positive number or max", file=sys.stderr)
            return EXIT_BAD_INPUT
    try:
        report = replay_service(
            args.file,
            args.service,
            speed,
            args.check,
            Path(args.log_dir),
            overrides=args.set,
            scenario_path=args.scenario,
            tolerance=args.tolerance,
        )
    except (ReplayError, ScenarioError) as exc:
        print(f"umay replay: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except ReplayFailed as exc:
        print(f"umay replay: {exc}", file=sys.stderr)
        return EXIT_NOT_CONVERGED
    print(format_report(report))
    return 0 if report.ok else EXIT_NOT_CONVERGED


def cmd_accuracy(args: argparse.Namespace) -> int:
    from rich.progress import Progress

    from common.config import load_scenario
    from common.runtime import parse_overrides

    if args.frames < 1 or args.seed < 0:
        print("umay accuracy: --frames must be at least 1, --seed 0 or more", file=sys.stderr)
        return EXIT_BAD_INPUT
    try:
        overrides = parse_overrides(args.set)
        scenarios = [load_scenario(p, overrides) for p in (args.scenario or [None])]
    except ScenarioError as exc:
        print(f"umay accuracy: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    if args.json:
        check_output_file("--json", args.json)
    from deploy.accuracy import default_conditions, evaluate, format_table  # loads pybullet

    conditions = default_conditions(args.seed)
    with Progress(transient=True) as bar:
        task = bar.add_task("postures", total=args.frames * len(scenarios))
        results = evaluate(
            scenarios,
            args.frames,
            conditions,
            args.seed,
            progress=lambda done, _total: bar.update(task, completed=done),
        )
    print(format_table(results))
    if args.json:
        Path(args.json).write_text(json.dumps([r.model_dump() for r in results], indent=2) + "\n")
    return 0


def cmd_bench(args: argparse.Namespace) -> int:
    from deploy.bench import BenchError, format_report, median_of_runs, run_bench, write_json
    from deploy.run import prepare

    size = args.size.lower().split("x")
    if len(size) != 2 or not all(p.isdigit() for p in size):
        print(f"umay bench: --size {args.size!r}: expected WxH, e.g. 640x480", file=sys.stderr)
        return EXIT_BAD_INPUT
    if args.mode not in {c.value for c in ClockMode}:
        print(f"umay bench: --mode {args.mode!r}: lockstep or realtime", file=sys.stderr)
        return EXIT_BAD_INPUT
    if args.frames < 2 or args.warmup < 0 or (args.synthetic_frames or 0) < 0 or args.repeat < 1:
        print(
            "umay bench: --frames >= 2, --repeat >= 1, --warmup and --synthetic-frames >= 0",
            file=sys.stderr,
        )
        return EXIT_BAD_INPUT
    overrides = [
        f"camera.width_px={size[0]}",
        f"camera.height_px={size[1]}",
        f"run.clock='{args.mode}'",
        *args.set,
    ]
    try:
        scenario = prepare(args.scenario, overrides)
    except ScenarioError as exc:
        print(f"umay bench: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    if args.json:
        check_output_file("--json", args.json)
    if args.figure:
        check_output_file("--figure", args.figure, FIGURE_SUFFIXES)
    check_output_dir("--log-dir", args.log_dir)
    runs = []
    for i in range(args.repeat):
        try:
            result = run_bench(
                args.scenario,
                scenario,
                overrides,
                args.frames,
                args.warmup,
                Path(args.log_dir),
                shm=not args.no_shm,
                synthetic_frames=args.synthetic_frames,
                command=" ".join(["umay", *sys.argv[1:]]),
                reference_renderer=not args.no_reference,
                view=args.view,
            )
        except BenchError as exc:
            print(f"umay bench: {exc}", file=sys.stderr)
            return 1
        runs.append(result)
        if args.repeat > 1:
            print(f"--- run {i + 1} of {args.repeat}\n{format_report(result)}\n", flush=True)
    result = runs[0] if len(runs) == 1 else {**median_of_runs(runs), "each_run": runs}
    print(format_report(result))
    try:  # checked before the runs; this fails only if the disk changed since (full, say)
        if args.json:
            write_json(result, args.json)
        if args.figure:
            from deploy.plots import write_bench_figure

            write_bench_figure(runs[0], Path(args.figure))  # frame by frame: the first run
            print(f"figure: {args.figure}" + (" (the first run)" if len(runs) > 1 else ""))
    except OSError as exc:
        print(f"umay bench: could not write the results: {exc}", file=sys.stderr)
        return 1
    return 0


def cmd_docs(args: argparse.Namespace) -> int:
    from deploy.docs import REPO_ROOT, DocsError, update

    try:
        outdated = update(Path(args.root) if args.root else REPO_ROOT, check=args.check)
    except DocsError as exc:
        print(f"umay docs: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    for o in outdated:
        print(o if args.check else f"rewrote {o.document}: {o.block}", file=sys.stderr)
    return 1 if args.check and outdated else 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="umay", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("run", help="bounded run: servo until converged or timeout, then report")
    _scenario_options(p, clock_default=None)
    p.add_argument("--timeout", type=float, default=None, help="simulated seconds")
    p.add_argument("--result", default=None, help="write the result JSON here")
    p.add_argument("--quiet", action="store_true", help="no live progress line")
    p.add_argument("--plot", default=None, metavar="DIR", help="write the run's figures here")
    p.add_argument("--record", default=None, metavar="OUT.mcap", help="record the run to MCAP")
    _view_options(p)
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("up", help="launch the four services and keep them running")
    _scenario_options(p, clock_default="realtime")
    p.add_argument(
        "--connect",
        type=endpoints_argument,
        default=None,
        help="Zenoh endpoint(s) to join as well",
    )
    _view_options(p)
    p.set_defaults(func=cmd_up)

    p = sub.add_parser(
        "view",
        help="live Foxglove view of a running system (WebSocket, default ws://127.0.0.1:8765)",
    )
    from deploy.foxglove.options import add_view_arguments

    add_view_arguments(p)
    p.set_defaults(func=cmd_view)

    p = sub.add_parser("export", help="a recording as an MCAP file Foxglove shows")
    p.add_argument("file", metavar="RUN.mcap")
    p.add_argument("--foxglove", default=None, metavar="OUT.mcap", help="write it here")
    p.add_argument("--jpeg-quality", type=int, default=85, help="colour images' JPEG quality")
    p.set_defaults(func=cmd_export)

    p = sub.add_parser("plot", help="figures of a recorded run (PNG)")
    p.add_argument("file", help="an MCAP recording (umay run --record / umay record)")
    p.add_argument("--out", default="out/plots", help="output folder")
    p.set_defaults(func=cmd_plot)

    p = sub.add_parser("accuracy", help="vision against ground truth under sensor conditions")
    p.add_argument("--scenario", action="append", default=None, help="scenario TOML (repeatable)")
    p.add_argument("--frames", type=int, default=100, help="postures per scenario")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", default=None, metavar="OUT.json", help="write the results here")
    p.add_argument("--set", action="append", default=[], metavar="TABLE.FIELD=VALUE")
    p.set_defaults(func=cmd_accuracy)

    p = sub.add_parser("bench", help="loop latency and throughput per stage, vs in-process")
    p.add_argument("--frames", type=int, default=100, help="measured frames (after warm-up)")
    p.add_argument("--warmup", type=int, default=5, help="frames left out at the start")
    p.add_argument("--size", default="640x480", help="colour image WxH (default 640x480)")
    p.add_argument("--mode", default="lockstep", help="clock: lockstep|realtime")
    p.add_argument(
        "--no-shm",
        action="store_true",
        help="shared memory off everywhere: camera frames whole, by copy, not by reference",
    )
    p.add_argument(
        "--no-reference",
        action="store_true",
        help="skip the TinyRenderer reference (its render cost and its loop)",
    )
    p.add_argument("--repeat", type=int, default=1, help="runs; the table shows their medians")
    p.add_argument(
        "--view",
        action="store_true",
        help="with a live view (umay view) and a Foxglove client connected during the loop",
    )
    p.add_argument(
        "--synthetic-frames",
        type=int,
        default=None,
        help="frames of the 30 Hz synthetic source (default: --frames; 0: skip it)",
    )
    p.add_argument("--json", default=None, metavar="OUT.json", help="write the results here")
    p.add_argument(
        "--figure",
        default=None,
        metavar="OUT.png",
        help="the frames' stages as a figure, .png, .svg or .pdf (1st run)",
    )
    p.add_argument("--scenario", default=None, help="scenario TOML (default: default.toml)")
    p.add_argument("--log-dir", default="out/logs/bench", help="the services' log files")
    p.add_argument("--set", action="append", default=[], metavar="TABLE.FIELD=VALUE")
    p.set_defaults(func=cmd_bench)

    p = sub.add_parser("docs", help="rewrite the docs' tables from the JSON they come from")
    p.add_argument("--check", action="store_true", help="change nothing; exit 1 if out of date")
    p.add_argument("--root", default=None, help="the repository (default: this one)")
    p.set_defaults(func=cmd_docs)

    from deploy.compare_cli import add_campaign_parser, add_compare_parser

    add_compare_parser(sub)  # umay compare: every strategy on every scenario of a suite
    add_campaign_parser(sub)  # umay campaign: every strategy from random starts
    from deploy.experiments.domains_cli import add_domains_parser

    add_domains_parser(sub)  # umay domains: convergence domains over large displacements

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

    p = sub.add_parser("logs", help="show a service's log file")
    p.add_argument("name", choices=(*SERVICES,))
    p.add_argument("--log-dir", default="out/logs")
    p.add_argument("-n", "--lines", type=int, default=40)
    p.add_argument("-f", "--follow", action="store_true")
    p.set_defaults(func=cmd_logs)

    p = sub.add_parser("service", help="run one service alone")
    p.add_argument("name", choices=SERVICES)
    p.add_argument("rest", nargs=argparse.REMAINDER, help="options of the service")
    p.set_defaults(func=cmd_service)

    p = sub.add_parser("status", help="ask every service for its status over Zenoh")
    p.add_argument("--prefix", type=prefix_argument)
    p.add_argument(
        "--connect",
        type=endpoints_argument,
        default=None,
        help="Zenoh endpoint(s) of the running system",
    )
    p.add_argument(
        "--timeout", type=_positive_seconds, default=1.0, help="seconds to wait for replies"
    )
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.add_argument("--watch", action="store_true", help="refresh every second until Ctrl-C")
    p.set_defaults(func=cmd_status)

    p = sub.add_parser("record", help="record the running system's messages to an MCAP file")
    p.add_argument("out", metavar="OUT.mcap")
    p.add_argument("--keys", default=None, help="key expression (default: <prefix>/**)")
    p.add_argument(
        "--duration", type=_positive_seconds, default=None, help="seconds (default: Ctrl-C)"
    )
    p.add_argument("--prefix", type=prefix_argument)
    p.add_argument(
        "--connect",
        type=endpoints_argument,
        default=None,
        help="Zenoh endpoint(s) of the running system",
    )
    p.add_argument("--scenario", default=None, help="scenario the system runs (for a replay)")
    p.add_argument("--set", action="append", default=[], metavar="TABLE.FIELD=VALUE")
    p.set_defaults(func=cmd_record)

    p = sub.add_parser("info", help="channels, counts, rates and metadata of an MCAP recording")
    p.add_argument("file", metavar="FILE.mcap")
    p.set_defaults(func=cmd_info)

    p = sub.add_parser("replay", help="re-run one service on a recording's inputs, compare")
    p.add_argument("file", metavar="FILE.mcap")
    p.add_argument("--service", required=True, help="vision|controller|actuation")
    p.add_argument("--speed", default="max", help="playback speed factor, or max (lockstep)")
    p.add_argument("--check", action="store_true", help="compare with the recorded outputs")
    p.add_argument(
        "--tolerance",
        type=float,
        default=None,
        help="default: controller 1e-12, vision and actuation 1e-9; 0 = bit-identical",
    )
    p.add_argument("--log-dir", default="out/logs/replay", help="the service's log file")
    p.add_argument("--scenario", default=None, help="instead of the recorded scenario")
    p.add_argument("--set", action="append", default=[], metavar="TABLE.FIELD=VALUE")
    p.set_defaults(func=cmd_replay)
    return parser


def main(argv: list[str] | None = None) -> int:
    setup_logging(os.path.basename(sys.argv[0]) or "umay")
    logging.getLogger().setLevel(os.environ.get("UMAY_LOG_LEVEL", "WARNING"))
    args = build_parser().parse_args(argv)
    # SIGTERM (a CI timeout, `kill`, a container stopping) ends a command as Ctrl-C does: the
    # services it launched are stopped on the way out. Commands that run until told to stop
    # (up, router, record, compare) install their own handlers.
    signal.signal(signal.SIGTERM, signal.default_int_handler)
    try:
        return int(args.func(args))
    except OutputPathError as exc:  # raised by the commands' checks, before any work starts
        print(f"umay {args.command}: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print(f"umay {args.command}: interrupted; what it started is stopped", file=sys.stderr)
        return EXIT_INTERRUPTED
    except zenoh.ZError as exc:  # a session that cannot open: endpoint unusable, port taken
        logging.getLogger("umay").debug("Zenoh error", exc_info=True)
        print(f"umay {args.command}: Zenoh: {zenoh_reason(exc)}", file=sys.stderr)
        return 1
