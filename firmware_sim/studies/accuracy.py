"""Accuracy study of the RBPF on simulator data: ``python -m firmware_sim.studies.accuracy WHAT``.

Produces the tables of docs/estimator.md (JSON lines on stdout, one per run):

- ``paper``: Sec. 4.2 scenario (theta = 20 kNs/m, 3000 kNs/m, 0.15; 42.5 m/s; Ar as
  printed), seeds 0-4, 3 and 5 sensors, 5 s (``--seconds`` to change, e.g. 20);
- ``roughness``: the same data, filter told Ar x0.5 and x2, and with Ar estimated;
- ``step``: Csy steps 40 -> 10 kNs/m at ``--fault-at`` s (other parameters nominal);
- ``nominal``: a long run at the nominal theta (``--seconds 600``): innovation-monitor
  false alarms (detections) and the largest CUSUM value reached.

Each row gives, at the checkpoints, the relative error of the posterior mean, sigma/mean,
and whether the truth lies within 2 sigma. Data seed ``1000 + seed``, filter seed
``seed``. Not used by the service; a measuring tool.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from firmware_sim.truth import add_sensor_noise, select, simulate
from gateway.estimator.monitor import MonitorConfig, cusum
from gateway.estimator.rbpf import RBPF, RBPFConfig
from gateway.model.vehicle import AR_PAPER_DEFAULT, THETA_NOMINAL, THETA_SEC42, sensor_set
from gateway.records import Estimate, Sample

FS_HZ = 1000.0
V_MPS = 42.5


def make_data(theta_t: np.ndarray, sensors: int, seed: int,
              ar_paper: float = AR_PAPER_DEFAULT) -> np.ndarray:
    """Noisy measurements (T, ny) of the linear truth at 1 kHz, 42.5 m/s."""
    rng = np.random.default_rng(1000 + seed)
    run = simulate(theta_t, np.full(len(theta_t), V_MPS), FS_HZ, rng, ar_paper=ar_paper)
    names = sensor_set(sensors)
    return add_sensor_noise(select(run.outputs, names), names, rng)


def run_filter(Y: np.ndarray, cfg: RBPFConfig, every: int = 100) -> tuple[list[Estimate],
                                                                           RBPF, float]:
    """Estimates every ``every`` samples, the filter, and the wall time in s."""
    filt = RBPF(cfg)
    samples = (Sample(t_s=(k + 1) / FS_HZ, values=Y[k], speed_mps=V_MPS) for k in range(len(Y)))
    t0 = time.perf_counter()
    est = filt.run(samples, output_every=every)
    return est, filt, time.perf_counter() - t0


def summarise(est: list[Estimate], truth: np.ndarray, at_s: Sequence[float]) -> dict:
    """Per checkpoint: error % of the mean, sigma/mean %, truth within 2 sigma."""
    out = {}
    for t in at_s:
        e = min(est, key=lambda x: abs(x.t_s - t))
        m, s = np.array(e.mean[:3]), np.array(e.std[:3])
        out[f"{t:g}s"] = {"err_pct": list(np.round(100 * (m - truth) / truth, 2)),
                          "sigma_pct": list(np.round(100 * s / m, 2)),
                          "within_2sigma": [bool(v) for v in np.abs(m - truth) <= 2 * s],
                          "ar_mean": e.mean[3] if len(e.mean) > 3 else None,
                          "ar_sigma_pct": 100 * e.std[3] / e.mean[3] if len(e.mean) > 3
                          else None}
    return out


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m firmware_sim.studies.accuracy")
    ap.add_argument("what", choices=("paper", "roughness", "step", "nominal"))
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    ap.add_argument("--sensors", type=int, nargs="+", default=[5, 3])
    ap.add_argument("--seconds", type=float, default=5.0)
    ap.add_argument("--particles", type=int, default=1000)
    ap.add_argument("--fault-at", type=float, default=10.0)
    ap.add_argument("--floor-reference", choices=("nominal", "value"),
                    default=RBPFConfig.floor_reference)
    ap.add_argument("--ess-threshold", type=float, default=RBPFConfig.ess_threshold,
                    help="resample when ESS < this x m (default: the estimator's)")
    ap.add_argument("--walk", type=float, default=None,
                    help="random-walk rate of every parameter, relative per sqrt(s) "
                         "(default: the estimator's)")
    args = ap.parse_args(argv)
    n = int(round(args.seconds * FS_HZ))
    for seed in args.seeds:
        for ns in args.sensors:
            base: dict[str, Any] = dict(fs_hz=FS_HZ, n_particles=args.particles, sensors=ns,
                                        seed=seed, floor_reference=args.floor_reference,
                                        ess_threshold=args.ess_threshold)
            if args.walk is not None:
                base["walk_rel_per_sqrt_s"] = (args.walk,) * 3
            if args.what == "nominal":
                th = np.repeat(THETA_NOMINAL.as_array()[None], n, 0)
                Y = make_data(th, ns, seed)
                filt = RBPF(RBPFConfig(**base))
                top, t0 = 0.0, time.perf_counter()
                for k in range(n):
                    filt.step(Sample(t_s=(k + 1) / FS_HZ, values=Y[k], speed_mps=V_MPS))
                    top = max(top, cusum(filt.monitor_state))
                print(json.dumps({"what": "nominal", "seed": seed, "sensors": ns,
                                  "seconds": args.seconds, "particles": args.particles,
                                  "detections": filt.n_detections, "max_cusum": top,
                                  "threshold": MonitorConfig().h_sigma,
                                  "wall_s": time.perf_counter() - t0}), flush=True)
                continue
            if args.what == "step":
                th = np.repeat(THETA_NOMINAL.as_array()[None], n, 0)
                k = int(round(args.fault_at * FS_HZ))
                th[k:, 0] = 10e3
                truth_after = th[-1]
                Y = make_data(th, ns, seed)
                est, filt, wall = run_filter(Y, RBPFConfig(**base))
                csy = [(e.t_s, e.mean[0], e.std[0]) for e in est]
                within = [t for t, m, _ in csy if t > args.fault_at
                          and abs(m - 10e3) <= 0.15 * 10e3]
                first = None
                for t, _, _ in csy:
                    if t > args.fault_at and all(abs(m - 10e3) <= 0.15 * 10e3
                                                 for tt, m, _ in csy if tt >= t):
                        first = t - args.fault_at
                        break
                row = {"what": "step", "seed": seed, "sensors": ns,
                       "settled_within_15pct_after_s": first,
                       "any_within": bool(within), "detections": filt.n_detections,
                       "final": summarise(est, truth_after, [args.seconds]),
                       "csy_trace": [(round(t, 2), round(m), round(s)) for t, m, s in csy[::5]],
                       "wall_s": wall}
                print(json.dumps(row), flush=True)
                continue
            th = np.repeat(THETA_SEC42.as_array()[None], n, 0)
            Y = make_data(th, ns, seed)
            truth = THETA_SEC42.as_array()
            checkpoints = [3.0, 5.0] + ([args.seconds] if args.seconds > 5 else [])
            variants: list[tuple[str, dict[str, Any]]] = [("exact_ar", {})]
            if args.what == "roughness":
                variants = [("ar_x0.5", {"ar_paper": 0.5 * AR_PAPER_DEFAULT}),
                            ("ar_x2", {"ar_paper": 2.0 * AR_PAPER_DEFAULT}),
                            ("ar_estimated", {"estimate_ar": True})]
            for name, extra in variants:
                est, filt, wall = run_filter(Y, RBPFConfig(**base, **extra))
                row = {"what": args.what, "variant": name, "seed": seed, "sensors": ns,
                       "seconds": args.seconds, **summarise(est, truth, checkpoints),
                       "resamples": filt.n_resamples, "detections": filt.n_detections,
                       "wall_s": wall}
                print(json.dumps(row), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
