"""Key prefixes and Zenoh endpoints as the command line checks them: good ones pass, bad ones
are named."""

from __future__ import annotations

import pytest

from common.keys import Keys
from common.session import check_endpoints


def test_endpoints_are_checked_by_zenohs_parser() -> None:
    assert check_endpoints("tcp/127.0.0.1:7447") == ["tcp/127.0.0.1:7447"]
    assert check_endpoints("tcp/a:1, udp/b:2") == ["tcp/a:1", "udp/b:2"]
    for bad, named in (("foo", "'foo'"), ("tcp/a:1,,tcp/b:2", "''"), ("", "''")):
        with pytest.raises(ValueError, match=f"invalid endpoint {named}: expected <protocol>/"):
            check_endpoints(bad)


def test_good_prefixes_pass() -> None:
    for prefix in ("umay/umay1", "test/3f2a9c", "robot-2/arm_left"):
        assert Keys(prefix).twist == f"{prefix}/controller/twist"


def test_the_well_known_endpoint_is_kept_after_a_run_and_left_while_in_use() -> None:
    """A run's closed connections leave its port in TIME_WAIT: the next run must still listen
    there (where ``umay status`` looks); a port someone listens on is left for a free one."""
    import socket

    from deploy.launch.run import default_listen_endpoint

    with socket.socket() as listener:
        listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        listener.bind(("127.0.0.1", 0))
        listener.listen()
        endpoint = f"tcp/127.0.0.1:{listener.getsockname()[1]}"
        assert default_listen_endpoint(endpoint) != endpoint  # in use
        with socket.create_connection(listener.getsockname()) as client:
            accepted, _ = listener.accept()
            accepted.close()  # the listening side closes first: its port enters TIME_WAIT
            client.recv(1)
    # The listener is closed; only the TIME_WAIT connection is left on the port.
    assert default_listen_endpoint(endpoint) == endpoint


def test_without_writable_dev_shm_the_session_opens_once_without_shared_memory(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A read-only or missing /dev/shm is known before opening: one open, shared memory off
    (not a failed open first, whose listeners a loaded host may not have let go of)."""
    import zenoh

    from common import session

    opened: list[str] = []

    def fake_open(config: zenoh.Config) -> str:
        opened.append(config.get_json("transport/shared_memory/enabled"))
        return "session"

    monkeypatch.setattr(session.zenoh, "open", fake_open)
    monkeypatch.setattr(session.os, "access", lambda path, mode: path != "/dev/shm")
    assert session.open_session(connect=[]) == "session"
    assert opened == ["false"]

    opened.clear()
    monkeypatch.setattr(session.os, "access", lambda path, mode: True)
    session.open_session(connect=[])
    assert opened == ["true"]  # writable: shared memory as configured


def test_each_process_of_a_service_has_a_liveliness_key_of_its_own() -> None:
    """Zenoh reports a key alive once however many tokens hold it: a restarted service that
    declared its token on its predecessor's key before that one's end had reached a watcher
    was never reported back. One key per process (its pid) is reported each time."""
    keys = Keys("umay/a1")
    old, new = keys.alive("vision", 101), keys.alive("vision", 102)
    assert old != new and old.startswith("umay/a1/alive/vision/")
    assert Keys.alive_service(old) == Keys.alive_service(new) == "vision"
    assert keys.all_alive == "umay/a1/alive/*/*"
