"""Access control (deploy/zenoh/acl): behind the router, only the actuation service can move
the arm, only the sim can publish camera frames, every key of the loop's data takes puts from
its own service only, and each service (and the live view) alone answers for its status and
stamps and holds its liveliness tokens; sessions without valid credentials are refused. The sim
runs for real (realtime clock, small image) and its joint encoders tell whether a command reached
the motors."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import zenoh

from common.codec import DEFAULT_MAX_BYTES, decode, encode
from common.keys import SERVICES, Keys, whole_frame_key
from common.messages import Header, JointState, JointVelocityCommand, ServiceStatus
from common.session import ENV_CONFIG, free_tcp_endpoint
from tests.prefixes import unique_keys
from tests.router_deployment import (
    ACL_DIR,
    REPO,
    SMALL_IMAGE,
    client_session,
    joint_state_decoder,
    router_and_tool,
    start_router,
    start_service,
    stop_all,
    wait_for_router,
)

JOINT_1_RATE_RAD_S = 0.5


def command(seq: int) -> bytes:
    header = Header(seq=seq, sim_time_s=0.0, send_time_s=time.time(), frame_seq=-1)
    rates = [JOINT_1_RATE_RAD_S, 0.0, 0.0, 0.0, 0.0, 0.0]
    return encode(JointVelocityCommand(header=header, velocity_rad_s=rates, reason="track"))


def push_commands_as(user: str, endpoint: str, keys: Keys, states: list[JointState]) -> float:
    """Publish joint commands for 1 s as ``user``; the fastest joint-1 speed the encoders saw."""
    session = client_session(user, endpoint)
    try:
        publisher = session.declare_publisher(keys.joint_command)
        time.sleep(0.3)  # let the declaration reach the router
        start = len(states)
        for seq in range(20):
            publisher.put(command(seq))
            time.sleep(0.05)
        time.sleep(0.2)
        seen = states[start:]
        assert seen, f"no joint state while {user!r} sent commands: nothing to judge them by"
        return max(abs(s.velocity_rad_s[0]) for s in seen)
    finally:
        session.close()


def test_only_the_actuation_service_can_move_the_arm(tmp_path: Path) -> None:
    endpoint = free_tcp_endpoint()
    keys = unique_keys()
    procs = [start_router(endpoint, tmp_path)]
    monitor = wait_for_router(endpoint)
    try:
        procs.append(
            start_service(
                "sim", endpoint, keys.prefix, tmp_path, "--set", "run.clock='realtime'",
                *SMALL_IMAGE,
            )
        )  # fmt: skip
        states: list[JointState] = []
        sub = monitor.declare_subscriber(keys.joint_state, joint_state_decoder(states))
        deadline = time.monotonic() + 60
        while len(states) < 5:
            assert time.monotonic() < deadline, "the sim never published joint states"
            time.sleep(0.1)

        seen = {user: push_commands_as(user, endpoint, keys, states) for user in
                ("tool", "vision", "controller", "actuation")}  # fmt: skip
        print("fastest joint-1 speed while each user sent 0.5 rad/s commands:", seen)
        for user in ("tool", "vision", "controller"):
            assert seen[user] < 1e-3, f"a command from {user!r} moved the arm"
        assert seen["actuation"] == pytest.approx(JOINT_1_RATE_RAD_S, abs=0.05)
        sub.undeclare()
    finally:
        monitor.close()
        stop_all(procs[::-1])


def test_only_the_sim_can_publish_frames_and_strangers_are_refused(tmp_path: Path) -> None:
    endpoint = free_tcp_endpoint()
    keys = unique_keys()
    procs = [start_router(endpoint, tmp_path)]
    monitor = wait_for_router(endpoint)
    try:
        with pytest.raises(zenoh.ZError):
            client_session(None, endpoint)  # no credentials
        with pytest.raises(zenoh.ZError):
            client_session("actuation", endpoint, password="guess")
        procs.append(
            start_service(
                "sim", endpoint, keys.prefix, tmp_path, "--set", "run.clock='realtime'",
                *SMALL_IMAGE,
            )
        )  # fmt: skip
        vision = client_session("vision", endpoint)
        received: list[bytes] = []
        sub = vision.declare_subscriber(keys.rgb, lambda s: received.append(s.payload.to_bytes()))
        forged = b"forged frame"
        rogue = client_session("controller", endpoint)
        publisher = rogue.declare_publisher(keys.rgb)
        deadline = time.monotonic() + 60
        while len(received) < 5:  # the sim's own frames arrive...
            assert time.monotonic() < deadline, "no frames from the sim"
            publisher.put(forged)
            time.sleep(0.1)
        for _ in range(10):
            publisher.put(forged)
            time.sleep(0.05)
        assert forged not in received  # ...the forged ones never do
        # Nor can anyone but the sim answer for its whole frames (what a subscriber that
        # cannot map the sim's frame ring asks for).
        rogue_queryable = rogue.declare_queryable(
            whole_frame_key(keys.rgb), lambda q: q.reply(q.key_expr, forged)
        )
        time.sleep(0.5)
        replies = list(vision.get(f"{whole_frame_key(keys.rgb)}?segment=s;seq=1", timeout=2.0))
        assert replies and all(r.ok is None for r in replies)  # the sim's "no such frame"
        rogue_queryable.undeclare()
        sub.undeclare()
        rogue.close()
        vision.close()
    finally:
        monitor.close()
        stop_all(procs[::-1])


# The keys of the loop's data and the one service that may put on each (deploy/zenoh/acl).
OWNERS = {
    "rgb": "sim",
    "depth": "sim",
    "joint_state": "sim",
    "truth": "sim",
    "features": "vision",
    "twist": "controller",
    "joint_command": "actuation",
}
# Every user the router knows (a user added there is checked here too).
USERS = tuple(line.split(":", 1)[0] for line in (ACL_DIR / "credentials.txt").read_text().split())
# Who answers for a status and holds liveliness tokens: the services and the live view.
NODES = (*SERVICES, "view")


def test_each_data_key_takes_puts_from_its_own_service_only(tmp_path: Path) -> None:
    """Behind the router every key of the loop's data is one service's alone: what another
    service or a tool puts there never reaches a subscriber (a forged twist, say, would move the
    arm through actuation), while the owner's put does, which shows the path was open."""
    with router_and_tool(tmp_path) as (endpoint, keys, monitor, sessions):
        received: dict[str, set[bytes]] = {name: set() for name in OWNERS}
        for name in OWNERS:
            monitor.declare_subscriber(
                getattr(keys, name), lambda s, name=name: received[name].add(s.payload.to_bytes())
            )
        publishers = []
        for user in USERS:
            session = client_session(user, endpoint)
            sessions.append(session)
            publishers += [
                (user.encode(), session.declare_publisher(getattr(keys, name))) for name in OWNERS
            ]

        def put_all() -> None:
            for payload, publisher in publishers:
                publisher.put(payload)
            time.sleep(0.1)

        deadline = time.monotonic() + 30
        while not all(owner.encode() in received[name] for name, owner in OWNERS.items()):
            assert time.monotonic() < deadline, f"an owner's put never arrived: {received}"
            put_all()
        for _ in range(5):  # every user's put has had time to arrive, had it been let through
            put_all()
        assert received == {name: {owner.encode()} for name, owner in OWNERS.items()}


def test_each_service_and_the_view_alone_answer_for_their_status_and_liveliness(
    tmp_path: Path,
) -> None:
    """Every user answers queries on every service's (and the live view's) status and stamps
    and declares a liveliness token for each: only the node's own answers and tokens reach a
    tool (another user's status answer could keep a hung service from being found hung, its
    token pass for a service that is not there), and only the sim's timing does."""
    with router_and_tool(tmp_path) as (endpoint, keys, monitor, sessions):
        timings: set[bytes] = set()
        monitor.declare_subscriber(keys.timing, lambda s: timings.add(s.payload.to_bytes()))
        held = []  # queryables and tokens, alive until the sessions close
        timing_publishers = []
        for pid, user in enumerate(USERS, start=1000):
            session = client_session(user, endpoint)
            sessions.append(session)
            for service in NODES:
                for key in (keys.status(service), keys.stamps(service)):
                    reply = user.encode()
                    held.append(
                        session.declare_queryable(key, lambda q, r=reply: q.reply(q.key_expr, r))
                    )
                held.append(session.liveliness().declare_token(keys.alive(service, pid)))
            timing_publishers.append((user.encode(), session.declare_publisher(keys.timing)))
        owners = {service: 1000 + USERS.index(service) for service in NODES}

        def answers(key: str) -> set[bytes]:
            """Every queryable's reply, not the best match's alone nor one per key."""
            replies = monitor.get(
                key,
                target=zenoh.QueryTarget.ALL,
                consolidation=zenoh.ConsolidationMode.NONE,
                timeout=2.0,
            )
            return {r.ok.payload.to_bytes() for r in replies if r.ok}

        deadline = time.monotonic() + 30
        while not all(answers(keys.status(s)) for s in NODES):
            assert time.monotonic() < deadline, "a service's own status never answered"
            time.sleep(0.1)
        for service in NODES:
            assert answers(keys.status(service)) == {service.encode()}, service
            assert answers(keys.stamps(service)) == {service.encode()}, service
        tokens = {str(r.ok.key_expr) for r in monitor.liveliness().get(keys.all_alive) if r.ok}
        assert tokens == {keys.alive(s, pid) for s, pid in owners.items()}
        for _ in range(10):
            for payload, publisher in timing_publishers:
                publisher.put(payload)
            time.sleep(0.05)
        assert timings == {b"sim"}


def test_the_live_view_logs_in_as_its_own_user(tmp_path: Path) -> None:
    """``umay view`` on deploy/zenoh/acl/view.json5 is the router's user "view": its status
    answers a tool and its liveliness token is there, both of which the router lets that user
    alone put (the test above)."""
    with router_and_tool(tmp_path) as (endpoint, keys, tool, _sessions):
        log = tmp_path / "view.log"
        with log.open("wb") as out:
            view = subprocess.Popen(
                [sys.executable, "-m", "deploy", "view", "--port", "0", "--prefix", keys.prefix,
                 "--connect", endpoint],
                stdout=out, stderr=subprocess.STDOUT, cwd=REPO,
                env={**os.environ, ENV_CONFIG: str(ACL_DIR / "view.json5")},
            )  # fmt: skip
        try:
            deadline = time.monotonic() + 60
            while not (
                answers := [r.ok for r in tool.get(keys.status("view"), timeout=2.0) if r.ok]
            ):
                assert view.poll() is None, log.read_text()
                assert time.monotonic() < deadline, f"the view never answered: {log.read_text()}"
                time.sleep(0.2)
            status = decode(answers[0].payload.to_bytes(), ServiceStatus, DEFAULT_MAX_BYTES)
            assert (status.service, status.pid) == ("view", view.pid)
            tokens = {str(r.ok.key_expr) for r in tool.liveliness().get(keys.all_alive) if r.ok}
            assert keys.alive("view", view.pid) in tokens
        finally:
            view.send_signal(signal.SIGTERM)
            try:
                code = view.wait(30)
            except subprocess.TimeoutExpired:
                view.kill()
                view.wait()
                raise
        assert code == 0, log.read_text()


@pytest.mark.parametrize("content", [None, "{ mode: 'peer', listen: { endpoints: [1, 2] } }"])
def test_a_bad_zenoh_config_is_named_and_nothing_starts(tmp_path: Path, content) -> None:
    path = tmp_path / "zenoh.json5"
    if content is not None:
        path.write_text(content)
    done = subprocess.run(
        [sys.executable, "-m", "services.vision", "--zenoh-config", str(path)],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert done.returncode == 2
    assert f"{path}: not a usable Zenoh config" in done.stderr
    assert "Traceback" not in done.stderr
