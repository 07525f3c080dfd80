"""``gateway estimate``: run the RBPF on an interchange CSV and write a JSON report."""

from __future__ import annotations

import argparse
import logging
import time

from gateway.cli import SEED, SPEED_MPS, config_value, integer, output_path, real, writing
from gateway.errors import InputError

log = logging.getLogger(__name__)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("estimate", help="estimate Csy, Csay, conicity from a recorded CSV")
    p.add_argument("csv", metavar="FILE.csv", help="interchange-format recording")
    p.add_argument("--report", required=True, type=output_path, metavar="OUT.json",
                   help="JSON report path")
    p.add_argument("--particles", type=config_value("estimator", "particles"), default=1000,
                   help="particles (1000)")
    p.add_argument("--seed", type=SEED, default=0, help="random seed (0)")
    p.add_argument("--sensors", type=int, choices=(3, 5), default=3,
                   help="3 (bogie + body) or 5 (also wheelsets)")
    p.add_argument("--track-roughness", type=config_value("estimator", "track_roughness"),
                   default=None, metavar="AR",
                   help="track roughness Ar as printed in the paper (default 2 x 0.33e-3)")
    p.add_argument("--estimate-ar", action="store_true",
                   help="estimate Ar jointly as a 4th parameter")
    p.add_argument("--drift", type=config_value("estimator", "drift_per_sqrt_s"), default=0.0,
                   metavar="REL",
                   help="random-walk drift of the parameters, relative per sqrt(s) (0: the "
                        "paper's static parameters; the service uses 0.01)")
    p.add_argument("--speed", type=SPEED_MPS, default=42.5,
                   help="speed in m/s when the CSV has no speed_mps column (42.5)")
    p.add_argument("--history-every-s", type=real(0.0, 3600.0, lo_open=True), default=0.01,
                   help="history interval in s (0.01)")
    p.add_argument("--mode", choices=("fast", "exact"), default="fast",
                   help="fast: steady-state gains (default); exact: the exact recursion")
    p.add_argument("--sensor-noise", choices=("measured", "model"), default="measured",
                   help="measured: test the paper's sensor noise against the first 5 s and "
                        "use the measured variances where the data reject it (default); "
                        "model: the paper's")
    p.add_argument("--threads", type=integer(1, 1024), default=None,
                   help="numba threads (default: all available cores)")
    p.add_argument("--plot", type=output_path, metavar="OUT.png",
                   help="draw Fig. 2-style panels")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from gateway.estimator.noisestart import NoiseCheckedStart
    from gateway.estimator.rbpf import RBPF, RBPFConfig
    from gateway.estimator.threads import configure, kernel_threads
    from gateway.model.vehicle import AR_PAPER_DEFAULT, sensor_set
    from gateway.offline import report
    from gateway.offline.grid import history_rows, to_grid
    from gateway.offline.interchange import read_csv

    configure(kernel_threads(args.particles, args.threads))
    sensors = sensor_set(args.sensors)
    rec = read_csv(args.csv)
    grid = to_grid(rec, sensors, args.speed)
    ar = args.track_roughness if args.track_roughness is not None else AR_PAPER_DEFAULT
    cfg = RBPFConfig(fs_hz=grid.fs_hz, n_particles=args.particles, sensors=args.sensors,
                     ar_paper=ar, estimate_ar=args.estimate_ar, seed=args.seed,
                     walk_rel_per_sqrt_s=(args.drift,) * 3, mode=args.mode)
    every = max(1, int(round(args.history_every_s * grid.fs_hz)))
    filt = NoiseCheckedStart(cfg) if args.sensor_noise == "measured" else RBPF(cfg)
    start = time.perf_counter()
    estimates = filt.run(grid.samples(), output_every=every)
    wall_s = time.perf_counter() - start
    if not estimates:
        raise InputError(f"{args.csv}: expected samples to estimate from, got none")
    history = history_rows(estimates)
    duration_s = float(grid.t_s[-1] - grid.t_s[0]) + 1.0 / grid.fs_hz
    settings = {"file": str(args.csv), "particles": args.particles, "mode": args.mode,
                "seed": args.seed,
                "sensors": list(sensors), "track_roughness_ar_paper": ar,
                "estimate_ar": bool(args.estimate_ar), "drift_per_sqrt_s": args.drift,
                "grid_rate_hz": grid.fs_hz, "sensor_noise": args.sensor_noise,
                "speed_source": "csv" if "speed" in rec.signals else "option",
                "speed_mps_option": args.speed, "delta": cfg.delta,
                "ess_threshold": cfg.ess_threshold, "history_every_s": every / grid.fs_hz}
    diagnostics = {"samples": int(len(grid.t_s)),
                   "missing_sensor_values": {name: int(np.isnan(grid.values[:, k]).sum())
                                             for k, name in enumerate(sensors)},
                   "predict_only_samples": int((~grid.update).sum()),
                   "resamples": filt.n_resamples, "detections": filt.n_detections,
                   "fault_detections": filt.n_fault_detections,
                   "last_fault": filt.last_fault(),
                   "reseeds": filt.n_reseeds, "wall_s": wall_s,
                   "noise_check": (None if (check := filt.noise_check()) is None
                                   else check.as_dict()),
                   "real_time_factor": duration_s / wall_s if wall_s > 0 else None}
    with writing(args.report):
        report.write_json(args.report, report.build(estimates[-1], history, settings,
                                                    diagnostics))
    if args.plot:
        with writing(args.plot):
            report.plot(args.plot, history, cfg.names)
    if (check := filt.noise_check()) is not None:
        print(check.summary())
    final = estimates[-1]
    for name, m, s in zip(final.names, final.mean, final.std, strict=True):
        print(f"{name:>14}: {m:.6g} +- {s:.3g}")
    print(f"{len(grid.t_s)} samples at {grid.fs_hz:.6g} Hz, real-time factor "
          f"{diagnostics['real_time_factor']:.2f}; report {args.report}")
    return 0
