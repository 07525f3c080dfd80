"""Fast mode, m = 1000, 5 sensors, the wheelset node's two sensors dead (NaN) from the
start or from 5 s: RTF over the whole 20 s run and after its first 8 s.

Run with PYTHONPATH set to a checkout to time that checkout's code (the rows in
docs/data/dead_sensor_speed_2026-11-27.jsonl: f4ebd60, then the commit that leaves dead
sensors out), alternating::

    PYTHONPATH=. python docs/data/scripts/dead_sensor_speed_2026-11-27.py TAG
"""

import json
import sys
from dataclasses import replace

import numpy as np

from firmware_sim.studies.sweep import FS_HZ, V_MPS, BenchData, filter_config, time_filter
from firmware_sim.truth import measured
from gateway.model.vehicle import AR_PAPER_DEFAULT, THETA_SEC42, sensor_set
from gateway.records import Sample


def data(seconds: float, dead_from_s: float | None, seed: int = 0) -> BenchData:
    n = int(round(seconds * FS_HZ))
    y = measured(np.repeat(THETA_SEC42.as_array()[None], n, 0), np.full(n, V_MPS), FS_HZ,
                 sensor_set(5), np.random.default_rng(seed))
    if dead_from_s is not None:
        y[int(round(dead_from_s * FS_HZ)):, :2] = np.nan
    s = tuple(Sample(t_s=k / FS_HZ, values=y[k], speed_mps=V_MPS) for k in range(n))
    return BenchData(fs_hz=FS_HZ, speed_mps=V_MPS, y=y, samples=s)


if __name__ == "__main__":
    tag = sys.argv[1]
    config = replace(filter_config("fast", 1000, 0, AR_PAPER_DEFAULT), sensors=5)
    time_filter(data(1.0, None), config, 0.5)          # loads the kernels, not timed
    for dead in (None, 0.0, 5.0):
        t = time_filter(data(20.0, dead), config, 8.0)
        print(json.dumps({"code": tag, "seconds": 20.0, "sensors": 5, "particles": 1000,
                          "dead": "acc_w1, acc_w2", "dead_from_s": dead,
                          "rtf_whole": round(t.rtf_whole_run, 2),
                          "rtf_after_8s": round(t.rtf_steady, 2)}), flush=True)
