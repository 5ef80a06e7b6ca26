"""A CPU wake-up latency request (Linux PM QoS), held while the services run.

Each of the loop's hops wakes a thread in another process. On an idle CPU that wake-up costs
what leaving its idle state costs: on a virtual machine whose idle vCPUs halt at once
(``haltpoll`` with ``guest_halt_poll_ns=0``), a trip through the hypervisor, after which the
woken code also finds its caches cold. Writing a latency bound to ``/dev/cpu_dma_latency``
and keeping the file open asks the kernel to use no idle state slower to leave than that
bound, on every CPU, until the file is closed (the kernel's "PM QoS interface"; ``cyclictest``
and tuned's ``latency-performance`` profile make the same request). A bound of 0 µs makes idle
CPUs poll instead of halting: the fastest wake-up, and a core that stays busy while idle.

The request needs write access to the device (root, as a rule). Where it cannot be made the
run goes on without it and :attr:`CpuWakeupLatency.state` says why.
"""

from __future__ import annotations

import logging
import os
import struct
from pathlib import Path

log = logging.getLogger("umay.supervisor")

PM_QOS_DEVICE = Path("/dev/cpu_dma_latency")


class CpuWakeupLatency:
    """The request for ``latency_us`` (None: none, the host's power management untouched),
    made at construction and withdrawn by :meth:`release` (or when the process ends)."""

    def __init__(self, latency_us: int | None, device: Path | None = None) -> None:
        self.latency_us = latency_us
        self.device = device or PM_QOS_DEVICE
        self._fd: int | None = None
        self.state = "not requested"
        if latency_us is None:
            return
        try:
            fd = os.open(self.device, os.O_WRONLY)
        except OSError as exc:
            self.state = f"refused: {self.device}: {exc.strerror or exc} (needs write access)"
            log.warning("CPU wake-up latency request of %d µs %s", latency_us, self.state)
            return
        try:
            os.write(fd, struct.pack("i", latency_us))  # the kernel's s32, in µs
        except OSError as exc:
            os.close(fd)
            self.state = f"refused: writing {self.device}: {exc.strerror or exc}"
            log.warning("CPU wake-up latency request of %d µs %s", latency_us, self.state)
            return
        self._fd = fd
        self.state = f"held: {latency_us} µs"
        log.info("CPU wake-up latency of %d µs requested through %s", latency_us, self.device)

    @property
    def held(self) -> bool:
        return self._fd is not None

    def release(self) -> None:
        """Withdraw the request (closing the file is what withdraws it); idempotent."""
        if self._fd is None:
            return
        os.close(self._fd)
        self._fd = None
        self.state = f"released: {self.latency_us} µs"
