"""One accuracy-study record through the paper's bare filter and through the service's.

    python docs/data/scripts/bare_vs_service_start_2026-11-29.py SEED SENSORS

The accuracy study's data for SEED (the Sec. 4.2 scenario, 20 s, data seed 1000 + SEED)
through the bare ``RBPFConfig`` that ``firmware_sim.studies.accuracy compare`` runs (fast
mode, m = 1000) and through the service's filter (``firmware_sim.studies.filtering.
service_filter``: the start's ramp, the drift, the tested noise, the fault bank), filter
seeds SEED, SEED + 100 and SEED + 200. Prints each parameter's z = (mean - truth) / sigma
at 3, 5 and 20 s, one JSON line per run. A measuring tool.
"""

import json
import sys

import numpy as np

from firmware_sim.studies.accuracy import FS_HZ, THETA_SEC42, make_data, run_filter
from firmware_sim.studies.filtering import run, service_filter
from gateway.estimator.rbpf import RBPFConfig
from gateway.records import Estimate


def z_at(est: list[Estimate], truth: np.ndarray) -> dict[str, list[float]]:
    out = {}
    for t in (3.0, 5.0, 20.0):
        e = min(est, key=lambda x: abs(x.t_s - t))
        out[f"{t:g}s"] = [round(float((e.mean[i] - truth[i]) / e.std[i]), 2) for i in range(3)]
    return out


if __name__ == "__main__":
    seed, sensors = int(sys.argv[1]), int(sys.argv[2])
    truth = THETA_SEC42.as_array()
    Y = make_data(np.repeat(truth[None], int(20 * FS_HZ), 0), sensors, seed)
    for fseed in (seed, seed + 100, seed + 200):
        bare = RBPFConfig(fs_hz=FS_HZ, n_particles=1000, sensors=sensors, seed=fseed,
                          mode="fast")
        est, _, _ = run_filter(Y, bare)
        print(json.dumps({"seed": seed, "sensors": sensors, "filter_seed": fseed,
                          "filter": "bare", "z": z_at(est, truth)}), flush=True)
        est, _, _ = run(Y, service_filter(sensors, fseed))
        print(json.dumps({"seed": seed, "sensors": sensors, "filter_seed": fseed,
                          "filter": "service", "z": z_at(est, truth)}), flush=True)
