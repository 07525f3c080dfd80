"""Kernel CAN-ID filters from the DBC: only the sensor ids reach the gateway's socket."""

from __future__ import annotations

from pathlib import Path

import can
import pytest
from vcanlib import CAN_EFF_FLAG, CAN_SFF_MASK, RawCan, kernel_filters, wait_for

from gateway.can.bus import open_bus
from gateway.can.source import BusSource, BusState
from gateway.config import Config, with_overrides
from gateway.service.daemon import Service

pytestmark = pytest.mark.vcan

END = b"END-MARK"
"""Payload of the last frame of a test: once it is read, everything before it was."""


def test_filters_installed_in_the_kernel_are_the_dbc_sensor_ids(channel, codec):
    with open_bus(f"socketcan:{channel}", can_filters=codec.can_filters()) as bus:
        installed = kernel_filters(bus.socket)
    # python-can adds CAN_EFF_FLAG to the mask of a filter with "extended": False, so
    # 29-bit frames whose low 11 bits equal a sensor id do not pass.
    assert sorted(installed) == [(i, CAN_SFF_MASK | CAN_EFF_FLAG) for i in codec.sensor_ids()]


def test_only_sensor_ids_are_delivered(channel, codec):
    """Sweep every 11-bit id and some 29-bit ones; the socket gets exactly the sensor ids."""
    sensor_ids = codec.sensor_ids()
    marker_id = sensor_ids[0]
    with open_bus(f"socketcan:{channel}", can_filters=codec.can_filters()) as bus, \
            RawCan(channel) as tx:
        for can_id in range(CAN_SFF_MASK + 1):
            tx.send(can_id, can_id.to_bytes(2, "little").ljust(8, b"\0"))
        for can_id in sensor_ids:
            tx.send(CAN_EFF_FLAG | 0x1000000 | can_id)   # 29-bit, same low 11 bits
            tx.send(CAN_EFF_FLAG | can_id)
        tx.send(marker_id, END)
        got: list[can.Message] = []
        while True:
            msg = bus.recv(timeout=60)
            assert msg is not None, f"the end marker never came; got {len(got)} frames"
            if bytes(msg.data) == END:
                break
            got.append(msg)
    assert [(m.arbitration_id, m.is_extended_id) for m in got] == \
        [(i, False) for i in sensor_ids]


def test_bus_source_with_filters_gets_sensor_frames_and_error_frames(channel, codec):
    """The production setup: filters on, error frames (not subject to them) still counted."""
    frame = codec.encode_message(
        "VEH_Speed", {"VEH_Speed_SampleIdx": 7, "VEH_Speed": 42.5, "VEH_Odometer": 1000.0},
        counter=3)
    with BusSource(lambda: open_bus(f"socketcan:{channel}", can_filters=codec.can_filters()),
                   reopen_min_s=0.05, reopen_max_s=0.5) as src, RawCan(channel) as tx:
        assert src.opened.wait(60)
        tx.send(0x7FF, bytes(8))                        # unknown id: filtered out
        tx.send_error(0x040)                            # bus-off error frame
        tx.send(frame.arbitration_id, bytes(frame.data))
        msg = src.get(60)
        assert msg is not None and msg.arbitration_id == frame.arbitration_id
        decoded = codec.decode_message(msg)
        assert (decoded.message, decoded.sample_idx, decoded.values["VEH_Speed"]) == \
            ("VEH_Speed", 7, 42.5)
        assert wait_for(lambda: src.stats.error_frames == 1)
        assert src.stats.bus_state is BusState.BUS_OFF
        assert src.stats.frames_rx == 1 and src.get() is None


def _rx_packets(channel: str) -> int:
    return int(Path(f"/sys/class/net/{channel}/statistics/rx_packets").read_text())


def test_a_foreign_flood_never_reaches_the_service_in_python(channel, codec, tmp_path):
    """The bus exactly as the service opens it (``Service.source``): 20 000 frames of
    foreign ids pass the interface (its kernel counter), none reaches the receive thread
    (frames_rx counts every frame Python takes off the socket), none is dropped."""
    cfg = with_overrides(Config(), {"bus.interface": "socketcan", "bus.channel": channel,
                                    "state.directory": str(tmp_path / "state")})
    svc = Service(cfg)
    sensors = set(codec.sensor_ids())
    foreign = [i for i in range(CAN_SFF_MASK + 1) if i not in sensors]
    marker = codec.encode_message(
        "VEH_Speed", {"VEH_Speed_SampleIdx": 9, "VEH_Speed": 42.5, "VEH_Odometer": 0.0}, 4)
    n_flood = 20_000
    svc.source.start()
    try:
        assert svc.source.opened.wait(60)
        before = _rx_packets(channel)
        with RawCan(channel) as tx:
            for k in range(n_flood):
                can_id = foreign[k % len(foreign)]
                if k % 10 == 9:                     # 29-bit, a sensor id's low 11 bits
                    can_id = CAN_EFF_FLAG | 0x1000000 | codec.sensor_ids()[k % len(sensors)]
                tx.send(can_id, k.to_bytes(4, "little").ljust(8, b"\0"))
            tx.send(marker.arbitration_id, bytes(marker.data))
        assert wait_for(lambda: svc.source.stats.frames_rx >= 1)
        msg = svc.source.get(1.0)
        passed = _rx_packets(channel) - before
        stats = svc.source.stats
        assert msg is not None and bytes(msg.data) == bytes(marker.data)
        assert svc.source.get() is None
    finally:
        svc.close()
    assert passed >= n_flood + 1, passed            # the kernel saw the whole flood
    assert stats.frames_rx == 1, stats              # Python saw only the sensor frame
    assert stats.dropped_kernel == 0 and stats.dropped_queue_full == 0, stats
    print(f"\nflood: {passed} frames on {channel}, {stats.frames_rx} reached Python")
