"""A fresh service filter at PARTICLES on a vehicle whose damper failed before it started.

Usage: python boot_faulty_particles_2026-11-29.py PARTICLES EDGE SENSORS PARAM FACTOR SEED...

The detection study's 12 s record with ``PARAM`` (0 Csy, 1 Csay) at ``FACTOR`` x nominal
from the first sample, through the service's filter at PARTICLES with the prior's damper
edge EDGE (``service`` for the service's own, ``prior_lo_for(PARTICLES)``). One JSON line
per record: the alerts the default policy raises, those on the healthy parameters, the
bank's detections, the end estimate over the truth. Thirteenth session (2026-11-29): the
edge 0.1 from 500 particles on was measured for this case at m = 1000 only.
"""

from __future__ import annotations

import sys

from firmware_sim.studies.detection import fault_data
from firmware_sim.studies.detection_alerts import alerts
from firmware_sim.studies.filtering import FilterOptions, run, service_filter
from firmware_sim.studies.rows import emit
from gateway.model.vehicle import PARAM_NAMES


def boot(m: int, edge: str, sensors: int, par: int, factor: float, seed: int) -> dict:
    th, Y = fault_data(par, factor, sensors, seed, 12.0, 0.0)
    lo = None if edge == "service" else (float(edge), float(edge), 0.3)
    est, found, filt = run(Y, service_filter(sensors, seed, FilterOptions(
        particles=m, prior_lo=lo)), replaced=[])
    raised = alerts(est)
    return {"what": "boot", "particles": m, "prior_lo": list(filt.config.prior_lo),
            "sensors": sensors, "parameter": PARAM_NAMES[par], "factor": factor,
            "seed": seed, "alerts": raised,
            "healthy_alerts": [a for a in raised if a[1] != PARAM_NAMES[par]],
            "detections": [(round(f[0], 3), f[1], round(f[2], 3)) for f in found],
            "end_rel": [round(e / t, 4) for e, t in zip(est[-1].mean, th[-1], strict=False)]}


if __name__ == "__main__":
    m, edge, ns, par, factor = (int(sys.argv[1]), sys.argv[2], int(sys.argv[3]),
                                int(sys.argv[4]), float(sys.argv[5]))
    for s in sys.argv[6:]:
        emit(boot(m, edge, ns, par, factor, int(s)))
