"""The stages ``umay bench`` splits a camera frame's way round the loop into, by name.

Every message header carries its send time and the time its publisher received the input it
answers, and the sim publishes per frame when it started the render, captured, sent the frame
and received and applied each joint command, so camera frame k splits exactly into consecutive
stages whose sum is the end-to-end latency from *frame captured* (images ready) to *command
applied* (motors set), render excluded:

======================= ==========================================================
stage                    from → to (wall clock)
======================= ==========================================================
render                   render start → images ready (not in the latency)
publish                  images ready → colour frame header stamped (sim)
frame_transport          colour frame header → vision receives its inputs
vision                   vision receives → features header stamped
features_transport       features header → controller has features and joints
controller               → twist header stamped
twist_transport          twist header → actuation has twist and joints
actuation                → joint command header stamped
command_transport        command header → the sim receives it
apply                    the sim receives it → the motors follow it
======================= ==========================================================

A "transport" stage holds the sender's message construction and encoding, Zenoh, and the
wait for the partner message (pairing); a service stage holds the receive copy, decoding,
queueing and the work.
"""

from __future__ import annotations

STAGES: tuple[str, ...] = (
    "render",
    "publish",
    "frame_transport",
    "vision",
    "features_transport",
    "controller",
    "twist_transport",
    "actuation",
    "command_transport",
    "apply",
)
LATENCY_STAGES = STAGES[1:]  # they add up to frame captured → command applied
SYNTHETIC_STAGES = STAGES[2:8]  # frame published → command published (no sim)
# The in-process loop's stages: the services' steps and setting the motors, no transport.
INPROCESS_STAGES: tuple[str, ...] = ("vision", "controller", "actuation", "apply")
# The codec work the distributed path does per frame, timed apart in the in-process loop.
CODEC_STAGES: tuple[str, ...] = ("frame_codec", "features_codec", "twist_codec", "command_codec")
PIPELINE: tuple[str, ...] = ("vision", "controller", "actuation")  # the services between
