"""A healthy vehicle with saturating dampers (the paper's Figs. 6-7) through the service's filter.

``python docs/data/scripts/nonlinear_dampers_2026-11-29.py SEED SENSORS SPEED_MPS bank|nobank``:
30 s of the detection study's record (data seed 2000 + SEED, ``--nonlinear-dampers``),
the service's filter (filter seed SEED) with its fault bank, or without it ("nobank":
the cloud alone); prints the alert events the default policy raises, the bank's
detections, and the estimates relative to the truth's linear values every 3 s
(docs/estimator.md "Dampers that saturate").
"""

import sys
from dataclasses import replace

import numpy as np

from firmware_sim.studies.detection import fault_data
from firmware_sim.studies.detection_alerts import alerts
from firmware_sim.studies.filtering import run, service_filter
from gateway.estimator.noisestart import NoiseCheckedStart
from gateway.estimator.rbpf import RBPF

seed, sensors, v, bank = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3]), sys.argv[4]
th, Y = fault_data(None, 1.0, sensors, seed, 30.0, 0.0, speed_mps=v, nonlinear=True)
filt = service_filter(sensors, seed)
if bank == "nobank":
    cfg = replace(filt.config, faults=None)
    filt = NoiseCheckedStart(cfg) if isinstance(filt, NoiseCheckedStart) else RBPF(cfg)
est, found, _ = run(Y, filt, speed_mps=v)
for a in alerts(est):
    print("alert", a)
print("detections", [(round(t, 2), n, round(x, 3)) for t, n, x, _ in found])
for e in est[29::30]:
    print(f"{e.t_s:5.1f}", np.round(np.array(e.mean[:3]) / th[0], 3),
          np.round(100 * np.array(e.std[:3]) / np.array(e.mean[:3]), 2))
