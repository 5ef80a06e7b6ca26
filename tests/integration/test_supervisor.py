"""Supervisor: restart policy, restarts after kill -9, clean shutdown, one per prefix."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import textwrap
import threading
import time
import uuid
from pathlib import Path

import pytest
from zenoh import SampleKind

from common.codec import DEFAULT_MAX_BYTES, encode
from common.config import SupervisorConfig
from common.keys import SERVICES, Keys
from common.messages import ServiceStatus, StatusFields
from common.node import MAX_REASON_CHARS, Node
from common.session import free_tcp_endpoint, open_session
from deploy.launch.status import collect
from deploy.service_process import exec_command
from deploy.supervisor import Supervisor
from tests.conftest import launch_umay_up, processes_mentioning
from tests.prefixes import unique_prefix


def stand_in(monkeypatch: pytest.MonkeyPatch, command: list[str]) -> None:
    """The supervisor starts ``command`` (its environment and log as a service's) instead of
    any service, forked or exec'd."""

    def start(_name: str, _args: list[str], env: dict[str, str], log_path: Path):
        return exec_command(command, env, log_path)

    monkeypatch.setattr("deploy.supervisor.fork_service", start)
    monkeypatch.setattr("deploy.supervisor.exec_service", start)


def test_tick_restarts_with_a_cap(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    cfg = SupervisorConfig(backoff_initial_s=0.0, max_restarts=2, restart_window_s=60.0)
    sup = Supervisor(None, "test/x", "tcp/127.0.0.1:1", tmp_path, services=("sim",), config=cfg)
    child = sup.children["sim"]
    stand_in(monkeypatch, [sys.executable, "-c", "import sys; sys.exit(3)"])
    sup.start()
    events: list[str] = []
    deadline = time.monotonic() + 20
    while not child.given_up and time.monotonic() < deadline:
        events += sup.tick()
        time.sleep(0.05)
    assert child.given_up and child.restarts == 2, events
    assert child.exit_codes == [3, 3, 3]
    assert any("giving up" in e for e in events)


def test_a_restart_that_cannot_start_a_process_is_a_death_the_others_outlive(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Vision dies, and its restart fails (its log folder is gone): a failed start counts as a
    death (exit 127) under the restart policy, until it gives up; the sim runs on."""
    cfg = SupervisorConfig(backoff_initial_s=0.0, max_restarts=2, restart_window_s=60.0)
    logs = tmp_path / "logs"
    sup = Supervisor(None, "test/x", "tcp/127.0.0.1:1", logs, services=("sim", "vision"),
                     config=cfg)  # fmt: skip
    stand_in(monkeypatch, [sys.executable, "-c", "import time; time.sleep(60)"])
    sup.start()
    try:
        for log_file in logs.iterdir():
            log_file.unlink()
        logs.rmdir()
        sup.children["vision"].process.kill()
        vision, events = sup.children["vision"], []
        deadline = time.monotonic() + 20
        while not vision.given_up and time.monotonic() < deadline:
            events += sup.tick()
            time.sleep(0.05)
        assert vision.given_up and vision.exit_codes == [-9, 127, 127], events
        assert any("vision could not be restarted" in e and "vision.log" in e for e in events)
        assert sup.children["sim"].process.poll() is None  # still running
    finally:
        sup.stop()


def test_the_frame_ring_of_a_child_killed_outright_is_removed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A sim killed by SIGKILL cannot unlink its shared-memory frame ring: the supervisor
    removes it when it sees the child gone."""
    sup = Supervisor(None, "test/x", "tcp/127.0.0.1:1", tmp_path, services=("sim",))
    child = sup.children["sim"]
    stand_in(monkeypatch, [sys.executable, "-c", textwrap.dedent("""
        import os, signal, numpy as np
        from common.frame_ring import RingWriter
        ring = RingWriter()
        ring.write(np.zeros(64, np.uint8), (8, 8), "uint8")
        print(ring.segment, flush=True)
        os.kill(os.getpid(), signal.SIGKILL)
        """)])  # fmt: skip
    sup.start()
    pid = child.process.pid
    deadline = time.monotonic() + 20
    while not sup.exited():
        assert time.monotonic() < deadline, "the child did not die"
        time.sleep(0.05)
    segment = (tmp_path / "sim.log").read_text().split()[-1]
    assert segment.startswith(f"umay-frames-{pid}-")
    assert not (Path("/dev/shm") / segment).exists()
    assert child.exit_codes == [-9]


def test_a_child_stuck_in_one_step_is_killed_and_its_run_says_why(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # A stand-in child (it sleeps) and a queryable answering for it, as a service whose event
    # loop is stuck in a handler would: alive, answering, loop_busy_s growing.
    session = open_session(connect=[], listen=[free_tcp_endpoint()])
    keys = Keys(f"test/{os.getpid()}stuck")
    cfg = SupervisorConfig(hang_timeout_s=1.0)
    sup = Supervisor(
        None, keys.prefix, "tcp/127.0.0.1:1", tmp_path, services=("vision",), config=cfg,
        session=session,
    )  # fmt: skip
    child = sup.children["vision"]
    stand_in(monkeypatch, [sys.executable, "-c", "import time; time.sleep(60)"])
    started = time.monotonic()

    def answer(query) -> None:
        busy = time.monotonic() - started
        status = ServiceStatus(
            service="vision", pid=child.process.pid, host="h", uptime_s=busy, state="running",
            loop_busy_s=busy,
        )  # fmt: skip
        query.reply(keys.status("vision"), encode(status))

    queryable = session.declare_queryable(keys.status("vision"), answer)
    try:
        sup.start()
        events: list[str] = []
        deadline = time.monotonic() + 20
        while not child.exit_codes and time.monotonic() < deadline:
            events += sup.check_hangs()
            sup.exited()
            time.sleep(0.05)
        assert child.exit_codes == [-signal.SIGKILL], events
        assert child.hang_kills == 1 and child.last_hang.startswith("event loop stuck"), events
        assert child.describe_exit().startswith("vision (exit -9, hung: event loop stuck in")
    finally:
        sup.stop()
        queryable.undeclare()
        session.close()


def test_loop_busy_s_is_zero_while_the_loop_waits_and_grows_while_it_works() -> None:
    session = open_session(connect=[], listen=[free_tcp_endpoint()])
    node = Node("vision", Keys(f"test/{os.getpid()}busy"), session)
    try:
        assert node.status().loop_busy_s is None  # the loop has not started
        node.next_event(0.0)
        time.sleep(0.3)  # "handling" an event
        assert 0.3 <= node.status().loop_busy_s < 5.0
        waiting = threading.Thread(target=node.next_event, args=(1.0,))
        waiting.start()
        time.sleep(0.2)
        assert node.status().loop_busy_s == 0.0  # blocked in next_event: idle, not stuck
        waiting.join()
        assert node.status().loop_busy_s < 0.2
    finally:
        node.close()


def test_a_node_waiting_before_its_loop_is_idle_and_its_rejections_are_clipped() -> None:
    """``wait_idle`` (the sim waiting for its peers) reads as a loop waiting, not one that
    never started; a rejection's reason, which quotes what the sender chose, stays short
    enough for the status to be read."""
    session = open_session(connect=[], listen=[free_tcp_endpoint()])
    node = Node("sim", Keys(f"test/{os.getpid()}idle"), session)
    try:
        assert node.status().loop_busy_s is None
        waiting = threading.Thread(target=node.wait_idle, args=(2.0,))
        waiting.start()
        assert wait_for(lambda: node.status().loop_busy_s == 0.0, 5.0)  # waiting, not stuck
        waiting.join()
        left = time.monotonic()
        busy = node.status().loop_busy_s
        assert busy is not None and busy <= time.monotonic() - left + 0.5  # started, and left
        node.reject("test/k", "x" * 70_000)
        status = node.status()
        assert len(status.last_rejection) == MAX_REASON_CHARS
        assert status.last_rejection.startswith("test/k: xxx") and status.last_rejection[-1] == "…"
        assert len(encode(status)) < DEFAULT_MAX_BYTES
    finally:
        node.close()


def test_a_starting_node_answers_without_the_fields_of_its_half_built_service() -> None:
    """The status is answered from the node's construction on, before the service object
    around it has all its attributes: until ready(), the answer leaves the service's own
    fields out instead of reporting their AttributeError as degraded (and never logging a
    later, real failure of them: that is logged once)."""
    session = open_session(connect=[], listen=[free_tcp_endpoint()])
    built: list[bool] = []

    def fields() -> StatusFields:
        if not built:
            raise AttributeError("'VisionService' object has no attribute 'states'")
        return StatusFields()

    node = Node("vision", Keys(f"test/{os.getpid()}starting"), session, fields)
    try:
        starting = node.status()
        assert (starting.state, starting.fields, starting.degraded_reason) == ("starting", {}, "")
        built.append(True)
        node.ready()
        assert node.status().state == "running"
    finally:
        node.close()


def wait_for(predicate, timeout_s: float, step_s: float = 0.05):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(step_s)
    return None


@pytest.fixture()
def umay_up(tmp_path: Path):
    proc, keys, endpoint = launch_umay_up(tmp_path / "logs", "lockstep")
    session = open_session(connect=[endpoint])
    yield proc, keys, session, endpoint
    if proc.poll() is None:
        proc.kill()
    session.close()


def test_kill_each_service_it_comes_back_and_the_hand_still_converges(umay_up) -> None:
    proc, keys, session, endpoint = umay_up

    def views():
        return {v.name: v for v in collect(session, keys, 0.3)}

    def all_running():
        v = views()
        ok = all(n in v and v[n].alive and v[n].status for n in (*SERVICES, "supervisor"))
        return v if ok else None

    v = wait_for(all_running, 60)
    assert v, f"services did not come up: {views()}"
    # Liveliness tokens tell exactly when a service is back (its token is declared once its
    # subscriptions are in place), without polling.
    tokens_up: dict[str, float] = {}

    def on_token(sample) -> None:
        if sample.kind == SampleKind.PUT:
            tokens_up[Keys.alive_service(str(sample.key_expr))] = time.monotonic()

    watcher = session.liveliness().declare_subscriber(keys.all_alive, on_token)
    latencies = {}
    for name in SERVICES:
        old_pid = views()[name].status.pid
        os.kill(old_pid, signal.SIGKILL)
        killed = time.monotonic()

        def back(name=name, old_pid=old_pid):
            s = views().get(name)
            return s is not None and s.alive and s.status and s.status.pid != old_pid

        assert wait_for(back, 20, 0.02), f"{name} did not come back"
        # The token's PUT and the answers saying it is back come by different paths: either
        # may be first.
        assert wait_for(lambda n=name, t=killed: tokens_up.get(n, 0.0) > t, 5, 0.02), (
            f"no new liveliness token for {name}"
        )
        latencies[name] = tokens_up[name] - killed
    watcher.undeclare()
    print(
        "restart latency (kill -9 → liveliness token back), s:",
        {k: round(t, 2) for k, t in latencies.items()},
    )
    sup_status = views()["supervisor"].status
    children = sup_status.fields["children"]
    assert all(children[n]["restarts"] == 1 for n in SERVICES), children
    # The default scenario leaves the host's power management alone, and says so.
    assert sup_status.fields["cpu_wakeup_latency"] == "not requested", sup_status.fields
    assert sup_status.fields["launch"] == "fork", sup_status.fields  # the default

    # A process that hangs without exiting (here frozen by SIGSTOP: it answers nothing) is
    # killed after supervisor.hang_timeout_s (5 s) and restarted like one that died. Frozen
    # once the supervisor has heard it: one it never heard is still starting for it, and is
    # judged only after supervisor.start_timeout_s (20 s).
    def heard_by_the_supervisor():
        s = views().get("supervisor")
        return s is not None and s.status and s.status.fields["children"]["vision"]["answered"]

    assert wait_for(heard_by_the_supervisor, 20, 0.1), "the supervisor never heard vision"
    frozen_pid = views()["vision"].status.pid
    os.kill(frozen_pid, signal.SIGSTOP)
    frozen = time.monotonic()

    def thawed():
        s = views().get("vision")
        return s is not None and s.alive and s.status and s.status.pid != frozen_pid

    assert wait_for(thawed, 30, 0.1), "a frozen vision was not replaced"
    print(f"frozen vision replaced after {time.monotonic() - frozen:.1f} s")
    vision = views()["supervisor"].status.fields["children"]["vision"]
    assert vision["hang_kills"] == 1 and vision["restarts"] == 2, vision
    assert vision["last_hang"].startswith("no status answer for "), vision
    assert vision["last_exit_codes"][-1] == -signal.SIGKILL, vision

    def converged():
        c = views().get("controller")
        return c is not None and c.status and c.status.fields.get("converged")

    assert wait_for(converged, 240, 0.5), "the hand did not reach the target after the restarts"

    # A second supervisor on the same prefix refuses to start.
    second = subprocess.run(
        [
            sys.executable,
            "-m",
            "deploy",
            "up",
            "--prefix",
            keys.prefix,
            "--listen",
            free_tcp_endpoint(),
            "--connect",
            umay_up[3],
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert second.returncode == 3 and "already running" in second.stderr

    running = wait_for(all_running, 20)  # a status query may time out on a loaded machine
    assert running, f"services not all answering: {views()}"
    pids = [running[n].status.pid for n in SERVICES]
    proc.send_signal(signal.SIGINT)
    stopped = time.monotonic()
    proc.wait(10)
    gone = wait_for(lambda: not any(_alive(p) for p in pids), 5)
    elapsed = time.monotonic() - stopped
    print(f"all services gone {elapsed:.2f} s after SIGINT")
    assert gone and elapsed < 3.0
    # Its last word says so, with each service's exit code: all stopped cleanly by SIGTERM.
    last = proc.stdout.read().strip().splitlines()[-1]
    assert last == (
        "umay up: services stopped (exit codes: sim 0, vision 0, controller 0, actuation 0)"
    ), last
    # Nothing left listening on the supervisor's port (bind fails while a listener holds it).
    host, port = endpoint.removeprefix("tcp/").rsplit(":", 1)
    with socket.socket() as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.bind((host, int(port)))


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # A zombie is gone for our purpose (its parent has not reaped it yet).
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def _umay_run_until_services_run(tmp_path: Path, *more: str) -> tuple[subprocess.Popen, list[int]]:
    """``umay run`` on a unique prefix, once its four services run. The run must still be
    going seconds later on any host: in real time, at a fifth of the default gain, it takes
    tens of seconds to converge (lockstep at the default gain converges in about 2 s of wall
    time on a fast host)."""
    prefix = f"test/{os.urandom(6).hex()}"
    options = ["--prefix", prefix, "--listen", free_tcp_endpoint(), "--log-dir", str(tmp_path),
               "--clock", "realtime", "--set", "controller.gain=0.2"]  # fmt: skip
    proc = subprocess.Popen(
        [sys.executable, "-m", "deploy", "run", "--timeout", "600", *options, *more],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )

    def services() -> list[int]:  # the run's children: every process on the prefix but it
        return [pid for pid in processes_mentioning(prefix) if pid != proc.pid]

    if not wait_for(lambda: len(services()) == len(SERVICES), 60):
        proc.kill()
        _, stderr = proc.communicate(timeout=30)
        pytest.fail(f"the services never all ran: {services()}; {stderr}")
    time.sleep(2.0)  # past start-up: sessions open, signal handlers in place
    assert proc.poll() is None and len(services()) == len(SERVICES)
    return proc, services()


def test_sigterm_ends_umay_run_and_its_services(tmp_path: Path) -> None:
    """A CI timeout or `kill` stops a run as Ctrl-C does: nothing is left running, and the
    run so far is reported and kept (result JSON, detail "interrupted"). Its live line, going
    to a pipe here (a CI log), ends before the message that says so."""
    result = tmp_path / "result.json"
    proc, pids = _umay_run_until_services_run(tmp_path, "--result", str(result))
    proc.send_signal(signal.SIGTERM)
    stdout, stderr = proc.communicate(timeout=30)
    assert proc.returncode == 130, stderr
    assert "\numay run: interrupted; what it started is stopped\n" in stderr, stderr
    assert not any(_alive(p) for p in pids)  # stopped before umay run returned
    assert "error (interrupted)" in stdout
    kept = json.loads(result.read_text())
    assert kept["detail"] == "interrupted" and not kept["converged"]


def test_sigterm_to_the_whole_process_group_stops_umay_up_with_clean_exit_codes(
    tmp_path: Path,
) -> None:
    """`timeout`, `kill -- -PGID` or a cancelled CI job signal a whole process group: the
    services stop cleanly, and umay up still reports each one's exit code. It takes them from
    the forkserver, which blocks SIGTERM (deploy/forkserver_guard.py): killed with them, it
    left every code unknown (255, as if they had crashed)."""
    prefix = f"test/{os.urandom(6).hex()}"
    endpoint = free_tcp_endpoint()
    proc = subprocess.Popen(
        [sys.executable, "-m", "deploy", "up", "--prefix", prefix, "--listen", endpoint,
         "--connect", endpoint, "--log-dir", str(tmp_path), "--clock", "realtime"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        start_new_session=True,  # its own process group, as under `timeout`
    )  # fmt: skip

    def services() -> list[int]:
        return [pid for pid in processes_mentioning(prefix) if pid != proc.pid]

    try:
        assert wait_for(lambda: len(services()) == len(SERVICES), 60), services()
        time.sleep(2.0)  # past start-up: sessions open, signal handlers in place
        pids = services()
        os.killpg(proc.pid, signal.SIGTERM)
        output, _ = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert output.strip().splitlines()[-1] == (
        "umay up: services stopped (exit codes: sim 0, vision 0, controller 0, actuation 0)"
    ), output
    assert not any(_alive(p) for p in pids)


@pytest.mark.parametrize("launch", ["fork", "exec"])
def test_services_stop_when_their_supervisor_is_killed(tmp_path: Path, launch: str) -> None:
    """SIGKILL (or the OOM killer) gives the supervisor no chance to stop its children: they
    notice it has ended and stop themselves, forked (the forkserver's children) or exec'd."""
    proc, pids = _umay_run_until_services_run(
        tmp_path, "--quiet", "--set", f"supervisor.launch='{launch}'"
    )
    proc.kill()
    proc.communicate(timeout=30)
    killed = time.monotonic()
    gone = wait_for(lambda: not any(_alive(p) for p in pids), 15)
    print(f"services gone {time.monotonic() - killed:.2f} s after their supervisor's SIGKILL")
    assert gone, [p for p in pids if _alive(p)]
    assert "supervisor" in (tmp_path / "vision.log").read_text()


def test_umay_up_that_fails_before_supervising_ends_and_closes_its_session(
    tmp_path: Path,
) -> None:
    """run_up failing after its supervisor node exists, before it supervises (here: the
    signal relay made to raise): the error comes out and the process ends, its session
    closed (left open, with the node holding it, its Zenoh threads kept the process alive)."""
    code = (
        "from pathlib import Path\n"
        "import deploy.launch.up as up\n"
        "from common.config import load_scenario\n"
        "def refuse(*args, **kwargs):\n"
        "    raise RuntimeError('no signal relay')\n"
        "up.SignalRelay = refuse\n"
        f"up.run_up(None, load_scenario(), [], 'test/{uuid.uuid4().hex[:12]}', "
        f"'{free_tcp_endpoint()}', [], Path({str(tmp_path)!r}))\n"
    )
    ends_with_error(code, "RuntimeError: no signal relay")


def ends_with_error(code: str, error: str) -> None:
    """``code``, run by a fresh Python, ends (exit 1; no hang) with ``error`` on stderr."""
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 1, proc.stderr[-2000:]
    assert error in proc.stderr


def test_a_run_whose_services_cannot_start_ends_and_closes_its_session(tmp_path: Path) -> None:
    """run_once called directly (no CLI check first) with a log folder that cannot be made:
    the error comes out and the process ends. It used to hang at exit, its Zenoh session
    left open because the supervisor failed before the try that closes it."""
    (tmp_path / "file").write_text("x")
    prefix = unique_prefix()  # another suite's run of this test: not this one
    code = (
        "from pathlib import Path\n"
        "from common.config import load_scenario\n"
        "from deploy.launch.run import run_once\n"
        f"run_once(None, load_scenario(), [], '{prefix}', "
        f"Path({str(tmp_path / 'file' / 'logs')!r}), listen='{free_tcp_endpoint()}', quiet=True)\n"
    )
    ends_with_error(code, "NotADirectoryError")
    assert not processes_mentioning(prefix)


def test_ctrl_c_ends_an_in_process_run_reported_so_far(tmp_path: Path) -> None:
    """`umay run --inprocess` as `umay run`: Ctrl-C ends it at the next frame with exit 130,
    the run so far reported and kept (it used to end with a KeyboardInterrupt, no result)."""
    result = tmp_path / "result.json"
    proc = subprocess.Popen(
        [sys.executable, "-m", "deploy", "run", "--inprocess", "--quiet", "--timeout", "600",
         "--set", "controller.gain=0.05", "--result", str(result)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    time.sleep(4.0)  # past its imports and first frames
    assert proc.poll() is None
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130, stderr
    assert stderr.endswith("umay run: interrupted\n"), stderr
    kept = json.loads(result.read_text())
    assert kept["detail"] == "interrupted" and kept["frames"] > 0 and not kept["converged"]
    assert "error (interrupted)" in stdout
