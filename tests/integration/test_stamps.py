"""Every service keeps the header stamps of what it published and answers for them over Zenoh
(``<prefix>/<service>/stamps``), so a benchmark can split the loop into stages after a run
without listening to every hop while it runs."""

from __future__ import annotations

import pytest

from common.messages import Header, JointVelocityCommand, ServiceStatus
from common.node import Node
from common.publishers import STAMPS_KEPT
from common.session import free_tcp_endpoint, open_session
from deploy.queries import query_stamps
from tests.prefixes import unique_keys


def command(frame_seq: int, send_s: float, recv_s: float) -> JointVelocityCommand:
    header = Header(
        seq=0, sim_time_s=0.0, send_time_s=send_s, frame_seq=frame_seq, recv_time_s=recv_s
    )
    return JointVelocityCommand(header=header, velocity_rad_s=[0.0] * 6)


def test_a_service_answers_for_the_stamps_of_what_it_published_last() -> None:
    endpoint = free_tcp_endpoint()
    keys = unique_keys()
    service_session = open_session(connect=[], listen=[endpoint])
    node = Node("actuation", keys, service_session)
    pub = node.publisher(keys.joint_command)
    status = node.publisher(keys.status("actuation"))  # a message without a header
    tool = open_session(connect=[endpoint])
    try:
        for k in range(STAMPS_KEPT + 3):
            pub.put(command(k - 1, 100.0 + k, 99.5 + k))  # the first answers no frame (-1)
        status.put(ServiceStatus(service="actuation", pid=1, host="h", uptime_s=1, state="running"))
        stamps = query_stamps(tool, keys, "actuation", timeout_s=5.0)
        assert stamps is not None and stamps.service == "actuation"
        assert set(stamps.stamps) == {"actuation/joint_command", "actuation/status"}
        assert stamps.stamps["actuation/status"] == []
        kept = stamps.stamps["actuation/joint_command"]
        assert len(kept) == STAMPS_KEPT  # the newest, oldest first
        # (frame_seq, recv_time_s, send_time_s) of each
        last = STAMPS_KEPT + 2
        assert kept[0] == (2, 102.5, 103.0) and kept[-1] == (last - 1, 99.5 + last, 100.0 + last)
        assert query_stamps(tool, keys, "vision", timeout_s=0.5) is None  # nobody answers
    finally:
        tool.close()
        node.close()


def test_a_status_whose_fields_fail_still_answers_degraded_saying_why() -> None:
    """A field its model refuses must not silence the status answer: the supervisor would take
    the service for hung and kill it."""
    from pydantic import ValidationError

    from deploy.queries import query_status
    from services.actuation.status import ActuationStatus

    def broken() -> ActuationStatus:
        return ActuationStatus(deadman="perhaps")  # type: ignore[call-arg]

    endpoint = free_tcp_endpoint()
    keys = unique_keys()
    service_session = open_session(connect=[], listen=[endpoint])
    node = Node("actuation", keys, service_session, broken)
    node.ready()
    tool = open_session(connect=[endpoint])
    try:
        with pytest.raises(ValidationError):
            broken()
        answers = query_status(tool, keys, 5.0)
        assert [a.service for a in answers] == ["actuation"]
        status = answers[0]
        assert status.state == "degraded" and status.fields == {}
        assert status.degraded_reason.startswith("status fields: ValidationError: ")
    finally:
        tool.close()
        node.close()
