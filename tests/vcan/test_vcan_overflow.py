"""Receive overflow: a socket nobody reads drops frames; SO_RXQ_OVFL counts them exactly."""

from __future__ import annotations

import socket
import threading

import can
import pytest
from vcanlib import RawCan, socket_drops, wait_for

from gateway.can.bus import open_bus, set_receive_buffer
from gateway.can.source import BusSource, kernel_drops
from gateway.config import Config

pytestmark = pytest.mark.vcan

SENT = 400
"""Frames sent into an unread socket whose buffer holds a few dozen."""
SMALL_RCVBUF_BYTES = 4096
"""Asked-for SO_RCVBUF (the kernel doubles it, then holds it at its minimum or above)."""
END = b"END-MARK"


def test_rxq_ovfl_counts_every_dropped_frame(channel):
    with RawCan(channel, rxq_ovfl=True, rcvbuf_bytes=SMALL_RCVBUF_BYTES) as rx, \
            RawCan(channel) as tx:
        for i in range(SENT):
            tx.send(0x101, i.to_bytes(4, "little").ljust(8, b"\0"))
        kept = rx.drain()
        # The drop count travels with each frame, as it was when the frame was queued:
        # a frame queued after the overflow brings the total.
        tx.send(0x101, END)
        assert rx.recv() == (0x101, END)
        dropped = rx.last_dropcount
        assert 0 < dropped < SENT
        assert len(kept) + dropped == SENT
        # The frames kept are the oldest ones, in order: the queue filled, then refused.
        assert [int.from_bytes(d[:4], "little") for _, d in kept] == list(range(len(kept)))
        assert rx.kernel_drops() == dropped   # SO_MEMINFO reads the same counter


def test_bus_source_counts_kernel_drops(channel):
    """The source, stalled while frames pile up, counts what the kernel dropped for it.

    Until gateway/can/source.py reads the count (docs/vcan.md, "Kernel drops"), its
    ``dropped_kernel`` stays 0 and this test reports xfail; everything before that
    check must pass already.
    """
    gate = threading.Event()
    sockets = []

    def stalled_bus() -> can.BusABC:
        bus = open_bus(f"socketcan:{channel}")
        bus.socket.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, SMALL_RCVBUF_BYTES)
        sockets.append(bus.socket)
        recv = bus.recv

        def gated_recv(timeout: float | None = None) -> can.Message | None:
            gate.wait()
            return recv(timeout)

        bus.recv = gated_recv  # type: ignore[method-assign]
        return bus

    src = BusSource(stalled_bus, reopen_min_s=0.05, reopen_max_s=0.5)
    try:
        src.start()
        assert src.opened.wait(60)
        with RawCan(channel) as tx:
            for _ in range(SENT):
                tx.send(0x101, bytes(8))
            dropped = socket_drops(sockets[-1])
            assert dropped > 0
            gate.set()
            # Only once the source has read what was kept is there room for the marker.
            assert wait_for(lambda: src.stats.frames_rx == SENT - dropped), (dropped, src.stats)
            tx.send(0x101, END)
            msg = src.get(60)
            while msg is not None and bytes(msg.data) != END:
                msg = src.get(60)
            assert msg is not None and src.stats.frames_rx == SENT - dropped + 1
            assert socket_drops(sockets[-1]) == dropped
        counted = wait_for(lambda: src.stats.dropped_kernel == dropped, timeout_s=5.0)
        assert counted, f"expected dropped_kernel == {dropped}, got {src.stats}"
    finally:
        gate.set()
        src.close()


BUS_SECOND = 3100
"""Frames the sensor nodes send in one second (docs/can-bus.md, "Bus load")."""


def test_the_configured_buffer_keeps_a_second_of_the_bus_through_a_stall(channel):
    """Nobody reads for a second of sensor traffic: a socket with the kernel's default
    receive buffer drops most of it; one with the service's default ``rcvbuf_bytes``
    (set as the daemon sets it, gateway.can.bus.set_receive_buffer) keeps every frame,
    in order. Prints the default buffer's capacity in frames (docs/can-bus.md)."""
    bus = open_bus(f"socketcan:{channel}")
    try:
        buf = set_receive_buffer(bus, Config().bus.rcvbuf_bytes)
        assert buf is not None and not buf.clamped      # the VM runs as root: no cap
        with RawCan(channel, rxq_ovfl=True) as small, RawCan(channel) as tx:
            for i in range(BUS_SECOND):
                tx.send(0x101, i.to_bytes(4, "little").ljust(8, b"\0"))
            kept_small = small.drain()
            got = []
            while len(got) < BUS_SECOND:
                msg = bus.recv(timeout=5.0)
                assert msg is not None, f"{len(got)} of {BUS_SECOND} frames came"
                got.append(int.from_bytes(bytes(msg.data[:4]), "little"))
            assert got == list(range(BUS_SECOND))
            assert kernel_drops(bus) == 0
            print(f"kernel default buffer: kept {len(kept_small)} of {BUS_SECOND} frames "
                  f"(SO_RCVBUF {small.sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)})")
            assert small.kernel_drops() == BUS_SECOND - len(kept_small) > 0
    finally:
        bus.shutdown()
