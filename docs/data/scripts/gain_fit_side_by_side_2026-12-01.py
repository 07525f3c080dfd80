"""Fast mode with and without the gain fit, side by side (2026-12-01, twenty-second session).

The bench's record and filters (:mod:`firmware_sim.studies.sweep`: the paper's bare filter
and the service's, m = 1000, 3 sensors, 1 kHz), timed as the bench times them
(:func:`firmware_sim.studies.sweep.time_filter`: whole run and steady window), with
``gain_fit`` True and False alternating, ``ROUNDS`` rounds, over a 5 s and a 20 s run;
then a 5 s run with one thread. One JSON line per run on stdout. Usage, on an idle
machine: ``OPENBLAS_CORETYPE=Haswell python docs/data/scripts/gain_fit_side_by_side_2026-12-01.py``.
docs/estimator.md "The twenty-second session".
"""

from __future__ import annotations

import json
import sys
from dataclasses import replace

import numba

from firmware_sim.studies.sweep import bench_data, filter_config, service_filter_config, time_filter
from gateway.model.vehicle import AR_PAPER_DEFAULT

ROUNDS = int(sys.argv[1]) if len(sys.argv) > 1 else 3
STEADY_AFTER_S = 2.0


def one(seconds: float, which: str, fit: bool, threads: int) -> dict[str, object]:
    numba.set_num_threads(threads)
    data = bench_data(seconds, 0)
    cfg = (service_filter_config(1000, 0, AR_PAPER_DEFAULT) if which == "service"
           else filter_config("fast", 1000, 0, AR_PAPER_DEFAULT))
    t = time_filter(data, replace(cfg, gain_fit=fit), STEADY_AFTER_S)
    return {"seconds": seconds, "filter": which, "gain_fit": fit, "threads": threads,
            "rtf_whole_run": round(t.rtf_whole_run, 3), "rtf_steady": round(t.rtf_steady, 3),
            "resamples": t.resamples_convergence + t.resamples_steady}


one(1.0, "bare", True, numba.config.NUMBA_NUM_THREADS)     # compiles, untimed
for seconds in (5.0, 20.0):
    for _ in range(ROUNDS):
        for which in ("bare", "service"):
            for fit in (False, True):
                print(json.dumps(one(seconds, which, fit, numba.config.NUMBA_NUM_THREADS)),
                      flush=True)
for which in ("bare", "service"):
    for fit in (False, True):
        print(json.dumps(one(5.0, which, fit, 1)), flush=True)
