"""sd_notify: datagrams arrive on a real unix socket; silent without NOTIFY_SOCKET."""

from __future__ import annotations

import socket

import pytest

from gateway.service.sdnotify import Notifier


@pytest.fixture
def server(tmp_path, monkeypatch):
    """A bound notify socket (2 s receive time-out) named in NOTIFY_SOCKET."""
    path = str(tmp_path / "notify")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(path)
    sock.settimeout(2)
    monkeypatch.setenv("NOTIFY_SOCKET", path)
    yield sock
    sock.close()


def test_messages_reach_the_socket(server, monkeypatch):
    monkeypatch.setenv("WATCHDOG_USEC", "10000000")
    n = Notifier()
    assert n.enabled and n.watchdog_s == 10.0
    assert n.ready("pipeline up")
    assert server.recv(256) == b"READY=1\nSTATUS=pipeline up"
    n.watchdog()
    assert server.recv(256) == b"WATCHDOG=1"
    n.status("Csy 40.1 kNs/m\nsecond line")
    assert server.recv(256) == b"STATUS=Csy 40.1 kNs/m second line"
    n.close()
    n.close()


def test_extend_timeout_is_in_microseconds(server):
    n = Notifier()
    assert n.extend_timeout(30.0, "warming up")
    assert server.recv(256) == b"EXTEND_TIMEOUT_USEC=30000000\nSTATUS=warming up"
    assert n.extend_timeout(0.5)
    assert server.recv(256) == b"EXTEND_TIMEOUT_USEC=500000"


def test_abstract_socket(monkeypatch):
    server = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    server.bind("\0railgw-test-notify")
    server.settimeout(2)
    monkeypatch.setenv("NOTIFY_SOCKET", "@railgw-test-notify")
    n = Notifier()
    assert n.stopping()
    assert server.recv(64) == b"STOPPING=1"
    server.close()


def test_silent_without_systemd(monkeypatch):
    monkeypatch.delenv("NOTIFY_SOCKET", raising=False)
    n = Notifier()
    assert not n.enabled and not n.ready() and not n.watchdog()


def test_a_receiver_that_does_not_read_never_blocks_the_sender(tmp_path, monkeypatch):
    """The datagram queue fills (net.unix.max_dgram_qlen); notify() then drops and counts
    instead of stalling the service's main loop in sendto()."""
    import threading

    path = str(tmp_path / "notify")
    server = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    server.bind(path)
    monkeypatch.setenv("NOTIFY_SOCKET", path)
    n = Notifier()
    sent: list[bool] = []
    t = threading.Thread(target=lambda: sent.extend(n.status(f"Csy {k}") for k in range(500)),
                         daemon=True)
    t.start()
    t.join(timeout=10)
    assert not t.is_alive(), "notify() blocked on a full receiver queue"
    assert len(sent) == 500 and sent[0] and not all(sent)
    assert n.dropped == sent.count(False) > 0
    assert server.recv(256) == b"STATUS=Csy 0"                # what was queued is intact
    n.close()
    server.close()
