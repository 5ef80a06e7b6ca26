"""The generated blocks in the Markdown: finding them, rewriting them, checking them."""

from __future__ import annotations

import posixpath
import re
from dataclasses import dataclass
from pathlib import Path

from deploy.docs.blocks import BLOCKS
from deploy.docs.sources import DocsError, Inputs, load_inputs

BEGIN = re.compile(r"<!-- generated: ([a-z0-9-]+) -->")
END = "<!-- end generated -->"


# --- the documents ---------------------------------------------------------------------------
@dataclass(frozen=True)
class Marked:
    """A generated block in a document: its name, and where its body starts and ends."""

    name: str
    start: int  # just after the opening marker
    end: int  # at the closing marker


def find_blocks(text: str) -> list[Marked]:
    """Every generated block of ``text``, in order; raises :class:`DocsError` on an unknown
    name, an opening marker without its end, or an end without its opening."""
    out: list[Marked] = []
    pos = 0
    while True:
        m = BEGIN.search(text, pos)
        stray = text.find(END, pos)
        if m is None:
            if stray != -1:
                raise DocsError(f"line {text.count(chr(10), 0, stray) + 1}: {END} without a start")
            return out
        line = text.count("\n", 0, m.start()) + 1
        if stray != -1 and stray < m.start():
            raise DocsError(f"line {text.count(chr(10), 0, stray) + 1}: {END} without a start")
        name = m.group(1)
        if name not in BLOCKS:
            raise DocsError(f"line {line}: unknown block {name!r} (known: {', '.join(BLOCKS)})")
        end = text.find(END, m.end())
        nested = BEGIN.search(text, m.end())
        if end == -1 or (nested is not None and nested.start() < end):
            raise DocsError(f"line {line}: block {name!r} has no {END}")
        out.append(Marked(name, m.end(), end))
        pos = end + len(END)


def rewrite(text: str, inputs: Inputs, here: str) -> tuple[str, list[str]]:
    """``text`` with every generated block rendered afresh, and the names of those that
    changed."""
    parts, changed, pos = [], [], 0
    for b in find_blocks(text):
        body = "\n" + BLOCKS[b.name].render(inputs, here) + "\n"
        if text[b.start : b.end] != body:
            changed.append(b.name)
        parts += [text[pos : b.start], body]
        pos = b.end
    parts.append(text[pos:])
    return "".join(parts), changed


def documents(root: Path) -> list[Path]:
    """README.md and the Markdown files of docs/ (not the comparison's own summary.md)."""
    return [p for p in [root / "README.md", *sorted((root / "docs").glob("*.md"))] if p.is_file()]


@dataclass(frozen=True)
class Outdated:
    document: str  # relative to the root
    block: str

    def __str__(self) -> str:
        return (
            f"{self.document}: block {self.block!r} differs from {BLOCKS[self.block].sources} "
            "(run `umay docs`)"
        )


def update(root: Path, check: bool = False, inputs: Inputs | None = None) -> list[Outdated]:
    """Render every block of every document under ``root`` from ``inputs`` (read from
    ``root`` when None); write the documents unless ``check``. Returns the blocks that
    differed (rewritten, unless ``check``)."""
    inputs = load_inputs(root) if inputs is None else inputs
    out: list[Outdated] = []
    for path in documents(root):
        rel = path.relative_to(root).as_posix()
        text = path.read_text()
        try:
            new, changed = rewrite(text, inputs, posixpath.dirname(rel))
        except DocsError as exc:
            raise DocsError(f"{rel}: {exc}") from exc
        out += [Outdated(rel, name) for name in changed]
        if changed and not check:
            path.write_text(new)
    return out
