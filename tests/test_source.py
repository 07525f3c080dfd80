"""The CAN source on python-can's virtual bus: receive, drops, bus state, reopen."""

from __future__ import annotations

import time

import can
import pytest

from gateway.can.bus import open_bus
from gateway.can.source import BusSource, BusState, next_bus_state


def _wait(cond, timeout_s=5.0):
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(0.01)
    return False


@pytest.fixture()
def channel(request):
    return f"virtual:src-{request.node.name}"


def test_receives_counts_and_sends(channel):
    with BusSource(lambda: open_bus(channel)) as src, open_bus(channel) as peer:
        assert src.opened.wait(5)
        for i in range(50):
            peer.send(can.Message(arbitration_id=0x102, data=bytes([i] * 8), is_extended_id=False))
        got = [src.get(1.0) for _ in range(50)]
        assert [m.data[0] for m in got if m] == list(range(50))
        assert src.stats.frames_rx == 50 and src.stats.dropped_queue_full == 0
        assert src.send(can.Message(arbitration_id=0x320, data=bytes(8), is_extended_id=False))
        assert peer.recv(1.0).arbitration_id == 0x320


def test_full_queue_drops_are_counted(channel):
    with BusSource(lambda: open_bus(channel), queue_frames=10) as src, open_bus(channel) as peer:
        assert src.opened.wait(5)
        for _ in range(100):
            peer.send(can.Message(arbitration_id=0x102, data=bytes(8), is_extended_id=False))
        assert _wait(lambda: src.stats.frames_rx == 100)
        assert src.stats.dropped_queue_full == 90


def test_error_frames_drive_the_bus_state(channel):
    with BusSource(lambda: open_bus(channel)) as src, open_bus(channel) as peer:
        assert src.opened.wait(5)
        passive = can.Message(is_error_frame=True, arbitration_id=0x004,
                              data=[0, 0x20, 0, 0, 0, 0, 0, 0])
        peer.send(passive)
        assert _wait(lambda: src.stats.bus_state is BusState.ERROR_PASSIVE)
        peer.send(can.Message(is_error_frame=True, arbitration_id=0x040, data=bytes(8)))
        assert _wait(lambda: src.stats.bus_state is BusState.BUS_OFF)
        peer.send(can.Message(is_error_frame=True, arbitration_id=0x100, data=bytes(8)))
        assert _wait(lambda: src.stats.bus_state is BusState.ERROR_ACTIVE)
        assert src.stats.error_frames == 3 and src.get() is None


def test_bus_state_transitions_pure():
    off = can.Message(is_error_frame=True, arbitration_id=0x040)
    warn = can.Message(is_error_frame=True, arbitration_id=0x004, data=[0, 0x04, 0, 0, 0, 0, 0, 0])
    assert next_bus_state(BusState.ERROR_ACTIVE, off) is BusState.BUS_OFF
    assert next_bus_state(BusState.ERROR_ACTIVE, warn) is BusState.ERROR_ACTIVE


def test_failed_bus_is_reopened_with_backoff(channel):
    opened: list[can.BusABC] = []
    attempts = {"n": 0}

    def flaky() -> can.BusABC:
        attempts["n"] += 1
        if attempts["n"] <= 2:
            raise can.CanOperationError("interface can0 does not exist")
        bus = open_bus(channel)
        opened.append(bus)
        return bus

    with BusSource(flaky, reopen_min_s=0.05, reopen_max_s=0.2) as src:
        assert src.opened.wait(5) and attempts["n"] == 3
        opened[0].shutdown()                # the interface goes away under the receiver
        assert _wait(lambda: len(opened) == 2 and src.stats.bus_open)
        assert src.stats.reopens == 1
        with open_bus(channel) as peer:
            peer.send(can.Message(arbitration_id=0x103, data=bytes(8), is_extended_id=False))
            assert src.get(2.0) is not None
