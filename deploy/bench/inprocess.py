"""``umay bench``'s in-process baseline: the same pipeline in this process, on the same frames
(a lockstep run renders the same images: the loop is deterministic).

:class:`services.pipeline.Pipeline` composes the services' own pure steps, the ones their node
shells call, and times each, from images ready to command applied: vision (``vision_step`` and
its features message), the controller (``control_step`` and its twist message), actuation
(``actuation_step``, the inverse under the acceleration limit) and setting the motors. What is
fair: a single-process program needs no transport, so the headline baseline
(``inprocess.per_frame_ms``) is the steps alone, and the ratio distributed / in-process charges
distribution with everything it adds, serialization included. The same loop also times the
codec work the distributed path does per frame (the sim's messages built, every message encoded
once and decoded where it is received); ``ratio.vs_with_codec`` divides by steps + codec, i.e.
what is left is transport, process boundaries and scheduling. In lockstep the in-process
commands are compared with the distributed ones (they must agree). Vision is also called a
second time at once on the same inputs (its step is pure), outside the frame's time:
``stages_ms.vision_warm`` is its cost with its code and data warm, against ``vision``, the
first call's after the render, as every service's call is after an idle wait.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from common.codec import DEFAULT_MAX_BYTES, FRAME_MAX_BYTES, decode, encode
from common.config import Scenario
from common.messages import (
    DepthFrame,
    EndEffectorTwist,
    Features,
    Header,
    ImageData,
    JointState,
    JointVelocityCommand,
    RgbFrame,
)
from deploy.bench.processes import machine_load
from deploy.bench.report import InprocessRun, summary_ms
from deploy.bench.stages import CODEC_STAGES, INPROCESS_STAGES, PIPELINE


@dataclass
class SourceFrame:
    """One rendered frame kept for the synthetic source."""

    rgb: np.ndarray
    depth_m: np.ndarray | None
    q_rad: np.ndarray
    qdot_rad_s: np.ndarray
    sim_time_s: float


def run_inprocess(
    scenario: Scenario, frames: int, warmup: int, keep: int
) -> tuple[InprocessRun, list[SourceFrame]]:
    """The in-process pipeline (:class:`services.pipeline.Pipeline`, the services' pure steps)
    on the lockstep frames, timed stage by stage (see the module doc); returns the statistics
    and the first ``keep`` measured frames (for the synthetic source)."""
    from common.marker import Marker
    from services.pipeline import Pipeline

    times: dict[str, list[float]] = {
        s: [] for s in ("render", *INPROCESS_STAGES, *CODEC_STAGES, "vision_warm")
    }
    per_frame: list[float] = []
    with_codec: list[float] = []
    velocities: dict[int, list[float]] = {}
    kept: list[SourceFrame] = []
    load_before = machine_load()
    clock = time.perf_counter
    warm_s = [0.0]

    def vision_again(measure: Callable[[], object]) -> None:
        # The same call again at once, outside the frame's time: vision's cost with its code
        # and data warm, against the first call's after the render (the step is pure).
        w0 = clock()
        measure()
        warm_s[0] = clock() - w0

    with Pipeline(scenario, truth=False) as pipeline:
        world = pipeline.world
        for seq in range(warmup + frames):
            f = pipeline.step(after_vision=vision_again)
            if seq >= warmup and len(kept) < keep:  # the measured frames
                kept.append(SourceFrame(f.rgb, f.depth_m, f.q_rad, f.qdot_rad_s, f.sim_time_s))
            # The codec work the distributed path does for this frame, timed apart: the sim's
            # messages built and encoded, and each message decoded where it is received.
            header = Header(
                seq=seq, sim_time_s=f.sim_time_s, send_time_s=time.time(), frame_seq=seq
            )
            c0 = clock()
            joints = JointState(
                header=header, position_rad=f.q_rad.tolist(), velocity_rad_s=f.qdot_rad_s.tolist()
            )
            frame_payloads = [encode(joints)]
            if f.depth_m is not None:
                frame_payloads.append(
                    encode(
                        DepthFrame(
                            header=header,
                            intrinsics=world.depth_intrinsics,
                            depth_m=ImageData.view_of(f.depth_m),
                        )
                    )
                )
            frame_payloads.append(
                encode(
                    RgbFrame(
                        header=header,
                        intrinsics=world.intrinsics,
                        rgb=ImageData.view_of(f.rgb),
                        depth_frame_seq=f.depth_frame_seq,
                    )
                )
            )
            decode(frame_payloads[-1], RgbFrame, FRAME_MAX_BYTES).rgb.to_array()
            if f.depth_m is not None:
                decode(frame_payloads[1], DepthFrame, FRAME_MAX_BYTES).depth_m.to_array()
            for _ in PIPELINE[1:]:  # the controller and actuation both decode the joint state
                decode(frame_payloads[0], JointState, DEFAULT_MAX_BYTES)
            c1 = clock()
            Marker.from_wire(decode(encode(f.features), Features, DEFAULT_MAX_BYTES).hand)
            c2 = clock()
            decode(encode(f.twist), EndEffectorTwist, DEFAULT_MAX_BYTES)
            c3 = clock()
            command = JointVelocityCommand(
                header=header, velocity_rad_s=f.actuation.velocity_rad_s.tolist()
            )
            decode(encode(command), JointVelocityCommand, DEFAULT_MAX_BYTES)
            c4 = clock()
            if seq < warmup:
                continue
            velocities[seq] = f.actuation.velocity_rad_s.tolist()
            for name in ("render", *INPROCESS_STAGES):
                times[name].append(f.stage_s[name])
            for name, d in zip(
                (*CODEC_STAGES, "vision_warm"),
                (c1 - c0, c2 - c1, c3 - c2, c4 - c3, warm_s[0]),
                strict=True,
            ):
                times[name].append(d)
            per_frame.append(sum(f.stage_s[name] for name in INPROCESS_STAGES))
            with_codec.append(per_frame[-1] + c4 - c0)
    return InprocessRun(
        frames=frames,
        stages_ms={s: summary_ms(v) for s, v in times.items()},
        per_frame_ms=summary_ms(per_frame),
        per_frame_with_codec_ms=summary_ms(with_codec),
        frames_ms=[  # frame by frame, for the figure
            {"frame_seq": k, "latency_ms": round(1000.0 * v, 4)}
            for k, v in zip(velocities, per_frame, strict=True)
        ],
        render_fps=round(1.0 / float(np.median(times["render"])), 3) if frames else None,
        load_before=load_before,
        load_after=machine_load(),
        velocities=velocities,
    ), kept
