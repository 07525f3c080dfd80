"""Tests of gateway.can.e2e: CRC-8 SAE J1850 known answers, E2E CRC, protect, counter check."""

from __future__ import annotations

import random

import pytest

from gateway.can.e2e import (
    CRC8_CHECK,
    CounterCheck,
    CounterResult,
    CounterState,
    CounterStatus,
    classify_counter,
    counter_of,
    crc8_sae_j1850,
    crc_ok,
    e2e_crc,
    next_counter,
    protect,
)
from gateway.errors import FrameError, GatewayError

# AUTOSAR SWS CRC Library, CRC8 SAE J1850 test vectors.
AUTOSAR_VECTORS = [
    ("00000000", 0x59), ("F20183", 0x37), ("0FAA0055", 0x79), ("00FF5511", 0xB8),
    ("332255AABBCCDDEEFF", 0xCB), ("926B55", 0x8C), ("FFFFFFFF", 0x74),
]


def _crc8_bitwise(data: bytes) -> int:
    """Independent bit-by-bit CRC-8 SAE J1850 (poly 0x1D, init 0xFF, xorout 0xFF)."""
    crc = 0xFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1D) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc ^ 0xFF


def test_crc8_check_value() -> None:
    assert crc8_sae_j1850(b"123456789") == 0x4B == CRC8_CHECK


@pytest.mark.parametrize(("hex_data", "expected"), AUTOSAR_VECTORS)
def test_crc8_autosar_vectors(hex_data: str, expected: int) -> None:
    assert crc8_sae_j1850(bytes.fromhex(hex_data)) == expected


def test_crc8_table_matches_bitwise_and_chains() -> None:
    rng = random.Random(1)
    for n in range(0, 20):
        data = bytes(rng.randrange(256) for _ in range(n))
        assert crc8_sae_j1850(data) == _crc8_bitwise(data)
        cut = n // 2
        head = crc8_sae_j1850(data[:cut])
        assert crc8_sae_j1850(data[cut:], start=head ^ 0xFF) == crc8_sae_j1850(data)


def test_e2e_crc_covers_data_id_then_payload_without_byte0() -> None:
    payload = bytes.fromhex("AA0B3412FEDC0080")
    expected = crc8_sae_j1850(bytes([0x01, 0x01]) + payload[1:])
    assert e2e_crc(0x0101, payload) == expected
    assert e2e_crc(0x0101, b"\x00" + payload[1:]) == expected  # byte 0 is not covered
    assert e2e_crc(0x0310, payload) == crc8_sae_j1850(bytes([0x10, 0x03]) + payload[1:])


def test_e2e_crc_detects_every_single_byte_corruption() -> None:
    rng = random.Random(7)
    for _ in range(3):
        frame = protect(0x0102, bytearray(rng.randrange(256) for _ in range(8)), 5)
        assert crc_ok(0x0102, frame)
        for pos in range(8):
            for mask in range(1, 256):
                bad = bytearray(frame)
                bad[pos] ^= mask
                assert not crc_ok(0x0102, bad), (pos, mask)


def test_e2e_crc_detects_wrong_data_id_in_one_byte() -> None:
    frame = protect(0x0101, bytearray(8), 0)
    for other in (0x0102, 0x0103, 0x0110, 0x0001, 0x0201):
        assert not crc_ok(other, frame)


def test_e2e_crc_rejects_bad_data_id() -> None:
    with pytest.raises(GatewayError, match="expected an E2E data id"):
        e2e_crc(0x10000, bytes(8))


def test_protect_fills_counter_and_crc_and_keeps_other_bits() -> None:
    data = bytearray.fromhex("00F7112233445566")
    out = protect(0x0300, data, 9)
    assert out[1] == 0xF9  # high nibble kept, low nibble = counter
    assert counter_of(out) == 9
    assert out[0] == e2e_crc(0x0300, out)
    assert bytes(data) == out  # modified in place too
    assert out[2:] == bytes.fromhex("112233445566")


@pytest.mark.parametrize("counter", [-1, 15, 16])
def test_protect_rejects_invalid_counter(counter: int) -> None:
    with pytest.raises(FrameError) as info:
        protect(0x0101, bytearray(8), counter)
    assert info.value.reason == "counter"


def test_protect_rejects_short_frame() -> None:
    with pytest.raises(FrameError) as info:
        protect(0x0101, bytearray(1), 0)
    assert info.value.reason == "dlc"


def test_next_counter_wraps_after_14() -> None:
    assert [next_counter(c) for c in (0, 13, 14)] == [1, 14, 0]


def test_counter_check_classifications() -> None:
    check = CounterCheck()
    seq = [3, 4, 4, 5, 8, 15, 9, 9, 10]
    got = [check.check(c) for c in seq]
    assert got == [
        CounterResult(CounterStatus.INITIAL),
        CounterResult(CounterStatus.OK),
        CounterResult(CounterStatus.REPEATED),
        CounterResult(CounterStatus.OK),
        CounterResult(CounterStatus.WRONG_SEQUENCE, 2),   # 6 and 7 lost
        CounterResult(CounterStatus.INVALID),
        CounterResult(CounterStatus.OK),                  # 15 did not move the state
        CounterResult(CounterStatus.REPEATED),
        CounterResult(CounterStatus.OK),
    ]


def test_counter_check_wraps_14_to_0_and_counts_loss_across_wrap() -> None:
    check = CounterCheck()
    assert [check.check(c).status for c in (13, 14, 0, 1)] == [
        CounterStatus.INITIAL, CounterStatus.OK, CounterStatus.OK, CounterStatus.OK]
    check = CounterCheck(CounterState(13))
    result = check.check(1)  # 14 and 0 lost
    assert result == CounterResult(CounterStatus.WRONG_SEQUENCE, 2)
    assert check.state == CounterState(1)
    # 14 -> 14 going "forward" by 15 is indistinguishable from a repeat (documented).
    assert classify_counter(CounterState(14), 14)[0].status is CounterStatus.REPEATED
    assert classify_counter(CounterState(0), 14)[0] == CounterResult(
        CounterStatus.WRONG_SEQUENCE, 13)


def test_counter_check_checkpoint_restores_identical_stream() -> None:
    rng = random.Random(3)
    stream = [rng.randrange(16) for _ in range(200)]
    full = CounterCheck()
    first = [full.check(c) for c in stream[:80]]
    saved = full.state
    rest_full = [full.check(c) for c in stream[80:]]
    resumed = CounterCheck(saved)
    assert [resumed.check(c) for c in stream[80:]] == rest_full
    assert first[0].status is CounterStatus.INITIAL
    full.reset()
    assert full.check(7).status is CounterStatus.INITIAL


def test_sender_sequence_is_all_ok() -> None:
    check, counter = CounterCheck(), 0
    statuses = []
    for _ in range(40):
        statuses.append(check.check(counter).status)
        counter = next_counter(counter)
    assert statuses[0] is CounterStatus.INITIAL
    assert set(statuses[1:]) == {CounterStatus.OK}
