"""Accuracy study of the RBPF on simulator data: ``python -m firmware_sim.studies.accuracy WHAT``.

Produces the tables of docs/estimator.md (JSON lines on stdout, one per run):

- ``paper``: Sec. 4.2 scenario (theta = 20 kNs/m, 3000 kNs/m, 0.15; 42.5 m/s; Ar as
  printed), seeds 0-4, 3 and 5 sensors, 5 s (``--seconds`` to change, e.g. 20);
- ``roughness``: the same data, filter told Ar x0.5 and x2, and with Ar estimated;
- ``step``: Csy steps 40 -> 10 kNs/m at ``--fault-at`` s (other parameters nominal):
  detection delay and settling time;
- ``nominal``: a long run at the nominal theta (``--seconds 600``): innovation-monitor
  false alarms (detections) and the largest CUSUM value reached;
- ``compare``: fast mode against exact mode, paired (same data, same filter seed): the
  paper scenario over seeds 0-9, 3 and 5 sensors, 20 s, checkpoints 3, 5 and 20 s, and
  the step case over ``--step-seeds``; then summary rows (paired gap
  |mean_fast - mean_exact| / sigma_exact, coverage, detection delay) per mode;
  ``--reseeded`` adds an exact run with another filter seed, whose gap to the exact run
  is the Monte Carlo noise floor of the paired gap; ``--frame-loss P`` loses each sensor
  value of the paired data with probability P (a lossy bus; generator seed 2000 + seed).

``--mode`` picks the estimator mode(s): ``exact``, ``fast`` or ``both`` (default: both for
``compare``, exact, the reference, for the others). Every row records its mode. Each row
gives, at the checkpoints, the relative error of the posterior mean, sigma/mean, and
whether the truth lies within 2 sigma. Data seed ``1000 + seed``, filter seed ``seed``,
in every mode. ``--moves-drop-null`` / ``--no-moves-drop-null`` sets that option of every
filter (:class:`gateway.estimator.rbpf_config.RBPFConfig`; rows record it). Not used by
the service; a measuring tool.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np

from firmware_sim.studies.rows import emit
from firmware_sim.truth import lose_values, measured
from gateway.estimator.monitor import MonitorConfig, cusum
from gateway.estimator.rbpf import RBPF, RBPFConfig
from gateway.model.vehicle import (
    AR_PAPER_DEFAULT,
    PARAM_NAMES,
    THETA_NOMINAL,
    THETA_SEC42,
    sensor_set,
)
from gateway.records import Estimate, Sample

FS_HZ = 1000.0
V_MPS = 42.5
COMPARE_AT_S = (3.0, 5.0, 20.0)
CSY_FAILED = 10e3
"""Csy after the step fault, N s/m (40 -> 10 kNs/m)."""
SETTLE_REL = 0.15
RESEED_OFFSET = 100
"""compare --reseeded: the second exact run's filter seed is seed + this."""


def make_data(theta_t: np.ndarray, sensors: int, seed: int,
              ar_paper: float = AR_PAPER_DEFAULT) -> np.ndarray:
    """Noisy measurements (T, ny) of the linear truth at 1 kHz, 42.5 m/s."""
    return measured(theta_t, np.full(len(theta_t), V_MPS), FS_HZ, sensor_set(sensors),
                    np.random.default_rng(1000 + seed), ar_paper=ar_paper)


def run_filter(Y: np.ndarray, cfg: RBPFConfig, every: int = 100,
               detected_at_s: list[float] | None = None) -> tuple[list[Estimate], RBPF, float]:
    """Estimates every ``every`` samples, the filter, and the wall time in s.

    ``detected_at_s``, if given, receives the data time [s] of each sample at which the
    innovation monitor raised a detection (``n_detections`` went up).
    """
    filt = RBPF(cfg)
    det = detected_at_s if detected_at_s is not None else []

    def samples() -> Iterator[Sample]:
        # Read between samples: when sample k is asked for, sample k-1 has been consumed.
        seen = 0
        for k in range(len(Y)):
            if filt.n_detections > seen:
                det.extend([k / FS_HZ] * (filt.n_detections - seen))
                seen = filt.n_detections
            yield Sample(t_s=(k + 1) / FS_HZ, values=Y[k], speed_mps=V_MPS)
        if filt.n_detections > seen:
            det.extend([len(Y) / FS_HZ] * (filt.n_detections - seen))

    t0 = time.perf_counter()
    est = filt.run(samples(), output_every=every)
    return est, filt, time.perf_counter() - t0


def summarise(est: list[Estimate], truth: np.ndarray, at_s: Sequence[float]) -> dict:
    """Per checkpoint: error % of the mean, sigma/mean %, truth within 2 sigma, and the
    unrounded mean and std (SI units) for paired comparisons."""
    out = {}
    for t in at_s:
        e = min(est, key=lambda x: abs(x.t_s - t))
        m, s = np.array(e.mean[:3]), np.array(e.std[:3])
        out[f"{t:g}s"] = {"err_pct": list(np.round(100 * (m - truth) / truth, 2)),
                          "sigma_pct": list(np.round(100 * s / m, 2)),
                          "within_2sigma": [bool(v) for v in np.abs(m - truth) <= 2 * s],
                          "mean": [float(v) for v in m], "std": [float(v) for v in s],
                          "ar_mean": e.mean[3] if len(e.mean) > 3 else None,
                          "ar_sigma_pct": 100 * e.std[3] / e.mean[3] if len(e.mean) > 3
                          else None}
    return out


def step_run(seed: int, sensors: int, seconds: float, fault_at_s: float,
             base: dict[str, Any]) -> dict[str, Any]:
    """The failed-damper case: Csy 40 -> 10 kNs/m at ``fault_at_s``, others nominal.

    ``detect_delay_s``: fault to the first detection after it; ``settled_within_15pct_after_s``:
    fault to the first estimate from which Csy stays within 15 % of 10 kNs/m to the end.
    """
    n = int(round(seconds * FS_HZ))
    th = np.repeat(THETA_NOMINAL.as_array()[None], n, 0)
    th[int(round(fault_at_s * FS_HZ)):, 0] = CSY_FAILED
    Y = make_data(th, sensors, seed)
    det_s: list[float] = []
    est, filt, wall = run_filter(Y, RBPFConfig(**base), detected_at_s=det_s)
    csy = [(e.t_s, e.mean[0], e.std[0]) for e in est]
    ok = [abs(m - CSY_FAILED) <= SETTLE_REL * CSY_FAILED for _, m, _ in csy]
    settled = None
    for i, (t, _, _) in enumerate(csy):
        if t > fault_at_s and all(ok[i:]):
            settled = t - fault_at_s
            break
    after = [t - fault_at_s for t in det_s if t > fault_at_s]
    return {"what": "step", "mode": base["mode"], "seed": seed, "sensors": sensors,
            "moves_drop_null": filt.config.moves_drop_null,
            "seconds": seconds, "fault_at_s": fault_at_s, "particles": base["n_particles"],
            "detect_delay_s": after[0] if after else None,
            "detections_before_fault": sum(t <= fault_at_s for t in det_s),
            "settled_within_15pct_after_s": settled,
            "any_within": any(o for (t, _, _), o in zip(csy, ok, strict=True) if t > fault_at_s),
            "detections": filt.n_detections,
            "final": summarise(est, th[-1], [seconds]),
            "csy_trace": [(round(t, 2), round(m), round(s)) for t, m, s in csy[::5]],
            "wall_s": wall}


def _base(particles: int, sensors: int, seed: int, mode: str, **extra: Any) -> dict[str, Any]:
    return dict(fs_hz=FS_HZ, n_particles=particles, sensors=sensors, seed=seed, mode=mode,
                **extra)


def _gap(a: dict[str, Any], ref: dict[str, Any], key: str) -> list[float]:
    """|mean_a - mean_ref| / sigma_ref per parameter at checkpoint ``key``."""
    return [abs(ma - mr) / sr for ma, mr, sr in
            zip(a[key]["mean"], ref[key]["mean"], ref[key]["std"], strict=True)]


def compare(seeds: Sequence[int], sensors: Sequence[int], particles: int, seconds: float,
            modes: Sequence[str] = ("fast", "exact"), reseeded: bool = False,
            frame_loss: float = 0.0, **extra: Any) -> Iterator[dict[str, Any]]:
    """Paired runs of the paper scenario, one row per (seed, sensors, mode), a ``pair`` row
    per (seed, sensors) when both modes run, then ``compare_summary`` rows.

    Both modes see the same data (seed 1000 + seed) and filter seed. The gap of a
    parameter is |mean_fast - mean_exact| / sigma_exact at a checkpoint (3, 5 and 20 s,
    those within ``seconds``; the end when none is). ``reseeded`` adds the Monte Carlo
    noise floor: an exact run with filter seed ``seed + RESEED_OFFSET`` (role
    ``exact_reseeded``) and its gap to the exact run. ``frame_loss``: the share of sensor
    values lost (NaN) in the data. ``extra``: further :class:`RBPFConfig` fields of every
    run.
    """
    at_s = [t for t in COMPARE_AT_S if t <= seconds] or [seconds]
    truth = THETA_SEC42.as_array()
    n = int(round(seconds * FS_HZ))
    runs: list[dict[str, Any]] = []
    pairs: list[dict[str, Any]] = []
    for seed in seeds:
        for ns in sensors:
            Y = make_data(np.repeat(truth[None], n, 0), ns, seed)
            if frame_loss > 0:
                Y = lose_values(Y, frame_loss, np.random.default_rng(2000 + seed))
            by_mode = {}
            roles = [(m, m, seed) for m in modes]
            if reseeded:
                roles.append(("exact_reseeded", "exact", seed + RESEED_OFFSET))
            for role, mode, fseed in roles:
                cfg = RBPFConfig(**_base(particles, ns, fseed, mode, **extra))
                est, filt, wall = run_filter(Y, cfg)
                row = {"what": "compare", "mode": mode, "role": role, "seed": seed,
                       "filter_seed": fseed, "sensors": ns,
                       "particles": particles, "seconds": seconds,
                       "moves_drop_null": cfg.moves_drop_null, "frame_loss": frame_loss,
                       **summarise(est, truth, at_s), "resamples": filt.n_resamples,
                       "detections": filt.n_detections, "wall_s": wall}
                runs.append(row)
                by_mode[role] = row
                yield row
            if "exact" in by_mode and len(by_mode) > 1:
                x = by_mode["exact"]
                pair = {"what": "pair", "seed": seed, "sensors": ns, "particles": particles,
                        **{f"{t:g}s": {f"{'gap' if r == 'fast' else 'reseed_gap'}_sigma":
                                       _gap(by_mode[r], x, f"{t:g}s")
                                       for r in ("fast", "exact_reseeded") if r in by_mode}
                           for t in at_s}}
                pairs.append(pair)
                yield pair
    yield from compare_summary(runs, pairs, at_s)


def compare_summary(runs: list[dict[str, Any]], pairs: list[dict[str, Any]],
                    at_s: Sequence[float]) -> Iterator[dict[str, Any]]:
    """Per sensor set and checkpoint: per mode the error and sigma statistics and the
    coverage counts; over the pairs the median and max gap per parameter, and the mean
    signed gap with its standard error (a systematic offset of the fast mode)."""
    for ns in sorted({r["sensors"] for r in runs}):
        for t in at_s:
            key = f"{t:g}s"
            row: dict[str, Any] = {"what": "compare_summary", "sensors": ns, "at": key,
                                   "params": list(PARAM_NAMES)}
            for mode in ("fast", "exact", "exact_reseeded"):
                rs = [r[key] for r in runs if r["sensors"] == ns
                      and r.get("role", r["mode"]) == mode]
                if not rs:
                    continue
                err = np.abs([r["err_pct"] for r in rs])
                sig = np.array([r["sigma_pct"] for r in rs])
                row[mode] = {"runs": len(rs),
                             "mean_abs_err_pct": list(np.round(err.mean(0), 2)),
                             "max_abs_err_pct": list(np.round(err.max(0), 2)),
                             "mean_sigma_pct": list(np.round(sig.mean(0), 2)),
                             "max_sigma_pct": list(np.round(sig.max(0), 2)),
                             "within_2sigma": [int(v) for v in
                                               np.sum([r["within_2sigma"] for r in rs], 0)]}
            for role, name in (("fast", "bias_sigma"), ("exact_reseeded", "reseed_bias_sigma")):
                d = _signed(runs, ns, key, role)
                if len(d) > 1:
                    row[name] = {"pairs": len(d), "mean": list(np.round(d.mean(0), 3)),
                                 "std_err": list(np.round(d.std(0, ddof=1) / np.sqrt(len(d)),
                                                          3))}
            for g in ("gap_sigma", "reseed_gap_sigma"):
                gaps = np.array([p[key][g] for p in pairs if p["sensors"] == ns
                                 and g in p[key]])
                if len(gaps):
                    row[g] = {"pairs": len(gaps),
                              "median": list(np.round(np.median(gaps, 0), 3)),
                              "max": list(np.round(gaps.max(0), 3)),
                              "within_0.3": [int(v) for v in np.sum(gaps <= 0.3, 0)]}
            yield row


def _signed(runs: list[dict[str, Any]], sensors: int, key: str, role: str) -> np.ndarray:
    """(mean_role - mean_exact) / sigma_exact (pairs, 3) over the seeds run in both roles."""
    by = {(r["seed"], r.get("role", r["mode"])): r[key] for r in runs if r["sensors"] == sensors}
    seeds = sorted(s for s, rl in by if rl == role and (s, "exact") in by)
    return np.array([(np.array(by[s, role]["mean"]) - by[s, "exact"]["mean"])
                     / np.array(by[s, "exact"]["std"]) for s in seeds]).reshape(-1, 3)


def step_summary(rows: list[dict[str, Any]]) -> Iterator[dict[str, Any]]:
    """Per mode: median and range of the detection delay and of the settling time."""
    for mode in ("fast", "exact"):
        rs = [r for r in rows if r["mode"] == mode]
        if not rs:
            continue
        out: dict[str, Any] = {"what": "step_summary", "mode": mode, "runs": len(rs),
                               "detections_before_fault": sum(r["detections_before_fault"]
                                                              for r in rs)}
        for k in ("detect_delay_s", "settled_within_15pct_after_s"):
            v = [r[k] for r in rs if r[k] is not None]
            out[k] = {"n": len(v), "median": float(np.median(v)) if v else None,
                      "min": min(v, default=None), "max": max(v, default=None)}
        yield out


def _modes(arg: str | None, what: str) -> tuple[str, ...]:
    chosen = arg or ("both" if what == "compare" else "exact")
    return ("fast", "exact") if chosen == "both" else (chosen,)


def _print(row: dict[str, Any]) -> None:
    emit(row)


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m firmware_sim.studies.accuracy")
    ap.add_argument("what", choices=("paper", "roughness", "step", "nominal", "compare"))
    ap.add_argument("--mode", choices=("fast", "exact", "both"), default=None,
                    help="estimator mode(s) (default: both for compare, else exact)")
    ap.add_argument("--seeds", type=int, nargs="+", default=None,
                    help="seeds (default: 0-9 for compare, else 0-4)")
    ap.add_argument("--sensors", type=int, nargs="+", default=[5, 3])
    ap.add_argument("--seconds", type=float, default=None,
                    help="run length in s (default: 20 for compare, else 5)")
    ap.add_argument("--particles", type=int, default=1000)
    ap.add_argument("--fault-at", type=float, default=None,
                    help="step time in s (default: 8 for compare, else 10)")
    ap.add_argument("--step-seeds", type=int, nargs="*", default=[0, 1, 2, 3, 4],
                    help="compare: seeds of the step case (3 sensors)")
    ap.add_argument("--step-seconds", type=float, default=18.0,
                    help="compare: length of the step runs in s")
    ap.add_argument("--reseeded", action="store_true",
                    help="compare: add an exact run with another filter seed (the Monte "
                         "Carlo noise floor of the gap)")
    ap.add_argument("--frame-loss", type=float, default=0.0,
                    help="compare: share of sensor values lost in the data (0)")
    ap.add_argument("--floor-reference", choices=("nominal", "value"),
                    default=RBPFConfig.floor_reference)
    ap.add_argument("--ess-threshold", type=float, default=RBPFConfig.ess_threshold,
                    help="resample when ESS < this x m (default: the estimator's)")
    ap.add_argument("--moves-drop-null", action=argparse.BooleanOptionalAction,
                    default=RBPFConfig.moves_drop_null,
                    help="the filter's moves_drop_null option (default: the estimator's)")
    ap.add_argument("--walk", type=float, default=None,
                    help="random-walk rate of every parameter, relative per sqrt(s) "
                         "(default: the estimator's)")
    args = ap.parse_args(argv)
    modes = _modes(args.mode, args.what)
    is_cmp = args.what == "compare"
    seeds = args.seeds if args.seeds is not None else list(range(10 if is_cmp else 5))
    seconds = args.seconds if args.seconds is not None else (20.0 if is_cmp else 5.0)
    fault_at = args.fault_at if args.fault_at is not None else (8.0 if is_cmp else 10.0)
    if is_cmp:
        opt = {"moves_drop_null": args.moves_drop_null}
        for row in compare(seeds, args.sensors, args.particles, seconds, modes,
                           args.reseeded, args.frame_loss, **opt):
            _print(row)
        steps = [step_run(seed, 3, args.step_seconds, fault_at,
                          _base(args.particles, 3, seed, mode, **opt))
                 for seed in args.step_seeds for mode in modes]
        for row in steps:
            _print(row)
        for row in step_summary(steps):
            _print(row)
        return 0
    n = int(round(seconds * FS_HZ))
    for seed in seeds:
        for ns in args.sensors:
            for mode in modes:
                _one(args, seed, ns, mode, n, seconds, fault_at)
    return 0


def _one(args: argparse.Namespace, seed: int, ns: int, mode: str, n: int, seconds: float,
         fault_at: float) -> None:
    """One run of the paper, roughness, step or nominal case; prints its rows."""
    base = _base(args.particles, ns, seed, mode, floor_reference=args.floor_reference,
                 ess_threshold=args.ess_threshold, moves_drop_null=args.moves_drop_null)
    if args.walk is not None:
        base["walk_rel_per_sqrt_s"] = (args.walk,) * 3
    if args.what == "nominal":
        Y = make_data(np.repeat(THETA_NOMINAL.as_array()[None], n, 0), ns, seed)
        filt = RBPF(RBPFConfig(**base))
        top, t0 = 0.0, time.perf_counter()
        for k in range(n):
            filt.step(Sample(t_s=(k + 1) / FS_HZ, values=Y[k], speed_mps=V_MPS))
            top = max(top, cusum(filt.monitor_state))
        _print({"what": "nominal", "mode": mode, "seed": seed, "sensors": ns,
                "seconds": seconds, "particles": args.particles,
                "detections": filt.n_detections, "max_cusum": top,
                "threshold": MonitorConfig().h_sigma, "wall_s": time.perf_counter() - t0})
        return
    if args.what == "step":
        _print(step_run(seed, ns, seconds, fault_at, base))
        return
    truth = THETA_SEC42.as_array()
    Y = make_data(np.repeat(truth[None], n, 0), ns, seed)
    checkpoints = [3.0, 5.0] + ([seconds] if seconds > 5 else [])
    variants: list[tuple[str, dict[str, Any]]] = [("exact_ar", {})]
    if args.what == "roughness":
        variants = [("ar_x0.5", {"ar_paper": 0.5 * AR_PAPER_DEFAULT}),
                    ("ar_x2", {"ar_paper": 2.0 * AR_PAPER_DEFAULT}),
                    ("ar_estimated", {"estimate_ar": True})]
    for name, extra in variants:
        est, filt, wall = run_filter(Y, RBPFConfig(**base, **extra))
        _print({"what": args.what, "mode": mode, "variant": name, "seed": seed,
                "moves_drop_null": filt.config.moves_drop_null,
                "sensors": ns, "seconds": seconds, **summarise(est, truth, checkpoints),
                "resamples": filt.n_resamples, "detections": filt.n_detections,
                "wall_s": wall})


if __name__ == "__main__":
    sys.exit(main())
