"""sd_notify: datagrams arrive on a real unix socket; silent without NOTIFY_SOCKET."""

from __future__ import annotations

import socket

from gateway.sdnotify import Notifier


def test_messages_reach_the_socket(tmp_path, monkeypatch):
    path = str(tmp_path / "notify")
    server = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    server.bind(path)
    server.settimeout(2)
    monkeypatch.setenv("NOTIFY_SOCKET", path)
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
    server.close()


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
