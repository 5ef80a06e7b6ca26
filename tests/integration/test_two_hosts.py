"""Two hosts on one machine: the sim runs in its own network namespace ("host B"), joined to
this one ("host A") by a veth pair, with a hostname and a ``/dev/shm`` of its own (UTS and
mount namespaces), so that nothing of host B's shared memory is in reach of host A; vision,
controller and actuation run on host A. Every service is a client of one router on host A's
veth address, logged in with its own ACL credentials, so the only path between the hosts is
TCP through that router. The lockstep run must converge exactly as on one host, vision getting
every camera frame whole from the sim (it cannot map the sim's frame ring). Needs root
(CAP_NET_ADMIN, CAP_SYS_ADMIN), as CI has."""

from __future__ import annotations

import os
import random
import socket
import subprocess
import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from common.codec import DEFAULT_MAX_BYTES, decode
from common.messages import EndEffectorTwist
from deploy.queries import query_status
from tests.prefixes import unique_keys
from tests.router_deployment import (
    SMALL_IMAGE,
    start_router,
    start_service,
    stop_all,
    wait_for_router,
)


@dataclass(frozen=True)
class NetnsHost:
    name: str
    host_ip: str  # host A's end of the veth pair
    netns_ip: str  # host B's end, inside the namespace


def ip(*args: str) -> None:
    subprocess.run(["ip", *args], check=True, capture_output=True, text=True)


@pytest.fixture()
def second_host() -> Iterator[NetnsHost]:
    if os.geteuid() != 0:
        pytest.fail("this test creates a network namespace: run it as root (CI does)")
    tag = uuid.uuid4().hex[:6]
    name, host_if, ns_if = f"umay{tag}", f"vh{tag}", f"vn{tag}"
    subnet = f"10.{random.randint(64, 127)}.{random.randint(0, 255)}"
    host = NetnsHost(name, f"{subnet}.1", f"{subnet}.2")
    ip("netns", "add", name)
    try:
        ip("link", "add", host_if, "type", "veth", "peer", "name", ns_if)
        ip("link", "set", ns_if, "netns", name)
        ip("addr", "add", f"{host.host_ip}/24", "dev", host_if)
        ip("link", "set", host_if, "up")
        ip("netns", "exec", name, "ip", "addr", "add", f"{host.netns_ip}/24", "dev", ns_if)
        ip("netns", "exec", name, "ip", "link", "set", ns_if, "up")
        ip("netns", "exec", name, "ip", "link", "set", "lo", "up")
        yield host
    finally:
        ip("netns", "del", name)  # takes the veth pair with it


def free_port(address: str) -> int:
    with socket.socket() as s:
        s.bind((address, 0))
        return s.getsockname()[1]


def test_sim_on_another_host_through_a_router_converges(
    tmp_path: Path, second_host: NetnsHost
) -> None:
    router = f"tcp/{second_host.host_ip}:{free_port(second_host.host_ip)}"
    keys = unique_keys()
    procs = [start_router(router, tmp_path)]
    monitor = wait_for_router(router)
    twists: list[EndEffectorTwist] = []
    sub = monitor.declare_subscriber(
        keys.twist,
        lambda s: twists.append(decode(s.payload.to_bytes(), EndEffectorTwist, DEFAULT_MAX_BYTES)),
    )
    try:
        own_shm_and_name = 'mount -t tmpfs tmpfs /dev/shm && hostname host-b && exec "$@"'
        in_netns = ("ip", "netns", "exec", second_host.name, "unshare", "-m", "-u")
        in_netns += ("sh", "-c", own_shm_and_name, "sh")
        sim = start_service("sim", router, keys.prefix, tmp_path, *SMALL_IMAGE, wrapper=in_netns)
        procs.append(sim)
        for name in ("vision", "controller", "actuation"):
            procs.append(start_service(name, router, keys.prefix, tmp_path, *SMALL_IMAGE))
        deadline = time.monotonic() + 180
        while not (twists and twists[-1].converged):
            assert time.monotonic() < deadline, f"no convergence; last twist: {twists[-1:]}"
            assert all(p.poll() is None for p in procs), "a process exited; see its log"
            time.sleep(0.2)
        # The sim really was on the other side of the veth pair.
        assert os.readlink(f"/proc/{sim.pid}/ns/net") != os.readlink("/proc/self/ns/net")
        last = twists[-1]
        print(f"converged at frame {last.header.frame_seq}, pixel RMS {last.error_px_rms:.3f} px")
        assert last.error_px_rms < 0.25
        # The sim sent references; vision, out of their reach, asked for every frame whole.
        status = {s.service: s for s in query_status(monitor, keys, 2.0)}
        sim_fields, vision = status["sim"].fields, status["vision"]
        assert sim_fields["frames_by_ref"] > 0 and sim_fields["whole_frames_served"] > 0
        rgb = vision.received[keys.rgb]
        assert rgb.by_ref == 0 and rgb.fetched == rgb.by_copy == rgb.count > last.header.frame_seq
        assert vision.fields["frames_by_ref"] == 0 and vision.rejected == 0
        assert vision.fields["frames_fetched"] == vision.fields["frames_by_copy"] > rgb.count
    finally:
        sub.undeclare()
        monitor.close()
        stop_all(procs[::-1])
