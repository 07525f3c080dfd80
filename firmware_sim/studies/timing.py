"""Node-timing study: does a node's clock phase move the estimate? (a measuring tool)

The same simulated run (same truth, same sensor noise) is sent with the sensor nodes'
clocks set four ways, written as a CAN log and replayed through the whole gateway
(``gateway.offline.replay``: decode, validate, resample, gate, estimator worker) with a
given ``[resampler] interpolation``:

- ``aligned``: every lateral node samples on the grid of the receive clock (phase one
  period minus the simulator's 150 us minimum bus latency, no drift);
- ``half``: every lateral node half-way between grid points (no drift), the worst
  case for linear interpolation;
- ``phase``: each lateral node at its own random phase in [0, 1 ms), no drift;
- ``drift``: each at its own random phase and drift (+-50 ppm): the phase then sweeps
  through the grid during the run.

Every node draws its noise per sample number (``SimConfig.noise_by_sample``, since
2026-11-29's tenth session), so every case of a seed is the same data at another node
timing, ``drift`` included: compare them pair by pair. (Before, the nodes shared one
noise stream in block order and a drift drew another noise realisation.)
Rows (JSON lines on stdout): the final estimate's error against the truth at the start
(``rel``, ``z``) and at the end (``rel_end``: a fault scenario's new values), the stated
sigma per parameter, and the alerts raised (data time, parameter, severity; ``t0_s``
the first estimate's data time). ``summary FILE...`` prints the table of docs/resampler.md
("Node timing"): mean ± standard error over seeds, truth within 2 sigma, and the paired
difference to ``aligned``; rows of several filter seeds (``--filter-seeds K``) are
averaged per seed and case first, which takes the filter's own Monte Carlo error out
of the pairs. Data seed = the seed; filter seed = the seed, or ``100 * seed + k`` for
k = 1..K; the clocks' random draws from 10000 + seed. ``--bus-loss P`` drops each frame
of the log with probability P (draws from 20000 + seed; rows record it): a lossy bus
through the whole replay path. Not used by the service; a measuring tool.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
import time
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from firmware_sim.nodes import MIN_LATENCY_S, NodeClock
from firmware_sim.output import drop_frames, write_log
from firmware_sim.scenarios import get_scenario
from firmware_sim.simulation import SimConfig, Simulation
from firmware_sim.studies.rows import emit
from gateway.config import INTERPOLATIONS, Config
from gateway.model.vehicle import PARAM_NAMES
from gateway.offline.replay import replay
from gateway.records import AlertState

CASES = ("aligned", "half", "phase", "drift")


def set_clocks(sim: Simulation, case: str, rng: np.random.Generator) -> None:
    """Put the lateral nodes' clocks of ``sim`` into ``case`` (VEH keeps its own)."""
    for node in sim.nodes:
        if node.node == "VEH":
            continue
        period_s = node.period_s
        if case == "aligned":
            clock = NodeClock(0.0, period_s - MIN_LATENCY_S)
        elif case == "half":
            clock = NodeClock(0.0, period_s / 2 - MIN_LATENCY_S)
        elif case == "phase":
            clock = NodeClock(0.0, float(rng.uniform(0, period_s)))
        elif case == "drift":
            clock = NodeClock(float(rng.uniform(-50, 50)), float(rng.uniform(0, period_s)))
        else:
            raise ValueError(f"expected a case from {CASES}, got {case!r}")
        sim.clocks[node.node] = clock


def _sensor_noise(interpolation: str) -> str:
    """The service's default, "measured", where the configuration allows it: linear
    interpolation colours the noise, and needs the model's (``gateway.config``)."""
    return "model" if interpolation == "linear" else "measured"


def run_case(seed: int, case: str, interpolation: str, sensors: int, seconds: float,
             particles: int, scenario: str, workdir: Path, bus_loss: float = 0.0,
             mode: str = "fast", filter_seed: int | None = None) -> dict[str, Any]:
    """One replay: the final estimate against the truth. The estimator's seed is
    ``filter_seed``, or the data's ``seed`` when None."""
    sim = Simulation(get_scenario(scenario),
                     SimConfig(duration_s=seconds, seed=seed, noise_by_sample=True))
    truth = sim.scenario.theta(np.array([0.0]), seconds)[0]
    truth_end = sim.scenario.theta(np.array([seconds]), seconds)[0]
    set_clocks(sim, case, np.random.default_rng(10_000 + seed))
    log_path = workdir / f"{scenario}-{seed}-{case}-{bus_loss:g}.log"
    if not log_path.exists():
        write_log(drop_frames(sim.messages(), bus_loss, np.random.default_rng(20_000 + seed)),
                  log_path)
    base = Config()
    cfg = dataclasses.replace(
        base, resampler=dataclasses.replace(base.resampler, interpolation=interpolation),
        estimator=dataclasses.replace(base.estimator, particles=particles, sensors=sensors,
                                      mode=mode,
                                      seed=seed if filter_seed is None else filter_seed,
                                      sensor_noise=_sensor_noise(interpolation)))
    wall0 = time.monotonic()
    result = replay(log_path, cfg)
    est = result.estimates[-1]
    return {"seed": seed, "filter_seed": seed if filter_seed is None else filter_seed,
            "noise": "by_sample", "case": case, "interpolation": interpolation,
            "sensors": sensors,
            "particles": particles, "scenario": scenario, "bus_loss": bus_loss, "mode": mode,
            "t_s": est.t_s,
            "rel": [est.mean[i] / truth[i] - 1 for i in range(3)],
            "z": [(est.mean[i] - truth[i]) / est.std[i] for i in range(3)],
            "sigma_rel": [est.std[i] / est.mean[i] for i in range(3)],
            "rel_end": [est.mean[i] / truth_end[i] - 1 for i in range(3)],
            "t0_s": result.estimates[0].t_s,
            "alerts": [[a.t_s, a.parameter, a.severity.name] for a in result.alerts
                       if a.state == AlertState.RAISED],
            "wall_s": round(time.monotonic() - wall0, 2)}


def summary(rows: Sequence[dict[str, Any]]) -> str:
    """Markdown tables: per (sensors, interpolation, case) the mean error ± s.e. and
    truth within 2 sigma; then each case minus ``aligned`` of the same seed."""
    groups: dict[tuple[int, str, str], list[dict[str, Any]]] = defaultdict(list)
    for r in rows:
        groups[(r["sensors"], r["interpolation"], r["case"])].append(r)

    def cell(x: np.ndarray) -> str:
        se = x.std(ddof=1) / np.sqrt(len(x)) if len(x) > 1 else float("nan")
        return f"{x.mean():+.2f} ± {se:.2f}"

    names = " / ".join(PARAM_NAMES)
    out = [f"| sensors | interpolation | case | runs | error % (mean ± s.e.): {names} "
           f"| truth within 2σ |", "|---|---|---|---|---|---|"]
    for key in sorted(groups):
        g = groups[key]
        rel = 100 * np.array([r["rel"] for r in g])
        inside = np.mean(np.abs(np.array([r["z"] for r in g])) < 2, axis=0)
        out.append(f"| {key[0]} | {key[1]} | {key[2]} | {len(g)} | "
                   + " / ".join(cell(rel[:, i]) for i in range(3)) + " | "
                   + " / ".join(f"{100 * x:.0f} %" for x in inside) + " |")
    # each (sensors, interpolation, seed, case): rel by filter seed, and their mean
    runs: dict[tuple[int, str, int, str], dict[int, np.ndarray]] = defaultdict(dict)
    for r in rows:
        runs[(r["sensors"], r["interpolation"], r["seed"], r["case"])][
            r.get("filter_seed", r["seed"])] = 100 * np.asarray(r["rel"])
    out += ["", f"| sensors | interpolation | case − aligned, same seed | pairs | filter seeds "
                f"| difference % (mean ± s.e.): {names} | largest | largest, one filter seed |",
            "|---|---|---|---|---|---|---|---|"]
    for key in sorted(groups):
        if key[2] == "aligned":
            continue
        mean_d, one_d, k_seeds = [], [], set()
        for (ns, interp, seed, case), by_seed in sorted(runs.items()):
            ref = runs.get((ns, interp, seed, "aligned"))
            if (ns, interp, case) != key or ref is None:
                continue
            mean_d.append(np.mean(list(by_seed.values()), 0) - np.mean(list(ref.values()), 0))
            one_d += [by_seed[f] - ref[f] for f in by_seed if f in ref]
            k_seeds.add(len(by_seed))
        if not mean_d:
            continue
        d, one = np.array(mean_d), np.abs(np.array(one_d))
        out.append(f"| {key[0]} | {key[1]} | {key[2]} | {len(d)} | "
                   + "/".join(str(k) for k in sorted(k_seeds)) + " | "
                   + " / ".join(cell(d[:, i]) for i in range(3)) + " | "
                   + " / ".join(f"{np.abs(d[:, i]).max():.2f}" for i in range(3)) + " | "
                   + (" / ".join(f"{one[:, i].max():.2f}" for i in range(3)) if len(one)
                      else "—") + " |")
    return "\n".join(out)


def _seeds(text: str) -> list[int]:
    lo, _, hi = text.partition("-")
    return list(range(int(lo), int(hi or lo) + 1))


def main(argv: Sequence[str] | None = None) -> int:
    """The command line: run the cases (JSON lines), or ``summary`` of such lines."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["summary"]:
        rows = [json.loads(line) for f in argv[1:] for line in Path(f).read_text().splitlines()
                if line.strip()]
        print(summary(rows))
        return 0
    p = argparse.ArgumentParser(prog="python -m firmware_sim.studies.timing",
                                description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=_seeds, default=_seeds("1-10"), help="e.g. 1-20")
    p.add_argument("--cases", default=",".join(CASES))
    p.add_argument("--interpolation", default="sinc",
                   help=f"comma-separated, from {list(INTERPOLATIONS)}")
    p.add_argument("--sensors", type=int, choices=(3, 5), default=3)
    p.add_argument("--seconds", type=float, default=10.0)
    p.add_argument("--particles", type=int, default=1000)
    p.add_argument("--scenario", default="nominal")
    p.add_argument("--bus-loss", type=float, default=0.0,
                   help="share of the log's frames dropped (0)")
    p.add_argument("--mode", choices=("fast", "exact"), default="fast",
                   help="the estimator's mode (fast)")
    p.add_argument("--filter-seeds", type=int, default=0, metavar="K",
                   help="replay each log with the filter seeds 100 * seed + 1..K "
                        "(0: the data's seed, once)")
    args = p.parse_args(argv)
    if args.filter_seeds < 0:
        p.error(f"expected --filter-seeds K >= 0, got {args.filter_seeds}")
    with tempfile.TemporaryDirectory(prefix="railgw-timing-") as tmp:
        for seed in args.seeds:
            for case in args.cases.split(","):
                for interpolation in args.interpolation.split(","):
                    for filter_seed in ([100 * seed + k for k in range(1, args.filter_seeds + 1)]
                                        or [None]):
                        row = run_case(seed, case, interpolation, args.sensors, args.seconds,
                                       args.particles, args.scenario, Path(tmp),
                                       args.bus_loss, args.mode, filter_seed)
                        emit(row)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
