"""Zenoh sessions: configuration (endpoints, shared memory, a config file), opening one with
a clear error, free loopback endpoints for tests and parallel pipelines."""

from __future__ import annotations

import json
import logging
import os
import socket
import sys

import zenoh

log = logging.getLogger("umay")

ENV_CONFIG = "UMAY_ZENOH_CONFIG"  # path of a Zenoh JSON5 config file: used as is
ENV_CONNECT = "UMAY_ZENOH_CONNECT"  # comma-separated endpoints to connect to
# "0": no shared memory, so payloads take the network path even between processes on one host
# (what a peer on another host gets); benchmarks compare both. Applies to config files too.
ENV_SHM = "UMAY_ZENOH_SHM"
DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"  # where `umay up` listens and tools connect


class ZenohConfigError(ValueError):
    """A Zenoh config file that cannot be read; the message names the file and the reason."""


def zenoh_config(
    config_path: str | None = None,
    connect: list[str] | None = None,
    listen: list[str] | None = None,
) -> zenoh.Config:
    """Peer mode, loopback only, multicast scouting off, unless a config file says otherwise.

    Precedence: ``config_path`` argument, then ``$UMAY_ZENOH_CONFIG``, then the defaults with
    ``connect`` (argument, else ``$UMAY_ZENOH_CONNECT``, else :data:`DEFAULT_ENDPOINT`).
    Peers find each other through gossip over the first connection. With a config file, an
    explicit ``connect`` (argument or environment) replaces the file's endpoints, so one file
    (say a client's credentials) serves wherever the router happens to be.

    Zenoh's shared memory is on by default: between processes on one host, payloads above
    3 KB (camera frames) go through a shared pool instead of the socket, and a peer that
    cannot map it (another host) gets them over the network. ``$UMAY_ZENOH_SHM=0`` turns it
    off.
    """
    cfg = _base_config(config_path, connect, listen)
    if not shm_enabled():
        cfg.insert_json5("transport/shared_memory/enabled", "false")
    return cfg


def where_connecting(connect: list[str] | None = None, config_path: str | None = None) -> str:
    """Where a session of :func:`zenoh_config` with these arguments looks for its peers, in
    words: the endpoints, or the config file's own when it has no ``connect`` of ours."""
    connect = _connect_from_env(connect)
    if connect:
        return ", ".join(connect)
    path = _config_path(config_path)
    return f"the endpoints of {path}" if path else DEFAULT_ENDPOINT


def _connect_from_env(connect: list[str] | None) -> list[str] | None:
    if connect is None:
        env = os.environ.get(ENV_CONNECT, "")
        connect = [e for e in env.split(",") if e] or None
    return connect


def _config_path(config_path: str | None) -> str | None:
    return config_path or os.environ.get(ENV_CONFIG)


def _base_config(
    config_path: str | None, connect: list[str] | None, listen: list[str] | None
) -> zenoh.Config:
    connect = _connect_from_env(connect)
    path = _config_path(config_path)
    if path:
        try:
            cfg = zenoh.Config.from_file(path)
            if connect:
                cfg.insert_json5("connect/endpoints", json.dumps(connect))
        except zenoh.ZError as exc:
            raise ZenohConfigError(f"{path}: not a usable Zenoh config: {exc}") from exc
        return cfg
    connect = connect if connect is not None else [DEFAULT_ENDPOINT]
    cfg = zenoh.Config()
    cfg.insert_json5("mode", '"peer"')
    cfg.insert_json5("listen/endpoints", json.dumps(listen or ["tcp/127.0.0.1:0"]))
    cfg.insert_json5("connect/endpoints", json.dumps(connect))
    cfg.insert_json5("scouting/multicast/enabled", "false")
    return cfg


# Protocols whose address ends in ``:port``: Zenoh's parser takes any port there, and a session
# told to connect to port 99999 only retries in silence.
PORTED_PROTOCOLS = ("tcp", "udp", "tls", "quic", "ws")


def _port_problem(endpoint: str) -> str:
    """Why ``endpoint``'s port is not a TCP/UDP port, or "" (no port to check)."""
    protocol, _, address = endpoint.partition("/")
    if protocol not in PORTED_PROTOCOLS:
        return ""
    _host, colon, port = address.split("?", 1)[0].split("#", 1)[0].rpartition(":")
    if not colon:
        return "no :port after its address"
    if not (port.isdigit() and int(port) <= 65535):
        return f"port {port!r} is not 0-65535"
    return ""


def check_endpoints(value: str) -> list[str]:
    """The comma-separated Zenoh endpoints in ``value`` (``tcp/127.0.0.1:7447,...``), each
    checked by Zenoh's own parser and for a port in range; ValueError naming the first bad
    one and why."""
    endpoints = [e.strip() for e in value.split(",")]
    for endpoint in endpoints:
        try:
            zenoh.Config().insert_json5("connect/endpoints", json.dumps([endpoint]))
        except zenoh.ZError:
            raise ValueError(
                f"invalid endpoint {endpoint!r}: expected <protocol>/<address>[?<metadata>], "
                f"e.g. {DEFAULT_ENDPOINT}"
            ) from None
        problem = _port_problem(endpoint)
        if problem:
            raise ValueError(f"invalid endpoint {endpoint!r}: {problem}")
    return endpoints


def open_session(
    config_path: str | None = None,
    connect: list[str] | None = None,
    listen: list[str] | None = None,
) -> zenoh.Session:
    """A session on :func:`zenoh_config` (opened by :func:`open_zenoh`). Raises
    :class:`ZenohConfigError` for a bad config file, ``zenoh.ZError`` if it cannot open."""
    return open_zenoh(zenoh_config(config_path, connect, listen))


def open_zenoh(config: zenoh.Config) -> zenoh.Session:
    """``zenoh.open(config)``; where the host cannot give Zenoh shared memory (no writable
    ``/dev/shm``, as in some containers, where Zenoh fails to open at all) it opens without
    it, with a warning: large payloads then go over the network."""
    unusable = _shm_unusable() if _shm_configured(config) else ""
    if unusable:  # known before trying: no failed open (and its half-bound listeners) first
        config.insert_json5("transport/shared_memory/enabled", "false")
        log.warning("Zenoh session opened without shared memory (%s)", unusable)
        return zenoh.open(config)
    try:
        return zenoh.open(config)
    except zenoh.ZError as exc:
        # Only for shared memory's errors ("Unable to create POSIX shm segment"): a retry
        # after any other (a router that does not answer) would double the wait for nothing.
        if "shm" not in str(exc).lower():
            raise
        config.insert_json5("transport/shared_memory/enabled", "false")
        try:
            session = zenoh.open(config)
        except zenoh.ZError as again:
            raise zenoh.ZError(
                f"{zenoh_reason(exc)}; and without shared memory: {zenoh_reason(again)}"
            ) from None
        log.warning("Zenoh session opened without shared memory (%s)", zenoh_reason(exc))
        return session


def _shm_configured(config: zenoh.Config) -> bool:
    try:
        return json.loads(config.get_json("transport/shared_memory/enabled")) is True
    except (zenoh.ZError, ValueError):
        return False


def _shm_unusable() -> str:
    """Why POSIX shared memory cannot be created here ("": it may be). Linux keeps it in
    ``/dev/shm``; elsewhere only trying tells."""
    if sys.platform.startswith("linux") and not os.access("/dev/shm", os.W_OK):
        return "/dev/shm is missing or not writable"
    return ""


def zenoh_reason(exc: BaseException) -> str:
    """A Zenoh error's message without the Rust source location that ends it."""
    return str(exc).split(" at /", 1)[0]


def free_tcp_endpoint() -> str:
    """A loopback endpoint on a port that is free right now (for tests and the supervisor)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def shm_enabled() -> bool:
    """False when ``$UMAY_ZENOH_SHM=0`` turns Zenoh's shared memory, and frames by
    reference, off."""
    return os.environ.get(ENV_SHM, "").strip() != "0"
