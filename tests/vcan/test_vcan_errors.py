"""Error frames injected on vcan drive the bus state (error-passive, bus-off, restarted)."""

from __future__ import annotations

import pytest
from vcanlib import CAN_ERR_FLAG, RawCan, wait_for

from gateway.can.bus import open_bus
from gateway.can.source import (
    CAN_ERR_BUSOFF,
    CAN_ERR_CRTL,
    CAN_ERR_CRTL_ACTIVE,
    CAN_ERR_CRTL_TX_PASSIVE,
    CAN_ERR_RESTARTED,
    BusSource,
    BusState,
)

pytestmark = pytest.mark.vcan


def test_injected_error_frame_arrives_as_an_error_frame(channel):
    """The kernel path itself: CAN_ERR_FLAG in, python-can's is_error_frame out."""
    with open_bus(f"socketcan:{channel}") as bus, RawCan(channel) as tx:
        tx.send_error(CAN_ERR_CRTL, bytes([0, CAN_ERR_CRTL_TX_PASSIVE, 0, 0, 0, 0, 0, 0]))
        msg = bus.recv(timeout=60)
    assert msg is not None and msg.is_error_frame
    assert msg.arbitration_id == CAN_ERR_CRTL and msg.data[1] == CAN_ERR_CRTL_TX_PASSIVE


def test_error_frames_are_not_delivered_without_the_error_mask(channel):
    """A raw socket without CAN_RAW_ERR_FILTER never sees them (the kernel's default)."""
    with RawCan(channel) as plain, RawCan(channel, error_frames=True) as errs, \
            RawCan(channel) as tx:
        tx.send_error(CAN_ERR_BUSOFF)
        tx.send(0x102, b"after")
        assert errs.recv() == (CAN_ERR_FLAG | CAN_ERR_BUSOFF, bytes(8))
        assert plain.recv() == (0x102, b"after")


def test_bus_source_follows_passive_bus_off_and_back(channel):
    with BusSource(lambda: open_bus(f"socketcan:{channel}"), reopen_min_s=0.05,
                   reopen_max_s=0.5) as src, RawCan(channel) as tx:
        assert src.opened.wait(60)
        assert src.stats.bus_state is BusState.ERROR_ACTIVE
        tx.send_error(CAN_ERR_CRTL, bytes([0, CAN_ERR_CRTL_TX_PASSIVE, 0, 0, 0, 0, 0, 0]))
        assert wait_for(lambda: src.stats.bus_state is BusState.ERROR_PASSIVE)
        tx.send_error(CAN_ERR_BUSOFF)
        assert wait_for(lambda: src.stats.bus_state is BusState.BUS_OFF)
        tx.send_error(CAN_ERR_RESTARTED)
        assert wait_for(lambda: src.stats.bus_state is BusState.ERROR_ACTIVE)
        tx.send_error(CAN_ERR_CRTL, bytes([0, CAN_ERR_CRTL_TX_PASSIVE, 0, 0, 0, 0, 0, 0]))
        assert wait_for(lambda: src.stats.bus_state is BusState.ERROR_PASSIVE)
        tx.send_error(CAN_ERR_CRTL, bytes([0, CAN_ERR_CRTL_ACTIVE, 0, 0, 0, 0, 0, 0]))
        assert wait_for(lambda: src.stats.bus_state is BusState.ERROR_ACTIVE)
        # Error frames are counted, never queued, and the bus stays open throughout.
        tx.send(0x102, b"data")
        msg = src.get(60)
        assert msg is not None and bytes(msg.data) == b"data"
        assert src.stats.error_frames == 5 and src.stats.frames_rx == 1
        assert src.stats.reopens == 0 and src.stats.bus_open
