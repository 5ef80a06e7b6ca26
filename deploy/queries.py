"""Asking the running services what they are doing: their status, their published stamps.

The tools' side of the services' queryables (:class:`common.node.Node` answers them); no
service asks another, so these live with the tools. Who is alive is
:func:`common.queries.alive_services`, which the sim needs too.
"""

from __future__ import annotations

import logging

import zenoh

from common.codec import DEFAULT_MAX_BYTES, MessageError, decode
from common.keys import Keys
from common.messages import PublishedStamps, ServiceStatus
from common.publishers import STAMPS_MAX_BYTES

log = logging.getLogger("umay")


def status_from_reply(reply: zenoh.Reply) -> ServiceStatus | None:
    """The status in a reply to a status query; None for an error reply. MessageError when
    the payload is not a valid status."""
    if reply.ok is None:
        return None
    return decode(reply.ok.payload.to_bytes(), ServiceStatus, DEFAULT_MAX_BYTES)


def query_status(session: zenoh.Session, keys: Keys, timeout_s: float = 1.0) -> list[ServiceStatus]:
    """Ask every service under ``keys.prefix`` for its status."""
    out = []
    for reply in session.get(keys.all_status, timeout=timeout_s):
        try:
            status = status_from_reply(reply)
        except MessageError as exc:
            log.warning("bad status reply: %s", exc)
            continue
        if status is not None:
            out.append(status)
    return out


def query_stamps(
    session: zenoh.Session, keys: Keys, service: str, timeout_s: float = 2.0
) -> PublishedStamps | None:
    """``service``'s :class:`PublishedStamps`, or None when it does not answer in time."""
    for reply in session.get(keys.stamps(service), timeout=timeout_s):
        if reply.ok is not None:
            return decode(reply.ok.payload.to_bytes(), PublishedStamps, STAMPS_MAX_BYTES)
    return None
