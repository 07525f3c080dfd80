"""Sensor nodes: own clocks, sampling of the truth, noise, packing, counters and CRCs.

Each node samples at its nominal rate on its *own* clock (a ppm drift and a phase),
numbers its samples with a 16-bit sample index, quantises to the DBC scaling and
protects every frame with the E2E alive counter and CRC-8. A frame leaves the node a
short, jittered latency after its sample instant. The frame layout is read from the
DBC (start bits, lengths, scale, limits), so the simulator cannot drift from it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import cantools
import numpy as np

from gateway.can.e2e import COUNTER_MODULUS, e2e_crc

SAMPLE_INDEX_MODULUS = 1 << 16
FRAME_TIME_S = 135e-6
"""Worst-case duration of one 8-byte classic frame at 1 Mbit/s."""


@dataclass(frozen=True)
class NodeSpec:
    """A sensor node: its DBC message and which simulated quantity feeds each signal."""

    node: str
    message: str
    signals: tuple[tuple[str, str], ...]
    """(quantity, DBC signal) pairs; quantities are sensor names or ``speed``/``odometer``."""
    period_s: float


NODES: tuple[NodeSpec, ...] = (
    NodeSpec("WSN", "WSN_Lat", (("acc_w1", "WSN_Acc1"), ("acc_w2", "WSN_Acc2")), 1e-3),
    NodeSpec("BGN", "BGN_Lat", (("acc_b", "BGN_Acc"), ("gyro_b", "BGN_YawRate")), 1e-3),
    NodeSpec("BDN", "BDN_Lat", (("acc_bd", "BDN_Acc"),), 1e-3),
    NodeSpec("VEH", "VEH_Speed", (("speed", "VEH_Speed"), ("odometer", "VEH_Odometer")), 10e-3),
)
NODE_BY_NAME = {n.node: n for n in NODES}


@dataclass(frozen=True)
class NodeClock:
    """A node's oscillator: nominal period scaled by (1 + drift), started at ``phase_s``."""

    drift_ppm: float = 0.0
    phase_s: float = 0.0

    def sample_time_s(self, k: np.ndarray, period_s: float) -> np.ndarray:
        """True (bus-master) time of the node's sample number k, shape of k."""
        return self.phase_s + k * period_s * (1.0 + 1e-6 * self.drift_ppm)

    def samples_in(self, t0_s: float, t1_s: float, period_s: float) -> np.ndarray:
        """Sample numbers k >= 0 whose time lies in [t0, t1), int64."""
        step = period_s * (1.0 + 1e-6 * self.drift_ppm)
        k0 = max(0, int(np.ceil((t0_s - self.phase_s) / step - 1e-9)))
        k1 = max(0, int(np.ceil((t1_s - self.phase_s) / step - 1e-9)))
        return np.arange(k0, k1, dtype=np.int64)


@dataclass(frozen=True)
class _Field:
    start: int
    length: int
    scale: float
    offset: float
    signed: bool
    raw_min: int
    raw_max: int


def _field(signal: cantools.database.can.Signal) -> _Field:
    if signal.byte_order != "little_endian":
        raise ValueError(f"expected little-endian signal {signal.name}, got {signal.byte_order}")
    lo = signal.minimum if signal.minimum is not None else -np.inf
    hi = signal.maximum if signal.maximum is not None else np.inf
    raw_lo = int(np.ceil((lo - signal.offset) / signal.scale - 1e-9))
    raw_hi = int(np.floor((hi - signal.offset) / signal.scale + 1e-9))
    type_lo = -(1 << (signal.length - 1)) if signal.is_signed else 0
    type_hi = (1 << (signal.length - 1)) - 1 if signal.is_signed else (1 << signal.length) - 1
    return _Field(signal.start, signal.length, float(signal.scale), float(signal.offset),
                  bool(signal.is_signed), max(raw_lo, type_lo), min(raw_hi, type_hi))


@dataclass
class FramePacker:
    """Packs arrays of physical values into protected 8-byte payloads of one message.

    Values outside the signal's min/max saturate at the limit, as a real sensor does.
    """

    message: cantools.database.can.Message
    data_id: int
    fields: dict[str, _Field] = field(init=False)

    def __post_init__(self) -> None:
        self.fields = {s.name: _field(s) for s in self.message.signals}

    def raw(self, signal: str, physical: np.ndarray) -> np.ndarray:
        """Quantised raw values (int64) of a signal, saturated to its limits."""
        f = self.fields[signal]
        raw = np.rint((np.asarray(physical, dtype=float) - f.offset) / f.scale)
        return np.clip(raw, f.raw_min, f.raw_max).astype(np.int64)

    def pack(self, raws: dict[str, np.ndarray], counters: np.ndarray) -> list[bytes]:
        """Payloads for n frames; ``raws`` maps signal name to (n,) raw ints."""
        n = len(counters)
        word = np.zeros(n, dtype=np.uint64)
        for name, values in raws.items():
            f = self.fields[name]
            mask = (1 << f.length) - 1
            word |= (values.astype(np.int64) & mask).astype(np.uint64) << np.uint64(f.start)
        word |= (counters.astype(np.uint64) & np.uint64(0xF)) << np.uint64(8)
        data = word.astype("<u8").view(np.uint8).reshape(n, 8)
        out = []
        for row in data:
            payload = bytearray(row.tobytes())
            payload[0] = e2e_crc(self.data_id, payload)
            out.append(bytes(payload))
        return out


Jitter = Callable[[np.random.Generator, int], np.ndarray]


MIN_LATENCY_S = 150e-6
"""A node's minimum sample-to-bus latency, s."""


def default_latency(rng: np.random.Generator, n: int) -> np.ndarray:
    """Sample-to-bus latency: :data:`MIN_LATENCY_S` plus exponential jitter (mean 100 us),
    seconds."""
    return MIN_LATENCY_S + rng.exponential(100e-6, n)


@dataclass
class NodeState:
    """What a node carries from one block of frames to the next (explicit state)."""

    counter: int = 0
    next_k: int = 0
    last_bus_s: float = -1.0


def counters_from(state: NodeState, n: int) -> np.ndarray:
    """The next n alive counters of a node, advancing its state."""
    c = (state.counter + np.arange(n)) % COUNTER_MODULUS
    state.counter = int((state.counter + n) % COUNTER_MODULUS)
    return c
