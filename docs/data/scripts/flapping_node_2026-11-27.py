"""Healthy data, the service's filter, 5 sensors, the wheelset node dead for ``OFF_S`` in
every ``EVERY_S`` (a loose connector): its sensors are left out and taken back at each
turn. Counts detections, alerts and monitor alarms, and the final z of each parameter.

    python docs/data/scripts/flapping_node_2026-11-27.py SEED... > rows.jsonl
"""

import json
import sys
import time

import numpy as np

from firmware_sim.studies.detection import alerts, fault_data
from firmware_sim.studies.filtering import FS_HZ, run, service_filter

SECONDS, EVERY_S, OFF_S = 600.0, 5.0, 1.0

if __name__ == "__main__":
    for seed in map(int, sys.argv[1:]):
        th, Y = fault_data(None, 1.0, 5, seed, SECONDS, 0.0)
        t = np.arange(len(Y)) / FS_HZ
        Y[(t % EVERY_S) >= EVERY_S - OFF_S, :2] = np.nan
        t0 = time.perf_counter()
        est, found, filt = run(Y, service_filter(5, seed))
        last = est[-1]
        print(json.dumps({
            "seed": seed, "seconds": SECONDS, "dead": "acc_w1, acc_w2",
            "off_s": OFF_S, "every_s": EVERY_S, "detections": len(found),
            "alerts": len(alerts(est)), "monitor_alarms": filt.n_detections,
            "final_z": [round((m - tt) / s, 2) for m, s, tt
                        in zip(last.mean[:3], last.std[:3], th[-1], strict=True)],
            "wall_s": round(time.perf_counter() - t0, 1)}), flush=True)
