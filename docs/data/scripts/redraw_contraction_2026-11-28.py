"""The cloud's Csy σ around a halved lateral damper at 20 m/s, against the data's bound.

The detection study's record (:func:`firmware_sim.studies.detection.fault_data`: Csy
40 -> 20 kNs/m at 8 s, 3 sensors, 18 s) through the service's filter
(``service_filter``: fast mode, m = 1000, the sensor-noise test), the estimate every
0.5 s, and the Cramér-Rao bound of Csy from t s of data at the post-fault vehicle
(:mod:`gateway.estimator.observability`), both relative to nominal. One JSON line per
estimate (``"what": "estimate"``) and per bound (``"what": "bound"``)::

    python S 2001 2002 2003 > docs/data/redraw_contraction_2026-11-28_20mps.jsonl
"""

import json
import sys

import numpy as np

from firmware_sim.studies.detection import fault_data
from firmware_sim.studies.filtering import FS_HZ, run, service_filter
from gateway.estimator import observability as obs
from gateway.model.coordinates import FilterCoords
from gateway.model.vehicle import (
    AR_PAPER_DEFAULT,
    SENSORS_3,
    THETA_NOMINAL,
    measurement_noise,
    track_intensity,
)

V_MPS, FAULT_S, SECONDS = 20.0, 8.0, 18.0
NOM = THETA_NOMINAL.csy_ns_per_m


def main(seeds: list[int]) -> None:
    coords = FilterCoords.build()
    for seed in seeds:
        th, Y = fault_data(0, 0.5, 3, seed, SECONDS, FAULT_S, 1.0, V_MPS)
        if seed == seeds[0]:
            for t in (0.5, 1.0, 2.0, 3.0, 5.0, 8.0):
                b = obs.bound_rel(coords, th[-1], V_MPS, coords.output(SENSORS_3, V_MPS),
                                  np.diag(measurement_noise(SENSORS_3)),
                                  track_intensity(AR_PAPER_DEFAULT, V_MPS), FS_HZ,
                                  horizon_s=t)
                print(json.dumps({"what": "bound", "data_s": t,
                                  "csy_sd_nominal": round(b[0] * th[-1, 0] / NOM, 5)}))
        est, found, _ = run(Y, service_filter(3, seed), speed_mps=V_MPS)
        for e in est:
            k = round(e.t_s * FS_HZ)
            if k % 500 == 0 and e.t_s >= 6.0:
                print(json.dumps({"what": "estimate", "seed": seed, "t_s": round(e.t_s, 3),
                                  "csy_nominal": round(e.mean[0] / NOM, 4),
                                  "csy_sd_nominal": round(e.std[0] / NOM, 5),
                                  "ess": round(e.ess), "detections": [
                                      [round(f[0], 3), f[1], round(f[2], 3)] for f in found],
                                  "located_like": None if e.located is None else
                                  [round(e.located.like_lo, 3), round(e.located.like_hi, 3)]}))


if __name__ == "__main__":
    main([int(s) for s in sys.argv[1:]])
