"""Helpers for tests that drive the services' event handlers directly, in one process, on a
loopback Zenoh session under a unique key prefix (the ``ctx`` and ``pipeline_frames`` fixtures of
tests/conftest.py are made of them): the default run's first frames as the services exchange
them, a message moved into another run of the sim, what a service publishes, and the sim on the
realtime clock with commands applied to it."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager
from types import SimpleNamespace
from typing import Any

from common.config import load_scenario
from common.messages import Header, ImageData, JointState, JointVelocityCommand, RgbFrame
from common.runtime import parse_overrides
from common.session import free_tcp_endpoint, open_session
from tests.prefixes import unique_keys

FRAMES = 6  # of the default run, for the tests to feed the services
RUN_A, RUN_B = 11, 22  # two runs of the sim (common/runs.py), as a restart makes them
# A deadman and a watchdog of seconds, so that "fresh" holds however slowly a loaded host runs a
# test (the tests move the clock back themselves to expire them).
LONG_TIMEOUTS = ("sim.command_watchdog_s=5.0", "actuation.deadman_timeout_s=4.0")


def first_frames() -> list[SimpleNamespace]:
    """The default run's first :data:`FRAMES` frames as the services exchange them (run 0): each its
    features, joint state, twist and colour frame (measured without depth)."""
    from services.pipeline import Pipeline

    out = []
    with Pipeline(load_scenario()) as pipeline:
        for _ in range(FRAMES):
            f = pipeline.step()
            joints = JointState(
                header=f.features.header,
                position_rad=f.q_rad.tolist(),
                velocity_rad_s=f.qdot_rad_s.tolist(),
            )
            rgb = RgbFrame(
                header=f.features.header,
                intrinsics=f.features.intrinsics,
                rgb=ImageData.view_of(f.rgb),
                depth_frame_seq=-1,  # measured without depth: no wait for a depth image
            )
            out.append(SimpleNamespace(features=f.features, joints=joints, twist=f.twist, rgb=rgb))
    return out


@contextmanager
def service_context() -> Iterator[SimpleNamespace]:
    """What a service is built from (a ``ServiceContext``'s fields): the default scenario, a
    key prefix of its own, a loopback session listening on a free port, a stop event."""
    endpoint = free_tcp_endpoint()
    session = open_session(connect=[], listen=[endpoint])
    try:
        yield SimpleNamespace(
            scenario=load_scenario(),
            keys=unique_keys(),
            session=session,
            stop=threading.Event(),
        )
    finally:
        session.close()


def in_run(message: Any, run: int) -> Any:
    """``message`` as the sim's run ``run`` sent it."""
    return message.model_copy(update={"header": message.header.model_copy(update={"run": run})})


def feed(service: Any, ctx: Any, frames: list, other: str = "twist", run: int = RUN_A) -> None:
    """Each frame's joint state, then its ``other`` input (``twist`` for actuation,
    ``features`` for the controller), as the sim's run ``run`` sent them."""
    for f in frames:
        service.on_event(ctx.keys.joint_state, in_run(f.joints, run))
        service.on_event(getattr(ctx.keys, other), in_run(getattr(f, other), run))


def published(service: Any) -> list:
    """What the service puts from now on (and still sends)."""
    sent: list = []
    put = service.pub.put
    service.pub.put = lambda message: (sent.append(message), put(message))
    return sent


@contextmanager
def realtime_sim(ctx: Any, *overrides: str) -> Iterator[Any]:
    """The sim service on the realtime clock (a command stays in force until the next one),
    the scenario's ``overrides`` applied, closed afterwards."""
    from services.sim.node import SimService

    ctx.scenario = load_scenario(None, parse_overrides(["run.clock='realtime'", *overrides]))
    sim = SimService(ctx)
    try:
        yield sim
    finally:
        sim.node.close()
        sim.world.close()


def command(sim: Any, velocity_rad_s: list[float]) -> None:
    """``velocity_rad_s`` applied by the sim as the command answering frame 0 of its run."""
    header = Header(seq=0, sim_time_s=0.0, send_time_s=1.0, frame_seq=0, run=sim.run_id)
    message = JointVelocityCommand(header=header, velocity_rad_s=velocity_rad_s, reason="track")
    sim.apply(message, 1.0)
