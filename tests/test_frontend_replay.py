"""Issue 12 acceptance through ``gateway replay`` (worker process, real log files).

- Finding 1: ten frames stamped 0.5 s early at t = 4 s. The replay keeps measurement
  updates at >= 99 % of the clean run's and its estimates within 1 % of the clean run.
- Finding 8: a second BGN node with valid CRCs (its own counter, SampleIdx, clock and
  values x 1.5) sends from 3 s to 6 s. The report counts it, the stream is excluded
  while two senders are seen, and the estimates stay near the clean run.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from firmware_sim.output import drop_frames, write_log
from firmware_sim.scenarios import get_scenario
from firmware_sim.simulation import SimConfig, Simulation

DURATION_S = 12.0
PARTICLES = "64"


def _log(path: Path, *, glitch_s: float = 0.0, loss: float = 0.0, **sim: object) -> Path:
    cfg = SimConfig(duration_s=DURATION_S, seed=1, **sim)  # type: ignore[arg-type]
    msgs = list(Simulation(get_scenario("nominal"), cfg).messages())
    msgs = list(drop_frames(msgs, loss, np.random.default_rng(7)))
    if glitch_s:
        i0 = next(i for i, m in enumerate(msgs) if m.timestamp >= 4.0)
        for m in msgs[i0:i0 + 10]:              # about 3 ms of traffic
            m.timestamp += glitch_s
    write_log(msgs, path)
    return path


def _replay(log: Path) -> dict:
    out = log.with_suffix(".json")
    proc = subprocess.run([sys.executable, "-m", "gateway", "replay", str(log), "--report",
                           str(out), "--particles", PARTICLES, "--no-progress"],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(out.read_text())


@pytest.fixture(scope="module")
def clean(tmp_path_factory) -> dict:
    return _replay(_log(tmp_path_factory.mktemp("fe") / "clean.log"))


def _rel(a: dict, b: dict, name: str) -> float:
    return abs(a["estimates"][name]["mean"] / b["estimates"][name]["mean"] - 1.0)


def test_timestamp_glitch_replay_keeps_updates_and_estimates(clean, tmp_path):
    rep = _replay(_log(tmp_path / "glitch.log", glitch_s=-0.5))
    fe, ref = rep["diagnostics"]["front_end"], clean["diagnostics"]["front_end"]
    assert fe["gating"]["updated"] >= 0.99 * ref["gating"]["updated"]
    assert ref["gating"]["updated"] >= 0.99 * DURATION_S * 1000
    assert sum(fe["late"].values()) == 0
    assert fe["retimed_frames"] == 10
    for name in ("csy_ns_per_m", "csay_ns_per_m", "conicity"):
        assert _rel(rep, clean, name) < 0.01, (name, rep["estimates"], clean["estimates"])


def test_a_lossy_bus_loses_only_its_lost_frames(clean, tmp_path):
    """One frame in 100 dropped on the bus (about 370 frames in 12 s): each lost sensor
    frame makes its node's entries MISSING on one or two grid points (reason ``lost``),
    no frame is late (a hole the node has overtaken is not waited for, and no frame
    comes after the grid took it for lost), the grid keeps at least 95 % of the clean
    run's updates (measured 11,993 of 11,998: before the yaw low-pass bridged short
    gyro gaps, its restarts were taken for curves and 9,019 samples were gated), and the
    estimates stay within 2 % of the clean run's (fast mode hands each partial sample
    to the exact recursion and comes back)."""
    rep = _replay(_log(tmp_path / "lossy.log", loss=0.01))
    fe, ref = rep["diagnostics"]["front_end"], clean["diagnostics"]["front_end"]
    lost = {msg: gaps["lost"] for msg, gaps in fe["gaps"].items()}
    assert sum(fe["late"].values()) == 0
    assert all(60 <= n <= 2 * 160 for n in lost.values()), lost  # ~120 frames each
    assert fe["gating"]["updated"] >= 0.95 * ref["gating"]["updated"]
    for name in ("csy_ns_per_m", "csay_ns_per_m", "conicity"):
        assert _rel(rep, clean, name) < 0.02, (name, rep["estimates"], clean["estimates"])


def test_second_sender_is_counted_excluded_and_harmless(tmp_path):
    # the reference is the same simulation with the second sender never sending: adding a
    # sender changes the simulator's random draws, so the default run is another noise
    # realisation, and comparing with it measured that (Csy 3-4 %), not the exclusion
    clean = _replay(_log(tmp_path / "clean.log", second_sender="BGN",
                         second_sender_window_s=(1e9, 1e9)))
    rep = _replay(_log(tmp_path / "rogue.log", second_sender="BGN",
                            second_sender_window_s=(3.0, 6.0)))
    fe = rep["diagnostics"]["front_end"]
    assert fe["two_sender_events"] == {"WSN_Lat": 0, "BGN_Lat": 1, "BDN_Lat": 0,
                                       "VEH_Speed": 0}
    assert fe["two_senders"] == []                 # single again by the end
    assert rep["diagnostics"]["rejected"]["two_senders"] > 5000   # 3 s x 2 senders
    excluded = fe["gaps"]["BGN_Lat"]["excluded"]
    assert 3000 <= excluded <= 4500                # the window plus the clearing hold
    assert fe["gating"]["updated"] >= 0.99 * (DURATION_S * 1000 - excluded - 1000)
    for name in ("csy_ns_per_m", "csay_ns_per_m", "conicity"):
        assert _rel(rep, clean, name) < 0.03, (name, rep["estimates"], clean["estimates"])
