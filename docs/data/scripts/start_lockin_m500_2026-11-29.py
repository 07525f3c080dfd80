"""Start-up at m = 500 with either prior box: the bare RBPF's defaults and the service's.

Usage:
  python start_lockin_m500_2026-11-29.py bare EDGE SEED...      # tests/test_fast_mode.py's data
  python start_lockin_m500_2026-11-29.py service EDGE SEED...   # the calibration study's record

``bare``: the record of ``tests/test_fast_mode.py`` (the paper's Sec. 4.2 vehicle, 42.5
m/s, 3 sensors, 5 s, the simulator's truth and sensor noise from ``seed``) through
``RBPF(RBPFConfig(...))`` at m = 500, fast mode: the RBPF's bare defaults, without the
start's likelihood ramp and with the paper's kernel discount 0.99, and the dampers'
prior edge at EDGE. ``service``: the calibration study's paper record of ``seed`` through
the service's filter at m = 500 (``rows_for(..., prior_lo=...)``: the ramp, the
discount 0.999, the noise test, the fault bank). One JSON line per record, with z =
(mean - truth) / sigma at 5 s. Twelfth session (2026-11-29), after seed 24 of that test
locked in with the edge at 0.1.
"""

from __future__ import annotations

import json
import sys

import numpy as np

from firmware_sim.studies.calibration import rows_for
from firmware_sim.truth import add_sensor_noise, select, simulate
from gateway.estimator.rbpf import RBPF, RBPFConfig
from gateway.model.vehicle import THETA_SEC42, sensor_set
from gateway.records import Sample

FS_HZ, V_MPS, M = 1000.0, 42.5, 500


def bare(edge: float, seed: int) -> dict[str, object]:
    theta, n = THETA_SEC42.as_array(), 5000
    rng = np.random.default_rng(seed)
    truth = simulate(np.repeat(theta[None], n, 0), np.full(n, V_MPS), FS_HZ, rng)
    sensors = sensor_set(3)
    Y = add_sensor_noise(select(truth.outputs, sensors), sensors, rng)
    f = RBPF(RBPFConfig(fs_hz=FS_HZ, n_particles=M, sensors=3, seed=seed, mode="fast",
                        prior_lo=(edge, edge, 0.3)))
    e = f.run([Sample(k / FS_HZ, Y[k], V_MPS) for k in range(n)], output_every=n)[-1]
    return {"what": "bare", "seed": seed, "particles": M, "sensors": 3,
            "prior_damper_edge": edge,
            "rel": np.round(np.array(e.mean) / theta, 4).tolist(),
            "z": np.round((np.array(e.mean) - theta) / np.array(e.std), 2).tolist()}


def service(edge: float, seed: int) -> dict[str, object]:
    row = rows_for("paper", seed, 3, M, "fast", ml=False, at_s=(5.0,),
                   prior_lo=(edge, edge, 0.3))[0]
    return {"what": "service", "prior_damper_edge": edge, **row}


if __name__ == "__main__":
    how = {"bare": bare, "service": service}[sys.argv[1]]
    for s in sys.argv[3:]:
        print(json.dumps(how(float(sys.argv[2]), int(s))), flush=True)
