"""The processes ``umay bench`` measures: the machine's load, a process's CPU time and memory
from ``/proc/<pid>``, the services coming up, their stamps and their own counters."""

from __future__ import annotations

import os
import platform
import time
from pathlib import Path

import zenoh

from common.keys import Keys
from common.publishers import STAMPS_KEPT
from common.queries import alive_services
from deploy.bench import BenchError
from deploy.bench.report import KeyCounts, Machine, ServiceCounters, ServiceUsage
from deploy.bench.stages import PIPELINE
from deploy.bench.trace import Trace
from deploy.queries import query_stamps, query_status
from deploy.supervisor import Supervisor

# How often a long run collects the services' stamps while it runs, in frames (a stamp a frame
# per key): a quarter of the ``common.publishers.STAMPS_KEPT`` each key keeps, whatever the
# loop's rate (by the clock, 30 s was more than a fast lockstep loop's 4096 frames).
STAMPS_POLL_FRAMES = STAMPS_KEPT // 4
CLOCK_TICKS_PER_S = os.sysconf("SC_CLK_TCK")
REPO_ROOT = Path(__file__).resolve().parents[2]  # the checkout whose code a report measured


def machine_load() -> list[float]:
    """1, 5 and 15 minute load averages (what ``uptime`` shows)."""
    return [round(x, 2) for x in os.getloadavg()]


def process_cpu_s(pid: int) -> float | None:
    """User + system CPU seconds of a process (all its threads) so far."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / CLOCK_TICKS_PER_S  # utime, stime


def process_memory_mb(pid: int) -> dict[str, float]:
    """``VmHWM`` (peak resident set), ``VmRSS`` and ``RssShmem`` (shared memory pages, e.g.
    Zenoh's pool, counted in the RSS) in MiB."""
    out: dict[str, float] = {}
    try:
        lines = Path(f"/proc/{pid}/status").read_text().splitlines()
    except OSError:
        return out
    for line in lines:
        name, _, value = line.partition(":")
        if name in ("VmHWM", "VmRSS", "RssShmem"):
            out[name] = round(int(value.split()[0]) / 1024.0, 1)
    return out


def wait_for_services(
    session: zenoh.Session, keys: Keys, sup: Supervisor, names: tuple[str, ...], timeout_s: float
) -> None:
    """Until ``names`` answer; BenchError if one exits or they are not up in ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        dead = sup.exited()
        if dead:
            c = dead[0]
            raise BenchError(f"{c.name} exited ({c.exit_codes[-1]}); see {c.log_path}")
        if set(names) <= alive_services(session, keys, 0.5):
            return
        time.sleep(0.05)
    raise BenchError(f"services did not come up within {timeout_s:.0f} s: {names}")


def service_usage(
    pids: dict[str, int | None], cpu_start: dict[str, float | None], frames: int
) -> dict[str, ServiceUsage]:
    """Each process's CPU time so far and since ``cpu_start``, per frame of ``frames``, and
    its memory."""
    out: dict[str, ServiceUsage] = {}
    for name, pid in pids.items():
        if pid is None:
            continue
        cpu = process_cpu_s(pid)
        start = cpu_start.get(name)
        window_cpu = None if cpu is None or start is None else cpu - start
        mem = process_memory_mb(pid)
        out[name] = ServiceUsage(
            pid=pid,
            cpu_s=None if cpu is None else round(cpu, 3),
            window_cpu_s=None if window_cpu is None else round(window_cpu, 3),
            cpu_ms_per_frame=(
                None if window_cpu is None or frames <= 0 else round(1000 * window_cpu / frames, 2)
            ),
            peak_rss_mb=mem.get("VmHWM"),
            rss_mb=mem.get("VmRSS"),
            rss_shmem_mb=mem.get("RssShmem"),
        )
    return out


def collect_stamps(
    session: zenoh.Session, keys: Keys, trace: Trace, services: tuple[str, ...] = PIPELINE
) -> None:
    """Ask ``services`` for the stamps of what they published and add them to ``trace``.
    BenchError naming the first that does not answer."""
    for name in services:
        published = query_stamps(session, keys, name)
        if published is None:
            raise BenchError(f"{name} did not answer for its stamps ({keys.stamps(name)})")
        trace.add_stamps(published)


def status_counters(session: zenoh.Session, keys: Keys) -> dict[str, ServiceCounters]:
    """Each service's own counters: messages received/dropped, camera frames by reference,
    by copy and fetched whole, rejected."""
    return {
        st.service: ServiceCounters(
            received={
                keys.relative(k): KeyCounts(
                    count=v.count,
                    dropped=v.dropped,
                    by_ref=v.by_ref,
                    by_copy=v.by_copy,
                    fetched=v.fetched,
                )
                for k, v in st.received.items()
            },
            rejected=st.rejected,
            processing_ms_p50=st.processing_ms_p50,
            processing_ms_p99=st.processing_ms_p99,
        )
        for st in query_status(session, keys, 2.0)
    }


def code_version(repo: Path = REPO_ROOT) -> str | None:
    """The commit of the code measured (``git describe``), with ``-dirty`` when tracked files
    other than ``docs/`` and ``README.md`` have changes on top, so that a report says which code
    it measured (a run whose command writes its JSON into ``docs/``, or ``umay docs`` its tables
    between runs, does not mark the next one dirty); None outside a git checkout."""
    import subprocess

    def git(*args: str) -> str | None:
        try:
            proc = subprocess.run(
                ["git", *args],
                cwd=repo,
                capture_output=True,
                text=True,
                timeout=10,
            )
        except (OSError, subprocess.SubprocessError):
            return None
        return proc.stdout.strip() if proc.returncode == 0 else None

    commit = git("describe", "--always", "--abbrev=10")
    if not commit:
        return None
    generated = (":(exclude)docs", ":(exclude)README.md")  # what the bench and umay docs write
    changed = git("status", "--porcelain", "--untracked-files=no", "--", ".", *generated)
    return f"{commit}-dirty" if changed else commit


def cpu_model(cpuinfo: str | None = None) -> str | None:
    """The first CPU's model name, family and model (``/proc/cpuinfo``), e.g. "AMD EPYC
    (family 26, model 2)": hosts of one machine class (2 × x86_64, the same VM image) run the
    loop at different speeds, and a virtual machine's model name alone can be as short as that.
    None where the file or its fields are missing."""
    if cpuinfo is None:
        try:
            cpuinfo = Path("/proc/cpuinfo").read_text()
        except OSError:
            return None
    fields: dict[str, str] = {}
    for line in cpuinfo.split("\n\n", 1)[0].splitlines():
        key, sep, value = line.partition(":")
        if sep:
            fields.setdefault(key.strip(), value.strip())
    name = fields.get("model name")
    if not name:
        return None
    numbers = [
        f"{k} {fields[f]}" for k, f in (("family", "cpu family"), ("model", "model")) if f in fields
    ]
    return f"{name} ({', '.join(numbers)})" if numbers else name


def zenoh_version() -> str:
    """The installed Zenoh's version, for the report's machine."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("eclipse-zenoh")
    except PackageNotFoundError:
        return "unknown"


def this_machine(load_start: list[float], code: str | None) -> Machine:
    """This host as a report records it: CPUs, Python and Zenoh, the load when the measurement
    began (``load_start``) and now, and the ``code`` measured (:func:`code_version`)."""
    return Machine(
        host=platform.node(),
        cpus=os.cpu_count(),
        processor=platform.processor() or platform.machine(),
        cpu_model=cpu_model(),
        python=platform.python_version(),
        zenoh=zenoh_version(),
        load_start=load_start,
        load_end=machine_load(),
        code=code,
    )
