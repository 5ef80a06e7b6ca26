"""``umay run --inprocess``: a whole lockstep run in this process, no services, no Zenoh.

The loop is :class:`services.pipeline.Pipeline` (the services' pure steps composed as the
lockstep run chains them), the end of the run and its result are :mod:`deploy.launch.run_end` (the
logic ``umay run`` uses), so a run here ends on the same frame, for the same reason, with the
same result as ``umay run --clock lockstep``; only the wall-clock fields differ. Made to be
called many times in one process (domain studies): each run opens one world and closes it.
"""

from __future__ import annotations

import argparse
import logging
import sys
import threading
import time

from common.config import ClockMode, Scenario
from common.messages import EndEffectorTwist, SimTruth
from deploy.exit_codes import (
    EXIT_BAD_INPUT,
    EXIT_CONVERGED,
    EXIT_INTERRUPTED,
    EXIT_NOT_CONVERGED,
)
from deploy.launch.evaluate import RunResult
from deploy.launch.run_end import EndLimits, HoldState, RunEnd, judge_twist, run_result
from services.pipeline import Pipeline

log = logging.getLogger("umay.run")


def run_scenario_inprocess(scenario: Scenario, stop: threading.Event | None = None) -> RunResult:
    """Servo ``scenario`` (lockstep clock) until the run ends; its result. ``stop``: set from
    another thread to end the run early (reason "error", detail "interrupted"). An exception
    in the loop ends the run as "error" naming it, as a service's exit ends ``umay run``."""
    if scenario.run.clock is not ClockMode.LOCKSTEP:
        raise ValueError("an in-process run is lockstep: set run.clock = 'lockstep'")
    started = time.monotonic()
    limits = EndLimits.of(scenario)
    truths: dict[int, SimTruth] = {}
    twists: dict[int, EndEffectorTwist] = {}
    hold = HoldState()
    end: RunEnd | None = None
    reason, detail = "error", ""
    try:
        with Pipeline(scenario) as pipeline:
            while end is None:
                if stop is not None and stop.is_set():
                    detail = "interrupted"
                    break
                frame = pipeline.step()
                assert frame.truth is not None
                truths[frame.frame_seq] = frame.truth
                twists[frame.frame_seq] = frame.twist
                hold, end = judge_twist(limits, hold, frame.twist)
    except Exception as exc:  # the run's result says what failed, as for a service's exit
        log.exception("in-process run of %s failed", scenario.name)
        if end is None:  # else the run had ended: its verdict stands
            detail = f"in-process run failed: {type(exc).__name__}: {exc}"
    if end is not None:
        reason, detail = end.reason, end.detail
    return run_result(scenario, reason, detail, end, truths, twists, time.monotonic() - started)


def cmd_run_inprocess(args: argparse.Namespace, scenario: Scenario) -> int:
    """``umay run --inprocess`` after the scenario was validated: the same report, result JSON
    and exit codes as ``umay run``. Options that need the services are refused."""
    from rich.console import Console

    from deploy.interrupts import stop_requested
    from deploy.launch.run import format_result, result_table, write_result
    from deploy.paths import check_output_file

    refused = [
        option
        for option, given in (
            ("--record", args.record),
            ("--plot", args.plot),
            ("--view", args.view),
        )
        if given
    ]
    if scenario.run.clock is not ClockMode.LOCKSTEP:
        refused.append("--clock realtime")
    if refused:
        print(
            f"umay run: --inprocess runs lockstep without services: not with {', '.join(refused)}",
            file=sys.stderr,
        )
        return EXIT_BAD_INPUT
    if args.result:
        check_output_file("--result", args.result)
    # Ctrl-C or SIGTERM ends the run at the next frame, reported as far as it went (as
    # `umay run` does); a second Ctrl-C does not wait for that.
    with stop_requested(second_interrupts=True) as stop:
        result = run_scenario_inprocess(scenario, stop)
    if args.quiet:
        print(format_result(result))
    else:
        Console().print(result_table(result))
    if args.result:
        write_result(result, args.result)
    if stop.is_set() and result.detail == "interrupted":  # not a run that had ended already
        print("umay run: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    return EXIT_CONVERGED if result.converged else EXIT_NOT_CONVERGED
