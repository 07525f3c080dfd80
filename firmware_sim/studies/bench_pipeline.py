"""Pipeline benchmarks for ``gateway bench``: frame throughput and end-to-end latency.

``pipeline``: decode + validate + resample + gate of simulator traffic in one thread,
timed in process CPU time, against the 8,000 frames/s of a full 1 Mbit/s bus; and the
DBC decode alone over the same frames.
``latency``: the live service on an in-process bus; for every estimate frame it sends,
the time from the newest sensor frame it includes (its wire timestamp) to the moment
the estimate frame goes out; and whether the worker kept up (samples dropped at the
full queue and in how many runs, samples not yet stepped when the traffic ended, the
worker's RTF). With
``--bus-loss P`` the sender drops each frame with probability P (a lossy bus: every
lost sensor frame is a grid sample with that sensor missing); with ``--silent-node M``
node M sends nothing at all (a dead node, or one the vehicle is not fitted with).
"""

from __future__ import annotations

import argparse
import tempfile
import threading
import time
from typing import Any

FULL_BUS_FRAMES_PER_S = 8000.0


def bench_pipeline(args: argparse.Namespace) -> dict[str, Any]:
    from firmware_sim.scenarios import get_scenario
    from firmware_sim.simulation import SimConfig, Simulation
    from gateway.can.codec import default_codec
    from gateway.config import Config
    from gateway.frontend.chain import FrontEnd

    messages = list(Simulation(get_scenario("nominal"),
                               SimConfig(duration_s=10.0, seed=args.seed)).messages())
    codec = default_codec()
    cpu0 = time.process_time()
    for msg in messages:
        codec.decode_message(msg)
    decode_rate = len(messages) / (time.process_time() - cpu0)
    front = FrontEnd(Config(), codec)
    cpu0, wall0 = time.process_time(), time.perf_counter()
    points = 0
    for msg in messages:
        points += len(front.on_frame(msg))
    cpu = time.process_time() - cpu0
    wall = time.perf_counter() - wall0
    rate = len(messages) / cpu
    return {"frames": len(messages), "grid_points": points, "cpu_s": cpu, "wall_s": wall,
            "frames_per_cpu_s": rate, "decode_frames_per_cpu_s": decode_rate,
            "cpu_share_at_full_bus_pct": 100.0 * FULL_BUS_FRAMES_PER_S / rate,
            "sustains_full_bus_on_one_core": rate >= FULL_BUS_FRAMES_PER_S}


def bench_latency(args: argparse.Namespace) -> dict[str, Any]:
    import numpy as np

    from firmware_sim.output import drop_frames, send_live
    from firmware_sim.scenarios import get_scenario
    from firmware_sim.simulation import SimConfig, Simulation
    from gateway.can.bus import open_node_bus
    from gateway.can.codec import default_codec
    from gateway.config import Config, with_overrides
    from gateway.service.daemon import Service

    channel = f"bench-latency-{time.monotonic_ns()}"
    lags: list[float] = []
    with tempfile.TemporaryDirectory() as state:
        cfg = with_overrides(Config(), {"bus.interface": "virtual", "bus.channel": channel,
                                        "state.directory": state,
                                        "estimator.particles": args.particles})
        service = Service(cfg)
        emit = service.can_sink.emit_estimate

        def timed(est: Any) -> None:
            emit(est)
            lags.append(time.time() - est.t_s)

        service.can_sink.emit_estimate = timed  # type: ignore[method-assign]
        runner = threading.Thread(target=service.run, daemon=True)
        runner.start()
        end = time.monotonic() + 300
        while not (service.pipeline and service.pipeline.worker.stats.ready):
            if time.monotonic() > end:
                break
            time.sleep(0.1)
        sim = Simulation(get_scenario("nominal"), SimConfig(duration_s=args.seconds + 5,
                                                            seed=args.seed))
        lost: list[Any] = []
        silent = {default_codec().message(m).frame_id for m in args.silent_node}
        with open_node_bus(f"virtual:{channel}") as tx:
            sent = (m for m in sim.messages() if m.arbitration_id not in silent)
            send_live(drop_frames(sent, args.bus_loss, np.random.default_rng(args.seed + 1),
                                  lost), tx)
        stats = service.pipeline.stats() if service.pipeline else None
        service.flags.stop = True
        runner.join(timeout=20)
    steady = np.array(lags[len(lags) // 4:]) * 1e3 if lags else np.array([np.nan])
    behind = {} if stats is None else {
        "samples_out": stats.samples_out, "samples_dropped": stats.samples_dropped,
        "drop_runs": stats.drop_runs,
        "samples_not_stepped_at_end": stats.samples_out - 1 - stats.last_seq_done,
        "worker_rtf": stats.rtf, "worker_restarts": stats.worker_restarts}
    return {"particles": args.particles, "mode": cfg.estimator.mode,
            "seconds": args.seconds, "bus_loss": args.bus_loss,
            "silent_nodes": list(args.silent_node),
            "frames_lost": len(lost), "estimate_frames": len(lags),
            "latency_median_ms": float(np.median(steady)),
            "latency_p95_ms": float(np.percentile(steady, 95)),
            "latency_max_ms": float(np.max(steady)), **behind}
