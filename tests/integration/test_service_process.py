"""A service forked from the supervisor's forkserver behaves as one exec'd: its arguments,
environment, log, exit code, command line, and a clean stop. The simulator prints nothing of
pybullet's on import."""

from __future__ import annotations

import multiprocessing
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from common.config import SupervisorConfig
from common.keys import Keys
from common.session import free_tcp_endpoint, open_session
from deploy.launch.status import collect
from deploy.service_process import ForkedService, ForkUnavailable
from deploy.supervisor import Supervisor


def wait_exit(sup: Supervisor, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while not sup.exited():
        assert time.monotonic() < deadline, "the service did not exit"
        time.sleep(0.02)


@pytest.mark.parametrize("launch", ["fork", "exec"])
def test_a_bad_override_ends_the_service_with_exit_2_and_says_why_in_its_log(
    tmp_path: Path, launch: str
) -> None:
    sup = Supervisor(
        None, f"test/{os.getpid()}bad{launch}", "tcp/127.0.0.1:1", tmp_path,
        overrides=["controller.gain=-1"], services=("controller",),
        config=SupervisorConfig(launch=launch),
    )  # fmt: skip
    sup.start()
    wait_exit(sup, 30)
    assert sup.children["controller"].exit_codes == [2]
    assert "controller.gain" in (tmp_path / "controller.log").read_text()


def test_a_forked_service_has_its_arguments_environment_and_command_line(tmp_path: Path) -> None:
    endpoint = free_tcp_endpoint()
    session = open_session(connect=[], listen=[endpoint])
    keys = Keys(f"test/{os.getpid()}forked")
    sup = Supervisor(
        None, keys.prefix, endpoint, tmp_path, services=("actuation",),
        config=SupervisorConfig(launch="fork"),
    )  # fmt: skip
    try:
        sup.start()
        pid = sup.pids()["actuation"]
        # It answers under its prefix (--prefix), through the endpoint it was given in its
        # environment (UMAY_ZENOH_CONNECT): it has both.
        deadline = time.monotonic() + 30
        views = []
        while time.monotonic() < deadline:
            views = [v for v in collect(session, keys, 0.3) if v.status is not None]
            if views:
                break
        assert [v.status.pid for v in views] == [pid], views
        cmdline = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
        assert f"-m services.actuation --prefix {keys.prefix}" in cmdline
        assert Path(f"/proc/{pid}/comm").read_text().strip() == "umay-actuation"
        parent = int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])
        assert parent != os.getpid()  # the forkserver's child, not this process's
        sup.stop()
        assert sup.children["actuation"].exit_codes == [0]  # SIGTERM: a clean stop
        assert "actuation running under" in (tmp_path / "actuation.log").read_text()
    finally:
        sup.stop()
        session.close()


def test_a_forked_service_stopped_as_it_starts_ends_at_once(tmp_path: Path) -> None:
    """The forkserver blocks SIGTERM (deploy/forkserver_guard.py) and a forked service inherits
    the block until it unblocks it first thing: a SIGTERM sent before then is held and
    delivered, never lost. Ignored instead, it was dropped, and each stop right after a
    (re)start waited out the grace time and ended in SIGKILL."""
    sup = Supervisor(
        None, f"test/{os.getpid()}early", "tcp/127.0.0.1:1", tmp_path, services=("controller",),
        config=SupervisorConfig(launch="fork"),
    )  # fmt: skip
    for _ in range(3):
        sup.start()
        sup.stop(grace_s=10.0)  # SIGTERM at once
        # Killed by the held signal (-15), or stopped by its handler (0); not SIGKILLed (-9).
        assert sup.children["controller"].exit_codes[-1] in (0, -signal.SIGTERM)


SERVICE_CLASSES = {
    "sim": "SimService",
    "vision": "VisionService",
    "controller": "ControllerService",
    "actuation": "ActuationService",
}


@pytest.mark.parametrize("name", SERVICE_CLASSES)
def test_a_service_that_fails_after_its_node_exists_exits_instead_of_hanging(name: str) -> None:
    """Its session is closed however it ends (ServiceContext as a context manager): left
    open, Zenoh's callback threads (not daemons) held the process after the exception, and
    it neither exited nor answered SIGTERM, so its supervisor never restarted it."""
    code = textwrap.dedent(f"""
        import services.{name}.node as node
        def fail(self):
            raise RuntimeError("failed after the node was made")
        node.{SERVICE_CLASSES[name]}.run = fail
        node.main(["--prefix", "test/{os.getpid()}fails", "--connect", "{free_tcp_endpoint()}"])
        """)  # fmt: skip
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=30)
    assert proc.returncode == 1, proc.stderr[-2000:]
    assert "RuntimeError: failed after the node was made" in proc.stderr


def test_where_no_forkserver_starts_the_services_are_execd_and_status_says_why(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def refused(*_args: object) -> None:
        raise ForkUnavailable("PermissionError: Unix sockets not allowed here")

    monkeypatch.setattr("deploy.supervisor.fork_service", refused)
    sup = Supervisor(
        None, f"test/{os.getpid()}refused", "tcp/127.0.0.1:1", tmp_path,
        overrides=["controller.gain=-1"], services=("controller",),
    )  # fmt: skip
    assert sup.launch == "fork"
    sup.start()
    wait_exit(sup, 30)
    assert sup.children["controller"].exit_codes == [2]  # exec'd: it ran, and said why it ended
    assert "controller.gain" in (tmp_path / "controller.log").read_text()
    assert sup.launch == "exec (fork refused: PermissionError: Unix sockets not allowed here)"


def _supervise_here(log_dir: str, results: multiprocessing.Queue) -> None:
    """In a child process: a controller with a bad override, and how it was started."""
    sup = Supervisor(
        None, f"test/{os.getpid()}daemon", "tcp/127.0.0.1:1", Path(log_dir),
        overrides=["controller.gain=-1"], services=("controller",),
    )  # fmt: skip
    sup.start()
    wait_exit(sup, 30)
    results.put((sup.launch, sup.children["controller"].exit_codes))


def test_a_supervisor_in_a_daemonic_worker_execs_its_services(tmp_path: Path) -> None:
    """A Dask worker is a daemonic process, which multiprocessing lets start no children of
    its own: a distributed run there (umay domains --cluster) execs its services."""
    context = multiprocessing.get_context("spawn")  # a fresh interpreter, as a Dask worker
    results = context.Queue()
    worker = context.Process(target=_supervise_here, args=(str(tmp_path), results), daemon=True)
    worker.start()
    launch, exit_codes = results.get(timeout=60)
    worker.join(30)
    assert launch == "exec (fork refused: this process is a daemonic worker (a Dask worker, say))"
    assert exit_codes == [2]
    assert "controller.gain" in (tmp_path / "controller.log").read_text()


def test_a_supervisor_forked_from_one_that_forked_services_execs_them(tmp_path: Path) -> None:
    """multiprocessing's forkserver belongs to the process that started it: a process forked
    from that one (a pool's worker, say) cannot use it, and execs its services."""
    sup = Supervisor(
        None, f"test/{os.getpid()}first", "tcp/127.0.0.1:1", tmp_path / "first",
        overrides=["controller.gain=-1"], services=("controller",),
    )  # fmt: skip
    sup.start()  # this process now has a forkserver
    wait_exit(sup, 30)
    assert sup.launch == "fork"
    context = multiprocessing.get_context("fork")
    results = context.Queue()
    worker = context.Process(target=_supervise_here, args=(str(tmp_path), results))
    worker.start()
    launch, exit_codes = results.get(timeout=60)
    worker.join(30)
    assert launch == "exec (fork refused: forked from a process whose forkserver it cannot use)"
    assert exit_codes == [2]


def _answering_pids(session, keys: Keys) -> list[int]:
    return [v.status.pid for v in collect(session, keys, 0.3) if v.status is not None]


def test_a_killed_forkserver_neither_ends_nor_doubles_its_services(tmp_path: Path) -> None:
    """The forkserver killed alone: multiprocessing reports its children ended (255), but the
    service still runs, so it is not started a second time; when it does end, a new
    forkserver forks its successor."""
    endpoint = free_tcp_endpoint()
    session = open_session(connect=[], listen=[endpoint])
    keys = Keys(f"test/{os.getpid()}fsk")
    sup = Supervisor(
        None, keys.prefix, endpoint, tmp_path, services=("actuation",),
        config=SupervisorConfig(launch="fork", backoff_initial_s=0.0),
    )  # fmt: skip
    try:
        sup.start()
        pid = sup.pids()["actuation"]
        deadline = time.monotonic() + 30
        while _answering_pids(session, keys) != [pid]:
            assert time.monotonic() < deadline, "the service never answered"
        forkserver = int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])
        os.kill(forkserver, signal.SIGKILL)
        time.sleep(1.0)
        assert sup.tick() == [] and sup.pids()["actuation"] == pid  # still its one service
        assert _answering_pids(session, keys) == [pid]
        os.kill(pid, signal.SIGKILL)
        deadline = time.monotonic() + 30
        events: list[str] = []
        while sup.pids()["actuation"] in (pid, None):
            assert time.monotonic() < deadline, events
            events += sup.tick()
            time.sleep(0.05)
        successor = sup.pids()["actuation"]
        assert sup.children["actuation"].exit_codes == [ForkedService.UNKNOWN_EXIT], events
        deadline = time.monotonic() + 30
        while _answering_pids(session, keys) != [successor]:
            assert time.monotonic() < deadline, "the successor never answered"
        assert sup.launch == "fork"
    finally:
        sup.stop()
        session.close()


FORKSERVER_SIGNALLED_AT_BIRTH = """
import os, signal, sys, time
from multiprocessing import util
from pathlib import Path

from deploy.service_process import fork_service

spawn = util.spawnv_passfds


def spawn_then_signal(path, args, passfds):
    pid = spawn(path, args, passfds)
    if any("forkserver" in str(a) for a in args):  # a Ctrl-C to the group as it starts
        os.kill(pid, signal.SIGINT)
        os.kill(pid, signal.SIGTERM)
    return pid


if __name__ == "__main__":
    util.spawnv_passfds = spawn_then_signal
    service = fork_service("controller", sys.argv[2:], dict(os.environ), Path(sys.argv[1]))
    while service.returncode is None:
        time.sleep(0.02)
    print("exit", service.returncode)
"""


def test_a_forkserver_signalled_as_it_starts_still_forks_the_service(tmp_path: Path) -> None:
    """Ctrl-C or SIGTERM to the process group in the moment the first service is forked (the
    forkserver's interpreter starting, then its imports) ended the forkserver, and the run
    with an EOFError: it starts with both signals blocked and keeps them so."""
    script = tmp_path / "signalled.py"
    script.write_text(FORKSERVER_SIGNALLED_AT_BIRTH)
    log = tmp_path / "controller.log"
    done = subprocess.run(
        [sys.executable, str(script), str(log), "--set", "controller.gain=-1"],
        capture_output=True, text=True, timeout=120, cwd=Path(__file__).resolve().parents[2],
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "exit 2", done.stderr  # the service ran: its bad override
    assert "controller.gain" in log.read_text()


def test_importing_the_simulator_prints_no_pybullet_banner() -> None:
    """pybullet's "build time" line (on standard error) is not the first line of every sim
    log and of ``umay run``'s output (services.sim.bullet)."""
    code = "import services.sim.world, pybullet; print('imported', pybullet.DIRECT == 2)"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert (proc.stdout, proc.stderr) == ("imported True\n", "")
