"""Vision service: colour frames + depth images → corners, depths and 3-D points of both markers.

The measurement itself is :func:`services.vision.step.vision_step` (pure); this shell adds
the transport. One event loop: depth images are kept (the last few, by the colour frame they
were taken with); each colour frame is measured with the depth image it names
(``depth_frame_seq``). If that image has not arrived yet the frame waits for it, at most
``DEPTH_WAIT_S``, then makes do with the newest one, and so do the frames after it until a depth
image comes again (:mod:`services.vision.depth_wait`): a lost depth image delays one frame, a
stopped depth stream does not stop vision.

Frames sent by reference (:mod:`common.frame_ring`) are read in place, as views of the sim's
shared-memory ring, which holds each stream's last 16 frames: the frames vision keeps (one
colour frame at a time, the last ``DEPTH_CACHE`` depth images) are far newer than that. After
measuring a frame, vision checks that neither image was overwritten meanwhile (a stall of half
a second would do it); if one was, the measurement is thrown away and the frame counted as
rejected, with the reason, instead of publishing features of torn pixels.

Before it subscribes, vision measures one synthetic frame (:mod:`services.vision.warmup`), so
that the camera's first frame is not the one that pays for its first step.
"""

from __future__ import annotations

import logging
import time
from collections import OrderedDict

from common.codec import FRAME_MAX_BYTES
from common.marker import Marker
from common.messages import DepthFrame, Features, RgbFrame
from common.node import Node
from common.runs import RunWatch
from common.runtime import ServiceContext
from services.vision.depth_wait import DepthWait
from services.vision.segmentation import MARKERS
from services.vision.status import VisionStatus
from services.vision.step import depth_for, depth_image, vision_step
from services.vision.tracking import TrackerState
from services.vision.warmup import warm_up

NOT_SEEN_YET = Marker.unseen("lost", "")  # a marker before the first frame: no reason to give

log = logging.getLogger("umay.vision")

DEPTH_WAIT_S = 0.5  # wall clock: how long a colour frame waits for its depth image
DEPTH_CACHE = 4  # depth images kept


class VisionService:
    def __init__(self, ctx: ServiceContext) -> None:
        self.ctx = ctx
        self.config = ctx.scenario.vision
        self.marker_size_m = ctx.scenario.marker.size_m
        self.orientation_cue = ctx.scenario.marker.orientation_cue
        self._warm_up()
        self.node = Node("vision", ctx.keys, ctx.session, self.status_fields, self.degraded)
        self.pub = self.node.publisher(ctx.keys.features)
        # A vision slower than the camera works on the newest frame: one that came whole is
        # replaced in the inbox by a newer one (latest only), one by reference, handled by the
        # thread that received it, is skipped when the sim has begun the next (on_event).
        self.node.subscribe(ctx.keys.rgb, RgbFrame, FRAME_MAX_BYTES, latest_only=True)
        self.node.subscribe(ctx.keys.depth, DepthFrame, FRAME_MAX_BYTES)
        self.runs = RunWatch()  # the sim's run the frames come from (common.runs)
        # Colour frames waiting for their depth image (counts: status's depth_waits/_missed).
        self.depth_wait: DepthWait[RgbFrame] = DepthWait(DEPTH_WAIT_S)
        self.new_run()
        self.frames_overwritten = 0  # measurements dropped: a ring slot changed while read
        self.depth_age_s: float | None = None
        # Each marker as the last frame measured it (replaced whole: status reads it on a
        # Zenoh thread); none yet: lost, for no reason given.
        self.seen: dict[str, Marker] = {}

    def new_run(self) -> None:
        """Forget what belongs to the sim's run before (a restarted sim starts again from
        frame 0): the tracking, the depth images kept, a frame waiting, the last answer."""
        self.tracker = TrackerState()
        self.depths: OrderedDict[int, DepthFrame] = OrderedDict()
        self.depth_wait.forget()
        # The last frame measured and what vision answered: a lockstep resend of that frame
        # gets the same answer, the tracker not stepped twice on it.
        self.answered: tuple[int, Features] | None = None

    def _warm_up(self) -> None:
        """One step on a synthetic frame; only an optimisation, so a failure is logged and
        the service goes on."""
        camera = self.ctx.scenario.camera
        started = time.perf_counter()
        try:
            warm_up(
                camera.intrinsics(),
                camera.depth_intrinsics(),
                self.config,
                self.marker_size_m,
                self.orientation_cue,
            )
        except Exception:
            log.exception("warm-up on a synthetic frame failed; the first frame pays for it")
            return
        log.info("warmed up on a synthetic frame in %.1f ms", 1e3 * (time.perf_counter() - started))

    def status_fields(self) -> VisionStatus:
        frames = self.node.received.values()
        seen = self._last_seen()  # once: a frame may replace it meanwhile (a Zenoh thread)
        return VisionStatus(
            markers={n: m.state for n, m in seen},
            lost_reasons={n: m.reason for n, m in seen},
            depth_age_s=self.depth_age_s,
            depth_waits=self.depth_wait.waits,
            depth_missed=self.depth_wait.missed,
            frames_by_ref=sum(m.by_ref for m in frames),
            frames_by_copy=sum(m.by_copy for m in frames),
            frames_fetched=sum(m.fetched for m in frames),
            frames_overwritten=self.frames_overwritten,
        )

    def _last_seen(self) -> list[tuple[str, Marker]]:
        seen = self.seen
        return [(n, seen.get(n) or NOT_SEEN_YET) for n in MARKERS]

    def degraded(self) -> str:
        # Hidden rather than gone (the hand over the target at the goal, a panel): said so.
        lost = [
            f"{n}: {m.state}, {m.reason}" + (", hidden by something in front" if m.occluded else "")
            for n, m in self._last_seen()
            if m.reason
        ]
        return "marker not usable (" + "; ".join(lost) + ")" if lost else ""

    def on_frame(self, frame: RgbFrame) -> None:
        depth_frame = depth_for(frame, self.depths)
        depth = None
        if depth_frame is not None:
            depth = depth_image(
                depth_frame.depth_m.to_array(),
                depth_frame.intrinsics,
                depth_frame.header.sim_time_s,
                frame.header.sim_time_s,
            )
        self.depth_age_s = None if depth is None else depth.age_s
        step = vision_step(
            frame.rgb.to_array(),
            frame.intrinsics,
            depth,
            self.config,
            self.marker_size_m,
            self.tracker,
            frame.header.sim_time_s,
            self.orientation_cue,
        )
        images = [(self.ctx.keys.rgb, frame.rgb)]
        if depth_frame is not None:
            images.append((self.ctx.keys.depth, depth_frame.depth_m))
        overwritten = [(key, image) for key, image in images if not image.intact()]
        if overwritten:  # the pixels changed under the step: forget what it measured
            self.frames_overwritten += 1
            for key, image in overwritten:
                self.node.reject(
                    key,
                    f"frame {frame.header.frame_seq}: ring slot {image.ring_ref.slot} "
                    f"overwritten while vision read it; measurement dropped",
                )
            return
        self.tracker = step.tracker
        self.seen = dict(step.measured)
        seq = frame.header.frame_seq
        header = self.node.header(frame.header.sim_time_s, seq, run=frame.header.run)
        features = step.features(header, frame.intrinsics)
        self.pub.put(features)
        self.answered = (seq, features)

    def on_event(self, key: str, msg: RgbFrame | DepthFrame) -> None:
        if not self.runs.admit(msg.header.run, self.new_run):
            self.node.count_dropped(key)  # sent before the sim restarted
            return
        if isinstance(msg, DepthFrame):
            self.depths[msg.header.frame_seq] = msg
            while len(self.depths) > DEPTH_CACHE:
                self.depths.popitem(last=False)
            frame = self.depth_wait.depth(msg.header.frame_seq)
            if frame is not None:
                self.on_frame(frame)
            return
        if self.answered is not None and self.answered[0] == msg.header.frame_seq:
            self.pub.put(self.answered[1])  # a lockstep resend of the frame measured last
            return
        if msg.rgb.superseded():  # fallen behind the camera: the next frame is on its way
            self.node.count_dropped(key)
            return
        replaced = self.depth_wait.replaced
        newest_depth = max(self.depths, default=-1)
        frame = self.depth_wait.colour(msg, msg.depth_frame_seq, newest_depth, time.monotonic())
        self.node.count_dropped(key, self.depth_wait.replaced - replaced)
        if frame is not None:
            self.on_frame(frame)

    def on_idle(self) -> None:
        frame = self.depth_wait.idle(time.monotonic())
        if frame is not None:
            self.on_frame(frame)

    def run(self) -> None:
        self.node.spin(self.ctx.stop, self.on_event, timeout_s=0.05, on_idle=self.on_idle)


def main(argv: list[str] | None = None) -> int:
    with ServiceContext("vision", argv) as ctx:  # its session closed however it ends
        VisionService(ctx).run()
    return 0
