"""Where a command will write, checked before it starts any work.

A bench or a comparison runs for minutes; an output path that cannot be written must stop it
at the start with the option named, not end it with a traceback after the measurements.
The checks create the missing folders (the command would create them anyway) and probe them
with a temporary file, which also catches what permission bits do not show (a read-only
mount, a pseudo-filesystem, a process running as root); a command that then refuses its input
removes the folders they created (``umay`` exits 2 having left nothing behind).
"""

from __future__ import annotations

import contextlib
import tempfile
from pathlib import Path

FIGURE_SUFFIXES = (".png", ".svg", ".pdf")


class OutputPathError(ValueError):
    """An output path that cannot be written; the message names the option and the reason."""


# Folders the checks created, outermost first: a command that then refuses other input removes
# them (remove_created_folders), so that bad input leaves nothing behind.
_created: list[Path] = []


def forget_created_folders() -> None:
    """A command starts: the folders earlier checks of this process created are its own."""
    _created.clear()


def remove_created_folders() -> None:
    """Remove the folders the checks created that are still empty, innermost first."""
    while _created:
        with contextlib.suppress(OSError):  # something was written there after all: kept
            _created.pop().rmdir()


def _unwritable(folder: Path) -> str | None:
    """Why files cannot be written into ``folder`` (created if missing), else None."""
    if folder.exists() and not folder.is_dir():
        return f"{folder} exists and is not a folder"
    try:
        missing = [f for f in (folder, *folder.parents) if not f.exists()]
        folder.mkdir(parents=True, exist_ok=True)
        _created.extend(reversed(missing))
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as exc:
        return f"cannot write into {folder} ({exc.strerror})"
    return None


def check_output_dir(option: str, path: str | Path) -> Path:
    """The folder ``path``, created if missing, into which files can be written; else
    :class:`OutputPathError`."""
    reason = _unwritable(Path(path))
    if reason:
        raise OutputPathError(f"{option} {path}: {reason}")
    return Path(path)


def check_output_file(option: str, path: str | Path, suffixes: tuple[str, ...] = ()) -> Path:
    """The file ``path``, whose folder is created if missing, that can be written (an existing
    file is replaced); ``suffixes``: the extensions allowed (for figures, the format)."""
    file = Path(path)
    if suffixes and file.suffix.lower() not in suffixes:
        raise OutputPathError(f"{option} {path}: expected a {' or '.join(suffixes)} file")
    if file.is_dir():
        raise OutputPathError(f"{option} {path}: is a folder, expected a file")
    reason = _unwritable(file.parent)
    if reason is None and file.exists():
        try:
            with file.open("ab"):  # opened for appending: its contents stay as they are
                pass
        except OSError as exc:
            reason = f"cannot be replaced ({exc.strerror})"
    if reason:
        raise OutputPathError(f"{option} {path}: {reason}")
    return file
