"""Replay: byte-identical outputs, and hostile traffic counted without changing estimates."""

from __future__ import annotations

import json
from pathlib import Path

import can
import numpy as np
import pytest

from firmware_sim.output import write_log
from firmware_sim.scenarios import get_scenario
from firmware_sim.simulation import SimConfig, Simulation
from gateway.can.codec import default_codec
from gateway.can.e2e import e2e_crc

PARTICLES = "64"


@pytest.fixture(scope="module")
def clean_log(tmp_path_factory) -> tuple[Path, list[can.Message]]:
    sim = Simulation(get_scenario("paper"), SimConfig(duration_s=3.0, seed=11))
    messages = list(sim.messages())
    path = tmp_path_factory.mktemp("replay") / "clean.log"
    write_log(messages, path)
    return path, messages


def _replay(cli, log: Path, out: Path) -> tuple[dict, bytes]:
    proc = cli("gateway", "replay", str(log), "--report", str(out / "r.json"), "--jsonl",
               str(out / "r.jsonl"), "--particles", PARTICLES, "--no-progress", timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads((out / "r.json").read_text()), (out / "r.jsonl").read_bytes()


def test_replay_twice_gives_identical_json_lines(cli, clean_log, tmp_path):
    log, _ = clean_log
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    rep_a, lines_a = _replay(cli, log, tmp_path / "a")
    rep_b, lines_b = _replay(cli, log, tmp_path / "b")
    assert lines_a == lines_b and len(lines_a) > 0
    rows = [json.loads(x) for x in lines_a.splitlines()]
    assert {r["type"] for r in rows} <= {"estimate", "alert"}
    assert rows[-1]["t_s"] > 2.5 or any(r["t_s"] > 2.5 for r in rows)
    assert set(rep_a["estimates"]) == {"csy_ns_per_m", "csay_ns_per_m", "conicity"}
    assert rep_a["history"] and "alerts" in rep_a
    assert rep_a["diagnostics"]["frames"] == sum(1 for _ in can.LogReader(str(log)))


def _hostile(messages: list[can.Message], rng: np.random.Generator) -> tuple[list, dict]:
    """The clean frames plus garbage of every kind, interleaved by timestamp."""
    codec = default_codec()
    extra: list[can.Message] = []
    expected = {"unknown_id": 0, "dlc": 0, "crc": 0}
    t_end = messages[-1].timestamp
    # a flood at twice the bus capacity (2 x 8000 frames/s) on ids the DBC does not know
    n_flood = int(2 * 8000 * t_end)
    for t in np.sort(rng.uniform(0, t_end, n_flood)):
        extra.append(can.Message(timestamp=float(t), arbitration_id=int(rng.integers(0x600, 0x7FF)),
                                 data=rng.bytes(8), is_extended_id=False))
    expected["unknown_id"] += n_flood
    sensors = [m for m in messages if m.arbitration_id in codec.sensor_ids()]
    for m in rng.choice(len(sensors), 300, replace=False):
        src = sensors[int(m)]
        t = src.timestamp + 1e-6
        extra.append(can.Message(timestamp=t, arbitration_id=src.arbitration_id,
                                 data=bytes(src.data[:5]), dlc=5, is_extended_id=False))
        expected["dlc"] += 1
        bad = bytearray(src.data)
        bad[4] ^= 0x55                       # corrupted payload, stale CRC
        extra.append(can.Message(timestamp=t + 1e-6, arbitration_id=src.arbitration_id,
                                 data=bytes(bad), is_extended_id=False))
        expected["crc"] += 1
    # replayed copies with a jumped counter and a valid CRC: accepted by E2E, but their
    # sample index is already taken, so the resampler ignores them as duplicates
    for m in rng.choice(len(sensors), 50, replace=False):
        src = sensors[int(m)]
        dup = bytearray(src.data)
        dup[1] = (dup[1] & 0xF0) | ((dup[1] + 7) % 15)
        data_id = codec.message(codec.decode_message(src).message).data_id
        dup[0] = e2e_crc(data_id, dup)
        extra.append(can.Message(timestamp=src.timestamp + 2e-6,
                                 arbitration_id=src.arbitration_id, data=bytes(dup),
                                 is_extended_id=False))
    merged = sorted(messages + extra, key=lambda m: m.timestamp)
    return merged, expected


def test_hostile_traffic_is_counted_and_does_not_change_the_estimates(cli, clean_log, tmp_path):
    log, messages = clean_log
    hostile, expected = _hostile(messages, np.random.default_rng(3))
    bad_log = tmp_path / "hostile.log"
    write_log(hostile, bad_log)
    (tmp_path / "clean").mkdir()
    (tmp_path / "bad").mkdir()
    _, clean_lines = _replay(cli, log, tmp_path / "clean")
    report, bad_lines = _replay(cli, bad_log, tmp_path / "bad")
    rejected = report["diagnostics"]["rejected"]
    for reason, n in expected.items():
        assert rejected.get(reason, 0) == n, (reason, rejected)
    assert report["diagnostics"]["frames"] == len(hostile)
    clean_est = [x for x in clean_lines.splitlines() if b'"estimate"' in x]
    bad_est = [x for x in bad_lines.splitlines() if b'"estimate"' in x]
    assert clean_est == bad_est


def test_replay_bad_inputs(cli, tmp_path):
    proc = cli("gateway", "replay", str(tmp_path / "missing.log"), "--report",
               str(tmp_path / "r.json"))
    assert proc.returncode != 0 and "Traceback" not in proc.stderr
    assert "expected a CAN log file" in proc.stderr
    junk = tmp_path / "junk.asc"
    junk.write_text("this is not a log\n")
    proc = cli("gateway", "replay", str(junk), "--report", str(tmp_path / "r.json"))
    assert proc.returncode != 0 and "Traceback" not in proc.stderr
