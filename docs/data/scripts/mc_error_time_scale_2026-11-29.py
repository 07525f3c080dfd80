"""Whether a time average of the estimate removes the filter's Monte Carlo error.

One healthy record (data seed argv[1], argv[2] sensors, 20 s) through the service's
filter with three filter seeds (7001-7003), estimates every 20 ms. For each parameter:
the rms difference (%) between two filter seeds, raw and after a trailing mean over
0.5, 1 and 2 s, and the difference's correlation at lags of 20 ms to 4 s (from 6 s on).
Usage: python docs/data/scripts/mc_error_time_scale_2026-11-29.py 5480 5
(docs/estimator.md "The filter's Monte Carlo error is slow").
"""

import sys

import numpy as np

from firmware_sim.studies.detection import fault_data
from firmware_sim.studies.filtering import run, service_filter

data_seed, sensors = int(sys.argv[1]), int(sys.argv[2])
th, Y = fault_data(None, 1.0, sensors, data_seed, 20.0, 0.0)
means = []
t = np.empty(0)
for fs in (1, 2, 3):
    est, _, _ = run(Y, service_filter(sensors, 7000 + fs), every=20)
    means.append(np.array([e.mean[:3] for e in est]) / th[0, :3])
    t = np.array([e.t_s for e in est])
M = np.array(means)                     # (filter seeds, estimates, 3)
sel = t >= 6


def trail(a: np.ndarray, w: int) -> np.ndarray:
    return np.convolve(a, np.ones(w) / w, mode="valid")


for p in range(3):
    d = (M[0, sel, p] - M[1, sel, p]) * 100
    x = d - d.mean()
    lags = (1, 5, 10, 25, 50, 100, 200)
    ac = [float(np.corrcoef(x[:-k], x[k:])[0, 1]) for k in lags]
    spread = [float(np.sqrt(np.mean(d**2)))] + [
        float(np.sqrt(np.mean(((trail(M[0, sel, p], w) - trail(M[1, sel, p], w)) * 100) ** 2)))
        for w in (25, 50, 100)]
    print(p, "rms difference %, raw and 0.5 / 1 / 2 s trailing means:", np.round(spread, 3),
          "correlation at 20 ms .. 4 s:", np.round(ac, 2))
