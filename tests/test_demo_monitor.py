"""The demo's monitor counts the gateway's estimate frames it reads back off the bus.

``gateway demo`` fails (exit 1, one line) when none came back: a worker that never
caught up used to leave a demo that showed nothing and exited 0.
"""

from __future__ import annotations

import time

from firmware_sim.commands.demo import Monitor
from gateway.can.bus import open_bus
from gateway.can.codec import default_codec


def test_the_monitor_counts_estimate_frames_and_not_the_others() -> None:
    channel = f"demo-monitor-{time.monotonic_ns()}"
    monitor = Monitor(channel)
    monitor.thread.start()
    codec = default_codec()
    try:
        with open_bus(f"virtual:{channel}") as tx:
            tx.send(codec.encode_message("GW_EstCsy", {
                "GW_EstCsy_Status": 1, "GW_EstCsy_Mean": 40_000.0, "GW_EstCsy_Std": 800.0,
                "GW_EstCsy_EssPct": 50}, 0))
            tx.send(codec.encode_message("GW_EstConicity", {
                "GW_EstConicity_Status": 1, "GW_EstConicity_Mean": 0.15,
                "GW_EstConicity_Std": 0.003, "GW_EstConicity_EssPct": 50}, 0))
            tx.send(codec.encode_message("GW_Alert", {
                "GW_Alert_Seq": 1, "GW_Alert_Code": 1, "GW_Alert_Severity": 3,
                "GW_Alert_Param": 0, "GW_Alert_State": 1, "GW_Alert_ValueRel": 0.25}, 0))
            deadline = time.monotonic() + 30
            while not monitor.alerts and time.monotonic() < deadline:
                monitor.stop.wait(0.01)
    finally:
        monitor.stop.set()
        monitor.thread.join(timeout=5)
        monitor.bus.shutdown()
    assert monitor.estimate_frames == 2
    assert monitor.values["GW_EstCsy_Mean"] == 40_000.0
    assert len(monitor.alerts) == 1 and monitor.alerts[0].startswith("ALERT #1: ")
