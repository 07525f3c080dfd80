"""Fast mode, m = 1000, 3 sensors, on bench data with lost values: RTF, whole and steady.

Run with PYTHONPATH set to a checkout to time that checkout's code (the rows in
docs/data/lossy_bus_2026-11-27.jsonl: 6838518, then the commit that added the rejoin)::

    PYTHONPATH=. python docs/data/scripts/lossy_bus_2026-11-27.py TAG
"""

import json
import sys

import numpy as np

from firmware_sim.studies.sweep import BenchData, bench_data, filter_config, time_filter
from gateway.model.vehicle import AR_PAPER_DEFAULT
from gateway.records import Sample


def lossy(data: BenchData, p: float, seed: int) -> BenchData:
    """``data`` with each value lost (NaN) with probability ``p`` (the code before had no
    ``sweep.lose_sensor_values``)."""
    rng = np.random.default_rng(seed)
    y = data.y.copy()
    y[rng.random(y.shape) < p] = np.nan
    s = tuple(Sample(t_s=k / data.fs_hz, values=y[k], speed_mps=data.speed_mps)
              for k in range(len(y)))
    return BenchData(fs_hz=data.fs_hz, speed_mps=data.speed_mps, y=y, samples=s)


if __name__ == "__main__":
    tag = sys.argv[1]
    config = filter_config("fast", 1000, 0, AR_PAPER_DEFAULT)
    time_filter(bench_data(1.0, 5), config, 0.5)          # loads the kernels, not timed
    for secs in (5.0, 20.0):
        data = bench_data(secs, 0)
        for p in (0.0, 1e-4, 1e-3, 1e-2):
            t = time_filter(lossy(data, p, 0), config, 2.0)
            print(json.dumps({"code": tag, "seconds": secs, "loss": p,
                              "rtf_whole": round(t.rtf_whole_run, 2),
                              "rtf_steady": round(t.rtf_steady, 2)}), flush=True)
