"""Absurd receive timestamps cost bounded work and memory (issue 12, follow-up).

One candump frame stamped 1e300 used to make the resampler walk its grid through empty
time point by point, for ever (memory growing); a 1e9 s jump took time growing with the
jump. Now a receive time beyond a horizon is counted by reason
(``FrontEndStats.horizon``) and never walked: asserted on counters (grid points emitted,
horizon reasons), not on wall time.
"""

from __future__ import annotations

import copy
import json
import subprocess
import sys
from functools import lru_cache
from pathlib import Path
from types import SimpleNamespace
from typing import Any, cast

import can
import pytest

from firmware_sim.output import write_log
from firmware_sim.scenarios import get_scenario
from firmware_sim.simulation import SimConfig, Simulation
from gateway.can.codec import default_codec
from gateway.config import Config, with_overrides
from gateway.frontend.chain import FrontEnd
from gateway.frontend.resample import FAR_TIME_S, MAX_WALK_S
from gateway.service.daemon import Service
from gateway.sinks.outputs import CanSink, Health

DURATION_S = 3.0
GRID_HZ = 1000.0
BOUND = int((DURATION_S + 0.1) * GRID_HZ)
"""Grid points a 3 s log may produce, whatever its timestamps."""


@lru_cache(maxsize=1)
def _clean() -> tuple[can.Message, ...]:
    return tuple(Simulation(get_scenario("nominal"),
                            SimConfig(duration_s=DURATION_S, seed=1)).messages())


def _traffic() -> list[can.Message]:
    return [copy.copy(m) for m in _clean()]


def _run(msgs: list[can.Message]) -> tuple[FrontEnd, int, int]:
    """Frames through the front end as the replay feeds them; (front end, grid points
    out, measurement updates)."""
    fe = FrontEnd(Config(), default_codec())
    out = []
    for i, m in enumerate(msgs):
        out += fe.on_frame(m)
        if i % 1000 == 999:
            out += fe.on_time(m.timestamp)
    out += fe.finish()
    return fe, len(out), sum(s.update for s in out)


@pytest.mark.parametrize("stamp", [1e300, -1e300, 2e10])
def test_one_frame_far_beyond_the_time_range_is_counted_not_walked(stamp: float) -> None:
    msgs = _traffic()
    i = next(i for i, m in enumerate(msgs) if m.timestamp >= 1.0)
    msgs[i].timestamp = stamp
    fe, n, updates = _run(msgs)
    s = fe.stats()
    assert s.horizon["time_range"] == 1
    assert n <= BOUND and updates >= 0.99 * DURATION_S * GRID_HZ
    assert s.late_total == 0 and s.grid_jump_points == 0


@pytest.mark.parametrize("jump_s", [1e9, -1e9, 500.0])
def test_receive_clock_jump_is_re_based_not_walked(jump_s: float) -> None:
    msgs = _traffic()
    for m in msgs:
        if m.timestamp >= 1.0:
            m.timestamp += jump_s
    fe, n, updates = _run(msgs)
    s = fe.stats()
    assert s.clock_steps == 1 and s.rx_offset_s == pytest.approx(-jump_s, abs=1e-3)
    assert n <= BOUND and updates >= 0.99 * DURATION_S * GRID_HZ
    assert s.late_total == 0
    assert (s.horizon["far_time"] > 0) == (abs(jump_s) > FAR_TIME_S)


@pytest.mark.parametrize("jump_s", [1e9, 500.0])
def test_one_node_alone_far_off_is_not_a_restart(jump_s: float) -> None:
    """One receive clock cannot step for one node: its run is settled as a glitch (frames
    placed by index or dropped), the others go on, the grid does not move."""
    msgs = _traffic()
    bdn = default_codec().message("BDN_Lat").frame_id
    for m in msgs:
        if m.timestamp >= 1.0 and m.arbitration_id == bdn:
            m.timestamp += jump_s
    fe, n, updates = _run(msgs)
    s = fe.stats()
    assert s.horizon["far_step"] >= 1 and s.resyncs == 0 and s.clock_steps == 0
    assert s.late_total == 0 and n <= BOUND
    assert s.horizon["grid_jump"] == 0


def test_silence_beyond_the_walk_horizon_jumps_the_grid_once() -> None:
    """The receive horizon leaps over a silent bus (host suspended for 10 min, then
    ``on_time``): the grid jumps, counted once, instead of emitting every empty point."""
    silence_s = 10 * MAX_WALK_S
    msgs = [m for m in _traffic() if m.timestamp < 1.0]
    fe, n, _ = _run(msgs)
    n += len(fe.on_time(msgs[-1].timestamp + silence_s))
    s = fe.stats()
    assert s.horizon["grid_jump"] == 1
    assert s.grid_jump_points >= (silence_s - MAX_WALK_S) * GRID_HZ
    assert n <= 3.0 * GRID_HZ                         # not the 600 000 empty points


def _replay(log: Path) -> dict:
    out = log.with_suffix(".json")
    proc = subprocess.run([sys.executable, "-m", "gateway", "replay", str(log), "--report",
                           str(out), "--particles", "16", "--no-progress"],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(out.read_text())


def test_replay_of_a_log_with_absurd_timestamps_finishes_bounded(tmp_path: Path) -> None:
    """Through ``gateway replay``: a candump log with one frame at 1e300, and one whose
    receive clock jumps by 1e9 s, give a report with the counts and a bounded grid."""
    huge = _traffic()
    huge[next(i for i, m in enumerate(huge) if m.timestamp >= 1.0)].timestamp = 1e300
    jump = _traffic()
    for m in jump:
        if m.timestamp >= 1.0:
            m.timestamp += 1e9
    write_log(huge, tmp_path / "huge.log")
    write_log(jump, tmp_path / "jump.log")
    rep_huge = _replay(tmp_path / "huge.log")["diagnostics"]
    rep_jump = _replay(tmp_path / "jump.log")["diagnostics"]
    assert rep_huge["front_end"]["horizon"]["time_range"] == 1
    assert rep_jump["front_end"]["clock_steps"] == 1
    for rep in (rep_huge, rep_jump):
        assert 0.99 * DURATION_S * GRID_HZ <= rep["grid_points"] <= BOUND
        assert rep["front_end"]["grid_jump_points"] == 0


def test_receive_clock_step_shows_in_health(tmp_path: Path) -> None:
    """A re-based receive-clock step counts as a resync in GW_HealthFlags (bytes off
    the health frame), and raises front-end-resyncing until reported."""
    msgs = _traffic()
    for m in msgs:
        if m.timestamp >= 1.0:
            m.timestamp -= 0.5
    fe, _, _ = _run(msgs)
    assert fe.stats().clock_steps == 1 and fe.stats().resyncs == 0
    cfg = with_overrides(Config(), {"bus.interface": "virtual",
                                    "bus.channel": f"health-{tmp_path.name}",
                                    "state.directory": str(tmp_path / "state")})
    svc = Service(cfg)
    try:
        svc.pipeline = cast(Any, SimpleNamespace(   # the real front end, no worker process
            front=fe, stats=lambda: SimpleNamespace(priority_error=None), last_estimate=None))
        flags = svc.health_flags()
        sent: list[can.Message] = []
        CanSink(default_codec(), lambda m: sent.append(m) or True, 64).emit_health(
            Health("Running", 0, 0, 0, 0, 0, 1.0, flags))
    finally:
        svc.pipeline = None
        svc.close()
    assert flags.resyncs == 1 and flags.front_end_resyncing
    [frame] = [default_codec().decode_message(m) for m in sent
               if m.arbitration_id == default_codec().message("GW_HealthFlags").frame_id]
    assert frame.values["GW_HealthFlags_Resyncs"] == 1
    assert frame.values["GW_HealthFlags_FrontEndResync"] == 1
