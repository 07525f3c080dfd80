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
from dataclasses import dataclass, field

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

    def resync(self, counter: int) -> None:
        """Take ``counter`` as the last one without classifying it (a caller that knows
        from elsewhere, e.g. the sample index, how many frames were lost)."""
        self._state = CounterState(counter)


# ---------------------------------------------------------------- masquerade detection
SAMPLE_INDEX_MODULUS = 1 << 16
"""Sensor frames carry a 16-bit sample index beside the alive counter."""
IDX_JUMP_REASONS: tuple[str, ...] = ("idx_jump", "idx_back", "idx_repeat")
"""Sample-index breaks the counter does not explain: ``idx_jump`` forward by more than
:data:`SenderParams.max_step` or not as far as the counter moved, ``idx_back`` backwards
(other than a one-frame overtake), ``idx_repeat`` the same index again."""


@dataclass(frozen=True)
class SenderParams:
    """Settings of the two-sender detector (per CAN id).

    A frame *continues* a sequence when its index moved 1..``max_step`` and its counter
    moved the same amount modulo 15. The detector keeps two sequences: the primary and
    the one the last unexplained jump started. Frames alternating between them are
    *switches*; a block of ``block_frames`` frames with ``raise_switches`` or more raises
    the flag, ``clear_blocks`` blocks in a row with fewer clear it (hysteresis). A
    second sequence continued ``promote_after`` times with no primary frame in between
    replaces the primary (the node restarted: one sender). If that sequence resumed
    *ahead* of the primary by more than ``max_step`` (lost frames: a burst the kernel or
    the queue dropped, or a node restart that kept counting), the hand-over is no
    switch; a switch into it counts only once the primary is heard again. One node whose
    frames are lost in bursts is therefore never taken for two senders, while two
    senders interleaving frame by frame count as before, and two senders taking turns in
    bursts still count the switches back into the sequence that is behind.
    """

    max_step: int = 16
    block_frames: int = 64
    raise_switches: int = 8
    clear_blocks: int = 16
    promote_after: int = 3


@dataclass
class SenderState:
    """What the detector carries for one id (plain, picklable)."""

    primary: tuple[int, int] | None = None
    """(counter, sample index) of the primary sequence's newest frame."""
    second: tuple[int, int] | None = None
    last_track: int = 0
    """1 primary, 2 second, 0 none yet."""
    second_run: int = 0
    second_ahead: bool = False
    """The second sequence started ahead of the primary by more than ``max_step``."""
    pending_switch: int = 0
    """A switch into such a sequence, counted only when the primary is heard again."""
    block_n: int = 0
    block_switches: int = 0
    clean_blocks: int = 0
    two_senders: bool = False
    events: int = 0
    """Times the flag was raised."""
    second_frames: int = 0
    """Frames that continued the second sequence."""
    jumps: dict[str, int] = field(default_factory=lambda: dict.fromkeys(IDX_JUMP_REASONS, 0))


def _continues(last: tuple[int, int], counter: int, idx: int, max_step: int) -> int:
    """1 if (counter, idx) continues the sequence ending in ``last``, -1 if it is the frame
    one before it (overtaken), else 0."""
    di = (idx - last[1]) % SAMPLE_INDEX_MODULUS
    dc = (counter - last[0]) % COUNTER_MODULUS
    if 1 <= di <= max_step and di % COUNTER_MODULUS == dc:
        return 1
    if di == SAMPLE_INDEX_MODULUS - 1 and dc == COUNTER_MODULUS - 1:
        return -1
    return 0


class SenderCheck:
    """Streaming two-sender detector for one CAN id: alive counter + sample index.

    E2E profile 1 cannot tell a masquerader with a valid CRC from the real node, but two
    senders on one id interleave two counter/index sequences, which one node never does.
    :meth:`feed` returns the track the frame belongs to (1 primary, 2 second, 0 a jump).
    """

    def __init__(self, params: SenderParams | None = None,
                 state: SenderState | None = None) -> None:
        self.params = params or SenderParams()
        self.state = state if state is not None else SenderState()

    def feed(self, counter: int, idx: int) -> int:
        """Classify one frame's (counter 0..14, sample index 0..65535) and advance."""
        p, st = self.params, self.state
        track = 1
        handover = False
        if st.primary is None:
            st.primary = (counter, idx)
        elif (c := _continues(st.primary, counter, idx, p.max_step)) != 0:
            if c > 0:
                st.primary = (counter, idx)
            st.second_run = 0
        elif st.second is not None and (c := _continues(st.second, counter, idx,
                                                        p.max_step)) != 0:
            track = 2
            st.second_frames += 1
            if c > 0:
                st.second = (counter, idx)
                st.second_run += 1
            if st.second_run >= p.promote_after and st.last_track != 1:
                st.primary, st.second, st.second_run, track = st.second, None, 0, 1
                handover = True
        else:
            di = (idx - st.primary[1]) % SAMPLE_INDEX_MODULUS
            why = ("idx_repeat" if di == 0 else
                   "idx_back" if di >= SAMPLE_INDEX_MODULUS // 2 else "idx_jump")
            st.jumps[why] += 1
            st.second, st.second_run, track = (counter, idx), 0, 0
            st.second_ahead = p.max_step < di < SAMPLE_INDEX_MODULUS // 2
        if handover and st.second_ahead:
            st.pending_switch = 0                  # lost frames, then one sender again
        elif track == 2 and st.last_track == 1 and st.second_ahead:
            st.pending_switch = 1                  # a gap or a second sender: not known yet
        elif track and st.last_track and track != st.last_track:
            st.block_switches += 1 + st.pending_switch
            st.pending_switch = 0
        if track:
            st.last_track = track
        st.block_n += 1
        if st.block_n >= p.block_frames:
            if st.block_switches >= p.raise_switches:
                st.clean_blocks = 0
                if not st.two_senders:
                    st.two_senders = True
                    st.events += 1
            elif st.two_senders:
                st.clean_blocks += 1
                if st.clean_blocks >= p.clear_blocks:
                    st.two_senders = False
            st.block_n = st.block_switches = 0
        return track
