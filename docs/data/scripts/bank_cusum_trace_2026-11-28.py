"""Trace the fault bank's watch phase on one detection-study record: the reference's Csy and
the largest CUSUM, every 0.2 s from 7.5 s (20 m/s, 3 sensors, Csy x 0.5 at 8 s, 18 s).

    python docs/data/scripts/bank_cusum_trace_2026-11-28.py 3405

Compare with the oracle on the same record (exact filters of the true model started at the
fault from the right state): ``python -m firmware_sim.studies.oracle --cases csy:0.5
--sensors 3 --seeds 3405 --speed-mps 20 --hypotheses 0.5 0.58 --after 8``. A measuring
tool: it wraps FaultBank.scan to log, and changes nothing the filter computes.
"""

import sys

import numpy as np

import gateway.estimator.faultbank as fb
from firmware_sim.studies import detection

LOG: list[tuple[float, float, float, int]] = []
_SCAN = fb.FaultBank.scan


def _logged_scan(self, Y, full, t0_s, dt_s):  # type: ignore[no-untyped-def]
    out = _SCAN(self, Y, full, t0_s, dt_s)
    if self.active:
        watching = self.vec[fb._MODE] == fb._WATCH
        LOG.append((t0_s + self.taken * dt_s, float(self.ref[0]) / 40e3,
                    float(self.g.max()) if watching else -1.0, int(np.argmax(self.g))))
    return out


if __name__ == "__main__":
    fb.FaultBank.scan = _logged_scan
    row = detection.fault_row(0, 0.5, 3, int(sys.argv[1]), seconds=18.0, fault_at_s=8.0,
                              speed_mps=20.0)
    print("confirmed", row["confirmed_s"], "detected", row["detect_s"], "alert", row["alert_s"])
    last = -1.0
    for t, ref, g, j in LOG:
        if t >= 7.5 and t - last >= 0.2:
            print(f"t {t:.2f} s  reference Csy {ref:.3f} of nominal  largest CUSUM {g:.1f} "
                  f"nats (hypothesis {j}; -1: locating)")
            last = t
