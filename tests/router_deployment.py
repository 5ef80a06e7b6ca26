"""Helpers for tests of the router deployment (deploy/zenoh/acl): a router and services as
separate OS processes, each service a client of the router with its own credentials."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import zenoh

from common.codec import DEFAULT_MAX_BYTES, decode
from common.keys import Keys
from common.messages import JointState
from common.session import free_tcp_endpoint
from tests.prefixes import unique_keys

REPO = Path(__file__).resolve().parent.parent
ACL_DIR = REPO / "deploy" / "zenoh" / "acl"
SMALL_IMAGE = ("--set", "camera.width_px=320", "--set", "camera.height_px=240")


def start_router(endpoint: str, log_dir: Path) -> subprocess.Popen:
    return _spawn(
        [sys.executable, "-m", "deploy", "router", "--config", str(ACL_DIR / "router.json5"),
         "--listen", endpoint],
        log_dir / "router.log",
    )  # fmt: skip


def start_service(
    name: str, endpoint: str, prefix: str, log_dir: Path, *extra: str, wrapper: tuple = ()
) -> subprocess.Popen:
    """``umay service NAME`` with its own ACL credentials, connected to the router only."""
    return _spawn(
        [*wrapper, sys.executable, "-m", f"services.{name}", "--prefix", prefix,
         "--zenoh-config", str(ACL_DIR / f"{name}.json5"), "--connect", endpoint, *extra],
        log_dir / f"{name}.log",
    )  # fmt: skip


def client_session(user: str | None, endpoint: str, password: str | None = None) -> zenoh.Session:
    """A client of the router logged in as ``user`` (None: no credentials at all)."""
    cfg = zenoh.Config()
    cfg.insert_json5("mode", '"client"')
    cfg.insert_json5("connect/endpoints", json.dumps([endpoint]))
    cfg.insert_json5("scouting/multicast/enabled", "false")
    if user is not None:
        secret = password or f"umay-{user}-demo"
        cfg.insert_json5("transport/auth/usrpwd", json.dumps({"user": user, "password": secret}))
    return zenoh.open(cfg)


def wait_for_router(endpoint: str, timeout_s: float = 20.0) -> zenoh.Session:
    """A tool session, once the router accepts connections."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            return client_session("tool", endpoint)
        except zenoh.ZError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.2)


def stop_all(processes: list[subprocess.Popen]) -> None:
    for p in processes:
        if p.poll() is None:
            p.terminate()
    for p in processes:
        try:
            p.wait(5)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def joint_state_decoder(states: list[JointState]):
    def on_sample(sample) -> None:
        states.append(decode(sample.payload.to_bytes(), JointState, DEFAULT_MAX_BYTES))

    return on_sample


def _spawn(argv: list[str], log_path: Path) -> subprocess.Popen:
    log_path.parent.mkdir(parents=True, exist_ok=True)
    with log_path.open("ab") as out:
        return subprocess.Popen(argv, stdout=out, stderr=subprocess.STDOUT, cwd=REPO)


@contextmanager
def router_and_tool(
    log_dir: Path,
) -> Iterator[tuple[str, Keys, zenoh.Session, list[zenoh.Session]]]:
    """A router with access control on a free port, a key prefix of the test's own and a tool
    session on it; yields those and a list the test adds its own sessions to, all closed after
    it (and the router stopped)."""
    endpoint = free_tcp_endpoint()
    router = start_router(endpoint, log_dir)
    sessions: list[zenoh.Session] = []
    try:
        tool = wait_for_router(endpoint)
        sessions.append(tool)
        yield endpoint, unique_keys(), tool, sessions
    finally:
        for session in sessions:
            session.close()
        stop_all([router])
