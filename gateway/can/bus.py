"""Open python-can buses from a one-word spec such as ``virtual:railgw`` or ``socketcan:can0``.

Daemons never read python-can's hidden config files: every bus is opened with
``ignore_config=True``. ``virtual`` is python-can's in-process bus (the embedded
default for the demo and tests); ``socketcan`` is the production path.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import can

from gateway.errors import InputError

DEFAULT_DEMO_BUS = "virtual:railgw"
DEFAULT_PRODUCTION_BUS = "socketcan:can0"
KNOWN_INTERFACES = ("virtual", "socketcan")


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
