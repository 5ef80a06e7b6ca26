"""The supervisor's CPU wake-up latency request (PM QoS): made, refused with a reason, withdrawn.

A plain file stands in for ``/dev/cpu_dma_latency``: what is checked is what the request writes
and when it holds the file, not the kernel's answer to it."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest
from pydantic import ValidationError

import deploy.cpu_latency as cpu_latency
from common.config import SupervisorConfig
from deploy.cpu_latency import CpuWakeupLatency
from deploy.supervisor import Supervisor


def test_no_request_leaves_the_device_alone(tmp_path: Path) -> None:
    device = tmp_path / "cpu_dma_latency"
    request = CpuWakeupLatency(None, device)
    assert request.state == "not requested" and not request.held
    assert not device.exists()
    request.release()  # nothing to withdraw
    assert request.state == "not requested"


def test_a_request_writes_the_bound_as_the_kernels_s32_and_holds_it_until_released(
    tmp_path: Path,
) -> None:
    device = tmp_path / "cpu_dma_latency"
    device.write_bytes(b"")
    request = CpuWakeupLatency(20, device)
    assert request.held and request.state == "held: 20 µs"
    assert device.read_bytes() == struct.pack("i", 20)
    request.release()
    request.release()  # a second release changes nothing
    assert not request.held and request.state == "released: 20 µs"


@pytest.mark.parametrize("make", ["absent", "directory"])
def test_a_request_the_host_refuses_says_why_and_holds_nothing(tmp_path: Path, make: str) -> None:
    device = tmp_path / "cpu_dma_latency"
    if make == "directory":
        device.mkdir()
    request = CpuWakeupLatency(0, device)
    assert not request.held
    assert request.state.startswith(f"refused: {device}: "), request.state
    assert request.state.endswith("(needs write access)"), request.state


def test_the_supervisor_holds_the_scenarios_request_from_start_to_stop(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    device = tmp_path / "cpu_dma_latency"
    device.write_bytes(b"")
    monkeypatch.setattr(cpu_latency, "PM_QOS_DEVICE", device)
    config = SupervisorConfig(cpu_wakeup_latency_us=0)
    sup = Supervisor(None, "test/cpu", "tcp/127.0.0.1:1", tmp_path, services=(), config=config)
    assert sup.cpu_wakeup.state == "not requested"  # nothing before start()
    sup.start()
    assert sup.cpu_wakeup.held and sup.cpu_wakeup.state == "held: 0 µs"
    assert device.read_bytes() == struct.pack("i", 0)
    sup.stop()
    assert not sup.cpu_wakeup.held and sup.cpu_wakeup.state == "released: 0 µs"


def test_a_negative_bound_is_refused_by_the_config() -> None:
    with pytest.raises(ValidationError, match="cpu_wakeup_latency_us"):
        SupervisorConfig(cpu_wakeup_latency_us=-1)
