"""``gateway identify``: calibrate the vehicle model from a recorded run (Kraft et al.).

``identify run DATA --track TRACK.csv`` (DATA an interchange CSV or a CAN log) fits by
time-domain least squares; without ``--track`` it fits Csy, Csay and lambda by Kalman
prediction-error maximum likelihood. ``identify synth`` writes a synthetic run (track,
data, truth) to try it on.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

from gateway.cli import SEED, SPEED_MPS, config_value, integer, output_dir, real, writing
from gateway.config import load_config
from gateway.errors import InputError
from gateway.identify.misfit import MisfitConfig, Section, sections_from_positions
from gateway.identify.optimise import METHODS, Budget
from gateway.identify.params import ALL_NAMES, ParamPoint, resolve_names
from gateway.identify.pipeline import (
    PredictionErrorIdentifier,
    TrackConfig,
    TrackIdentifier,
)
from gateway.identify.report import (
    prediction_error_report,
    table1,
    write_json,
    write_track_report,
)
from gateway.identify.sources import load_dataset
from gateway.identify.synthetic import TRACK_KINDS, SyntheticSpec, demo_track, record
from gateway.identify.track import read_track_csv, sine_track, write_track_csv
from gateway.model.vehicle import AR_PAPER_DEFAULT, PARAM_NAMES
from gateway.offline.interchange import write_csv


def _range(text: str) -> tuple[float, float]:
    try:
        a, b = (float(v) for v in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected START:STOP, got {text!r}") from None
    if not (math.isfinite(a) and math.isfinite(b) and abs(a) <= 1e9 and abs(b) <= 1e9
            and a < b):
        raise argparse.ArgumentTypeError(f"expected finite START < STOP within +-1e9, "
                                         f"got {text!r}")
    return a, b


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("identify", help="offline identification of model parameters")
    isub = parser.add_subparsers(dest="identify_command", metavar="WHAT", required=True)
    p = isub.add_parser("run", help="identify parameters from a recorded run")
    p.add_argument("data", help="recorded run: interchange CSV (.csv) or CAN log "
                   "(.log, .asc, .blf, .trc, .mf4)")
    p.add_argument("--config", metavar="FILE", help="gateway TOML whose [resampler] and "
                   "[gating] settings read a CAN log (default: built-in)")
    p.add_argument("--track", help="track CSV (position_m, lateral_alignment_m); "
                   "without it the prediction-error (maximum likelihood) path is used")
    p.add_argument("--out", type=output_dir, default="identify-report",
                   help="output directory")
    p.add_argument("--speed-mps", type=SPEED_MPS,
                   help="speed if the data has no speed_mps column")
    p.add_argument("--sensors", help="comma-separated sensors (default: all in the file)")
    p.add_argument("--section", type=_range, action="append", default=[],
                   metavar="T0:T1", help="learn section in seconds (repeatable)")
    p.add_argument("--section-m", type=_range, action="append", default=[],
                   metavar="X0:X1", help="learn section as track positions in m (repeatable)")
    p.add_argument("--track-offset-m", type=real(-1e7, 1e7), default=0.0,
                   help="track position of the leading wheelset at the first sample [m]")
    p.add_argument("--free-offset-m", type=real(0.0, 1e5, lo_open=True), metavar="HALF_WIDTH",
                   help="identify the track offset too, within --track-offset-m +- HALF_WIDTH "
                   "[m], instead of synchronising by cross-correlation")
    p.add_argument("--params", help="parameters to identify, e.g. Kx,f11,lambda "
                   "(default: Morris top-k on the track path; Csy,Csay,lambda otherwise)")
    p.add_argument("--top-k", type=integer(1, len(ALL_NAMES)), default=5,
                   help="parameters Morris selects")
    p.add_argument("--tolerance", type=real(0.0, 0.95, lo_open=True),
                   help="relative half-width of the box "
                   "(default 0.3 with a track, 0.75 without)")
    p.add_argument("--methods", default="de,da,nm,ps",
                   help=f"optimisers, from {','.join(METHODS)}")
    p.add_argument("--morris-trajectories", type=integer(2, 1000), default=8)
    p.add_argument("--max-lag-s", type=real(0.0, 60.0), default=1.0,
                   help="synchronisation search range; 0 disables it")
    p.add_argument("--sim-rate-hz", type=real(10.0, 10_000.0), default=200.0)
    p.add_argument("--band-hz", type=_range, default=(0.4, 20.0), metavar="LO:HI")
    p.add_argument("--ar-paper", type=config_value("estimator", "track_roughness"),
                   default=AR_PAPER_DEFAULT,
                   help="track roughness Ar, paper units (prediction-error path)")
    p.add_argument("--de-maxiter", type=integer(1, 100_000), default=Budget.de_maxiter)
    p.add_argument("--da-maxfun", type=integer(1, 10_000_000), default=Budget.da_maxfun)
    p.add_argument("--local-maxfev", type=integer(1, 10_000_000), default=Budget.local_maxfev)
    p.add_argument("--workers", type=integer(1, 256),
                   help="processes (default: all available cores)")
    p.add_argument("--seed", type=SEED, default=0)
    p.add_argument("--truth", help="truth JSON from 'identify synth', to report errors")
    p.set_defaults(func=run_identify)
    s = isub.add_parser("synth", help="write a synthetic run: track.csv, data.csv, truth.json")
    s.add_argument("--out", type=output_dir, required=True, help="output directory")
    s.add_argument("--perturb", default="", help="e.g. Kx=+25,f11=-25 (percent)")
    s.add_argument("--duration-s", type=real(0.0, 3600.0, lo_open=True), default=40.0)
    s.add_argument("--fs-hz", type=real(10.0, 10_000.0), default=200.0)
    s.add_argument("--speed-mps", type=SPEED_MPS, default=42.5)
    s.add_argument("--track-kind", choices=(*TRACK_KINDS, "sines"), default="random",
                   help="random (IRIS band), jointed (25 m rails, cusp at each joint) or sines")
    s.add_argument("--track-rms-m", type=real(0.0, 0.1, lo_open=True), default=3e-3,
                   help="random: RMS; jointed: joint cusp (random part a third of it) [m]")
    s.add_argument("--offset-m", type=real(0.0, 1e6), default=500.0)
    s.add_argument("--shift-samples", type=integer(-100_000, 100_000), default=0)
    s.add_argument("--seed", type=SEED, default=0)
    s.set_defaults(func=run_synth)


def _perturbation(text: str) -> dict[str, float]:
    out: dict[str, float] = {}
    for item in filter(None, (t.strip() for t in text.split(","))):
        name, _, pct = item.partition("=")
        try:
            value = float(pct)
            out[resolve_names([name.strip()])[0]] = 1.0 + value / 100.0
        except ValueError:
            raise InputError(f"expected NAME=PERCENT in --perturb, got {item!r}") from None
        if not -90.0 <= value <= 900.0:
            raise InputError(f"expected a PERCENT in [-90, 900] in --perturb, got {item!r}")
    return out


def run_synth(args: argparse.Namespace) -> int:
    out = Path(args.out)
    with writing(out):
        out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(args.seed)
    length = args.offset_m + args.speed_mps * (args.duration_s + 5) + 100
    if args.track_kind in TRACK_KINDS:
        track = demo_track(args.track_kind, length, args.track_rms_m, rng)
    else:
        track = sine_track(length, 0.05, (40.0, 25.0, 12.5, 6.0),
                           tuple(args.track_rms_m * f for f in (1.0, 0.8, 0.5, 0.3)),
                           (0.0, 1.0, 2.0, 3.0))
    truth = ParamPoint.nominal().scaled(_perturbation(args.perturb))
    spec = SyntheticSpec(duration_s=args.duration_s, fs_hz=args.fs_hz,
                         speed_mps=args.speed_mps, offset_m=args.offset_m,
                         shift_samples=args.shift_samples)
    ds = record(truth, track, spec, rng)
    signals = {s: ds.measured[:, i] for i, s in enumerate(ds.sensors)}
    signals["speed"] = ds.speed_mps
    with writing(out):
        write_track_csv(out / "track.csv", track)
        write_csv(out / "data.csv", ds.t_s, signals)
        (out / "truth.json").write_text(json.dumps(
            {**truth.as_dict(), TRUTH_OFFSET_KEY: args.offset_m}, indent=2) + "\n")
    print(f"wrote {out / 'track.csv'}, {out / 'data.csv'}, {out / 'truth.json'} "
          f"(track offset {args.offset_m:g} m)")
    return 0


TRUTH_OFFSET_KEY = "track_offset_m"
"""The true track offset [m] in truth.json, next to the parameters (optional)."""


def _truth(path: str | None) -> tuple[ParamPoint | None, float | None]:
    """The true parameters and, when recorded, the true track offset [m]."""
    if path is None:
        return None, None
    try:
        values = json.loads(Path(path).read_text())
        offset_m = values.pop(TRUTH_OFFSET_KEY, None)
        return ParamPoint.from_dict(values), None if offset_m is None else float(offset_m)
    except (OSError, ValueError, TypeError, AttributeError) as err:
        raise InputError(f"expected a truth JSON of all {len(ALL_NAMES)} parameters, got "
                         f"{path}: {err}") from err


def run_identify(args: argparse.Namespace) -> int:
    sensors = tuple(s.strip() for s in args.sensors.split(",")) if args.sensors else None
    gateway_cfg = load_config(args.config) if args.config else None
    ds = load_dataset(args.data, sensors, args.speed_mps, gateway_cfg)
    params = resolve_names(args.params.split(",")) if args.params else None
    truth, truth_offset_m = _truth(args.truth)
    sections = [Section(a, b) for a, b in args.section]
    out = Path(args.out)
    if args.track is None:
        if args.section_m:
            raise InputError("expected --section (seconds) without a track, got --section-m")
        if args.free_offset_m is not None:
            raise InputError("expected --track with --free-offset-m, got no track")
        ident = PredictionErrorIdentifier(sections or None, params or PARAM_NAMES,
                                          args.tolerance or 0.75, args.ar_paper)
        ml = ident.fit(ds)
        doc = prediction_error_report(ml, truth)
        with writing(out):
            out.mkdir(parents=True, exist_ok=True)
            write_json(out / "report.json", doc)
        for n, v in doc["estimates"].items():
            print(f"{n:>16} {v['value']:14.6g} +- {v['std']:.3g}")
        print(f"wrote {out / 'report.json'}")
        return 0
    track = read_track_csv(args.track)
    sections += sections_from_positions(ds, list(args.section_m), args.track_offset_m)
    if not sections:
        margin = min(2.0, 0.1 * ds.duration_s)
        sections = [Section(float(ds.t_s[0]) + margin, float(ds.t_s[-1]) - margin)]
    methods = tuple(m.strip() for m in args.methods.split(",") if m.strip())
    unknown = [m for m in methods if m not in METHODS]
    if unknown or not methods:
        raise InputError(f"expected --methods from {list(METHODS)}, got {args.methods!r}")
    config = TrackConfig(
        misfit=MisfitConfig(band_low_hz=args.band_hz[0], band_high_hz=args.band_hz[1],
                            sim_rate_hz=args.sim_rate_hz),
        offset_m=args.track_offset_m, tolerance=args.tolerance or 0.3, params=params,
        top_k=args.top_k, morris_trajectories=args.morris_trajectories, methods=methods,
        budget=Budget(de_maxiter=args.de_maxiter, da_maxfun=args.da_maxfun,
                      local_maxfev=args.local_maxfev, seed=args.seed),
        max_lag_s=args.max_lag_s, workers=args.workers, free_offset_m=args.free_offset_m)
    res = TrackIdentifier(track, sections, config).fit(ds)
    with writing(out):
        files = write_track_report(res, out, truth, truth_offset_m)
    print(f"identified {', '.join(res.space.names)}; nominal J {res.j_nominal:.4g}")
    if res.space.offset is not None:
        print(f"track offset {res.offset_m():.3f} m (given {res.space.offset.base_m:g} "
              f"+- {res.space.offset.half_width_m:g} m, best method {res.best.method})")
    print(f"{'method':<40} {'reduction %':>12} {'final %':>9} {'evals':>7}")
    for row in table1(res):
        print(f"{row['method']:<40} {row['reduction_pct']:12.2f} {row['final_pct']:9.3f} "
              f"{row['evaluations']:7d}")
    print(f"{res.evals_per_s_one_core:.0f} misfit evaluations/s on one core; "
          f"wall time {res.wall_s:.1f} s", file=sys.stderr)
    print("wrote " + ", ".join(str(f) for f in files))
    return 0
