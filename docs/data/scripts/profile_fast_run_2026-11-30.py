"""Where fast mode's 5 s bench run spends its time (2026-11-30, seventeenth session).

cProfile of one 5 s run at m = 1000 over the bench's data (after one untimed run that
warms numba's caches), for the bench's bare filter and for the service's, sorted by own
time. Usage: ``OPENBLAS_CORETYPE=Haswell python docs/data/scripts/profile_fast_run_2026-11-30.py
bare|service``. docs/estimator.md "The seventeenth session".
"""

from __future__ import annotations

import cProfile
import pstats
import sys

from firmware_sim.studies.sweep import bench_data, filter_config, service_filter_config
from gateway.estimator.rbpf import RBPF
from gateway.model.vehicle import AR_PAPER_DEFAULT

which = sys.argv[1] if len(sys.argv) > 1 else "bare"
data = bench_data(5.0, 0)
cfg = (service_filter_config(1000, 0, AR_PAPER_DEFAULT) if which == "service"
       else filter_config("fast", 1000, 0, AR_PAPER_DEFAULT))
for profile in (False, True):
    filt = RBPF(cfg)
    filt.step(data.samples[0])
    prof = cProfile.Profile()
    if profile:
        prof.enable()
    filt.run(data.samples[1:], output_every=10)
    if profile:
        prof.disable()
        print(f"{which}: {filt.n_resamples} resample-moves")
        pstats.Stats(prof).sort_stats("tottime").print_stats(14)
