"""Replay a recording into one service and compare what it publishes with what was recorded.

``umay replay FILE.mcap --service controller --check`` starts only that service (the scenario
and overrides recorded in the file, plus any extra ``--set``), under a fresh prefix on a fresh
loopback endpoint, publishes the recorded inputs of that service re-keyed to the new prefix,
captures its outputs and compares them, frame by frame, with the recorded ones:

=========== ============================ ==========================
service     inputs                       output
=========== ============================ ==========================
vision      ``sim/depth``, ``sim/rgb``   ``vision/features``
controller  ``sim/joint_state``,         ``controller/twist``
            ``vision/features``
actuation   ``sim/joint_state``,         ``actuation/joint_command``
            ``controller/twist``
=========== ============================ ==========================

Timing: ``speed=None`` ("max") is lockstep: the inputs of frame k (joint state first, however
they were logged), then wait for the output of frame k, then frame k+1; deterministic, as fast
as the service goes. A float keeps the recorded timing divided by ``speed`` (vision may then
drop frames as it did live: it only ever works on the newest image).

With ``check``, only the frames the service answered in the recording are replayed (a frame it
never processed, e.g. cut off when the run stopped, cannot be compared and would change its
state), outputs are matched by ``header.frame_seq`` (the actuation deadman's ``frame_seq`` -1
commands are ignored on both sides) and compared field by field, ignoring ``header.seq`` and
``header.send_time_s``; a field the recording predates reads as its default. On the machine
that recorded, the outputs are bit-identical; on another CPU numpy's BLAS/LAPACK kernels
(least squares, pseudo-inverses) may round the last bit differently, which is not a change in
behaviour. The controller's and actuation's twists and velocities then differ by about 1e-15;
vision's corners of a partly hidden target, fitted by Gauss-Newton from least-squares steps,
by up to 5e-12 px (an AVX-512 CPU replaying a recording made on one without). So the
controller is allowed 1e-12, vision and actuation 1e-9 (px, m, rad/s: far below any change in
behaviour). ``--tolerance 0`` asks for bit-identity.
"""

from __future__ import annotations

import tempfile
import threading
import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from itertools import pairwise
from pathlib import Path

import zenoh

from common.codec import unpack
from common.config import DEFAULT_SCENARIO, ScenarioError, load_scenario
from common.keys import Keys
from common.queries import alive_services
from common.runtime import parse_overrides
from common.session import free_tcp_endpoint, open_session
from deploy.paths import check_output_dir
from deploy.recording.channels import DATA_SUFFIXES, split_data_key
from deploy.recording.read import NotARecordingError, RecordingReader
from deploy.recording.replay_check import ReplayReport, check_outputs, field_defaults
from deploy.supervisor import Supervisor

JOINT_STATE = "sim/joint_state"


@dataclass(frozen=True)
class ServiceIO:
    inputs: tuple[str, ...]  # key suffixes, in the order one frame's inputs are published
    trigger: str  # the input the service answers (one output per trigger)
    output: str
    tolerance: float  # default for --check


SERVICE_IO: dict[str, ServiceIO] = {
    "vision": ServiceIO(("sim/depth", "sim/rgb"), "sim/rgb", "vision/features", 1e-9),
    "controller": ServiceIO(
        (JOINT_STATE, "vision/features"), "vision/features", "controller/twist", 1e-12
    ),
    "actuation": ServiceIO(
        (JOINT_STATE, "controller/twist"), "controller/twist", "actuation/joint_command", 1e-9
    ),
}
REPLAYABLE: tuple[str, ...] = tuple(SERVICE_IO)


class ReplayError(ValueError):
    """Bad input: not a recording, no inputs for that service, an unknown service..."""


class ReplayFailed(RuntimeError):
    """The service could not be started or died during the replay."""


# --- recorded data -----------------------------------------------------------------------
@dataclass
class Recorded:
    suffix: str
    log_time_ns: int
    frame_seq: int
    payload: bytes
    run: int = 0  # the sim's run the message belongs to (Header.run; 0: not stamped)


def frame_seq_of(payload: bytes) -> int | None:
    stamp = stamp_of(payload)
    return None if stamp is None else stamp[1]


def stamp_of(payload: bytes) -> tuple[int, int] | None:
    """(run, frame_seq) of a message's header, None for a message without one."""
    try:
        header = unpack(payload)["header"]  # type: ignore[index]
        return int(header.get("run", 0)), int(header["frame_seq"])
    except Exception:  # not a message with a header
        return None


def source_prefix(recording: RecordingReader, metadata: dict[str, str]) -> str:
    """The key prefix the recording's data was published under: its metadata's, unless no
    recorded key has it (``umay record --keys P/**`` without ``--prefix`` noted the default
    one), then the one its data keys share."""
    topics = recording.topics()
    noted = metadata.get("prefix")
    if noted and any(t.startswith(f"{noted}/") for t in topics):
        return noted
    prefixes = {s[0] for s in map(split_data_key, topics) if s is not None}
    if len(prefixes) != 1:
        found = ", ".join(sorted(prefixes)) or "none"
        raise ReplayError(
            f"{recording.path}: cannot tell the recording's key prefix (found: {found})"
        )
    return prefixes.pop()


def load_recorded(recording: RecordingReader, prefix: str, suffixes: set[str]) -> list[Recorded]:
    wanted = {f"{prefix}/{s}" for s in suffixes}
    out = []
    for _schema, channel, message in recording.messages(wanted.__contains__):
        stamp = stamp_of(message.data)
        if stamp is not None:
            suffix = channel.topic[len(prefix) + 1 :]
            out.append(Recorded(suffix, message.log_time, stamp[1], message.data, stamp[0]))
    return out


def first_by_frame(payloads: Iterator[tuple[int, bytes]]) -> dict[int, bytes]:
    """First message of each frame (frame_seq -1, the deadman's, is left out)."""
    out: dict[int, bytes] = {}
    for seq, data in payloads:
        if seq >= 0 and seq not in out:
            out[seq] = data
    return out


def frame_going_back(frame_seqs: list[int]) -> int | None:
    """The first frame number lower than the one before it (a second run), else None; a
    number repeated (a lockstep resend) does not go back."""
    return next((b for a, b in pairwise(frame_seqs) if b < a), None)


def lockstep_steps(inputs: list[Recorded], io: ServiceIO) -> list[list[Recorded]]:
    """One step per trigger, in the recorded order: the other inputs of its frame (the joint
    states) not yet published, then itself. A frame's inputs come from different services, so
    the recorder may log its joint state after its trigger (vision answering before the joint
    state reached the recorder): they are grouped by frame, not by the order they were logged,
    and by run (a recording that spans a sim restart has each frame number once a run)."""
    others: dict[tuple[int, int], list[Recorded]] = {}
    for r in inputs:
        if r.suffix != io.trigger:
            others.setdefault((r.run, r.frame_seq), []).append(r)
    return [[*others.pop((r.run, r.frame_seq), []), r] for r in inputs if r.suffix == io.trigger]


# --- the replay ---------------------------------------------------------------------------
class OutputCapture:
    """Zenoh callback threads append; the replay loop waits for a frame's output."""

    def __init__(self) -> None:
        self.cond = threading.Condition()
        self.messages: list[tuple[int, bytes]] = []
        self.per_frame: dict[int, int] = {}

    def on_sample(self, sample: zenoh.Sample) -> None:
        data = sample.payload.to_bytes()
        seq = frame_seq_of(data)
        if seq is None:
            return
        with self.cond:
            self.messages.append((seq, data))
            self.per_frame[seq] = self.per_frame.get(seq, 0) + 1
            self.cond.notify_all()

    def count(self, seq: int) -> int:
        with self.cond:
            return self.per_frame.get(seq, 0)

    def wait_for(self, seq: int, more_than: int, timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        with self.cond:
            while self.per_frame.get(seq, 0) <= more_than:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return False
                self.cond.wait(remaining)
            return True

    def wait_for_all(self, seqs: set[int], timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        with self.cond:
            while not seqs <= self.per_frame.keys():
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return
                self.cond.wait(remaining)


def _wait_alive(
    session: zenoh.Session,
    keys: Keys,
    service: str,
    sup: Supervisor,
    timeout_s: float,
    publishers: list[zenoh.Publisher],
) -> None:
    """Until ``service`` is alive and its subscriptions have reached every one of
    ``publishers`` (Zenoh's matching status): a message put before that would be lost."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        dead = sup.exited()
        if dead:
            code = dead[0].exit_codes[-1]
            raise ReplayFailed(f"{service} exited (code {code}); see {dead[0].log_path}")
        if service in alive_services(session, keys, 0.5):
            break
        time.sleep(0.05)
    else:
        raise ReplayFailed(f"{service} did not come up within {timeout_s:.0f} s")
    while not all(p.matching_status.matching for p in publishers):
        if time.monotonic() > deadline:
            raise ReplayFailed(f"{service} did not subscribe within {timeout_s:.0f} s")
        time.sleep(0.02)


def replay_service(
    path: str | Path,
    service: str,
    speed: float | None,
    check: bool,
    log_dir: Path,
    overrides: list[str] | None = None,
    scenario_path: str | Path | None = None,
    tolerance: float | None = None,
    frame_timeout_s: float = 5.0,
    startup_timeout_s: float = 30.0,
) -> ReplayReport:
    """Replay the recorded inputs of ``service`` into a fresh instance of it (see the module
    docstring). ``overrides`` are applied after the recorded ones; ``scenario_path`` replaces
    the recorded scenario. Raises ReplayError (bad input), ScenarioError, ReplayFailed."""
    if service not in SERVICE_IO:
        raise ReplayError(f"unknown service {service!r} (choose from {', '.join(REPLAYABLE)})")
    if speed is not None and not speed > 0:
        raise ReplayError(f"speed must be positive or None (max), got {speed}")
    if tolerance is not None and not tolerance >= 0:
        raise ReplayError(f"tolerance must be >= 0, got {tolerance}")
    path = Path(path)
    if not path.is_file():
        raise ReplayError(f"{path}: no such file")
    io = SERVICE_IO[service]
    notes: list[str] = []
    try:
        recording = RecordingReader(path)
        metadata = recording.metadata().get("umay", {})
        old_prefix = source_prefix(recording, metadata)
        recorded = load_recorded(recording, old_prefix, {*io.inputs, io.output})  # one pass
        recorded_inputs = [r for r in recorded if r.suffix in io.inputs]
        recorded_outputs = first_by_frame(
            (r.frame_seq, r.payload) for r in recorded if r.suffix == io.output
        )
    except ReplayError:
        raise
    except NotARecordingError as exc:
        raise ReplayError(str(exc)) from exc
    except Exception as exc:  # the mcap reader raises several types for a bad file
        raise ReplayError(f"{path}: not a readable MCAP recording ({exc})") from exc
    if recording.damage:  # a recording cut short: what precedes the damage is replayed
        notes.append(f"recording {recording.damage}")
    if not any(r.suffix == io.trigger for r in recorded_inputs):
        raise ReplayError(f"{path}: no {io.trigger} messages to replay into {service}")
    present = {r.suffix for r in recorded_inputs}
    missing = [k for k in io.inputs if k not in present]
    if missing:  # it would wait for each frame's in vain (a recording made with --keys)
        raise ReplayError(
            f"{path}: no {', '.join(missing)} messages: {service} needs "
            f"{' and '.join(io.inputs)} for every frame"
        )

    all_overrides = [*_recorded_overrides(metadata), *(overrides or [])]
    skipped = 0
    first = min(r.frame_seq for r in recorded_inputs if r.suffix == io.trigger)
    if check and first > 0:
        # The service carries state from frame to frame (vision's tracking, the controller's
        # memory, actuation's last command): from a frame mid-run, its outputs cannot match.
        raise ReplayError(
            f"{path}: --check needs the run from its first frame, and this recording starts "
            f"at frame {first} ({service} keeps state from frame to frame, and the frames "
            "before are not in it; `umay run --record` records a run whole). Replay it "
            "without --check to see what the service makes of it"
        )
    triggers = [r.frame_seq for r in recorded_inputs if r.suffix == io.trigger]
    back = frame_going_back(triggers)
    if check and back is not None:
        # Outputs are matched by frame: a second run (a restarted sim, two runs recorded) would
        # be matched against the first one's, or not compared at all. (A frame sent again, a
        # lockstep resend, repeats its number without going back: answered alike, it checks.)
        raise ReplayError(
            f"{path}: the frame numbers go back (to frame {back}): the recording holds more "
            "than one run, and --check compares one run frame by frame. Replay it without "
            "--check, or record each run on its own (`umay run --record`)"
        )
    if check:
        answered = recorded_outputs.keys()
        kept = [r for r in recorded_inputs if r.frame_seq in answered]
        skipped = len(recorded_inputs) - len(kept)
        recorded_inputs = kept
        if skipped:
            notes.append(f"{skipped} inputs of frames without a recorded output not replayed")
        if not recorded_inputs:
            raise ReplayError(f"{path}: no recorded {io.output} to check against")

    keys = Keys(f"replay/{uuid.uuid4().hex[:12]}")
    started = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="umay-replay-") as tmp:
        if scenario_path is None:
            if metadata.get("scenario_toml"):
                scenario_path = Path(tmp) / "scenario.toml"
                scenario_path.write_text(metadata["scenario_toml"])
            else:
                notes.append("the recording holds no scenario: the default one was used")
                scenario_path = DEFAULT_SCENARIO
        try:
            load_scenario(scenario_path, parse_overrides(all_overrides))
        except ScenarioError as exc:  # bad input: name the recording, not the temporary file
            raise ScenarioError(str(exc).replace(str(scenario_path), f"{path} scenario")) from exc
        check_output_dir("--log-dir", log_dir)  # last, so that bad input leaves no folder
        published, no_answer, frames, capture = _run(
            keys,
            service,
            io,
            recorded_inputs,
            speed,
            scenario_path,
            all_overrides,
            log_dir,
            frame_timeout_s,
            startup_timeout_s,
        )
    replayed = first_by_frame(iter(capture.messages))
    report = ReplayReport(
        recording=str(path),
        service=service,
        speed="max" if speed is None else f"{speed:g}",
        prefix=keys.prefix,
        log_path=str(log_dir / f"{service}.log"),
        inputs_published=published,
        frames=frames,
        outputs=sum(1 for seq, _ in capture.messages if seq >= 0),
        no_answer=no_answer,
        skipped_inputs=skipped,
        wall_time_s=time.monotonic() - started,
        check=check,
        tolerance=io.tolerance if tolerance is None else tolerance,
        notes=notes,
        # At the service's own pace every frame has its answer: one missing is a failure (at a
        # --speed a service that falls behind drops frames, as it would live).
        ok=speed is not None or no_answer == 0,
    )
    if check:
        check_outputs(report, recorded_outputs, replayed, field_defaults(DATA_SUFFIXES[io.output]))
    return report


def _recorded_overrides(metadata: dict[str, str]) -> list[str]:
    import json

    try:
        items = json.loads(metadata.get("overrides_json", "[]"))
    except ValueError as exc:
        raise ReplayError(f"bad overrides_json in the recording's metadata: {exc}") from exc
    return [str(i) for i in items]


def _run(
    keys: Keys,
    service: str,
    io: ServiceIO,
    inputs: list[Recorded],
    speed: float | None,
    scenario_path: str | Path,
    overrides: list[str],
    log_dir: Path,
    frame_timeout_s: float,
    startup_timeout_s: float,
) -> tuple[int, int, int, OutputCapture]:
    """Start the service, publish, capture; returns (published, no answer, frames, capture)."""
    endpoint = free_tcp_endpoint()
    session = open_session(connect=[], listen=[endpoint])
    capture = OutputCapture()
    subscriber = session.declare_subscriber(f"{keys.prefix}/{io.output}", capture.on_sample)
    publishers = {
        s: session.declare_publisher(
            f"{keys.prefix}/{s}", congestion_control=zenoh.CongestionControl.BLOCK
        )
        for s in io.inputs
    }
    sup = Supervisor(str(scenario_path), keys.prefix, endpoint, log_dir, overrides, (service,))
    published = no_answer = frames = 0
    try:
        sup.start()
        _wait_alive(session, keys, service, sup, startup_timeout_s, list(publishers.values()))
        if speed is None:
            for step in lockstep_steps(inputs, io):
                seq = step[-1].frame_seq
                before = capture.count(seq)
                for r in step:
                    publishers[r.suffix].put(r.payload)
                published += len(step)
                frames += 1
                if not capture.wait_for(seq, before, frame_timeout_s):
                    no_answer += 1
                    dead = sup.exited()
                    if dead:
                        code = dead[0].exit_codes[-1]
                        raise ReplayFailed(
                            f"{service} exited (code {code}) at frame {seq}; see {dead[0].log_path}"
                        )
        else:
            t0 = inputs[0].log_time_ns
            start = time.monotonic()
            for r in inputs:
                delay = start + (r.log_time_ns - t0) / 1e9 / speed - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
                publishers[r.suffix].put(r.payload)
                published += 1
                frames += r.suffix == io.trigger
            expected = {r.frame_seq for r in inputs if r.suffix == io.trigger}
            capture.wait_for_all(expected, frame_timeout_s)
            no_answer = len(expected - capture.per_frame.keys())
    finally:
        sup.stop()
        subscriber.undeclare()
        for p in publishers.values():
            p.undeclare()
        session.close()
    return published, no_answer, frames, capture
