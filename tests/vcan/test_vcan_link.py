"""The link going down and up, or vanishing and coming back: the source recovers.

These run on a scratch vcan interface of their own (``rgw-vcan0``, needs root), so a
developer's vcan0 is never taken down.
"""

from __future__ import annotations

import errno

import can
import pytest
from vcanlib import RawCan, add_vcan, ip, wait_for

from gateway.can.bus import open_bus
from gateway.can.source import BusSource

pytestmark = pytest.mark.vcan


def _source(name: str) -> BusSource:
    return BusSource(lambda: open_bus(f"socketcan:{name}"), reopen_min_s=0.05,
                     reopen_max_s=0.5)


def _send_until_received(src: BusSource, name: str, payload: bytes, tries: int = 12) -> None:
    """A fresh sender (an old one may still hold the link's error) sends until src gets it.

    Right after the link comes back the source may still hold a socket bound while the
    link was down (the kernel flags ENETDOWN on it, so it is reopened once more): a
    frame sent in that gap is lost, hence the retries.
    """
    for _ in range(tries):
        with RawCan(name) as tx:
            tx.send(0x102, payload)
        while (msg := src.get(5.0)) is not None:
            if bytes(msg.data) == payload:
                return      # (a late duplicate of an earlier payload is skipped)
    raise AssertionError(f"{payload!r} never arrived: {src.stats}")


def test_down_raises_enetdown_and_the_same_socket_resumes_after_up(scratch):
    """The kernel's behaviour that the source relies on."""
    with open_bus(f"socketcan:{scratch}") as bus:
        ip("link", "set", "down", scratch)
        with pytest.raises(can.CanOperationError) as info:
            bus.recv(timeout=60)
        assert info.value.error_code == errno.ENETDOWN
        ip("link", "set", "up", scratch)
        with RawCan(scratch) as tx:
            tx.send(0x102, b"resumed")
        msg = bus.recv(timeout=60)
        assert msg is not None and bytes(msg.data) == b"resumed"


def test_bus_source_recovers_after_down_and_up(scratch):
    with _source(scratch) as src:
        assert src.opened.wait(60)
        _send_until_received(src, scratch, b"before")
        ip("link", "set", "down", scratch)
        assert wait_for(lambda: src.stats.reopens >= 1), src.stats
        assert "Network is down" in src.stats.last_error
        ip("link", "set", "up", scratch)
        assert wait_for(lambda: src.stats.bus_open)
        _send_until_received(src, scratch, b"after")


def test_deleted_link_raises_enodev(scratch):
    with open_bus(f"socketcan:{scratch}") as bus:
        ip("link", "del", "dev", scratch)
        with pytest.raises(can.CanOperationError) as info:
            bus.recv(timeout=60)
        assert info.value.error_code == errno.ENODEV


def test_bus_source_reopens_a_deleted_and_recreated_link(scratch):
    with _source(scratch) as src:
        assert src.opened.wait(60)
        _send_until_received(src, scratch, b"before")
        ip("link", "del", "dev", scratch)
        # The link is gone: the source closed the bus and keeps failing to open it.
        assert wait_for(lambda: src.stats.last_error.startswith("open failed")), src.stats
        assert not src.stats.bus_open and src.stats.reopens >= 1
        add_vcan(scratch)
        assert wait_for(lambda: src.stats.bus_open), src.stats
        _send_until_received(src, scratch, b"after")
