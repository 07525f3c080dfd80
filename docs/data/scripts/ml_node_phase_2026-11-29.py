"""Node timing without particle noise: the maximum-likelihood answer on the same data.

`gateway identify run` (prediction error) on one record with the lateral nodes' clocks
aligned, at their own phases, and at their own phases and drifts (+-50 ppm): the timing
study's clocks (``firmware_sim.studies.timing.set_clocks``), the sensor noise drawn per
sample (``SimConfig.noise_by_sample``), so the three logs carry the same data. The ML
uses the sensor set given (3 or 5). One JSON line per run (tenth session, 2026-11-29)::

    python S nominal 10 5 5901 5902 5903 5904 5905
    python S nominal 10 3 5901 5902 5903 5904 5905
"""

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from firmware_sim.output import write_log
from firmware_sim.scenarios import get_scenario
from firmware_sim.simulation import SimConfig, Simulation
from firmware_sim.studies.timing import set_clocks
from gateway.model.vehicle import sensor_set

scenario, seconds, sensors = sys.argv[1], float(sys.argv[2]), int(sys.argv[3])
work = Path(tempfile.mkdtemp())
conf = work / "c.toml"
conf.write_text('[estimator]\nsensor_noise = "model"\n')
for seed in [int(s) for s in sys.argv[4:]]:
    for case in ("aligned", "phase", "drift"):
        sim = Simulation(get_scenario(scenario),
                         SimConfig(duration_s=seconds, seed=seed, noise_by_sample=True))
        set_clocks(sim, case, np.random.default_rng(10_000 + seed))
        log = work / f"{seed}-{case}.log"
        write_log(sim.messages(), log)
        rep = work / f"rep-{seed}-{case}"
        t0 = time.monotonic()
        p = subprocess.run([sys.executable, "-m", "gateway", "identify", "run", str(log),
                            "--out", str(rep), "--config", str(conf),
                            "--sensors", ",".join(sensor_set(sensors))],
                           capture_output=True, text=True, check=False)
        if p.returncode:
            sys.exit(p.stderr)
        est = json.loads((rep / "report.json").read_text())["estimates"]
        print(json.dumps({"seed": seed, "case": case, "sensors": sensors,
                          "scenario": scenario, "seconds": seconds,
                          "value": {k: v["value"] for k, v in est.items()},
                          "sigma": {k: v.get("std") for k, v in est.items()},
                          "drift_ppm": {n: sim.clocks[n].drift_ppm
                                        for n in ("WSN", "BGN", "BDN")},
                          "wall_s": round(time.monotonic() - t0, 1)}), flush=True)
