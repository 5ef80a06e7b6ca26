"""A typed publisher knows whether anyone subscribes to its key (``TypedPublisher.matched``,
Zenoh's matching status): the sim puts its first lockstep frame once its frames and joint
states have a subscriber, not into the void (services/sim/node.py, ``wait_for_subscribers``)."""

from __future__ import annotations

import time
import uuid
from collections.abc import Callable

from common.keys import Keys
from common.node import Node
from common.session import free_tcp_endpoint, open_session


def becomes(predicate: Callable[[], bool], timeout_s: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.005)
    return True


def test_matched_follows_a_subscriber_on_another_session() -> None:
    endpoint = free_tcp_endpoint()
    keys = Keys(f"test/{uuid.uuid4().hex[:12]}")
    node = Node("sim", keys, open_session(connect=[], listen=[endpoint]))
    other = open_session(connect=[endpoint])
    try:
        joints = node.publisher(keys.joint_state)
        frames = node.publisher(keys.rgb, frames=True)
        assert not joints.matched and not frames.matched  # nobody subscribes yet
        subscriber = other.declare_subscriber(keys.joint_state, lambda _sample: None)
        assert becomes(lambda: joints.matched), "the subscriber never reached the publisher"
        assert not frames.matched  # another key's subscriber is not this one's
        subscriber.undeclare()
        assert becomes(lambda: not joints.matched), "the undeclared subscriber still matched"
    finally:
        other.close()
        node.close()
