"""Tests of dbc/railgw.dbc, gateway.can.codec and gateway.can.busload against real cantools."""

from __future__ import annotations

import math
import random
from pathlib import Path

import can
import cantools
import pytest

from dbc import DBC_PATH
from gateway.can.busload import CyclicFrame, bus_load, frame_bits_worst_case
from gateway.can.codec import REASONS, SENSOR_SIGNALS, Codec, MessageSpec, SignalSpec, default_codec
from gateway.can.e2e import e2e_crc, protect
from gateway.errors import DbcError, FrameError
from gateway.model.vehicle import SENSOR_NOISE_VAR, SENSOR_UNITS, SENSORS_5

CYCLES_MS = {"WSN_Lat": 1, "BGN_Lat": 1, "BDN_Lat": 1, "VEH_Speed": 10, "GW_EstCsy": 100,
             "GW_EstCsay": 100, "GW_EstConicity": 100, "GW_Alert": None, "GW_Health": 1000,
             "GW_HealthFlags": 1000}
IDS = {"WSN_Lat": 0x101, "BGN_Lat": 0x102, "BDN_Lat": 0x103, "VEH_Speed": 0x110,
       "GW_EstCsy": 0x300, "GW_EstCsay": 0x301, "GW_EstConicity": 0x302, "GW_Alert": 0x310,
       "GW_Health": 0x320, "GW_HealthFlags": 0x321}


@pytest.fixture(scope="module")
def codec() -> Codec:
    return default_codec()


@pytest.fixture(scope="module")
def db() -> cantools.database.can.Database:
    loaded = cantools.database.load_file(str(DBC_PATH), strict=True)
    assert isinstance(loaded, cantools.database.can.Database)
    return loaded


def _raw_frame(codec: Codec, name: str, raw: dict[str, int], counter: int = 0) -> bytes:
    """A correctly protected frame built from raw values (bypasses encode's checks)."""
    spec = codec.message(name)
    msg = codec.cantools_message(name)
    full = {s.name: 0 for s in msg.signals} | raw
    return protect(spec.data_id, bytearray(msg.encode(full, scaling=False, strict=False)),
                   counter)


def _random_value(rng: random.Random, s: SignalSpec) -> float | str:
    if s.choices and rng.random() < 0.5:
        names = [v for k, v in s.choices.items() if k != s.na_raw]
        if names:
            return rng.choice(names)
    return rng.uniform(s.minimum, s.maximum)


# ------------------------------------------------------------------ the DBC itself
def test_strict_load_and_bus_parameters(db: cantools.database.can.Database) -> None:
    assert db.dbc is not None
    assert db.dbc.attributes["Baudrate"].value == 1_000_000
    assert {m.name: m.frame_id for m in db.messages} == IDS
    assert sorted(n.name for n in db.nodes) == ["BDN", "BGN", "GW", "VEH", "WSN"]
    for m in db.messages:
        assert not m.is_extended_frame and not m.is_fd and m.length == 8
        assert m.comment, m.name
        assert m.dbc is not None and m.dbc.attributes["E2EDataID"].value == m.frame_id
        assert m.cycle_time == CYCLES_MS[m.name]
        assert m.send_type == ("Event" if CYCLES_MS[m.name] is None else "Cyclic")
        for s in m.signals:
            assert s.byte_order == "little_endian", s.name
            assert s.minimum is not None and s.maximum is not None and s.unit, s.name
            assert s.comment, s.name


def test_strict_load_rejects_overlapping_signals(tmp_path: Path) -> None:
    text = DBC_PATH.read_text().replace(" SG_ WSN_Acc2 : 48|16@1-", " SG_ WSN_Acc2 : 40|16@1-")
    bad = tmp_path / "bad.dbc"
    bad.write_text(text)
    with pytest.raises(DbcError, match="overlapping"):
        Codec(bad)


def test_missing_file_is_a_dbc_error(tmp_path: Path) -> None:
    with pytest.raises(DbcError, match="expected a loadable DBC"):
        Codec(tmp_path / "none.dbc")


def test_dbc_survives_a_cantools_dump_and_reload(db: cantools.database.can.Database,
                                                 tmp_path: Path) -> None:
    out = tmp_path / "dumped.dbc"
    out.write_text(db.as_dbc_string())
    again = Codec(out)
    assert [m.name for m in again.messages] == [m.name for m in default_codec().messages]


def test_header_layout(codec: Codec) -> None:
    for spec in codec.messages:
        msg = codec.cantools_message(spec.name)
        crc = msg.get_signal_by_name(f"{spec.name}_CRC")
        ctr = msg.get_signal_by_name(f"{spec.name}_Counter")
        assert (crc.start, crc.length, ctr.start, ctr.length) == (0, 8, 8, 4)
        assert (ctr.minimum, ctr.maximum) == (0, 14)
        if spec.sender in ("WSN", "BGN", "BDN", "VEH"):
            sample = spec.signal(f"{spec.name}_SampleIdx")
            assert (sample.start_bit, sample.length_bits, sample.wraps) == (16, 16, True)
            assert all(s.start_bit >= 32 for s in spec.signals if s is not sample)


def test_not_available_values_declared_twice_and_outside_range(codec: Codec) -> None:
    for spec in codec.messages:
        for s in spec.signals:
            if s.wraps:
                assert s.na_raw is None, s.name
                continue
            assert s.na_raw is not None, f"{spec.name}.{s.name} has no NotAvailable"
            assert s.choices[s.na_raw] == "NotAvailable"
            assert not s.raw_min <= s.na_raw <= s.raw_max
            if s.length_bits == 16:
                assert s.na_raw == (-0x8000 if s.is_signed else 0xFFFF), s.name
            else:
                assert s.na_raw == (1 << s.length_bits) - 1, s.name
    acc = codec.message("WSN_Lat").signal("WSN_Acc1")
    assert (acc.minimum, acc.maximum, acc.raw_min, acc.raw_max) == (-16.3835, 16.3835,
                                                                    -32767, 32767)


def test_resolution_is_ten_times_finer_than_sensor_noise(codec: Codec) -> None:
    assert set(SENSORS_5) <= set(SENSOR_SIGNALS)
    for sensor in SENSORS_5:
        msg, sig = codec.sensor_signal(sensor)
        spec = codec.message(msg).signal(sig)
        noise_std = math.sqrt(SENSOR_NOISE_VAR[sensor])
        assert 10 * spec.scale <= noise_std, (sensor, spec.scale, noise_std)
        assert spec.unit == SENSOR_UNITS[sensor]
    assert codec.message("VEH_Speed").signal("VEH_Speed").unit == "m/s"


def test_sensor_helpers(codec: Codec) -> None:
    assert codec.sensor_messages() == ("WSN_Lat", "BGN_Lat", "BDN_Lat", "VEH_Speed")
    assert codec.sensor_ids() == (0x101, 0x102, 0x103, 0x110)
    assert codec.can_filters()[0] == {"can_id": 0x101, "can_mask": 0x7FF, "extended": False}
    assert codec.cycle_time_ms("VEH_Speed") == 10
    assert codec.cycle_time_ms("GW_Alert") is None
    assert codec.sensor_signal("gyro_b") == ("BGN_Lat", "BGN_YawRate")
    assert codec.choices("GW_Alert", "GW_Alert_Severity")[3] == "Alarm"
    with pytest.raises(DbcError, match="expected a sensor"):
        codec.sensor_signal("acc_x")
    assert isinstance(codec.message("GW_Health"), MessageSpec)


# ------------------------------------------------------------------ bus load
def test_frame_bits_worst_case_known_values() -> None:
    assert frame_bits_worst_case(8) == 135  # 47 + 64 + floor(97 / 4)
    assert frame_bits_worst_case(0) == 55   # 47 + 0 + floor(33 / 4)


def test_bus_load_below_half_and_hand_computed(codec: Codec) -> None:
    load = codec.bus_load()
    # frames/s: 3 x 1000 sensor + 100 speed + 3 x 10 estimates + 2 health, 135 bits each
    assert load.bits_per_s == pytest.approx((3000 + 100 + 30 + 2) * 135)
    assert load.load_fraction == pytest.approx(0.42282)
    assert load.load_fraction <= 0.5
    sensors = bus_load([f for f in codec.cyclic_frames() if f.cycle_time_ms == 1], 1e6)
    assert sensors.load_fraction == pytest.approx(0.405)
    assert bus_load([CyclicFrame("x", 8, 0.5)], 500_000).load_percent == pytest.approx(54.0)


# ------------------------------------------------------------------ encode/decode
@pytest.mark.parametrize("name", list(IDS))
def test_every_message_round_trips(codec: Codec, name: str) -> None:
    rng = random.Random(name)
    spec = codec.message(name)
    for counter in range(15):
        values = {s.name: _random_value(rng, s) for s in spec.signals}
        data = codec.encode(name, values, counter)
        assert len(data) == 8
        frame = codec.decode(spec.frame_id, data, timestamp_s=12.5)
        assert (frame.message, frame.arbitration_id, frame.counter) == (name, IDS[name], counter)
        assert frame.timestamp_s == 12.5 and not frame.not_available
        for s in spec.signals:
            sent = values[s.name]
            if isinstance(sent, str):
                sent = next(k for k, v in s.choices.items() if v == sent)
            if s.name == spec.sample_idx_signal:
                assert frame.sample_idx == round(sent)
                continue
            assert abs(frame.values[s.name] - sent) <= s.scale / 2 + 1e-9 * abs(sent), s.name


def test_decode_accepts_python_can_message(codec: Codec) -> None:
    msg = codec.encode_message("BGN_Lat", {"BGN_Lat_SampleIdx": 65536 + 17, "BGN_Acc": -0.5,
                                           "BGN_YawRate": 0.01}, 14)
    assert isinstance(msg, can.Message) and msg.arbitration_id == 0x102
    assert not msg.is_extended_id and msg.dlc == 8
    frame = codec.decode_message(msg)
    assert frame.sample_idx == 17  # wraps at 65536
    assert frame.values == {"BGN_Acc": -0.5, "BGN_YawRate": pytest.approx(0.01)}
    ext = can.Message(arbitration_id=0x102, data=msg.data, is_extended_id=True)
    with pytest.raises(FrameError) as info:
        codec.decode_message(ext)
    assert info.value.reason == "frame_type"


def test_known_bytes(codec: Codec) -> None:
    data = codec.encode("WSN_Lat", {"WSN_Lat_SampleIdx": 0x1234, "WSN_Acc1": 1.0,
                                    "WSN_Acc2": -1.0}, 3)
    # raw 2000 = 0x07D0, -2000 = 0xF830, little-endian
    assert data[1:] == bytes.fromhex("033412D00730F8")


def test_not_available_decodes_as_nan(codec: Codec) -> None:
    data = _raw_frame(codec, "WSN_Lat", {"WSN_Acc1": -32768, "WSN_Acc2": 10})
    frame = codec.decode(0x101, data, 0.0)
    assert math.isnan(frame.values["WSN_Acc1"]) and frame.values["WSN_Acc2"] == 0.005
    assert frame.not_available == {"WSN_Acc1"}
    speed = codec.decode(0x110, codec.encode("VEH_Speed", {
        "VEH_Speed_SampleIdx": 1, "VEH_Speed": None, "VEH_Odometer": math.nan}, 0), 0.0)
    assert speed.not_available == {"VEH_Speed", "VEH_Odometer"}
    assert codec.encode("VEH_Speed", {"VEH_Speed_SampleIdx": 1, "VEH_Speed": None,
                                      "VEH_Odometer": 0.0}, 0)[4:6] == b"\xff\xff"


@pytest.mark.parametrize(("name", "raw"), [
    ("GW_EstCsy", {"GW_EstCsy_Status": 5}),
    ("GW_EstCsay", {"GW_EstCsay_EssPct": 101}),
    ("GW_Alert", {"GW_Alert_Param": 4}),
    ("GW_Health", {"GW_Health_RtFactor": 0}),  # in range: control case
])
def test_out_of_range_raw_raises_range(codec: Codec, name: str, raw: dict[str, int]) -> None:
    data = _raw_frame(codec, name, raw, counter=2)
    if name == "GW_Health":
        assert codec.decode(IDS[name], data, 0.0).counter == 2
        return
    with pytest.raises(FrameError) as info:
        codec.decode(IDS[name], data, 0.0)
    assert info.value.reason == "range"
    assert "expected raw" in str(info.value)


def test_decode_rejection_reasons(codec: Codec) -> None:
    good = codec.encode("BDN_Lat", {"BDN_Lat_SampleIdx": 5, "BDN_Acc": 0.25}, 7)
    bad_counter = bytearray(8)
    bad_counter[1] = 0x0F  # counter 15 under a valid CRC
    bad_counter[0] = e2e_crc(0x103, bad_counter)
    cases = {
        "unknown_id": (0x555, good),
        "dlc": (0x103, good[:7]),
        "crc": (0x103, bytes([good[0] ^ 0x01]) + good[1:]),
        "counter": (0x103, bytes(bad_counter)),
    }
    for reason, (can_id, data) in cases.items():
        with pytest.raises(FrameError) as info:
            codec.decode(can_id, data, 0.0)
        assert info.value.reason == reason
        assert info.value.reason in REASONS
        assert "expected" in str(info.value) and "got" in str(info.value)
    # the same frame under another message's id fails its CRC (data id differs)
    with pytest.raises(FrameError, match="CRC"):
        codec.decode(0x101, good, 0.0)


def test_encode_errors(codec: Codec) -> None:
    with pytest.raises(DbcError, match="expected a message name"):
        codec.encode("NoSuch", {}, 0)
    with pytest.raises(DbcError, match=r"unknown \['Typo'\], missing \['BDN_Acc'\]"):
        codec.encode("BDN_Lat", {"BDN_Lat_SampleIdx": 0, "Typo": 1.0}, 0)
    with pytest.raises(DbcError, match="expected a value name"):
        codec.encode("GW_Alert", {"GW_Alert_Seq": 0, "GW_Alert_Code": 1,
                                  "GW_Alert_Severity": "Panic", "GW_Alert_Param": "Csy",
                                  "GW_Alert_State": "Raised", "GW_Alert_ValueRel": 1.0}, 0)
    est: dict[str, float | str | None] = {
        "GW_EstCsay_Status": "Valid", "GW_EstCsay_Mean": 2e7, "GW_EstCsay_Std": 1e5,
        "GW_EstCsay_EssPct": 50.0}
    with pytest.raises(FrameError) as info:
        codec.encode("GW_EstCsay", est, 0)
    assert info.value.reason == "range"
    frame = codec.decode(0x301, codec.encode("GW_EstCsay", est, 0, saturate=True), 0.0)
    assert frame.values["GW_EstCsay_Mean"] == 13_106_800.0
    with pytest.raises(FrameError) as info:
        codec.encode("GW_EstCsay", est | {"GW_EstCsay_Mean": 1e6}, 15)
    assert info.value.reason == "counter"


def test_health_flags_frame_carries_every_flag_and_counter(codec: Codec) -> None:
    from gateway.sinks.outputs import CanSink, Health, HealthFlags

    sent: list[can.Message] = []
    sink = CanSink(codec, lambda m: sent.append(m) or True, 500)
    for k, flag in enumerate(("state_quarantined", "persistence_failing",
                              "priority_not_applied", "front_end_resyncing", "two_senders")):
        flags = HealthFlags(**{flag: True}, late_frames=4096 + k, gap_samples=7,
                            write_failures=3, resyncs=256 + k)
        sink.emit_health(Health("Running", 0, 0, 1, 0, 0, 1.0, flags))
        frames = {codec.decode_message(m).message: codec.decode_message(m) for m in sent[-2:]}
        v = frames["GW_HealthFlags"].values
        raised = [name for name in ("StateQuarantined", "PersistFailing", "PriorityNotApplied",
                                    "FrontEndResync", "TwoSenders")
                  if v[f"GW_HealthFlags_{name}"] == 1]
        assert len(raised) == 1 and flags.names() == [flag.replace("_", "-")]
        assert raised[0] == ("StateQuarantined", "PersistFailing", "PriorityNotApplied",
                             "FrontEndResync", "TwoSenders")[k]
        assert (v["GW_HealthFlags_LateFrames"], v["GW_HealthFlags_GapSamples"],
                v["GW_HealthFlags_WriteFailures"], v["GW_HealthFlags_Resyncs"]) == (k, 7, 3, k)
        assert frames["GW_Health"].values["GW_Health_GwState"] == 1
    for node in ("WSN", "BGN", "BDN"):
        flags = HealthFlags(left_out_nodes=(node,))
        sink.emit_health(Health("Running", 0, 0, 1, 0, 0, 1.0, flags))
        v = codec.decode_message(sent[-1]).values
        raised = [n for n in ("Wsn", "Bgn", "Bdn") if v[f"GW_HealthFlags_{n}LeftOut"] == 1]
        assert raised == [node.capitalize()] and flags.names() == [f"left-out-{node}"]


def test_a_provisional_estimate_goes_on_the_bus_as_converging_at_best(codec: Codec) -> None:
    """The estimator's sensor-noise test window: a converged estimate still says
    Converging until the test is made, then Valid."""
    from gateway.records import Estimate
    from gateway.sinks.outputs import CanSink

    sent: list[can.Message] = []
    sink = CanSink(codec, lambda m: sent.append(m) or True, 1000)
    tight = Estimate(1.0, (40e3, 3.0e6, 0.15), (100.0, 1e4, 3e-4), 900.0, provisional=True)
    sink.emit_estimate(tight)
    sink.emit_estimate(Estimate(2.0, tight.mean, tight.std, 900.0))
    status = [v for m in sent for k, v in codec.decode_message(m).values.items()
              if k.endswith("_Status")]
    assert status == [1] * 3 + [2] * 3          # 1 Converging, 2 Valid (docs/can-bus.md)


def test_an_unresolved_parameter_goes_on_the_bus_as_unresolved(
        codec: Codec, db: cantools.database.can.Database) -> None:
    """A parameter the sensors in use cannot resolve (a node left out,
    gateway.estimator.observability) says 4 Unresolved, however narrow its σ; the others
    keep Valid, and a gated estimate still says PredictOnly."""
    from gateway.records import Estimate
    from gateway.sinks.outputs import CanSink

    sent: list[can.Message] = []
    sink = CanSink(codec, lambda m: sent.append(m) or True, 1000)
    tight = Estimate(1.0, (40e3, 3.0e6, 0.15), (100.0, 1e4, 3e-4), 900.0,
                     left_out=("acc_bd",), unresolved=("csy_ns_per_m",))
    sink.emit_estimate(tight)
    sink.emit_estimate(Estimate(2.0, tight.mean, tight.std, 900.0, updated=False,
                                unresolved=("csy_ns_per_m",)))
    decoded = [codec.decode_message(m).values for m in sent]
    status = [v for d in decoded for k, v in d.items() if k.endswith("_Status")]
    assert status == [4, 2, 2, 3, 3, 3]     # 4 Unresolved, 2 Valid, 3 PredictOnly
    for msg in ("GW_EstCsy", "GW_EstCsay", "GW_EstConicity"):
        signal = db.get_message_by_name(msg).get_signal_by_name(f"{msg}_Status")
        assert signal.choices[4] == "Unresolved" and signal.maximum == 4
