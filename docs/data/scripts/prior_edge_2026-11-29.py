"""The prior box's damper edge: 0.3 x nominal (the paper's, the default) against 0.1.

Usage:
  python prior_edge_2026-11-29.py boot LO SENSORS PARAM FACTOR SEED...   # failed from t = 0
  python prior_edge_2026-11-29.py box LO SENSORS SEED...                 # truth over 0.3-2.5
  python prior_edge_2026-11-29.py wide LO SENSORS SEED...                # truth over 0.1-2.5

``boot``: a 12 s record whose ``PARAM`` (0 Csy, 1 Csay) is ``FACTOR`` x nominal from the
first sample (the detection study's data, ``fault_data`` with the fault at 0 s: a fresh
estimator on a vehicle whose damper failed before it started), through the service's
filter with ``prior_lo`` (LO, LO, 0.3); prints the alerts the default policy raises on
the healthy parameters, the bank's detections and the end estimate / truth.
``box``: the calibration study's ``box`` records (truth uniform over today's prior box,
0.3-2.5 x for the dampers, 0.3-3.5 x for lambda; 10 s) through the same filter; prints
z = (mean - truth) / sigma at 10 s. Run with LO = 0.3 and 0.1 on the same seeds to pair.
``wide`` (twelfth session): the same records with theta drawn over the box whose damper
edge is 0.1 (lambda 0.3-3.5 as before): with LO = 0.1, is start-up calibrated over the
wider prior (truth within 2 sigma in 90 % of sets, none beyond 4 sigma)?
``RBPFConfig.prior_lo`` is replaced here only; the truth's box is fixed per mode, not
read from the filter's default (which is 0.1 since the twelfth session).
"""

from __future__ import annotations

import json
import sys
from dataclasses import replace

import numpy as np

from firmware_sim.studies.calibration import SEED_OFFSET, record
from firmware_sim.studies.detection import fault_data
from firmware_sim.studies.detection_alerts import alerts
from firmware_sim.studies.filtering import (
    FS_HZ,
    RBPF,
    FilterOptions,
    NoiseCheckedStart,
    run,
    service_filter,
)
from gateway.estimator.rbpf_config import RBPFConfig
from gateway.model.vehicle import PARAM_NAMES

DAMPER_EDGE = {"box": 0.3, "wide": 0.1}
"""The truth's lower edge for the dampers, per mode (lambda from 0.3, all to 2.5 / 3.5)."""


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


def truth_theta(seed: int, edge: float) -> np.ndarray:
    """theta (3,) uniform over (edge, edge, 0.3)-(2.5, 2.5, 3.5) x nominal, drawn as the
    calibration study's ``box`` draws it (the same seed stream)."""
    cfg = RBPFConfig(fs_hz=FS_HZ)
    lo, hi = cfg.box((edge, edge, 0.3), (2.5, 2.5, 3.5))
    return np.random.default_rng(SEED_OFFSET["box"] + 500 + seed).uniform(lo, hi)


def box(lo: float, sensors: int, seed: int, mode: str = "box") -> dict[str, object]:
    theta = truth_theta(seed, DAMPER_EDGE[mode])
    Y = record(theta, sensors, SEED_OFFSET["box"] + seed, 10.0, False, 42.5, "white")
    est, found, _ = run(Y, with_edge(sensors, seed, lo), speed_mps=42.5)
    e = min(est, key=lambda x: abs(x.t_s - 10.0))
    m, s = np.array(e.mean[:3]), np.array(e.std[:3])
    return {"what": mode, "lo": lo, "sensors": sensors, "seed": seed,
            "truth": theta.tolist(),
            "truth_rel": np.round(theta / RBPFConfig(fs_hz=FS_HZ).nominal_array, 3).tolist(),
            "z": np.round((m - theta) / s, 3).tolist(),
            "err_pct": np.round(100 * (m - theta) / theta, 3).tolist(),
            "sigma_pct": np.round(100 * s / m, 3).tolist(), "detections": len(found)}


if __name__ == "__main__":
    a = sys.argv[1:]
    if a[0] == "boot":
        for s in a[5:]:
            print(json.dumps(boot(float(a[1]), int(a[2]), int(a[3]), float(a[4]), int(s))),
                  flush=True)
    else:
        for s in a[3:]:
            print(json.dumps(box(float(a[1]), int(a[2]), int(s), a[0])), flush=True)
