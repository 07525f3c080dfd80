"""A worker slower than the data: the live service at many particles, what comes out.

Usage: python worker_behind_2026-11-29.py PARTICLES QUEUE_SAMPLES SECONDS [SEED [STOP_AT_S STOP_S]]

The live service (fast mode, the service's defaults but particles and queue) on an
in-process virtual bus, fed SECONDS of the simulator's nominal traffic in real time, as
``gateway bench --what latency`` does. Prints one JSON line: estimates received and how
many of them rest on data (``updated``), samples dropped and in how many runs (the
``drop_runs`` counter exists since 2026-11-29; null before), samples not yet stepped
when the traffic ended, the worker's real-time factor, how far the last estimate's data
time trails the traffic's end, and the last updated estimate against the truth
(the paper's nominal vehicle). With STOP_AT_S and STOP_S the worker process is
stopped (SIGSTOP) STOP_AT_S after the traffic starts, for STOP_S of wall time (a stall:
another load, swapping), then continued. Run against two checkouts with PYTHONPATH to
compare.
"""

from __future__ import annotations

import json
import os
import signal
import sys
import tempfile
import threading
import time

import numpy as np

from firmware_sim.output import send_live
from firmware_sim.scenarios import get_scenario
from firmware_sim.simulation import SimConfig, Simulation
from gateway.can.bus import open_node_bus
from gateway.config import Config, with_overrides
from gateway.model.vehicle import THETA_NOMINAL
from gateway.service.daemon import Service


def stall(pid: int, at_s: float, for_s: float) -> None:
    time.sleep(at_s)
    os.kill(pid, signal.SIGSTOP)
    time.sleep(for_s)
    os.kill(pid, signal.SIGCONT)


def main(particles: int, queue: int, seconds: float, seed: int, stop_at_s: float = 0.0,
         stop_s: float = 0.0) -> dict[str, object]:
    channel = f"behind-{time.monotonic_ns()}"
    got: list = []
    with tempfile.TemporaryDirectory() as state:
        cfg = with_overrides(Config(), {"bus.interface": "virtual", "bus.channel": channel,
                                        "state.directory": state,
                                        "estimator.particles": particles,
                                        "estimator.queue_samples": queue})
        service = Service(cfg)
        emit = service.can_sink.emit_estimate

        def keep(est: object) -> None:
            emit(est)
            got.append(est)

        service.can_sink.emit_estimate = keep  # type: ignore[method-assign]
        runner = threading.Thread(target=service.run, daemon=True)
        runner.start()
        end = time.monotonic() + 600
        while not (service.pipeline and service.pipeline.worker.stats.ready) \
                and time.monotonic() < end:
            time.sleep(0.1)
        sim = Simulation(get_scenario("nominal"), SimConfig(duration_s=seconds, seed=seed))
        pid = service.pipeline.worker.pid if service.pipeline else None
        if stop_s > 0 and pid is not None:
            threading.Thread(target=stall, args=(pid, stop_at_s, stop_s), daemon=True).start()
        with open_node_bus(f"virtual:{channel}") as tx:
            send_live(sim.messages(), tx)
        t_end = time.time()
        stats = service.pipeline.stats() if service.pipeline else None
        worker = service.pipeline.worker.stats if service.pipeline else None
        service.flags.stop = True
        runner.join(timeout=30)
    updated = [e for e in got if e.updated]
    truth = THETA_NOMINAL.as_array()
    last = updated[-1] if updated else None
    return {"particles": particles, "queue_samples": queue, "seconds": seconds, "seed": seed,
            "stop_at_s": stop_at_s, "stop_s": stop_s,
            "estimates": len(got), "updated": len(updated),
            "samples_out": stats.samples_out if stats else None,
            "samples_dropped": stats.samples_dropped if stats else None,
            "drop_runs": getattr(worker, "drop_runs", None),
            "not_stepped_at_end": stats.samples_out - 1 - stats.last_seq_done if stats else None,
            "worker_rtf": stats.rtf if stats else None,
            "last_estimate_trails_s": (t_end - got[-1].t_s) if got else None,
            "last_updated_t_s": last.t_s if last else None,
            "last_rel_error": (list(np.asarray(last.mean[:3]) / truth - 1.0) if last else None),
            "last_rel_std": (list(np.asarray(last.std[:3]) / np.asarray(last.mean[:3]))
                             if last else None)}


if __name__ == "__main__":
    a = sys.argv[1:]
    print(json.dumps(main(int(a[0]), int(a[1]), float(a[2]), int(a[3]) if len(a) > 3 else 1,
                          *(float(x) for x in a[4:6]))))
