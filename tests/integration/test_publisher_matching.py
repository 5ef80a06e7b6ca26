"""A typed publisher knows whether anyone subscribes to its key (``TypedPublisher.matched``,
Zenoh's matching status): the sim puts its first lockstep frame once its frames and joint
states have a subscriber, not into the void (services/sim/node.py, ``wait_for_subscribers``)."""

from __future__ import annotations

from common.node import Node
from common.session import free_tcp_endpoint, open_session
from tests.integration.test_supervisor import wait_for
from tests.prefixes import unique_keys


def test_matched_follows_a_subscriber_on_another_session() -> None:
    endpoint = free_tcp_endpoint()
    keys = unique_keys()
    node = Node("sim", keys, open_session(connect=[], listen=[endpoint]))
    other = open_session(connect=[endpoint])
    try:
        joints = node.publisher(keys.joint_state)
        frames = node.publisher(keys.rgb, frames=True)
        assert not joints.matched and not frames.matched  # nobody subscribes yet
        subscriber = other.declare_subscriber(keys.joint_state, lambda _sample: None)
        reached = wait_for(lambda: joints.matched, 10.0, 0.005)
        assert reached, "the subscriber never reached the publisher"
        assert not frames.matched  # another key's subscriber is not this one's
        subscriber.undeclare()
        gone = wait_for(lambda: not joints.matched, 10.0, 0.005)
        assert gone, "the undeclared subscriber still matched"
    finally:
        other.close()
        node.close()
