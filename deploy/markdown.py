"""Markdown for the reports and documents the commands write: tables, cells, links."""

from __future__ import annotations

import posixpath
from collections.abc import Sequence


def markdown_table(
    headers: Sequence[str], rows: Sequence[Sequence[str]], right_from: int = 1
) -> str:
    """A pipe table; the columns from ``right_from`` on right-aligned (figures)."""
    align = ["---" if i < right_from else "---:" for i in range(len(headers))]
    lines = ["| " + " | ".join(headers) + " |", "| " + " | ".join(align) + " |"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def format_cell(value: float | None, scale: float = 1.0, fmt: str = ".3f") -> str:
    """``value`` times ``scale`` in ``fmt``; a dash for none."""
    return "–" if value is None else format(value * scale, fmt)


def link(here: str, path: str) -> str:
    """``path`` (relative to the repository) as seen from the folder ``here`` (same)."""
    return posixpath.relpath(path, here or ".")
