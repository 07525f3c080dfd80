"""Node phase with the filter's Monte Carlo error averaged out: each clock case, K filter seeds.

The timing study's set-up (:mod:`firmware_sim.studies.timing`: nominal scenario, 10 s,
the whole replay path, the case's node clocks from ``10000 + seed``), each case's CAN
log replayed with K estimator seeds (``100 * seed + k``). Rows in
docs/data/node_phase_filter_seeds_2026-11-28_seeds2301-2314.jsonl (S = this script)::

    python S run 3 3 aligned,phase,drift 2301 2302 2303 2304 2305 2306
    python S run 5 3 aligned,phase,drift 2311 2312 2313 2314
    python S summary < rows.jsonl
"""

import dataclasses
import json
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

from firmware_sim.output import drop_frames, write_log
from firmware_sim.scenarios import get_scenario
from firmware_sim.simulation import SimConfig, Simulation
from firmware_sim.studies.timing import set_clocks
from gateway.config import Config
from gateway.offline.replay import replay

SECONDS = 10.0


def run(sensors: int, k_seeds: int, cases: list[str], seeds: list[int]) -> None:
    """One JSON line per replay: the final estimate against the truth."""
    work = Path(tempfile.mkdtemp())
    for seed in seeds:
        for case in cases:
            sim = Simulation(get_scenario("nominal"), SimConfig(duration_s=SECONDS, seed=seed))
            truth = sim.scenario.theta(np.array([0.0]), SECONDS)[0]
            set_clocks(sim, case, np.random.default_rng(10_000 + seed))
            log = work / f"{seed}-{case}.log"
            write_log(drop_frames(sim.messages(), 0.0, np.random.default_rng(20_000 + seed)),
                      log)
            for k in range(1, k_seeds + 1):
                base = Config()
                cfg = dataclasses.replace(base, estimator=dataclasses.replace(
                    base.estimator, particles=1000, sensors=sensors, seed=100 * seed + k))
                t0 = time.monotonic()
                est = replay(log, cfg).estimates[-1]
                print(json.dumps({
                    "seed": seed, "case": case, "filter_seed": 100 * seed + k,
                    "sensors": sensors, "rel": [est.mean[i] / truth[i] - 1 for i in range(3)],
                    "z": [(est.mean[i] - truth[i]) / est.std[i] for i in range(3)],
                    "sigma_rel": [est.std[i] / est.mean[i] for i in range(3)],
                    "wall_s": round(time.monotonic() - t0, 1)}), flush=True)


def summary(rows: list[dict]) -> None:
    """Each case minus aligned, per data seed: one filter seed, and the mean over K."""
    g: dict[tuple[int, int, str], list[list[float]]] = defaultdict(list)
    for r in rows:
        g[(r["sensors"], r["seed"], r["case"])].append(r["rel"])
    for ns in sorted({r["sensors"] for r in rows}):
        seeds = sorted({r["seed"] for r in rows if r["sensors"] == ns})
        for case in sorted({r["case"] for r in rows if r["sensors"] == ns} - {"aligned"}):
            one = np.array([100 * (np.array(g[(ns, s, case)][0])
                                   - np.array(g[(ns, s, "aligned")][0])) for s in seeds])
            mean = np.array([100 * (np.mean(g[(ns, s, case)], 0)
                                    - np.mean(g[(ns, s, "aligned")], 0)) for s in seeds])
            se = mean.std(0, ddof=1) / np.sqrt(len(mean))
            print(f"{ns} sensors, {case} - aligned, {len(seeds)} pairs: mean of K "
                  f"{np.round(mean.mean(0), 2)} ± {np.round(se, 2)}, largest "
                  f"{np.round(np.abs(mean).max(0), 2)}; one seed largest "
                  f"{np.round(np.abs(one).max(0), 2)}")


if __name__ == "__main__":
    if sys.argv[1] == "summary":
        summary([json.loads(line) for line in sys.stdin if line.strip()])
    else:
        run(int(sys.argv[2]), int(sys.argv[3]), sys.argv[4].split(","),
            [int(s) for s in sys.argv[5:]])
