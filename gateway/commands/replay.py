"""``gateway replay``: the service pipeline over a CAN log, deterministic outputs."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from gateway.cli import output_path, real, writing
from gateway.commands.run import add_overrides, config_from_args
from gateway.errors import InputError
from gateway.offline.replay import alert_json, replay


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("replay", help="run the pipeline over a CAN log (.log, .asc, .blf)")
    p.add_argument("log", help="CAN log recorded from the vehicle bus or the simulator")
    p.add_argument("--report", required=True, type=output_path, metavar="OUT.json",
                   help="report JSON")
    p.add_argument("--jsonl", type=output_path, metavar="OUT.jsonl",
                   help="estimates and alerts as JSON Lines (default: next to the report)")
    p.add_argument("--plot", type=output_path, metavar="OUT.png",
                   help="Fig. 2-style plot of the estimates")
    p.add_argument("--speed", type=real(0.0, 1000.0), default=0.0,
                   help="pace at N x real time (default 0: as fast as possible)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_overrides(p, live=False)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    cfg = config_from_args(args)
    report_path = Path(args.report)
    jsonl_path = Path(args.jsonl) if args.jsonl else report_path.with_suffix(".jsonl")
    bars: list[Any] = []

    def progress(frames: int, t_s: float) -> None:
        if args.no_progress:
            return
        if not bars:                          # created on first progress, not before errors
            from tqdm import tqdm

            bars.append(tqdm(unit=" frames", file=sys.stderr, mininterval=0.5, leave=False))
        bars[0].n = frames
        bars[0].set_postfix_str(f"data {t_s:.1f} s", refresh=False)
        bars[0].refresh()

    if jsonl_path.is_dir():
        raise InputError(f"{jsonl_path}: expected a writable file, got a directory")
    with writing(jsonl_path):
        jsonl = open(jsonl_path, "w", encoding="utf-8")  # noqa: SIM115 - closed below
    with jsonl:
        result = replay(args.log, cfg, speed=args.speed, jsonl=jsonl, progress=progress)
    for bar in bars:
        bar.close()
    if not result.estimates:
        raise InputError(f"expected sensor traffic the gateway could estimate from in "
                         f"{args.log}, got {result.frames} frames and no estimate")
    from gateway.offline import report
    from gateway.offline.grid import history_rows
    from gateway.runtime.pipeline import estimator_config

    history = history_rows(result.estimates)
    settings = {"particles": cfg.estimator.particles, "mode": cfg.estimator.mode,
                "sensors": cfg.estimator.sensors,
                "seed": cfg.estimator.seed, "track_roughness": cfg.estimator.track_roughness,
                "estimate_track_roughness": cfg.estimator.estimate_track_roughness,
                "drift_per_sqrt_s": cfg.estimator.drift_per_sqrt_s,
                "start_ramp_s": cfg.estimator.start_ramp_s,
                "start_ramp_m": cfg.estimator.start_ramp_m,
                # the discount that ran (auto resolved), from the one mapping
                "kernel_delta": estimator_config(cfg.estimator, cfg.resampler.fs_hz).delta,
                "sensor_noise": cfg.estimator.sensor_noise,
                "fs_hz": cfg.resampler.fs_hz, "source": str(args.log)}
    diagnostics = {"frames": result.frames, "rejected": result.rejected,
                   "grid_points": result.grid_points}
    if result.front_end is not None:           # late/gap samples by reason (issue 12)
        diagnostics["front_end"] = result.front_end.as_dict()
    diagnostics["sensor_noise"] = (None if result.noise_check is None
                                   else result.noise_check.as_dict())
    doc = report.build(result.estimates[-1], history, settings, diagnostics)
    doc["alerts"] = [alert_json(a) for a in result.alerts]
    with writing(report_path):
        report.write_json(report_path, doc)
    if args.plot:
        with writing(args.plot):
            report.plot(args.plot, history, result.estimates[-1].names)
    if result.noise_check is not None:
        print(result.noise_check.summary())
    print(f"replayed {result.frames} frames ({result.grid_points} grid points): "
          f"{len(result.estimates)} estimates, {len(result.alerts)} alert events -> {report_path}, "
          f"{jsonl_path}")
    return 0
