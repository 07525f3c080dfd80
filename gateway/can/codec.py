"""Encode and decode the gateway's CAN frames with the DBC, checking E2E, range and NotAvailable.

The DBC (``dbc.DBC_PATH``) is loaded once with ``strict=True``; cantools compiles each
message codec at load, and decoding is one dict lookup by CAN id plus the compiled
unpack. On top of cantools this module

- checks the frame length (8 bytes), the E2E CRC and the alive counter value
  (see :mod:`gateway.can.e2e`);
- checks every decoded data signal against its DBC min/max, which cantools does not;
- maps each signal's NotAvailable raw value (signal attribute ``NotAvailableRaw``,
  also a ``VAL_`` "NotAvailable") to NaN.

Failures raise :class:`FrameError` whose ``reason`` is one of :data:`REASONS`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import cast

import can
import cantools
import cantools.database

from dbc import DBC_PATH
from gateway.can.busload import BusLoad, CyclicFrame, bus_load
from gateway.can.e2e import COUNTER_MASK, COUNTER_MODULUS, e2e_crc, protect
from gateway.errors import DbcError, FrameError
from gateway.records import DecodedFrame

FRAME_LENGTH_BYTES = 8
"""Every frame on this bus has DLC 8."""
STD_ID_MASK = 0x7FF
REASONS: tuple[str, ...] = ("unknown_id", "frame_type", "dlc", "crc", "counter", "range")
"""Machine-readable :attr:`FrameError.reason` values raised by :meth:`Codec.decode`."""
SENSOR_NODES: tuple[str, ...] = ("WSN", "BGN", "BDN", "VEH")
"""Nodes whose messages the gateway receives."""
SENSOR_SIGNALS: dict[str, tuple[str, str]] = {
    "acc_w1": ("WSN_Lat", "WSN_Acc1"),
    "acc_w2": ("WSN_Lat", "WSN_Acc2"),
    "acc_b": ("BGN_Lat", "BGN_Acc"),
    "gyro_b": ("BGN_Lat", "BGN_YawRate"),
    "acc_bd": ("BDN_Lat", "BDN_Acc"),
    "speed": ("VEH_Speed", "VEH_Speed"),
}
"""Sensor name (as in :data:`gateway.model.vehicle.SENSORS_5`, plus speed) -> (message, signal)."""
SENSOR_NODE: dict[str, str] = {name: msg.split("_")[0] for name, (msg, _) in SENSOR_SIGNALS.items()}
"""Sensor name -> the node that sends it (one of :data:`SENSOR_NODES`)."""

_NAN = math.nan
SignalValue = float | str | None
"""An encode input: a physical value, a VAL_ name, or None/NaN for NotAvailable."""


@dataclass(frozen=True)
class SignalSpec:
    """What the codec needs of one signal; raw limits are the DBC min/max in raw counts."""

    name: str
    start_bit: int
    length_bits: int
    is_signed: bool
    scale: float
    offset: float
    minimum: float
    maximum: float
    unit: str
    raw_min: int
    raw_max: int
    na_raw: int | None
    wraps: bool
    """A sequence counter: no NotAvailable, encoded modulo 2**length_bits."""
    choices: dict[int, str]


@dataclass(frozen=True)
class MessageSpec:
    """One message: ids, timing and its data signals (CRC and counter excluded)."""

    name: str
    frame_id: int
    data_id: int
    sender: str
    cycle_time_ms: int | None
    send_type: str
    sample_idx_signal: str | None
    signals: tuple[SignalSpec, ...]
    """Data signals in start-bit order; includes the SampleIdx signal if any."""

    def signal(self, name: str) -> SignalSpec:
        for spec in self.signals:
            if spec.name == name:
                return spec
        raise DbcError(f"expected a signal of {self.name} from "
                       f"{[s.name for s in self.signals]}, got {name!r}")


def _attr(obj: object, name: str) -> object | None:
    """The explicitly set DBC attribute ``name`` of a message or signal (not defaults)."""
    specifics = getattr(obj, "dbc", None)
    if specifics is None or name not in specifics.attributes:
        return None
    return specifics.attributes[name].value


def _signal_spec(msg_name: str, sig: cantools.database.Signal) -> SignalSpec:
    if sig.minimum is None or sig.maximum is None or not sig.unit:
        raise DbcError(f"expected min, max and unit on {msg_name}.{sig.name}, got "
                       f"[{sig.minimum}|{sig.maximum}] {sig.unit!r}")
    scale, offset = float(sig.scale), float(sig.offset)
    raw_min = math.ceil((sig.minimum - offset) / scale - 1e-6)
    raw_max = math.floor((sig.maximum - offset) / scale + 1e-6)
    na = _attr(sig, "NotAvailableRaw")
    na_raw = int(na) if isinstance(na, int) else None
    choices = {int(k): str(v) for k, v in (sig.choices or {}).items()}
    if na_raw is not None:
        if choices.get(na_raw) != "NotAvailable":
            raise DbcError(f"expected VAL_ {na_raw} \"NotAvailable\" on {msg_name}.{sig.name}, "
                           f"got {choices.get(na_raw)!r}")
        if raw_min <= na_raw <= raw_max:
            raise DbcError(f"expected the NotAvailable raw {na_raw} of {msg_name}.{sig.name} "
                           f"outside its raw range {raw_min}..{raw_max}")
    wraps = na_raw is None and raw_min == 0 and raw_max == 2**sig.length - 1
    return SignalSpec(sig.name, sig.start, sig.length, sig.is_signed, scale, offset,
                      float(sig.minimum), float(sig.maximum), sig.unit, raw_min, raw_max,
                      na_raw, wraps, choices)


def _message_spec(msg: cantools.database.Message) -> MessageSpec:
    where = f"{msg.name} (0x{msg.frame_id:03X})"
    if msg.is_extended_frame or msg.is_fd or msg.length != FRAME_LENGTH_BYTES:
        raise DbcError(f"expected a classic standard-id frame with DLC 8 for {where}, got "
                       f"extended={msg.is_extended_frame} fd={msg.is_fd} dlc={msg.length}")
    header = {s.name: s for s in msg.signals}
    crc, ctr = header.get(f"{msg.name}_CRC"), header.get(f"{msg.name}_Counter")
    if crc is None or ctr is None or (crc.start, crc.length, ctr.start, ctr.length) != (0, 8, 8, 4):
        raise DbcError(f"expected {msg.name}_CRC at bits 0..7 and {msg.name}_Counter at "
                       f"bits 8..11 in {where}, got {sorted(header)}")
    data_id = _attr(msg, "E2EDataID")
    if not isinstance(data_id, int):
        raise DbcError(f"expected an E2EDataID attribute on {where}, got {data_id!r}")
    send = _attr(msg, "GenMsgSendType")
    send_type = str(msg.send_type) if msg.send_type is not None else str(send)
    cycle = int(msg.cycle_time) if msg.cycle_time else None
    if (send_type == "Cyclic") != (cycle is not None):
        raise DbcError(f"expected GenMsgCycleTime exactly on cyclic messages, got "
                       f"{send_type} with cycle {cycle} ms on {where}")
    sample = f"{msg.name}_SampleIdx"
    data = sorted((s for s in msg.signals if s not in (crc, ctr)), key=lambda s: s.start)
    return MessageSpec(msg.name, msg.frame_id, data_id, msg.senders[0] if msg.senders else "",
                       cycle, send_type, sample if sample in header else None,
                       tuple(_signal_spec(msg.name, s) for s in data))


class Codec:
    """The gateway's CAN codec, built once from a DBC file (strict load).

    Use :func:`default_codec` for the packaged DBC. Instances are read-only after
    construction and safe to share between threads.
    """

    def __init__(self, path: Path | str = DBC_PATH) -> None:
        try:
            db = cantools.database.load_file(str(path), strict=True)
        except (OSError, cantools.database.Error) as err:
            raise DbcError(f"{path}: expected a loadable DBC file, got {err}") from err
        if not isinstance(db, cantools.database.can.Database):
            raise DbcError(f"{path}: expected a CAN database, got {type(db).__name__}")
        self.path = Path(path)
        baud = db.dbc.attributes.get("Baudrate") if db.dbc else None
        if baud is None:
            raise DbcError(f"{path}: expected a database attribute Baudrate, got none")
        self.bitrate_bps: int = int(baud.value)
        self._db = db
        self.messages: tuple[MessageSpec, ...] = tuple(
            _message_spec(m) for m in sorted(db.messages, key=lambda m: m.frame_id))
        self._by_name = {m.name: m for m in self.messages}
        self._cantools = {m.name: db.get_message_by_name(m.name) for m in self.messages}
        # Hot path: id -> (spec, cantools message, field tuples).
        self._by_id = {
            m.frame_id: (m, self._cantools[m.name],
                         tuple((s.name, s.scale, s.offset, s.na_raw, s.raw_min, s.raw_max)
                               for s in m.signals if s.name != m.sample_idx_signal))
            for m in self.messages}
        for sensor, (msg_name, sig_name) in SENSOR_SIGNALS.items():
            if msg_name not in self._by_name:
                raise DbcError(f"{path}: expected message {msg_name} for sensor {sensor}")
            self._by_name[msg_name].signal(sig_name)

    # ----------------------------------------------------------------- lookups
    def message(self, name: str) -> MessageSpec:
        """The spec of message ``name``; DbcError if unknown."""
        try:
            return self._by_name[name]
        except KeyError:
            raise DbcError(f"expected a message name from {sorted(self._by_name)}, "
                           f"got {name!r}") from None

    def cantools_message(self, name: str) -> cantools.database.Message:
        """The underlying cantools message (for tools and tests that need raw access)."""
        return self._cantools[self.message(name).name]

    def sensor_periods_s(self) -> dict[str, float]:
        """Each sensor message's cycle time (GenMsgCycleTime), s: the resampler's
        per-stream periods, handed to it so the front end reads no DBC itself."""
        return {m: (self.cycle_time_ms(m) or 1) * 1e-3 for m in self.sensor_messages()}

    def cycle_time_ms(self, name: str) -> int | None:
        """GenMsgCycleTime of message ``name`` in ms; None for event-driven messages."""
        return self.message(name).cycle_time_ms

    def sensor_messages(self) -> tuple[str, ...]:
        """Names of the messages the gateway receives (senders WSN, BGN, BDN, VEH), by id."""
        return tuple(m.name for m in self.messages if m.sender in SENSOR_NODES)

    def sensor_ids(self) -> tuple[int, ...]:
        """CAN ids of :meth:`sensor_messages`, ascending."""
        return tuple(self._by_name[n].frame_id for n in self.sensor_messages())

    def can_filters(self) -> list[dict[str, int | bool]]:
        """python-can / SocketCAN receive filters: exact match on each sensor id."""
        return [{"can_id": i, "can_mask": STD_ID_MASK, "extended": False}
                for i in self.sensor_ids()]

    @staticmethod
    def sensor_signal(sensor: str) -> tuple[str, str]:
        """(message, signal) carrying ``sensor`` (acc_w1 .. acc_bd, speed)."""
        try:
            return SENSOR_SIGNALS[sensor]
        except KeyError:
            raise DbcError(f"expected a sensor from {sorted(SENSOR_SIGNALS)}, "
                           f"got {sensor!r}") from None

    def choices(self, message: str, signal: str) -> dict[int, str]:
        """The VAL_ table of a signal, raw value -> name (empty if none)."""
        return dict(self.message(message).signal(signal).choices)

    def cyclic_frames(self) -> tuple[CyclicFrame, ...]:
        """Every cyclic message as a :class:`CyclicFrame` for :func:`bus_load`."""
        return tuple(CyclicFrame(m.name, FRAME_LENGTH_BYTES, float(m.cycle_time_ms))
                     for m in self.messages if m.cycle_time_ms is not None)

    def bus_load(self) -> BusLoad:
        """Worst-case bus load of all cyclic messages at the DBC's Baudrate."""
        return bus_load(self.cyclic_frames(), self.bitrate_bps)

    # ----------------------------------------------------------------- encode
    def _raw(self, msg: str, spec: SignalSpec, value: SignalValue, saturate: bool) -> int:
        if isinstance(value, str):
            for raw, label in spec.choices.items():
                if label == value:
                    return raw
            raise DbcError(f"expected a value name of {msg}.{spec.name} from "
                           f"{sorted(spec.choices.values())}, got {value!r}")
        if value is None or math.isnan(value):
            if spec.na_raw is None:
                raise FrameError("range", f"expected a number for {msg}.{spec.name} "
                                          f"(it has no NotAvailable value), got {value}")
            return spec.na_raw
        raw = round((value - spec.offset) / spec.scale)
        if spec.wraps:
            return raw % (1 << spec.length_bits)
        if spec.raw_min <= raw <= spec.raw_max:
            return raw
        if saturate:
            return min(max(raw, spec.raw_min), spec.raw_max)
        raise FrameError("range", f"expected {msg}.{spec.name} in [{spec.minimum}, "
                                  f"{spec.maximum}] {spec.unit}, got {value}")

    def encode(self, name: str, signals: Mapping[str, SignalValue], counter: int, *,
               saturate: bool = False) -> bytes:
        """The 8 protected bytes of message ``name``: counter and E2E CRC filled in.

        ``signals`` maps every data signal of the message (including its SampleIdx, if
        any; not CRC or counter) to a physical value in DBC units, a VAL_ name, or
        None/NaN for NotAvailable. Sequence counters (SampleIdx, Alert_Seq, Frames*)
        are taken modulo their width. Out-of-range values raise FrameError("range")
        unless ``saturate``; unknown or missing names raise DbcError.
        """
        spec = self.message(name)
        expected = {s.name for s in spec.signals}
        if set(signals) != expected:
            raise DbcError(f"expected signals {sorted(expected)} for {name}, got unknown "
                           f"{sorted(set(signals) - expected)}, missing "
                           f"{sorted(expected - set(signals))}")
        raw: dict[str, int] = {f"{name}_CRC": 0, f"{name}_Counter": 0}
        for s in spec.signals:
            raw[s.name] = self._raw(name, s, signals[s.name], saturate)
        data = bytearray(self._cantools[name].encode(raw, scaling=False, strict=False))
        return protect(spec.data_id, data, counter)

    def encode_message(self, name: str, signals: Mapping[str, SignalValue], counter: int, *,
                       saturate: bool = False) -> can.Message:
        """:meth:`encode` wrapped in a python-can message (standard id, DLC 8)."""
        data = self.encode(name, signals, counter, saturate=saturate)
        return can.Message(arbitration_id=self._by_name[name].frame_id, data=data,
                           is_extended_id=False, dlc=FRAME_LENGTH_BYTES)

    # ----------------------------------------------------------------- decode
    def decode(self, arbitration_id: int, data: bytes | bytearray,
               timestamp_s: float) -> DecodedFrame:
        """Validate and decode one frame received at ``timestamp_s`` (any clock, s).

        Raises FrameError with reason "unknown_id", "dlc", "crc", "counter" (the
        invalid counter 15) or "range" (a raw value outside the DBC min/max that is not
        the NotAvailable value). Counter *sequence* checks are the caller's
        (:class:`gateway.can.e2e.CounterCheck`, one per message).
        """
        entry = self._by_id.get(arbitration_id)
        if entry is None:
            raise FrameError("unknown_id", f"expected a CAN id from "
                             f"{[hex(i) for i in self._by_id]}, got 0x{arbitration_id:X}")
        spec, msg, fields = entry
        if len(data) != FRAME_LENGTH_BYTES:
            raise FrameError("dlc", f"expected {FRAME_LENGTH_BYTES} data bytes for "
                             f"{spec.name}, got {len(data)}")
        crc = e2e_crc(spec.data_id, data)
        if crc != data[0]:
            raise FrameError("crc", f"expected E2E CRC 0x{crc:02X} for {spec.name}, "
                             f"got 0x{data[0]:02X}")
        counter = data[1] & COUNTER_MASK
        if counter >= COUNTER_MODULUS:
            raise FrameError("counter", f"expected an alive counter 0..14 in {spec.name}, "
                             f"got {counter}")
        # scaling off: raw ints, checked and scaled below (bytearray is fine at run time).
        raw = cast("dict[str, int]", msg.decode_simple(cast(bytes, data), False, False))
        values: dict[str, float] = {}
        for sig, scale, offset, na_raw, lo, hi in fields:
            r = raw[sig]
            if r == na_raw:
                values[sig] = _NAN
            elif lo <= r <= hi:
                values[sig] = r * scale + offset
            else:
                raise FrameError("range", f"expected raw {spec.name}.{sig} in {lo}..{hi} "
                                 f"(or NotAvailable {na_raw}), got {r}")
        sample = spec.sample_idx_signal
        return DecodedFrame(spec.name, arbitration_id, counter,
                            int(raw[sample]) if sample else None, values, timestamp_s)

    def decode_message(self, message: can.Message) -> DecodedFrame:
        """:meth:`decode` for a python-can message; extended, remote, error and FD
        frames raise FrameError("frame_type")."""
        if (message.is_extended_id or message.is_remote_frame or message.is_error_frame
                or message.is_fd):
            raise FrameError("frame_type", f"expected a classic standard-id data frame, got "
                             f"id 0x{message.arbitration_id:X} extended={message.is_extended_id} "
                             f"remote={message.is_remote_frame} error={message.is_error_frame} "
                             f"fd={message.is_fd}")
        return self.decode(message.arbitration_id, message.data, message.timestamp)


@lru_cache(maxsize=4)
def default_codec(path: Path | str = DBC_PATH) -> Codec:
    """The codec for ``path`` (default: the packaged DBC), loaded once per process."""
    return Codec(path)
