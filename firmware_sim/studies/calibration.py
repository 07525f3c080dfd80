"""Calibration study: does the truth lie inside the stated +-2 sigma, and how does sigma
compare with the maximum-likelihood sigma on the same record?

``python -m firmware_sim.studies.calibration paper --seeds 1 ... 20`` runs the paper's
Sec. 4.2 scenario (theta = 20 kNs/m, 3000 kNs/m, 0.15; 42.5 m/s), 3 and 5 sensors, 20 s,
through the service's filter (:func:`firmware_sim.studies.filtering.service_filter`: fast
mode, m = 1000, drift, monitor and fault bank) and, on the same record's first 5 s and
all 20 s, through the prediction-error maximum likelihood with its observed-information
sigma (:class:`gateway.identify.pipeline.PredictionErrorIdentifier`). One JSON line per
record and check time: the filter's mean and sigma, the ML estimate and sigma, the
filter's z-score ``(mean - truth) / sigma`` and ``sigma / sigma_ML``.

``box --seeds 1 ... 50`` draws theta uniformly over the filter's prior box
(:class:`gateway.estimator.rbpf_config.RBPFConfig` ``prior_lo``/``prior_hi`` times
nominal) and runs 10 s (start-up: is the lock-in gone everywhere in the box?); no ML fit.

``--moves-drop-null`` / ``--no-moves-drop-null`` runs the filter with that option of
:class:`gateway.estimator.rbpf_config.RBPFConfig` on or off (default: the filter's own),
``--start-ramp-s`` with that ``start_ramp_s`` and ``--start-ramp-m`` with that
``start_ramp_m`` (default: the service's; ``--start-ramp-m 0``: the ramp in seconds
alone, as before 2026-11-27). ``--at-s`` sets
the check times (the record lasts until the last one).
``--hold AT FOR`` holds the updates from AT s for FOR s (a curve and its straight hold:
the filters predict through it). ``--from-rest`` starts the truth at rest instead of in
stationary vibration (another simulator's convention;
:func:`firmware_sim.truth.simulate` ``burn_in_s`` = 0).

``--kernel-delta`` runs the service's filter with that ``[estimator] kernel_delta``.
``--theta nominal`` runs the paper scenario on the service's nominal vehicle
(:data:`gateway.model.vehicle.THETA_NOMINAL`) instead of the paper's Sec. 4.2 values.

``summary < rows.jsonl`` gives, per (study, option, sensors, time): the share of records
with the truth inside +-2 sigma per parameter, the largest |z|, and the smallest
sigma / sigma_ML. ``window LO HI < rows.jsonl`` gives, per case, each record's z
averaged over its check times in [LO, HI] s, then the mean over records with its
standard error and the records below the truth: a bias over minutes, which one check
time cannot show (with the parameters' random walk an estimate remembers only its last
few seconds of data).
Data seed ``3000 + seed`` (paper) or ``4000 + seed`` (box), fresh against the accuracy
(1000 +) and detection (2000 +) studies; filter seed ``seed``. A measuring tool, not used
by the service.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from typing import Any

import numpy as np

from firmware_sim.studies.arguments import add_track_input, kernel_delta_arg
from firmware_sim.studies.filtering import FS_HZ, V_MPS, FilterOptions, run, service_filter
from firmware_sim.studies.holds import holds
from firmware_sim.studies.rows import emit
from firmware_sim.truth import BURN_IN_S, measured
from gateway.estimator.rbpf_config import PAPER_DELTA, RBPFConfig
from gateway.identify.data import Dataset
from gateway.identify.pipeline import PredictionErrorIdentifier
from gateway.model.vehicle import PARAM_NAMES, THETA_NOMINAL, THETA_SEC42, sensor_set

PAPER_AT_S = (5.0, 20.0)
BOX_AT_S = (10.0,)
SEED_OFFSET = {"paper": 3000, "box": 4000}
PAPER_THETA = {"paper": THETA_SEC42, "nominal": THETA_NOMINAL}


def record(theta: np.ndarray, sensors: int, data_seed: int, seconds: float,
           from_rest: bool = False, speed_mps: float = V_MPS,
           track_input: str = "white") -> np.ndarray:
    """Noisy measurements (T, ny) of the linear truth at ``theta`` (3,), 1 kHz,
    ``speed_mps``, in stationary vibration from the first sample, or ``from_rest``;
    ``track_input`` one of :data:`firmware_sim.truth.TRACK_INPUTS`."""
    n = int(round(seconds * FS_HZ))
    return measured(np.repeat(np.asarray(theta, dtype=float)[None], n, 0),
                    np.full(n, speed_mps), FS_HZ, sensor_set(sensors),
                    np.random.default_rng(data_seed),
                    burn_in_s=0.0 if from_rest else BURN_IN_S, track_input=track_input)


def box_theta(seed: int) -> np.ndarray:
    """theta (3,) drawn uniformly over the prior box (the filter's own prior)."""
    cfg = RBPFConfig(fs_hz=FS_HZ)
    lo, hi = cfg.box(cfg.prior_lo, cfg.prior_hi)
    return np.random.default_rng(SEED_OFFSET["box"] + 500 + seed).uniform(lo, hi)


def ml_fit(Y: np.ndarray, sensors: int, seconds: float, speed_mps: float = V_MPS
           ) -> tuple[list[float], list[float]]:
    """Maximum-likelihood theta and its sigma (SI) from the first ``seconds`` of ``Y``
    (T, ny), recorded at ``speed_mps``."""
    n = int(round(seconds * FS_HZ))
    t = np.arange(n) / FS_HZ
    ds = Dataset(t_s=t, measured=Y[:n], sensors=sensor_set(sensors),
                 speed_mps=np.full(n, speed_mps), fs_hz=FS_HZ, source="calibration")
    res = PredictionErrorIdentifier().fit(ds)
    return list(res.values), list(res.std)


def rows_for(what: str, seed: int, sensors: int, particles: int, mode: str,
             ml: bool, at_s: Sequence[float] | None = None,
             moves_drop_null: bool | None = None, from_rest: bool = False,
             start_ramp_s: float | None = None, hold: tuple[float, float] | None = None,
             speed_mps: float = V_MPS, start_ramp_m: float | None = None,
             theta_name: str = "paper", kernel_delta: float | None = None,
             track_input: str = "white",
             prior_lo: tuple[float, float, float] | None = None) -> list[dict[str, Any]]:
    """One row per check time (default :data:`PAPER_AT_S` or :data:`BOX_AT_S`) for one
    record, which lasts until the last of them; ``moves_drop_null`` overrides that
    option of the service's filter (:class:`gateway.estimator.rbpf_config.RBPFConfig`;
    None: the default), and ``start_ramp_s`` and ``start_ramp_m`` those; ``from_rest``:
    the truth starts at rest; ``hold`` (start, length) in s: no updates then, as the
    gate holds them in a curve; ``speed_mps``: the vehicle's constant speed;
    ``theta_name``: the paper study's vehicle, a key of :data:`PAPER_THETA`;
    ``kernel_delta``: the service's ``[estimator] kernel_delta`` (None: its default);
    ``track_input``: how the truth's track velocities enter
    (:data:`firmware_sim.truth.TRACK_INPUTS`); ``prior_lo``: the filter's prior box's
    lower edges (None: the service's)."""
    theta = PAPER_THETA[theta_name].as_array() if what == "paper" else box_theta(seed)
    at_s = at_s or (PAPER_AT_S if what == "paper" else BOX_AT_S)
    Y = record(theta, sensors, SEED_OFFSET[what] + seed, max(at_s), from_rest, speed_mps,
               track_input)
    filt = service_filter(sensors, seed, FilterOptions(
        particles=particles, mode=mode, moves_drop_null=moves_drop_null,
        start_ramp_s=start_ramp_s, start_ramp_m=start_ramp_m, kernel_delta=kernel_delta,
        prior_lo=prior_lo))
    held = None if hold is None else holds(len(Y), FS_HZ, [hold[0]], hold[1])
    est, found, _ = run(Y, filt, held=held, speed_mps=speed_mps)
    out = []
    for t in at_s:
        e = min(est, key=lambda x: abs(x.t_s - t))
        m, s = np.array(e.mean[:3]), np.array(e.std[:3])
        row: dict[str, Any] = {
            "study": what, "theta_name": theta_name if what == "paper" else "box",
            "sensors": sensors, "speed_mps": speed_mps, "seed": seed,
            "t_s": t, "mode": mode,
            "moves_drop_null": filt.config.moves_drop_null,
            "from_rest": from_rest, "start_ramp_s": filt.config.start_ramp_s,
            "start_ramp_m": filt.config.start_ramp_m, "kernel_delta": filt.config.delta,
            "hold": None if hold is None else list(hold), "track_input": track_input,
            "particles": particles, "truth": theta.tolist(), "mean": m.tolist(),
            "std": s.tolist(), "z": np.round((m - theta) / s, 3).tolist(),
            "err_pct": np.round(100 * (m - theta) / theta, 3).tolist(),
            "sigma_pct": np.round(100 * s / m, 3).tolist(),
            "detections": len(found)}
        if ml:
            ml_m, ml_s = ml_fit(Y, sensors, t, speed_mps)
            row["ml_mean"], row["ml_std"] = ml_m, ml_s
            row["ml_z"] = np.round((np.array(ml_m) - theta) / np.array(ml_s), 3).tolist()
            row["sigma_over_ml"] = np.round(s / np.array(ml_s), 3).tolist()
        out.append(row)
    return out


CASE_FIELDS = ("study", "theta_name", "moves_drop_null", "start_ramp_s", "from_rest",
               "sensors", "mode", "hold", "speed_mps", "start_ramp_m", "kernel_delta",
               "track_input")


def case_of(r: dict[str, Any]) -> tuple[Any, ...]:
    """A row's case, :data:`CASE_FIELDS` in order (older rows lack some: their defaults)."""
    return (r["study"], r.get("theta_name", "paper" if r["study"] == "paper" else "box"),
            bool(r.get("moves_drop_null", False)), float(r.get("start_ramp_s", 0.0)),
            bool(r.get("from_rest", False)), r["sensors"], r.get("mode", "fast"),
            str(r.get("hold")), float(r.get("speed_mps", V_MPS)),
            float(r.get("start_ramp_m", 0.0)), float(r.get("kernel_delta", PAPER_DELTA)),
            r.get("track_input", "white"))


def summary(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per case (:func:`case_of`) and t_s: records; per parameter the share with |z| <= 2,
    the largest |z|, the smallest sigma / sigma_ML (and the ML's own |z| <= 2 share)."""
    out = []
    for key in sorted({(case_of(r), r["t_s"]) for r in rows}):
        case = [r for r in rows if (case_of(r), r["t_s"]) == key]
        z = np.abs(np.array([r["z"] for r in case]))
        row: dict[str, Any] = dict(zip(CASE_FIELDS, key[0], strict=True))
        row.update(t_s=key[1], records=len(case))
        for i, name in enumerate(PARAM_NAMES):
            row[f"{name}_within_2sigma"] = round(float(np.mean(z[:, i] <= 2.0)), 3)
            row[f"{name}_max_abs_z"] = round(float(z[:, i].max()), 2)
            if all("sigma_over_ml" in r for r in case):
                ratio = np.array([r["sigma_over_ml"][i] for r in case])
                mlz = np.abs(np.array([r["ml_z"][i] for r in case]))
                row[f"{name}_min_sigma_over_ml"] = round(float(np.nanmin(ratio)), 3)
                row[f"{name}_median_sigma_over_ml"] = round(float(np.nanmedian(ratio)), 3)
                row[f"{name}_ml_within_2sigma"] = round(float(np.mean(mlz <= 2.0)), 3)
        out.append(row)
    return out


def window(rows: Sequence[dict[str, Any]], lo_s: float, hi_s: float
           ) -> list[dict[str, Any]]:
    """Per case (:func:`case_of`): each record's z and error (%) averaged over its check
    times in [lo_s, hi_s]; per parameter the mean of those over the records, its standard
    error, and the records whose average error is below the truth."""
    inside = [r for r in rows if lo_s <= r["t_s"] <= hi_s]
    out = []
    for key in sorted({case_of(r) for r in inside}):
        per_seed: dict[int, list[dict[str, Any]]] = {}
        for r in inside:
            if case_of(r) == key:
                per_seed.setdefault(r["seed"], []).append(r)
        z = np.array([np.mean([r["z"] for r in rs], axis=0) for rs in per_seed.values()])
        err = np.array([np.mean([r["err_pct"] for r in rs], axis=0)
                        for rs in per_seed.values()])
        n = len(z)
        row: dict[str, Any] = dict(zip(CASE_FIELDS, key, strict=True))
        row.update(from_s=lo_s, to_s=hi_s, records=n,
                   checks=int(np.mean([len(rs) for rs in per_seed.values()])))
        se = z.std(axis=0, ddof=1) / np.sqrt(n) if n > 1 else None
        for i, name in enumerate(PARAM_NAMES):
            row[f"{name}_mean_z"] = round(float(z[:, i].mean()), 3)
            row[f"{name}_se_z"] = None if se is None else round(float(se[i]), 3)
            row[f"{name}_mean_err_pct"] = round(float(err[:, i].mean()), 3)
            row[f"{name}_below"] = int((err[:, i] < 0).sum())
        out.append(row)
    return out


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m firmware_sim.studies.calibration",
                                 description=__doc__.split("\n")[0])
    ap.add_argument("what", choices=("paper", "box", "summary", "window"),
                    help="summary, window: read the rows (JSON lines) from stdin")
    ap.add_argument("window_s", type=float, nargs="*", metavar="LO HI",
                    help="window: the check times averaged, from LO to HI s")
    ap.add_argument("--kernel-delta", type=kernel_delta_arg, default=None,
                    help="the service's [estimator] kernel_delta (default: the service's)")
    ap.add_argument("--theta", choices=sorted(PAPER_THETA), default="paper",
                    help="paper: the vehicle (default: the paper's Sec. 4.2 values)")
    ap.add_argument("--seeds", type=int, nargs="+", default=list(range(1, 21)))
    ap.add_argument("--sensors", type=int, nargs="+", default=[3, 5])
    ap.add_argument("--particles", type=int, default=1000)
    ap.add_argument("--mode", choices=("fast", "exact"), default="fast")
    ap.add_argument("--no-ml", action="store_true", help="paper: skip the ML fits")
    ap.add_argument("--moves-drop-null", action=argparse.BooleanOptionalAction,
                    default=None, help="the filter's moves_drop_null option (default: the "
                    "filter's own)")
    ap.add_argument("--start-ramp-s", type=float, default=None,
                    help="the filter's start_ramp_s (default: the service's)")
    ap.add_argument("--start-ramp-m", type=float, default=None,
                    help="the filter's start_ramp_m (default: the service's; 0: the ramp "
                         "in seconds alone)")
    ap.add_argument("--at-s", type=float, nargs="+", default=None,
                    help="check times in s (default: paper 5 20, box 10)")
    ap.add_argument("--from-rest", action="store_true",
                    help="the truth starts at rest (default: in stationary vibration)")
    ap.add_argument("--speed-mps", type=float, default=V_MPS,
                    help="the vehicle's constant speed, m/s (default: the paper's 42.5)")
    ap.add_argument("--hold", type=float, nargs=2, default=None, metavar=("AT_S", "FOR_S"),
                    help="no updates from AT_S for FOR_S seconds, as the gate holds them in "
                         "a curve (default: none)")
    add_track_input(ap)
    args = ap.parse_args(argv)
    if not 0 < args.speed_mps <= 150:
        ap.error(f"expected 0 < --speed-mps <= 150 m/s, got {args.speed_mps}")
    if (args.what == "window") != bool(args.window_s):
        ap.error("expected LO HI only with window, got " + " ".join(map(str, args.window_s)))
    if args.what == "window" and not (len(args.window_s) == 2
                                      and args.window_s[0] <= args.window_s[1]):
        ap.error(f"expected window LO HI with LO <= HI, got {args.window_s}")
    if args.what == "box" and args.theta != "paper":
        ap.error(f"expected --theta only with paper (box draws its own), got {args.theta}")
    if args.what in ("summary", "window"):
        rows = [json.loads(line) for line in sys.stdin if line.strip()]
        found = summary(rows) if args.what == "summary" else window(rows, *args.window_s)
        for row in found:
            print(json.dumps(row))
        return 0
    for seed in args.seeds:
        for ns in args.sensors:
            for row in rows_for(args.what, seed, ns, args.particles, args.mode,
                                ml=args.what == "paper" and not args.no_ml,
                                at_s=args.at_s, moves_drop_null=args.moves_drop_null,
                                from_rest=args.from_rest, start_ramp_s=args.start_ramp_s,
                                hold=None if args.hold is None else tuple(args.hold),
                                speed_mps=args.speed_mps,
                                start_ramp_m=args.start_ramp_m, theta_name=args.theta,
                                kernel_delta=args.kernel_delta,
                                track_input=args.track_input):
                emit(row)
    return 0


if __name__ == "__main__":
    sys.exit(main())
