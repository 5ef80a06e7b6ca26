"""A key prefix of a test's own, so that tests run at once (pytest-xdist workers, two suites on
one host) never hear each other's messages."""

from __future__ import annotations

import uuid

from common.keys import Keys


def unique_prefix() -> str:
    """``test/`` and twelve random hex digits."""
    return f"test/{uuid.uuid4().hex[:12]}"


def unique_keys() -> Keys:
    """The keys under a :func:`unique_prefix`."""
    return Keys(unique_prefix())
