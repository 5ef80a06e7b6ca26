"""Runners for the domain-study executor tests (``--pipeline tests.domains_fakes:NAME``): a
cheap deterministic stand-in for a pipeline, so the tests check what the executors do
(every task run once, its record routed to its key, a lost worker's task run again) in
seconds. Each result is a function of the task's scenario only."""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np

from common import kinematics as kin
from deploy.experiments.domains.study import RunTask
from deploy.launch.evaluate import RunResult

KILL_DIR_ENV = "UMAY_TEST_KILL_DIR"


def fake_run(task: RunTask) -> RunResult:
    """Converged when the start's hand marker is within 6 cm of the target (points3d always),
    else a timeout; the numbers come from the scenario's joint angles and mode."""
    scenario = task.scenario()
    q = np.array(scenario.robot.q0)
    hand = kin.forward_kinematics(q) @ kin.hand_marker_in_ee()
    spread = float(np.linalg.norm(hand[:3, 3] - np.array(scenario.target.position)))
    converged = spread < 0.06 or scenario.controller.mode.value == "points3d"
    time.sleep(0.05)  # long enough that both workers take tasks
    return RunResult(
        scenario=scenario.name,
        mode=scenario.controller.mode.value,
        clock=scenario.run.clock.value,
        converged=converged,
        reason="converged" if converged else "timeout",
        frames=int(1000 * spread) + len(scenario.controller.mode.value),
        sim_time_s=spread * 100.0,
        wall_time_s=0.05,
        final_pixel_rms=0.2 if converged else 3.0,
        final_position_error_m=0.001 if converged else spread,
        final_orientation_error_deg=float(np.degrees(q[5])),
        path_length_m=spread,
        final_joint_margin_deg=30.0,
        final_hand_border_px=40.0,
        min_manipulability=0.01,
        detail="" if converged else "fake: still servoing",
    )


def kill_once(task: RunTask) -> RunResult:
    """:func:`fake_run`, except that the first task to get here kills its own worker process
    (as a crashed or lost machine would) before answering."""
    marker = Path(os.environ[KILL_DIR_ENV]) / "killed"
    try:
        fd = os.open(marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
    except FileExistsError:
        return fake_run(task)
    os.write(fd, f"{task.key} {os.getpid()}\n".encode())
    os.close(fd)
    os._exit(1)


def no_run(task: RunTask) -> RunResult:
    """A pipeline that must not be called (a resumed study with every run kept)."""
    raise AssertionError(f"{task.key} was run again")
