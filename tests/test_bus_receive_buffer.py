"""The CAN socket's receive buffer (``[bus] rcvbuf_bytes``): asked of the kernel at every
open, reported in the journal, and the sysctl drop-in that lets the kernel grant it.

The kernel side is tested on a real socket here (a UNIX socket pair: SO_RCVBUF is a
socket-level option, the same call as on a CAN socket) and on vcan in the VM
(tests/vcan/test_vcan_overflow.py: the buffer keeps a stall's frames).
"""

from __future__ import annotations

import configparser
import logging
import socket
from pathlib import Path

import can
import pytest

from gateway.can.bus import ReceiveBuffer, open_bus, set_receive_buffer
from gateway.config import Config, load_config
from gateway.errors import ConfigError
from gateway.service.daemon import Service

ROOT = Path(__file__).resolve().parent.parent


class _SocketBus:
    """The one attribute ``set_receive_buffer`` reads of a SocketCAN bus: its socket."""

    def __init__(self, sock: socket.socket) -> None:
        self.socket = sock


def test_the_kernel_holds_the_asked_size_on_a_real_socket() -> None:
    a, b = socket.socketpair()
    with a, b:
        before = a.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
        asked = 3 * before                    # past the default, not past most limits
        got = set_receive_buffer(_SocketBus(a), asked)   # type: ignore[arg-type]
        assert got is not None and got.asked_bytes == asked
        assert got.granted_bytes == a.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
        limit = got.limit_bytes
        if limit is None or asked <= limit or not got.clamped:
            assert got.granted_bytes == 2 * asked       # the kernel's doubled bookkeeping
        else:                                           # unprivileged, above rmem_max
            assert got.granted_bytes == 2 * limit


def test_a_bus_without_a_kernel_socket_or_a_size_of_0_is_left_alone() -> None:
    bus = open_bus("virtual:rcvbuf-test")
    try:
        assert set_receive_buffer(bus, 4 << 20) is None
    finally:
        bus.shutdown()
    a, b = socket.socketpair()
    with a, b:
        before = a.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
        assert set_receive_buffer(_SocketBus(a), 0) is None   # type: ignore[arg-type]
        assert a.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF) == before


def test_the_journal_line_says_the_size_or_how_to_raise_the_limit() -> None:
    full = ReceiveBuffer(asked_bytes=4 << 20, granted_bytes=8 << 20, limit_bytes=212992)
    assert not full.clamped
    assert full.describe() == "CAN receive buffer: 8388608 bytes"
    capped = ReceiveBuffer(asked_bytes=4 << 20, granted_bytes=425984, limit_bytes=212992)
    assert capped.clamped
    line = capped.describe()
    assert "asked 4194304 bytes, the kernel allows 212992" in line
    assert "net.core.rmem_max = 212992" in line and "60-railgw-can.conf" in line


def test_the_service_asks_for_the_configured_buffer_at_every_open(
        monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture,
        tmp_path: Path) -> None:
    """The daemon's bus opener: the DBC's filters, then the buffer, logged (a real
    socket stands in for the CAN socket; the opener is what BusSource calls)."""
    a, b = socket.socketpair()
    asked: list[int] = []

    class FakeBus(_SocketBus):
        channel_info = "fake"

    def fake_open(spec: object, **kwargs: object) -> can.BusABC:
        return FakeBus(a)   # type: ignore[return-value]

    def spy(bus: can.BusABC, size: int) -> ReceiveBuffer | None:
        asked.append(size)
        return set_receive_buffer(bus, size)

    monkeypatch.setattr("gateway.service.daemon.open_bus", fake_open)
    monkeypatch.setattr("gateway.service.daemon.set_receive_buffer", spy)
    conf = tmp_path / "railgw.toml"
    conf.write_text(f"[bus]\ninterface = \"virtual\"\nrcvbuf_bytes = 65536\n"
                    f"[state]\ndirectory = \"{tmp_path / 'state'}\"\n")
    svc = Service(load_config(conf))
    with a, b, caplog.at_level(logging.INFO, logger="gateway.service.daemon"):
        bus = svc.source._open_bus()
        assert asked == [65536]
        assert a.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF) == 2 * 65536
        assert bus.socket is a
    assert "CAN receive buffer: 131072 bytes" in caplog.text


@pytest.mark.parametrize(("text", "expected"), [
    ("[bus]\nrcvbuf_bytes = 100\n", "[bus] rcvbuf_bytes: expected a value in [4096, "),
    ("[bus]\nrcvbuf_bytes = 4294967296\n", "[bus] rcvbuf_bytes: expected a value in [4096, "),
])
def test_a_bad_size_is_one_clear_line(tmp_path: Path, text: str, expected: str) -> None:
    conf = tmp_path / "railgw.toml"
    conf.write_text(text)
    with pytest.raises(ConfigError) as err:
        load_config(conf)
    assert expected in str(err.value) and "\n" not in str(err.value)


def test_the_sysctl_drop_in_allows_the_default_buffer() -> None:
    """systemd/60-railgw-can.conf raises net.core.rmem_max to at least the default
    request, so an installed service gets what its configuration asks for."""
    text = (ROOT / "systemd" / "60-railgw-can.conf").read_text()
    parser = configparser.ConfigParser()
    parser.read_string("[sysctl]\n" + text)
    assert int(parser["sysctl"]["net.core.rmem_max"]) >= Config().bus.rcvbuf_bytes
