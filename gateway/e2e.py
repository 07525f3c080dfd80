"""End-to-end protection of 8-byte CAN payloads: CRC-8 SAE J1850 and alive counter.

E2E profile-1 style, as laid out in ``docs/can-bus.md``:

- byte 0: CRC-8 SAE J1850 (poly 0x1D, init 0xFF, final xor 0xFF) over the data-id low
  byte, the data-id high byte, then payload bytes 1..n-1 (everything but the CRC byte);
- byte 1, low nibble (bits 8..11): alive counter 0..14, +1 per frame, 14 wraps to 0.
  15 is never sent (profile 1 skips it) and is classified as invalid.

Pure functions plus one streaming checker whose state is an explicit frozen record
(:class:`CounterState`), so it can be checkpointed and restored. No I/O, no clock.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from gateway.errors import FrameError, GatewayError

CRC8_POLY = 0x1D
CRC8_INIT = 0xFF
CRC8_XOR_OUT = 0xFF
CRC8_CHECK = 0x4B
"""CRC-8 SAE J1850 of b"123456789" (the catalogue check value)."""

COUNTER_MODULUS = 15
"""Alive counters run 0..14; 15 is invalid."""
COUNTER_INVALID = 15
CRC_BYTE = 0
COUNTER_BYTE = 1
COUNTER_MASK = 0x0F


def _crc8_table(poly: int) -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ poly) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table.append(crc)
    return tuple(table)


_TABLE = _crc8_table(CRC8_POLY)


def crc8_sae_j1850(data: bytes | bytearray | memoryview, start: int = CRC8_INIT) -> int:
    """CRC-8 SAE J1850 of ``data`` (table driven); returns 0..255.

    ``start`` is the register value before the first byte (0xFF for a fresh CRC). To
    continue a CRC over more bytes pass the previous result xor 0xFF:
    ``crc8_sae_j1850(b, start=crc8_sae_j1850(a) ^ 0xFF) == crc8_sae_j1850(a + b)``.
    """
    crc = start
    table = _TABLE
    for byte in data:
        crc = table[crc ^ byte]
    return crc ^ CRC8_XOR_OUT


def _check_data_id(data_id: int) -> None:
    if not 0 <= data_id <= 0xFFFF:
        raise GatewayError(f"expected an E2E data id 0..65535, got {data_id}")


def e2e_crc(data_id: int, payload: bytes | bytearray) -> int:
    """The E2E CRC of a frame: CRC-8 over (id low, id high, payload[1:]); returns 0..255.

    ``payload`` is the whole frame (its byte 0, the CRC itself, is skipped).
    """
    _check_data_id(data_id)
    table = _TABLE
    crc = table[CRC8_INIT ^ (data_id & 0xFF)]
    crc = table[crc ^ (data_id >> 8)]
    for i in range(1, len(payload)):
        crc = table[crc ^ payload[i]]
    return crc ^ CRC8_XOR_OUT


def crc_ok(data_id: int, payload: bytes | bytearray) -> bool:
    """Whether byte 0 of ``payload`` holds its E2E CRC."""
    return len(payload) >= 2 and payload[CRC_BYTE] == e2e_crc(data_id, payload)


def counter_of(payload: bytes | bytearray) -> int:
    """The alive counter (low nibble of byte 1), 0..15."""
    return payload[COUNTER_BYTE] & COUNTER_MASK


def protect(data_id: int, data: bytearray, counter: int) -> bytes:
    """Write ``counter`` into bits 8..11 and the E2E CRC into byte 0; return the frame.

    ``data`` is modified in place (bits 12..15 are kept) and also returned as bytes.
    Raises FrameError(reason "dlc") for fewer than 2 bytes and (reason "counter") for a
    counter outside 0..14.
    """
    if len(data) < 2:
        raise FrameError("dlc", f"expected at least 2 bytes to protect, got {len(data)}")
    if not 0 <= counter < COUNTER_MODULUS:
        raise FrameError("counter", f"expected an alive counter 0..14, got {counter}")
    data[COUNTER_BYTE] = (data[COUNTER_BYTE] & 0xF0) | counter
    data[CRC_BYTE] = e2e_crc(data_id, data)
    return bytes(data)


def next_counter(counter: int) -> int:
    """The counter a sender uses after ``counter`` (14 wraps to 0)."""
    return (counter + 1) % COUNTER_MODULUS


class CounterStatus(enum.Enum):
    """How a received alive counter relates to the previous accepted one."""

    INITIAL = "initial"
    """First counter after start or reset; nothing to compare with."""
    OK = "ok"
    """Exactly one more than the previous counter (modulo 15)."""
    REPEATED = "repeated"
    """Same counter as the previous frame: a repeated (stale) frame."""
    WRONG_SEQUENCE = "wrong_sequence"
    """A jump: ``lost_frames`` frames are missing (modulo 15) and the check resyncs."""
    INVALID = "invalid"
    """Counter 15, which profile 1 never sends; the state is left unchanged."""


@dataclass(frozen=True)
class CounterResult:
    """The classification of one counter; ``lost_frames`` is 0 except for WRONG_SEQUENCE.

    Counters are modulo 15, so a gap of 15 or more frames aliases; use the 16-bit
    sample index for long gaps.
    """

    status: CounterStatus
    lost_frames: int = 0


@dataclass(frozen=True)
class CounterState:
    """Checkpointable state of a counter check: the last accepted counter, if any."""

    last_counter: int | None = None


_INITIAL = CounterResult(CounterStatus.INITIAL)
_OK = CounterResult(CounterStatus.OK)
_REPEATED = CounterResult(CounterStatus.REPEATED)
_INVALID = CounterResult(CounterStatus.INVALID)


def classify_counter(state: CounterState, counter: int) -> tuple[CounterResult, CounterState]:
    """Classify ``counter`` (0..15) against ``state``; return (result, next state).

    Pure function; :class:`CounterCheck` wraps it for streaming use.
    """
    if not 0 <= counter < COUNTER_MODULUS:
        return _INVALID, state
    last = state.last_counter
    if last is None:
        return _INITIAL, CounterState(counter)
    delta = (counter - last) % COUNTER_MODULUS
    if delta == 1:
        return _OK, CounterState(counter)
    if delta == 0:
        return _REPEATED, state
    return CounterResult(CounterStatus.WRONG_SEQUENCE, delta - 1), CounterState(counter)


class CounterCheck:
    """Streaming alive-counter check for one message stream.

    >>> check = CounterCheck()
    >>> check.check(3).status, check.check(4).status
    (<CounterStatus.INITIAL: 'initial'>, <CounterStatus.OK: 'ok'>)

    ``state`` can be read for a checkpoint and passed back to the constructor.
    """

    def __init__(self, state: CounterState | None = None) -> None:
        self._state = state if state is not None else CounterState()

    @property
    def state(self) -> CounterState:
        """The current (immutable) state; save it to checkpoint."""
        return self._state

    def check(self, counter: int) -> CounterResult:
        """Classify the next received counter and advance the state."""
        result, self._state = classify_counter(self._state, counter)
        return result

    def reset(self) -> None:
        """Forget the last counter; the next one is INITIAL."""
        self._state = CounterState()
