"""Seed 6501's late alert: the whole-path replay of a failed lateral damper, read closely.

The timing study's ``lateral-failing`` log of seed 6501 (3 sensors, aligned node clocks,
20 s, Csy x 0.25 at 10 s) through ``gateway replay`` at m = 1000 with the service's
filter; prints, every 0.5 s from 9 to 17 s, Csy, Csay and lambda over nominal, their
sigma over the mean, the ESS and the fault bank's location (None: none). Thirteenth
session (2026-11-29), docs/estimator.md "The thirteenth session".
"""

from __future__ import annotations

import dataclasses
import tempfile
from pathlib import Path

import numpy as np

from firmware_sim.output import drop_frames, write_log
from firmware_sim.scenarios import get_scenario
from firmware_sim.simulation import SimConfig, Simulation
from firmware_sim.studies.timing import set_clocks
from gateway.config import Config
from gateway.offline.replay import replay

NOMINAL = (40e3, 4114e3, 0.15)


def main(seed: int = 6501) -> None:
    sim = Simulation(get_scenario("lateral-failing"),
                     SimConfig(duration_s=20.0, seed=seed, noise_by_sample=True))
    set_clocks(sim, "aligned", np.random.default_rng(10_000 + seed))
    log = Path(tempfile.mkdtemp()) / "lateral-failing.log"
    write_log(drop_frames(sim.messages(), 0.0, np.random.default_rng(20_000 + seed)), log)
    base = Config()
    cfg = dataclasses.replace(base, estimator=dataclasses.replace(
        base.estimator, particles=1000, sensors=3, seed=seed))
    for e in replay(log, cfg).estimates:
        if 9.0 <= e.t_s <= 17.0 and (round(e.t_s * 10) % 5 == 0 or e.located is not None):
            rel = [round(m / n, 3) for m, n in zip(e.mean[:3], NOMINAL, strict=True)]
            sig = [round(s / m, 3) for s, m in zip(e.std[:3], e.mean[:3], strict=True)]
            print(round(e.t_s, 2), rel, sig, round(e.ess), e.located)


if __name__ == "__main__":
    main()
