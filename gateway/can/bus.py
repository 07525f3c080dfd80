"""Open python-can buses from a one-word spec such as ``virtual:railgw`` or ``socketcan:can0``.

Daemons never read python-can's hidden config files: every bus is opened with
``ignore_config=True``. ``virtual`` is python-can's in-process bus (the embedded
default for the demo and tests); ``socketcan`` is the production path.
"""

from __future__ import annotations

import socket
import sys
from dataclasses import dataclass
from typing import Any

import can

from gateway.errors import InputError

DEFAULT_DEMO_BUS = "virtual:railgw"
DEFAULT_PRODUCTION_BUS = "socketcan:can0"
KNOWN_INTERFACES = ("virtual", "socketcan")
SO_RCVBUFFORCE = 33
"""Linux (asm-generic/socket.h): SO_RCVBUF beyond ``net.core.rmem_max``, with
CAP_NET_ADMIN."""
RMEM_MAX_PATH = "/proc/sys/net/core/rmem_max"


@dataclass(frozen=True)
class BusSpec:
    """An interface name and a channel, e.g. ``BusSpec("socketcan", "can0")``."""

    interface: str
    channel: str

    def __str__(self) -> str:
        return f"{self.interface}:{self.channel}"


def parse_bus_spec(text: str) -> BusSpec:
    """``INTERFACE:CHANNEL`` (or just ``virtual``) -> BusSpec; InputError when malformed."""
    interface, _, channel = text.partition(":")
    interface = interface.strip().lower()
    if interface not in KNOWN_INTERFACES:
        raise InputError(f"expected a bus like 'virtual:railgw' or 'socketcan:can0' "
                         f"(interfaces {list(KNOWN_INTERFACES)}), got {text!r}")
    if not channel:
        if interface != "virtual":
            raise InputError(f"expected a channel after {interface!r}, e.g. "
                             f"'{interface}:can0', got {text!r}")
        channel = "railgw"
    return BusSpec(interface, channel)


def open_bus(spec: BusSpec | str, **kwargs: Any) -> can.BusABC:
    """Open the bus (receive_own_messages off); python-can errors propagate."""
    s = parse_bus_spec(spec) if isinstance(spec, str) else spec
    return can.Bus(interface=s.interface, channel=s.channel, ignore_config=True, **kwargs)


def open_node_bus(spec: BusSpec | str) -> can.BusABC:
    """A bus for simulated nodes: on ``virtual`` their frames keep the timestamps the
    sender gives them (the simulated wire time), as kernel timestamps would."""
    s = parse_bus_spec(spec) if isinstance(spec, str) else spec
    if s.interface == "virtual":
        return open_bus(s, preserve_timestamps=True)
    return open_bus(s)


@dataclass(frozen=True)
class ReceiveBuffer:
    """A kernel socket's receive buffer after :func:`set_receive_buffer`.

    ``asked_bytes`` is the request; ``granted_bytes`` what the kernel reports back: twice
    the request (its own bookkeeping), or twice ``net.core.rmem_max`` when the request
    was above that limit and the process may not exceed it (``limit_bytes``, None where
    unreadable).
    """

    asked_bytes: int
    granted_bytes: int
    limit_bytes: int | None

    @property
    def clamped(self) -> bool:
        """The kernel granted less than asked (``net.core.rmem_max``)."""
        return self.granted_bytes < 2 * self.asked_bytes

    def describe(self) -> str:
        """One journal line: the size, and where it was clamped, how to raise it."""
        if not self.clamped:
            return f"CAN receive buffer: {self.granted_bytes} bytes"
        limit = "" if self.limit_bytes is None else f" (net.core.rmem_max = {self.limit_bytes})"
        return (f"CAN receive buffer: asked {self.asked_bytes} bytes, the kernel allows "
                f"{self.granted_bytes // 2}{limit}: a stall of the service loses frames "
                f"sooner; install systemd/60-railgw-can.conf in /etc/sysctl.d/ to raise it")


def set_receive_buffer(bus: can.BusABC, size_bytes: int) -> ReceiveBuffer | None:
    """Ask the kernel for a ``size_bytes`` receive buffer on ``bus``'s socket (first past
    ``net.core.rmem_max``, which needs CAP_NET_ADMIN, then within it); None for a bus
    without a kernel socket (``virtual``) or a size of 0 (the kernel's default)."""
    sock = getattr(bus, "socket", None)
    if not isinstance(sock, socket.socket) or size_bytes <= 0:
        return None
    size = int(size_bytes)
    forced = False
    if sys.platform.startswith("linux"):
        try:
            sock.setsockopt(socket.SOL_SOCKET, SO_RCVBUFFORCE, size)
            forced = True
        except PermissionError:
            pass
    if not forced:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, size)
    granted = sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
    return ReceiveBuffer(size, int(granted), _rmem_max())


def _rmem_max() -> int | None:
    try:
        with open(RMEM_MAX_PATH, encoding="ascii") as f:
            return int(f.read().strip())
    except (OSError, ValueError):
        return None
