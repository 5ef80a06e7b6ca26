"""How the supervisor starts one service's OS process: ``exec`` or ``fork``.

``exec`` runs ``python -m services.NAME`` afresh. Each such process imports numpy, pydantic,
Zenoh and the project's modules before its first frame, and in a suite of short runs that
import is about half of all the CPU spent: four processes a run, each importing the same.

``fork`` starts the service as a fork of Python's forkserver (``multiprocessing``, standard
library), which imported the four services' modules once for every later service of this
supervising process: still a separate OS process with its own pid, environment, arguments and
log file, that the supervisor signals, waits for and restarts as it does an exec'd one. The
forkserver has no Zenoh session, no pybullet connection and no OpenGL context to share: each
service opens its own after the fork, as after an exec.

Both give a :class:`ServiceProcess`, the part of ``subprocess.Popen`` the supervisor uses.
"""

from __future__ import annotations

import contextlib
import importlib
import multiprocessing
import multiprocessing.resource_tracker
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Protocol

import setproctitle

from common.keys import SERVICES
from common.processes import ProcessEnd

# What the forkserver imports before its first fork: every service's node and what it imports.
# "__main__": the launching program's main module (a script, such as the ``umay`` entry point),
# which multiprocessing imports in every process it starts, is then imported once, here.
# First, what only the forkserver imports: it keeps SIGTERM and SIGINT blocked
# (deploy/forkserver_guard.py).
PRELOAD = [
    "deploy.forkserver_guard",
    "__main__",
    *(f"services.{name}.node" for name in SERVICES),
    __name__,
]


class ServiceProcess(Protocol):
    """What the supervisor does with a child: ``subprocess.Popen``'s names and meanings."""

    pid: int

    @property
    def returncode(self) -> int | None: ...

    def poll(self) -> int | None: ...

    def wait(self, timeout: float | None = None) -> int: ...

    def send_signal(self, sig: int) -> None: ...

    def kill(self) -> None: ...


def exec_command(command: list[str], env: dict[str, str], log_path: Path) -> ServiceProcess:
    """``command`` with ``env``, its output appended to ``log_path``."""
    with log_path.open("ab") as out:
        return subprocess.Popen(command, stdout=out, stderr=subprocess.STDOUT, env=env)


def service_command(name: str, argv: list[str]) -> list[str]:
    """``python -m services.NAME ARGV``: what is exec'd, and what a forked one shows in ps."""
    return [sys.executable, "-m", f"services.{name}", *argv]


def exec_service(name: str, argv: list[str], env: dict[str, str], log_path: Path) -> ServiceProcess:
    """:func:`service_command`, its output appended to ``log_path``."""
    return exec_command(service_command(name, argv), env, log_path)


class ForkedService:
    """A service forked by the forkserver, seen through ``Popen``'s methods. Its exit code
    comes from the forkserver, whose child it is; whether it has ended, from the process
    itself: a forkserver killed alone reports its children ended (255), and the supervisor
    would start a second set beside the first, which still runs."""

    UNKNOWN_EXIT = 255  # what multiprocessing reports when the forkserver is gone

    def __init__(self, process: multiprocessing.process.BaseProcess, name: str) -> None:
        self._process = process
        self._name = name
        self.pid: int = process.pid  # type: ignore[assignment]  # set once started
        self._ended = ProcessEnd(self.pid)

    @property
    def returncode(self) -> int | None:
        return self.poll()

    def poll(self) -> int | None:
        code = self._process.exitcode
        if code is None or not self._ended():
            return None
        return code

    def wait(self, timeout: float | None = None) -> int:
        deadline = None if timeout is None else time.monotonic() + timeout
        self._process.join(timeout)  # at its exit, or at once if the forkserver is gone
        left = None if deadline is None else max(0.0, deadline - time.monotonic())
        if not self._ended(left):
            raise subprocess.TimeoutExpired(f"services.{self._name}", timeout or 0.0)
        self._process.join(1.0)  # ended: the forkserver's report of its code is on its way
        code = self._process.exitcode
        return self.UNKNOWN_EXIT if code is None else code

    def send_signal(self, sig: int) -> None:
        if not self._ended():
            with contextlib.suppress(ProcessLookupError):
                os.kill(self.pid, sig)

    def kill(self) -> None:
        self.send_signal(signal.SIGKILL)


def _forkserver() -> multiprocessing.context.BaseContext:
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload(PRELOAD)  # no effect once it runs: it has them already
    return context


class ForkUnavailable(RuntimeError):
    """The forkserver cannot start a service from this process; the message says why."""


def fork_service(name: str, argv: list[str], env: dict[str, str], log_path: Path) -> ServiceProcess:
    """The service as a fork of the forkserver (started, with its imports, at the first call).
    :class:`ForkUnavailable` where it cannot be: nothing is started then."""
    if multiprocessing.current_process().daemon:  # multiprocessing lets it start no children
        raise ForkUnavailable("this process is a daemonic worker (a Dask worker, say)")
    process = _forkserver().Process(
        target=serve, args=(name, argv, env, str(log_path)), name=f"umay-{name}"
    )
    # Blocked in this thread while it starts: a forkserver started now (the first call)
    # inherits the mask through its exec, so a Ctrl-C or SIGTERM to the process group during
    # its interpreter's start and imports (the main script's, then the preload's) is held, not
    # fatal (deploy/forkserver_guard.py keeps it so); here it is delivered when the mask is put
    # back.
    # The resource tracker first: starting it unblocks both signals again in this thread.
    multiprocessing.resource_tracker.ensure_running()
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})
    try:
        process.start()
    except ChildProcessError as exc:  # multiprocessing looks for its parent's forkserver
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)
        raise ForkUnavailable("forked from a process whose forkserver it cannot use") from exc
    except OSError as exc:  # no forkserver here (a sandbox without Unix sockets...)
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)
        raise ForkUnavailable(f"{type(exc).__name__}: {exc}") from exc
    except BaseException:
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)
        raise
    service = ForkedService(process, name)
    try:
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)  # a signal held meanwhile comes now
    except BaseException:
        # Forked after the signal reached the group, the service did not get it, and its
        # supervisor will not hear of it: it is stopped here.
        service.send_signal(signal.SIGTERM)
        raise
    return service


def serve(name: str, argv: list[str], env: dict[str, str], log_path: str) -> None:
    """In the forked child: take the service's environment, output and name, then run it as
    ``python -m services.NAME`` would."""
    # The forkserver blocks SIGTERM and SIGINT (deploy/forkserver_guard.py): one already sent
    # comes now.
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGTERM, signal.SIGINT})
    # ps, top and /proc show the command line an exec'd service would have, not the
    # forkserver's. Before the environment is replaced: the title takes the room of the
    # original environment's strings, and finds none to take once they were moved.
    setproctitle.setproctitle(" ".join(service_command(name, argv)))
    setproctitle.setthreadtitle(f"umay-{name}")
    os.environ.clear()
    os.environ.update(env)
    fd = os.open(log_path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    os.dup2(fd, 1)
    os.dup2(fd, 2)
    os.close(fd)
    sys.stdout = open(1, "w", buffering=1, closefd=False)  # noqa: SIM115 - the process's own
    sys.stderr = open(2, "w", buffering=1, closefd=False)  # noqa: SIM115
    node = importlib.import_module(f"services.{name}.node")
    raise SystemExit(node.main(argv))
