"""Whether a process exists, or has ended: for the supervisor (its children), a service (its
supervisor) and the frame rings (the writers of segments left behind)."""

from __future__ import annotations

import os
import select
import time


class ProcessEnd:
    """Whether process ``pid`` has ended: called, it answers at once or within ``timeout_s``.
    Through a pidfd where Linux has one (that very process, whoever it is a child of, even if
    its pid is later reused), else by whether the pid still exists."""

    def __init__(self, pid: int) -> None:
        self.pid = pid
        self._pidfd: int | None = None
        self._ended = False
        try:
            self._pidfd = os.pidfd_open(pid)
        except ProcessLookupError:
            self._ended = True
        except (AttributeError, OSError):  # no pidfd here: Python or kernel too old
            pass

    def __call__(self, timeout_s: float | None = 0.0) -> bool:
        """``timeout_s``: how long to wait for the end (None: until it comes)."""
        if not self._ended:
            if self._pidfd is not None:  # readable once the process has ended
                self._ended = bool(select.select([self._pidfd], [], [], timeout_s)[0])
            else:
                deadline = None if timeout_s is None else time.monotonic() + timeout_s
                while pid_exists(self.pid) and (deadline is None or time.monotonic() < deadline):
                    time.sleep(0.01)
                self._ended = not pid_exists(self.pid)
            if self._ended:
                self.close()
        return self._ended

    def close(self) -> None:
        if self._pidfd is not None:
            os.close(self._pidfd)
            self._pidfd = None


def pid_exists(pid: int) -> bool:
    """Whether a process of this pid exists (in this host's pid namespace)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process: it exists
        return True
    return True
