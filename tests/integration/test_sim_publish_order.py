"""The sim's publishing order per camera frame, which keeps every process but vision asleep as
the frame goes out (docs/performance.md): the joint state and the truth before the frame's
images, and a frame's timing only once the next frame starts, carrying the command that
answered it. The sim runs alone as its own process in lockstep; this test answers its frames
with zero commands, as actuation would, and stands in for the other services' liveliness."""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

from common.codec import DEFAULT_MAX_BYTES, decode, unpack
from common.keys import Keys
from common.messages import Header, JointVelocityCommand, SimTiming
from common.node import Node
from common.publishers import TypedPublisher
from common.session import free_tcp_endpoint, open_session
from deploy.supervisor import Supervisor
from tests.prefixes import unique_keys

FRAMES = 6


@contextlib.contextmanager
def sim_alone(
    log_dir: Path, keys: Keys, on_sim: Callable[[Any], None], overrides: Sequence[str] = ()
) -> Iterator[tuple[TypedPublisher, Supervisor]]:
    """The sim as its own process in lockstep, ``on_sim`` hearing everything it publishes;
    yields a publisher of joint commands (as actuation's) and its supervisor. The other
    services are stand-ins, alive as far as the sim can tell."""
    endpoint = free_tcp_endpoint()
    session = open_session(connect=[], listen=[endpoint])
    # One subscriber for all of them: zenoh-python calls each subscriber's callback on a
    # thread of its own, so two subscribers could see two keys in either order.
    subscriber = session.declare_subscriber(f"{keys.prefix}/sim/**", on_sim)
    stand_ins = [Node(name, keys, session) for name in ("vision", "controller", "actuation")]
    for node in stand_ins:
        node.ready()
    sup = Supervisor(None, keys.prefix, endpoint, log_dir, list(overrides), services=("sim",))
    try:
        sup.start()
        yield stand_ins[2].publisher(keys.joint_command), sup
    finally:
        sup.stop()
        subscriber.undeclare()
        for node in stand_ins:
            node.close()
        session.close()


def answer(commands: TypedPublisher, frame_seq: int, run: int) -> None:
    """Frame ``frame_seq`` of ``run`` answered with a zero command, as actuation would."""
    header = Header(seq=frame_seq, sim_time_s=0.0, send_time_s=time.time(), frame_seq=frame_seq,
                    run=run)  # fmt: skip
    commands.put(JointVelocityCommand(header=header, velocity_rad_s=[0.0] * 6))


def test_the_joint_state_and_truth_go_before_the_frame_and_its_timing_after_its_command(
    tmp_path: Path,
) -> None:
    keys = unique_keys()
    arrivals: list[tuple[str, int]] = []  # (key suffix, frame_seq) in arrival order
    runs: set[int] = set()  # the sim's run, on every message (a command must carry it)
    timings: dict[int, SimTiming] = {}
    sent_s: dict[tuple[str, int], float] = {}  # the images' header send times
    lock = threading.Lock()
    frame_in = threading.Condition(lock)

    watched = ("joint_state", "truth", "depth", "rgb", "timing")

    def on_sim(sample) -> None:
        suffix = str(sample.key_expr).removeprefix(f"{keys.prefix}/sim/")
        if suffix not in watched:
            return
        payload = sample.payload.to_bytes()
        if suffix == "timing":
            t = decode(payload, SimTiming, DEFAULT_MAX_BYTES)
            frame_seq = t.header.frame_seq
        else:
            data = unpack(payload)  # the header alone, frames included
            assert data is not None, f"{suffix}: not a message"
            frame_seq = int(data["header"]["frame_seq"])
            runs.add(int(data["header"]["run"]))
            sent_s[suffix, frame_seq] = float(data["header"]["send_time_s"])
        with lock:
            if suffix == "timing":
                timings[frame_seq] = t
            arrivals.append((suffix, frame_seq))
            frame_in.notify_all()

    with sim_alone(tmp_path, keys, on_sim) as (commands, sup):
        for seq in range(FRAMES + 1):
            deadline = time.monotonic() + 60
            with frame_in:
                while ("rgb", seq) not in arrivals:
                    assert not sup.exited(), (tmp_path / "sim.log").read_text()[-2000:]
                    assert frame_in.wait(max(0.0, deadline - time.monotonic())), f"no frame {seq}"
                (run,) = runs  # one run, and no message of the sim without it
            answer(commands, seq, run)
        time.sleep(0.5)  # frame FRAMES+1 starts: frame FRAMES's timing goes out
        with lock:
            order = list(arrivals)
            got = dict(timings)

    def at(suffix: str, seq: int) -> int:
        return order.index((suffix, seq))

    for seq in range(FRAMES):
        # A resend would repeat a frame's messages; lockstep answered at once, so none.
        assert order.count(("rgb", seq)) == 1
        assert at("joint_state", seq) < at("depth", seq) < at("rgb", seq)
        assert at("truth", seq) < at("depth", seq)
        # The timing after its frame and before the next frame's images...
        assert at("rgb", seq) < at("timing", seq) < at("depth", seq + 1)
        # ... with the command that answered the frame.
        assert [a.frame_seq for a in got[seq].applied] == [seq]
        assert got[seq].frame_send_time_s >= got[seq].capture_time_s >= got[seq].render_start_s
        # The images' messages are made before the render, but stamped as they go: after it.
        assert sent_s["rgb", seq] == got[seq].frame_send_time_s
        assert sent_s["rgb", seq] >= sent_s["depth", seq] >= got[seq].capture_time_s


def test_a_resend_puts_again_the_depth_image_its_frame_names(tmp_path: Path) -> None:
    """Depth at 1 Hz: frame 1 carries no depth image of its own but names frame 0's. Left
    unanswered, frame 1 is sent again with that depth image before it, so a vision started
    since frame 0 measures it at once instead of waiting for the next depth tick."""
    keys = unique_keys()
    arrivals: list[tuple[str, int]] = []
    runs: set[int] = set()
    lock = threading.Condition()

    def on_sim(sample) -> None:
        suffix = str(sample.key_expr).removeprefix(f"{keys.prefix}/sim/")
        if suffix in ("depth", "rgb"):
            header = unpack(sample.payload.to_bytes())["header"]
            with lock:
                runs.add(int(header["run"]))
                arrivals.append((suffix, int(header["frame_seq"])))
                lock.notify_all()

    overrides = ["camera.depth_hz=1.0", "sim.lockstep_resend_s=0.3"]
    with sim_alone(tmp_path, keys, on_sim, overrides) as (commands, _sup):
        with lock:
            assert lock.wait_for(lambda: ("rgb", 0) in arrivals, 60), arrivals
            (run,) = runs
        answer(commands, 0, run)
        with lock:  # frame 1, then (no command for it) frame 1 again
            assert lock.wait_for(lambda: arrivals.count(("rgb", 1)) >= 2, 30), arrivals
            order = list(arrivals)
    first, again = [i for i, a in enumerate(order) if a == ("rgb", 1)][:2]
    assert ("depth", 1) not in order  # frame 1 took no depth image
    assert order[:first].count(("depth", 0)) == 1  # frame 0's, sent once with frame 0
    assert ("depth", 0) in order[first + 1 : again]  # and again before frame 1's resend
