"""Who is alive: the services' liveliness tokens under a key prefix.

The sim waits for its peers with it before its first frame, and the tools ask it too; the
tools' other questions (status, stamps) are :mod:`deploy.queries`.
"""

from __future__ import annotations

import zenoh

from common.keys import Keys


def alive_services(session: zenoh.Session, keys: Keys, timeout_s: float = 1.0) -> set[str]:
    """Services whose liveliness token is present under ``keys.prefix``."""
    names = set()
    for reply in session.liveliness().get(keys.all_alive, timeout=timeout_s):
        if reply.ok is not None:
            names.add(Keys.alive_service(str(reply.ok.key_expr)))
    return names
