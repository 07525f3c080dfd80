"""Worst-case load of a classic CAN bus (11-bit ids) from its cyclic frames.

A classic base-format data frame with ``n`` data bytes is at most::

    bits(n) = 47 + 8 n + floor((34 + 8 n - 1) / 4)

47 fixed bits (SOF 1, id 11, RTR 1, IDE 1, r0 1, DLC 4, CRC 15, CRC delimiter 1,
ACK 2, EOF 7, intermission 3) plus the data, plus worst-case bit stuffing over the
34 + 8 n bits from SOF to the end of the CRC (Davis et al., 2007). For n = 8 this is
135 bits. Load = sum over frames of bits * rate / bitrate. Event-driven frames have
no rate and are left out. No I/O.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

from gateway.errors import GatewayError

FIXED_BITS_STD = 47
"""Frame bits other than data and stuffing, standard id, including the 3-bit intermission."""
STUFFABLE_BITS_STD = 34
"""Bits from SOF to the end of the CRC field that are exposed to stuffing, besides data."""


def frame_bits_worst_case(n_data_bytes: int) -> int:
    """Worst-case length in bits of a classic standard-id data frame with ``n_data_bytes``."""
    if not 0 <= n_data_bytes <= 8:
        raise GatewayError(f"expected 0..8 data bytes for a classic CAN frame, got {n_data_bytes}")
    n_bits = 8 * n_data_bytes
    return FIXED_BITS_STD + n_bits + (STUFFABLE_BITS_STD + n_bits - 1) // 4


@dataclass(frozen=True)
class CyclicFrame:
    """One cyclic message as the bus sees it."""

    name: str
    n_data_bytes: int
    cycle_time_ms: float


@dataclass(frozen=True)
class MessageLoad:
    """The share of one cyclic message in the bus load."""

    name: str
    frame_bits: int
    rate_hz: float
    bits_per_s: float
    load_fraction: float


@dataclass(frozen=True)
class BusLoad:
    """Worst-case bus load: total and per message (fractions of the bitrate, 0..1+)."""

    bitrate_bps: float
    bits_per_s: float
    load_fraction: float
    messages: tuple[MessageLoad, ...]

    @property
    def load_percent(self) -> float:
        return 100.0 * self.load_fraction


def bus_load(frames: Iterable[CyclicFrame], bitrate_bps: float) -> BusLoad:
    """Worst-case load (with bit stuffing) of ``frames`` on a bus of ``bitrate_bps``."""
    if not bitrate_bps > 0:
        raise GatewayError(f"expected a positive bitrate in bit/s, got {bitrate_bps}")
    rows = []
    for frame in frames:
        if not frame.cycle_time_ms > 0:
            raise GatewayError(f"expected a positive cycle time for {frame.name}, "
                               f"got {frame.cycle_time_ms} ms")
        bits = frame_bits_worst_case(frame.n_data_bytes)
        rate_hz = 1000.0 / frame.cycle_time_ms
        rows.append(MessageLoad(frame.name, bits, rate_hz, bits * rate_hz,
                                bits * rate_hz / bitrate_bps))
    total = sum(r.bits_per_s for r in rows)
    return BusLoad(bitrate_bps, total, total / bitrate_bps, tuple(rows))
