"""The front end's view of each node, checked from outside (issue 15, item 3).

A simulator CAN log whose nodes run on known clocks (drift and phase set per node) goes
through ``gateway replay``; the report's ``diagnostics.front_end.nodes`` must give each
node's drift within a few ppm of the truth and the phase of its sample instants against
the 1 kHz grid within a few microseconds. One node (BDN) has frames dropped, delayed past
the deadline and overtaken on the bus: those counts show for that node, and only there.
The same records reach the service's ``status`` reply and its text.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from typing import Any

import can
import pytest

from firmware_sim.nodes import NodeClock
from firmware_sim.output import write_log
from firmware_sim.scenarios import get_scenario
from firmware_sim.simulation import SimConfig, Simulation
from gateway.can.codec import default_codec
from gateway.config import Config
from gateway.console import render
from gateway.frontend.chain import FrontEnd
from gateway.service.view import front_end_view

DURATION_S = 8.0
GRID_PERIOD_US = 1000.0                  # the service's 1 kHz grid
L_MIN_S = 150e-6
"""The simulator's minimum sample-to-bus latency: the model's common shift."""
CLOCKS = {"WSN": NodeClock(drift_ppm=40.0, phase_s=0.30e-3),
          "BGN": NodeClock(drift_ppm=-20.0, phase_s=0.80e-3),
          "BDN": NodeClock(drift_ppm=5.0, phase_s=0.55e-3),
          "VEH": NodeClock(drift_ppm=-10.0, phase_s=4.20e-3)}
MESSAGE = {"WSN": "WSN_Lat", "BGN": "BGN_Lat", "BDN": "BDN_Lat", "VEH": "VEH_Speed"}
DROPPED, LATE, REORDERED = 30, 4, 20
"""BDN frames removed from the log, delayed 70 ms (past the 50 ms deadline), and
delayed just behind the node's next frame (overtaken)."""
DRIFT_TOL_PPM = {"WSN": 3.0, "BGN": 3.0, "BDN": 3.0, "VEH": 5.0}
PHASE_TOL_US = 5.0
"""Model time of the newest sample against truth + L_min: the envelope fit (a few us),
the excess of the lowest latency over L_min, and the log's 1 us timestamps."""
PHASE_DIFF_TOL_US = 4.0
"""Phase difference between two 1 ms nodes (the common shift cancels)."""


def _simulate(duration_s: float) -> tuple[list[can.Message], dict[str, float]]:
    """Frames of a nominal run on the known clocks, and each node's newest true sample
    time, s."""
    sim = Simulation(get_scenario("nominal"), SimConfig(duration_s=duration_s, seed=3),
                     record=True)
    sim.clocks.update(CLOCKS)
    msgs = list(sim.messages())
    assert sim.records is not None
    last = {n: float(r.t_true_s[-1][-1]) for n, r in sim.records.items()}
    return msgs, last


def _faulty(msgs: list[can.Message]) -> list[can.Message]:
    """BDN only: DROPPED frames removed (every 10th in 2.0-2.3 s), LATE frames delayed
    70 ms (4.0-4.4 s) and REORDERED frames moved 10 us behind the next BDN frame
    (every 20th in 5.0-5.4 s). Receive order = timestamp order."""
    bdn = default_codec().message("BDN_Lat").frame_id
    idx = [i for i, m in enumerate(msgs) if m.arbitration_id == bdn]
    drop: set[int] = set()
    for window, every, n, what in (((2.0, 2.3), 10, DROPPED, "drop"),
                                   ((4.0, 4.4), 100, LATE, "late"),
                                   ((5.0, 5.4), 20, REORDERED, "reorder")):
        inside = [j for j, i in enumerate(idx) if window[0] <= msgs[i].timestamp < window[1]]
        picked = inside[::every][:n]
        assert len(picked) == n
        for j in picked:
            m = msgs[idx[j]]
            if what == "drop":
                drop.add(idx[j])
            elif what == "late":
                m.timestamp += 0.070
            else:
                m.timestamp = msgs[idx[j + 1]].timestamp + 10e-6
    kept = [m for i, m in enumerate(msgs) if i not in drop]
    return sorted(kept, key=lambda m: m.timestamp)


def _phase_us(t_s: float) -> float:
    """Where time t_s sits after the grid point at or before it, us."""
    x = t_s * 1e6 / GRID_PERIOD_US
    return (x - math.floor(x)) * GRID_PERIOD_US


def _circ_us(a: float, b: float) -> float:
    """|a - b| on the circle of one grid period, us."""
    d = (a - b) % GRID_PERIOD_US
    return min(d, GRID_PERIOD_US - d)


@pytest.fixture(scope="module")
def replayed(tmp_path_factory) -> tuple[dict[str, Any], dict[str, float]]:
    tmp = tmp_path_factory.mktemp("timing")
    msgs, last = _simulate(DURATION_S)
    log = tmp / "timing.log"
    write_log(_faulty(msgs), log)
    cfg = tmp / "deadline.toml"
    cfg.write_text("[resampler]\ndeadline_s = 0.05\n")
    out = tmp / "report.json"
    proc = subprocess.run([sys.executable, "-m", "gateway", "replay", str(log), "--report",
                           str(out), "--config", str(cfg), "--particles", "64",
                           "--no-progress"], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(out.read_text()), last


def test_report_gives_each_nodes_drift_and_phase(replayed):
    rep, last = replayed
    nodes = rep["diagnostics"]["front_end"]["nodes"]
    assert set(nodes) == set(MESSAGE.values())
    for node, clock in CLOCKS.items():
        got = nodes[MESSAGE[node]]
        assert got["message"] == MESSAGE[node]
        assert abs(got["drift_ppm"] - clock.drift_ppm) <= DRIFT_TOL_PPM[node], (node, got)
        truth_us = _phase_us(last[node] + L_MIN_S)
        assert _circ_us(got["grid_phase_us"], truth_us) <= PHASE_TOL_US, (node, got, truth_us)
        assert 0.0 <= got["grid_phase_us"] < GRID_PERIOD_US
    for a, b in (("WSN", "BGN"), ("WSN", "BDN"), ("BGN", "BDN")):
        seen = nodes[MESSAGE[a]]["grid_phase_us"] - nodes[MESSAGE[b]]["grid_phase_us"]
        truth = _phase_us(last[a]) - _phase_us(last[b])
        assert _circ_us(seen, truth) <= PHASE_DIFF_TOL_US, (a, b, seen, truth)


def test_report_counts_late_missing_and_reordered_for_that_node_only(replayed):
    rep, _ = replayed
    fe = rep["diagnostics"]["front_end"]
    nodes = fe["nodes"]
    bdn = nodes["BDN_Lat"]
    assert (bdn["missing_samples"], bdn["late_samples"], bdn["reordered_samples"]) == (
        DROPPED, LATE, REORDERED), bdn
    for message in ("WSN_Lat", "BGN_Lat", "VEH_Speed"):
        n = nodes[message]
        assert (n["missing_samples"], n["late_samples"], n["reordered_samples"]) == (0, 0, 0), n
    assert sum(n["late_samples"] for n in nodes.values()) == sum(fe["late"].values())
    assert fe["late"]["deadline"] == LATE


def test_clean_log_has_no_late_missing_or_reordered_samples():
    """Guard for the counts above: the drops, delays and swaps are what the test put in
    (a clean front end over the same clocks counts nothing)."""
    msgs, _ = _simulate(2.0)
    codec = default_codec()
    front = FrontEnd(Config(), codec)
    for m in msgs:
        front.on_frame(m)
    front.finish()
    for t in front.stats().nodes.values():
        assert (t.late_samples, t.missing_samples, t.reordered_samples) == (0, 0, 0), t


def test_status_reply_and_text_show_each_node():
    msgs, last = _simulate(2.0)
    front = FrontEnd(Config(), default_codec())
    for m in _faulty_short(msgs):
        front.on_frame(m)
    front.finish()
    view = front_end_view(front.stats())
    assert set(view["nodes"]) == set(MESSAGE.values())
    wsn = view["nodes"]["WSN_Lat"]
    assert abs(wsn["drift_ppm"] - 40.0) <= 5.0
    assert _circ_us(wsn["grid_phase_us"], _phase_us(last["WSN"] + L_MIN_S)) <= PHASE_TOL_US
    assert view["nodes"]["BGN_Lat"]["missing_samples"] == 5
    assert view["nodes"]["WSN_Lat"]["missing_samples"] == 0
    text = render.front_end(view)
    lines = {ln.split()[0]: ln for ln in text.splitlines()[2:]}
    assert set(lines) == set(MESSAGE.values())
    assert "drift +4" in lines["WSN_Lat"] and " ppm, phase " in lines["WSN_Lat"]
    assert "missing 5," in lines["BGN_Lat"] and "missing 0," in lines["WSN_Lat"]
    assert front_end_view(None)["nodes"] == {}


def _faulty_short(msgs: list[can.Message]) -> list[can.Message]:
    """Five BGN frames removed (every 50th from 1.0 s)."""
    bgn = default_codec().message("BGN_Lat").frame_id
    idx = [i for i, m in enumerate(msgs) if m.arbitration_id == bgn and m.timestamp >= 1.0]
    drop = set(idx[::50][:5])
    return [m for i, m in enumerate(msgs) if i not in drop]
