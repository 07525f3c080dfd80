"""Run the detection or calibration study with the prior's damper edge at 0.1 (exploration).

Usage: python prior_edge_study_2026-11-29.py detection|calibration ARGS...  (the study's
own arguments). The service's filter with ``RBPFConfig.prior_lo`` (0.1, 0.1, lambda's)
instead of the paper's 0.3; not a setting of the service.
"""

import sys
from dataclasses import replace

from firmware_sim.studies import calibration, detection, filtering

service_filter = filtering.service_filter


def with_edge(sensors, seed, options=None):
    f = service_filter(sensors, seed, options)
    cfg = replace(f.config, prior_lo=(0.1, 0.1, f.config.prior_lo[2]))
    if isinstance(f, filtering.NoiseCheckedStart):
        return filtering.NoiseCheckedStart(cfg)
    return filtering.RBPF(cfg)


detection.service_filter = with_edge
calibration.service_filter = with_edge
study = {"detection": detection, "calibration": calibration}[sys.argv[1]]
raise SystemExit(study.main(sys.argv[2:]))
