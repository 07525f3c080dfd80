"""Frame validation: decode, E2E counter sequence, range and timeouts; count every rejection.

A frame is *accepted* (handed to the resampler) or *rejected* with one reason:
``unknown_id``, ``frame_type``, ``dlc``, ``crc``, ``counter`` (invalid value 15),
``range`` (from the codec), ``two_senders`` (see below), ``counter_repeated`` (the
alive counter did not move: a replayed or frozen sender) or ``not_sensor`` (a known
non-sensor message, e.g. another gateway's output). A counter jump is accepted but
its lost frames are counted. A message times out when nothing valid arrived for
``timeout_cycles`` x its ``GenMsgCycleTime``.

Every sensor frame's (alive counter, SampleIdx) also goes through the two-sender
detector (:class:`gateway.can.e2e.SenderCheck`): sample-index breaks the counter does not
explain are counted by reason (``sample_idx_jumps``), and while two interleaved
sequences are seen on one id (a masquerader with valid CRCs, or a second node with the
same id) the message is flagged ``two_senders`` and all its frames are rejected with
reason ``two_senders``, until the flag clears (hysteresis in
:class:`gateway.can.e2e.SenderParams`). Core stage: no I/O, time from frame timestamps.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field

import can

from gateway.can.codec import Codec
from gateway.can.e2e import (
    COUNTER_MODULUS,
    SAMPLE_INDEX_MODULUS,
    CounterCheck,
    CounterStatus,
    SenderCheck,
    SenderParams,
)
from gateway.errors import FrameError
from gateway.records import DecodedFrame


@dataclass
class MessageStats:
    """Per-message counters and last values, for health and the console."""

    name: str
    cycle_time_s: float
    accepted: int = 0
    rejected: Counter[str] = field(default_factory=Counter)
    lost_frames: int = 0
    reordered: int = 0
    timeouts: int = 0
    timed_out: bool = True
    first_s: float = math.nan
    last_s: float = math.nan
    last_values: dict[str, float] = field(default_factory=dict)
    sender: SenderCheck = field(default_factory=SenderCheck)
    """The two-sender detector of this id (its state holds the SampleIdx jump counts)."""
    last_idx: int | None = None
    """SampleIdx of the frame that last moved the alive-counter check."""

    @property
    def two_senders(self) -> bool:
        """Two interleaved counter/SampleIdx sequences seen (flag, with hysteresis)."""
        return self.sender.state.two_senders

    @property
    def sample_idx_jumps(self) -> dict[str, int]:
        """SampleIdx breaks the alive counter does not explain, by reason."""
        return dict(self.sender.state.jumps)

    @property
    def lost_net(self) -> int:
        """Frames never seen: counter jumps minus the frames that arrived late."""
        return max(0, self.lost_frames - self.reordered)

    def rate_hz(self) -> float:
        """Mean accepted-frame rate since the first frame."""
        span = self.last_s - self.first_s
        return (self.accepted - 1) / span if self.accepted > 1 and span > 0 else 0.0


MAX_LOST_BY_INDEX = 5000
"""Frames (5 s of a 1 kHz node) a sample-index step may account for as lost; a larger
step is a jump (a restart, a second sender: :class:`gateway.can.e2e.SenderCheck`)."""


def _lost_by_index(dc: int | None, idx: int | None, last_idx: int | None) -> int | None:
    """Frames lost before this one when its sample index moved on by 2 or more from the
    last frame's, by a step its alive-counter step ``dc`` agrees with (the step mod 15);
    else None (no sample index, in sequence, a repeat, a reorder, a jump)."""
    if dc is None or idx is None or last_idx is None:
        return None
    di = (idx - last_idx) % SAMPLE_INDEX_MODULUS
    if 2 <= di <= MAX_LOST_BY_INDEX and di % COUNTER_MODULUS == dc:
        return di - 1
    return None


@dataclass
class ValidatorStats:
    """Totals over all messages."""

    frames: int = 0
    accepted: int = 0
    rejected: Counter[str] = field(default_factory=Counter)

    @property
    def rejected_total(self) -> int:
        return sum(self.rejected.values())


class Validator:
    """Decodes and validates frames of the sensor messages; keeps per-message state."""

    def __init__(self, codec: Codec, *, timeout_cycles: float = 10.0,
                 sender_params: SenderParams | None = None) -> None:
        self._codec = codec
        self._sensor_ids = set(codec.sensor_ids())
        self._counters: dict[int, CounterCheck] = {i: CounterCheck() for i in self._sensor_ids}
        self.timeout_cycles = timeout_cycles
        self.stats = ValidatorStats()
        self.messages: dict[str, MessageStats] = {}
        for name in codec.sensor_messages():
            cycle_ms = codec.cycle_time_ms(name) or 1000
            self.messages[name] = MessageStats(name, cycle_ms / 1000.0,
                                               sender=SenderCheck(sender_params))
        self._by_id = {codec.message(n).frame_id: self.messages[n] for n in self.messages}

    def _reject(self, reason: str, stats: MessageStats | None) -> None:
        self.stats.rejected[reason] += 1
        if stats is not None:
            stats.rejected[reason] += 1

    def feed(self, msg: can.Message) -> DecodedFrame | None:
        """Validate one frame; the decoded frame if accepted, None if rejected (counted)."""
        self.stats.frames += 1
        stats = self._by_id.get(msg.arbitration_id)
        try:
            frame = self._codec.decode_message(msg)
        except FrameError as err:
            self._reject(err.reason, stats)
            return None
        if stats is None:
            self._reject("not_sensor", None)
            return None
        if frame.sample_idx is not None:
            stats.sender.feed(frame.counter, frame.sample_idx)
            if stats.sender.state.two_senders:
                self._reject("two_senders", stats)
                return None
        check = self._counters[msg.arbitration_id]
        last = check.state.last_counter
        dc = None if last is None else (frame.counter - last) % COUNTER_MODULUS
        lost = _lost_by_index(dc, frame.sample_idx, stats.last_idx)
        if lost is not None:
            # frames lost, as many as the sample index says: the counter alone would take
            # a loss of 15k frames for a repeat and one of 15k - 1 for a reordered frame
            # (and reject the next one as a repeat); 2026-11-26, a stalled reader
            check.resync(frame.counter)
            stats.lost_frames += lost
            stats.last_idx = frame.sample_idx
            return self._accept(frame, stats)
        if dc == COUNTER_MODULUS - 1:
            # one behind the newest: a frame overtaken on the bus; the sample index
            # puts it back in place, so accept it without moving the counter check
            stats.reordered += 1
            return self._accept(frame, stats)
        result = check.check(frame.counter)
        if result.status is CounterStatus.REPEATED:
            self._reject("counter_repeated", stats)
            return None
        if result.status is CounterStatus.WRONG_SEQUENCE:
            stats.lost_frames += result.lost_frames
        stats.last_idx = frame.sample_idx
        return self._accept(frame, stats)

    def _accept(self, frame: DecodedFrame, stats: MessageStats) -> DecodedFrame:
        self.stats.accepted += 1
        stats.accepted += 1
        if math.isnan(stats.first_s):
            stats.first_s = frame.timestamp_s
        stats.last_s = frame.timestamp_s
        stats.timed_out = False
        stats.last_values = frame.values
        return frame

    def two_senders(self) -> tuple[str, ...]:
        """Messages flagged with two interleaved senders now."""
        return tuple(n for n, m in self.messages.items() if m.two_senders)

    def check_timeouts(self, now_s: float) -> list[str]:
        """Messages that have just timed out at ``now_s`` (each counted once per outage)."""
        newly = []
        for stats in self.messages.values():
            if stats.timed_out or math.isnan(stats.last_s):
                continue
            if now_s - stats.last_s > self.timeout_cycles * stats.cycle_time_s:
                stats.timed_out = True
                stats.timeouts += 1
                newly.append(stats.name)
        return newly
