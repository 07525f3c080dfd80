"""The prior box's damper edge: 0.3 x nominal (the paper's, the default) against 0.1.

Usage:
  python prior_edge_2026-11-29.py boot LO SENSORS PARAM FACTOR SEED...   # failed from t = 0
  python prior_edge_2026-11-29.py box LO SENSORS SEED...                 # truth over 0.3-2.5

``boot``: a 12 s record whose ``PARAM`` (0 Csy, 1 Csay) is ``FACTOR`` x nominal from the
first sample (the detection study's data, ``fault_data`` with the fault at 0 s: a fresh
estimator on a vehicle whose damper failed before it started), through the service's
filter with ``prior_lo`` (LO, LO, 0.3); prints the alerts the default policy raises on
the healthy parameters, the bank's detections and the end estimate / truth.
``box``: the calibration study's ``box`` records (truth uniform over today's prior box,
0.3-2.5 x for the dampers, 0.3-3.5 x for lambda; 10 s) through the same filter; prints
z = (mean - truth) / sigma at 10 s. Run with LO = 0.3 and 0.1 on the same seeds to pair.
Not a setting of the service: ``RBPFConfig.prior_lo`` is replaced here only.
"""

from __future__ import annotations

import json
import sys
from dataclasses import replace

import numpy as np

from firmware_sim.studies.calibration import SEED_OFFSET, box_theta, record
from firmware_sim.studies.detection import fault_data
from firmware_sim.studies.detection_alerts import alerts
from firmware_sim.studies.filtering import (
    RBPF,
    FilterOptions,
    NoiseCheckedStart,
    run,
    service_filter,
)
from gateway.model.vehicle import PARAM_NAMES


def with_edge(sensors: int, seed: int, lo: float):
    f = service_filter(sensors, seed, FilterOptions())
    if lo == f.config.prior_lo[0]:
        return f
    cfg = replace(f.config, prior_lo=(lo, lo, f.config.prior_lo[2]))
    return NoiseCheckedStart(cfg) if isinstance(f, NoiseCheckedStart) else RBPF(cfg)


def boot(lo: float, sensors: int, par: int, factor: float, seed: int) -> dict[str, object]:
    th, Y = fault_data(par, factor, sensors, seed, 12.0, 0.0, 1.0, 42.5, False, "white")
    est, found, _ = run(Y, with_edge(sensors, seed, lo), speed_mps=42.5, replaced=[])
    return {"what": "boot", "lo": lo, "sensors": sensors, "parameter": PARAM_NAMES[par],
            "factor": factor, "seed": seed,
            "healthy_alerts": [a for a in alerts(est) if a[1] != PARAM_NAMES[par]],
            "alerts": alerts(est),
            "detections": [(round(f[0], 3), f[1], round(f[2], 3)) for f in found],
            "end_rel": [round(m / t, 4) for m, t in zip(est[-1].mean, th[-1], strict=True)]}


def box(lo: float, sensors: int, seed: int) -> dict[str, object]:
    theta = box_theta(seed)
    Y = record(theta, sensors, SEED_OFFSET["box"] + seed, 10.0, False, 42.5, "white")
    est, found, _ = run(Y, with_edge(sensors, seed, lo), speed_mps=42.5)
    e = min(est, key=lambda x: abs(x.t_s - 10.0))
    m, s = np.array(e.mean[:3]), np.array(e.std[:3])
    return {"what": "box", "lo": lo, "sensors": sensors, "seed": seed,
            "truth": theta.tolist(), "z": np.round((m - theta) / s, 3).tolist(),
            "sigma_pct": np.round(100 * s / m, 3).tolist(), "detections": len(found)}


if __name__ == "__main__":
    a = sys.argv[1:]
    if a[0] == "boot":
        for s in a[5:]:
            print(json.dumps(boot(float(a[1]), int(a[2]), int(a[3]), float(a[4]), int(s))),
                  flush=True)
    else:
        for s in a[3:]:
            print(json.dumps(box(float(a[1]), int(a[2]), int(s))), flush=True)
