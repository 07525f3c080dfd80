"""The node simulator's CLI sends over vcan0; every frame arrives, in order, and decodes."""

from __future__ import annotations

import re
from collections import defaultdict

import can
import pytest
from vcanlib import python_module, socket_drops, wait_for

from gateway.can.bus import open_bus, set_receive_buffer
from gateway.can.e2e import COUNTER_MODULUS
from gateway.can.source import BusSource

pytestmark = pytest.mark.vcan

DURATION_S = 1.0
RCVBUF_BYTES = 32 << 20
"""Room for the whole run, so a receiver slowed down by TCG still loses nothing."""
SAMPLE_INDEX_MODULUS = 1 << 16


def test_simulator_frames_arrive_complete_and_decode(channel, codec):
    sockets = []

    def bus() -> can.BusABC:
        b = open_bus(f"socketcan:{channel}", can_filters=codec.can_filters())
        set_receive_buffer(b, RCVBUF_BYTES)
        sockets.append(b.socket)
        return b

    with BusSource(bus, reopen_min_s=0.05, reopen_max_s=0.5) as src:
        assert src.opened.wait(60)
        proc = python_module("firmware_sim", "run", "--scenario", "nominal", "--duration",
                             str(DURATION_S), "--seed", "3", "--bus", f"socketcan:{channel}")
        assert proc.returncode == 0, proc.stderr[-3000:]
        m = re.search(r"sent (\d+) frames on socketcan:" + re.escape(channel), proc.stdout)
        assert m, proc.stdout
        sent = int(m.group(1))
        assert wait_for(lambda: src.stats.frames_rx >= sent), (sent, src.stats)
        assert socket_drops(sockets[-1]) == 0 and src.stats.dropped_queue_full == 0
        frames = []
        while (msg := src.get()) is not None:
            frames.append(msg)
    assert len(frames) == sent
    decoded = [codec.decode_message(f) for f in frames]     # raises on any bad frame
    by_message = defaultdict(list)
    for d in decoded:
        by_message[d.message].append(d)
    assert sorted(by_message) == sorted(codec.sensor_messages())
    for name, seq in by_message.items():
        period_ms = codec.cycle_time_ms(name)
        assert period_ms is not None
        assert abs(len(seq) - DURATION_S * 1000 / period_ms) <= 2, (name, len(seq))
        # Nothing lost or reordered: alive counter and sample index step by one.
        for a, b in zip(seq, seq[1:], strict=False):
            assert b.counter == (a.counter + 1) % COUNTER_MODULUS, (name, a, b)
            assert b.sample_idx == (a.sample_idx + 1) % SAMPLE_INDEX_MODULUS, (name, a, b)
