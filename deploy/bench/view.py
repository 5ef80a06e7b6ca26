"""``umay bench --view``: the loop measured with a live view running and a client connected,
to show what watching costs the loop (nothing, by design: the view is an observer)."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from common.keys import Keys
from deploy.bench import BenchError
from deploy.foxglove import topics
from deploy.foxglove.client import FoxgloveClient
from deploy.foxglove.node import ViewStartError, view_process
from deploy.foxglove.options import DEFAULT_HOST


@contextlib.contextmanager
def watched_by_a_view(
    keys: Keys,
    endpoint: str,
    log_dir: Path,
    scenario_path: str | None,
    overrides: list[str],
    startup_timeout_s: float = 60.0,
) -> Iterator[dict[str, Any]]:
    """``umay view`` on the run, and a client that subscribes to every channel and reads all
    it gets (the Foxglove app's load). Yields a dict that, once left, holds the client's
    message counts per topic."""
    report: dict[str, Any] = {}
    with contextlib.ExitStack() as stack:
        try:
            view = stack.enter_context(  # port 0: the view takes a free one and says which
                view_process(keys.prefix, endpoint, 0, log_dir / "view.log", scenario_path,
                             overrides)
            )  # fmt: skip
        except ViewStartError as exc:
            raise BenchError(str(exc)) from exc
        report["port"] = view.port
        client = FoxgloveClient(f"ws://{DEFAULT_HOST}:{view.port}", keep=False).start()
        try:
            if not client.wait_for(
                lambda cl: cl.counts.get(topics.COLOUR_IMAGE, 0) > 0, startup_timeout_s
            ):
                raise BenchError(f"the view client got no image; see {log_dir}/view.log")
            yield report
        finally:
            client.stop()
            report["client_messages"] = dict(sorted(client.counts.items()))
