"""The live view's own status fields (``umay status``; docs/operations.md renders them)."""

from __future__ import annotations

from pydantic import Field

from common.messages import StatusFields


class ViewStatus(StatusFields):
    port: int = Field(description="the WebSocket port Foxglove connects to")
    messages_shown: int = Field(description="messages sent to the view's clients")
    dropped: dict[str, int] = Field(
        description="per key: messages left out (over the view's rate, the view behind, or a "
        "ring slot overwritten while converted)"
    )
    rejected: int = Field(description="messages that did not decode")
