"""``gateway bench``: measured real-time factors, in one run, on this machine.

Benchmarks are a registry (:data:`BENCHES`, name -> function returning a JSON-able dict
or list) so that pipeline benchmarks can be added next to the estimator one; ``--what``
picks them (default: :data:`DEFAULT_BENCHES`).

``estimator``: the RBPF (m particles, 3 sensors, 1 kHz, paper Sec. 4.2 data), exact mode
then fast mode over the same data with the same seed, each over a whole run (including the
convergence phase with frequent resampling) and over its steady state, against the naive
baseline (:mod:`firmware_sim.studies.naive`) measured on a short slice; then fast mode
again on the same data with lost frames (``--frame-loss``, each sensor value lost
independently: a lossy bus, where every lost frame hands fast mode to the exact
recursion for a while); then, on the clean data again, fast mode as the service builds
it from its default configuration (``service_*`` keys: its kernel discount, floor, prior
box and start ramp; the others are the paper's bare filter). Real-time factor =
simulated seconds / wall seconds.

``sweep``: the cost curve (:mod:`firmware_sim.studies.sweep`): the same three at each m
of ``--sweep-particles``, a list of records, and with ``--plot`` a PNG (RTF against m,
log-log). Exact mode costs ~m/1000 s of wall time per simulated second, so the sweep is
not in the default set.
"""

from __future__ import annotations

import argparse
import json
import os
from collections.abc import Callable
from dataclasses import asdict
from typing import Any

from gateway.cli import SEED, config_value, integer, output_path, real

SWEEP_PARTICLES = (250, 500, 1000, 2000, 4000, 8000)
"""Issue 14's particle counts for the cost curve."""
FLOP_PER_PARTICLE_STEP = 2 * (16**3 + 136 * 16 + 16**2 + 3 * (16**2 + 2 * 16 + 136 + 16))
"""Multiply-adds x 2 of one exact 16-state predict + 3-sensor update, upper-triangle
products counted as such (about 17 kflop)."""
PEAK_GFLOPS_PER_CORE = 62.5
"""Two 8-wide AVX-512 FMA units at about 2 GHz: the issue's ~125 GFLOP/s for 2 cores."""


def particle_counts(text: str) -> tuple[int, ...]:
    """An argparse type: comma-separated particle counts, each in [estimator] particles'
    domain; returned sorted, without repeats."""
    parse = config_value("estimator", "particles")
    words = [w.strip() for w in text.split(",")]
    if not all(words):
        raise argparse.ArgumentTypeError(f"expected comma-separated particle counts such as "
                                         f"250,500,1000, got {text!r}")
    return tuple(sorted({parse(w) for w in words}))


def _cores() -> dict[str, int]:
    try:
        affinity = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not on Linux
        affinity = os.cpu_count() or 1
    return {"cpu_count": os.cpu_count() or 1, "available_cores": affinity}


def bench_estimator(args: argparse.Namespace) -> dict[str, Any]:
    from firmware_sim.studies.sweep import (
        FS_HZ,
        SENSORS,
        bench_data,
        filter_config,
        lose_sensor_values,
        naive_rtf,
        service_filter_config,
        time_filter,
    )
    from gateway.estimator.threads import threading_layer

    m = args.particles
    data = bench_data(args.seconds, args.seed)
    exact = time_filter(data, filter_config("exact", m, args.seed, args.ar_paper),
                        args.steady_after_s)
    fast_cfg = filter_config("fast", m, args.seed, args.ar_paper, args.fast_warmup_s)
    fast = time_filter(data, fast_cfg, args.steady_after_s)
    naive = naive_rtf(data, m, args.naive_steps, args.ar_paper)
    lossy = time_filter(lose_sensor_values(data, args.frame_loss, args.seed), fast_cfg,
                        args.steady_after_s)
    service_cfg = service_filter_config(m, args.seed, args.ar_paper, args.fast_warmup_s)
    service = time_filter(data, service_cfg, args.steady_after_s)
    return {"particles": m, "sensors": SENSORS, "rate_hz": FS_HZ, "seconds": args.seconds,
            "threads": exact.threads, "numba_threads": exact.threads, **_cores(),
            "threading_layer": threading_layer(),
            "exact_rtf_whole_run": exact.rtf_whole_run, "exact_rtf_steady": exact.rtf_steady,
            "steady_after_s": args.steady_after_s,
            "resamples_convergence": exact.resamples_convergence,
            "resamples_steady": exact.resamples_steady,
            "fast_rtf_whole_run": fast.rtf_whole_run, "fast_rtf_steady": fast.rtf_steady,
            "fast_warmup_s": fast_cfg.fast_warmup_s,
            "fast_resamples_convergence": fast.resamples_convergence,
            "fast_resamples_steady": fast.resamples_steady,
            "frame_loss": args.frame_loss,
            "fast_rtf_whole_run_lossy": lossy.rtf_whole_run,
            "fast_rtf_steady_lossy": lossy.rtf_steady,
            "service_fast_rtf_whole_run": service.rtf_whole_run,
            "service_fast_rtf_steady": service.rtf_steady,
            "service_fast_resamples_convergence": service.resamples_convergence,
            "service_fast_resamples_steady": service.resamples_steady,
            "service_filter": {"kernel_delta": service_cfg.delta,
                               "start_ramp_s": service_cfg.start_ramp_s,
                               "start_ramp_m": service_cfg.start_ramp_m,
                               "prior_lo": list(service_cfg.prior_lo)},
            "naive_rtf": naive, "naive_steps_measured": args.naive_steps,
            "ratio_whole_run": exact.rtf_whole_run / naive,
            "ratio_steady": exact.rtf_steady / naive,
            "ratio_fast_naive_whole_run": fast.rtf_whole_run / naive,
            "ratio_fast_naive_steady": fast.rtf_steady / naive,
            "ratio_service_fast_naive_whole_run": service.rtf_whole_run / naive,
            "steady_gflops": FLOP_PER_PARTICLE_STEP * m * FS_HZ * exact.rtf_steady / 1e9,
            "ceiling_rtf": PEAK_GFLOPS_PER_CORE * exact.threads * 1e9
            / (FLOP_PER_PARTICLE_STEP * m * FS_HZ)}


def bench_sweep(args: argparse.Namespace) -> list[dict[str, Any]]:
    """The cost curve (:mod:`firmware_sim.studies.sweep`); threads set per particle count."""
    from firmware_sim.studies.sweep import bench_data, plot_sweep, sweep_point
    from gateway.estimator.threads import configure, kernel_threads

    data = bench_data(args.seconds, args.seed)
    records = []
    for m in args.sweep_particles:
        configure(kernel_threads(m, args.threads))
        records.append(sweep_point(data, m, seed=args.seed,
                                   steady_after_s=args.steady_after_s,
                                   naive_steps_n=args.naive_steps, ar_paper=args.ar_paper,
                                   exact=m <= args.sweep_exact_max,
                                   fast_warmup_s=args.fast_warmup_s))
    configure(kernel_threads(args.particles, args.threads))
    if args.plot:
        from gateway.cli import writing

        with writing(args.plot):
            plot_sweep(records, args.plot)
    return [asdict(r) for r in records]


def _pipeline(args: argparse.Namespace) -> dict[str, Any]:
    from firmware_sim.studies.bench_pipeline import bench_pipeline

    return {**bench_pipeline(args), **_cores()}


def _latency(args: argparse.Namespace) -> dict[str, Any]:
    from firmware_sim.studies.bench_pipeline import bench_latency

    return {**bench_latency(args), **_cores()}


BENCHES: dict[str, Callable[[argparse.Namespace], dict[str, Any] | list[dict[str, Any]]]] = {
    "estimator": bench_estimator,
    "pipeline": _pipeline,
    "latency": _latency,
    "sweep": bench_sweep,
}
DEFAULT_BENCHES = ("estimator", "latency", "pipeline")
"""What runs without ``--what``: everything but the (slow) sweep."""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench", help="measure real-time factors on this machine")
    p.add_argument("--what", choices=sorted(BENCHES), action="append",
                   help="benchmark(s) to run, repeatable (default: "
                   f"{', '.join(DEFAULT_BENCHES)})")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--particles", type=config_value("estimator", "particles"), default=1000,
                   help="particles (1000)")
    p.add_argument("--seconds", type=real(0.0, 3600.0, lo_open=True), default=5.0,
                   help="simulated seconds (5)")
    p.add_argument("--steady-after-s", type=real(0.0, 3600.0), default=2.0,
                   help="start of the steady-state window in s (2)")
    p.add_argument("--naive-steps", type=integer(1, 100_000), default=20,
                   help="naive baseline steps (20)")
    p.add_argument("--threads", type=integer(1, 1024), default=None,
                   help="numba threads (all cores)")
    p.add_argument("--fast-warmup-s", type=float, default=None,
                   help="fast mode's exact warm-up in s (the estimator's default; the "
                        "estimator's configuration checks it before any run)")
    p.add_argument("--frame-loss", type=real(0.0, 1.0), default=1e-3,
                   help="estimator: share of sensor values lost in the lossy fast run "
                        "(0.001)")
    p.add_argument("--bus-loss", type=real(0.0, 1.0), default=0.0,
                   help="latency: share of CAN frames the sender drops (0)")
    p.add_argument("--silent-node", action="append", default=[], metavar="MESSAGE",
                   help="latency: a sensor node's message that is never sent (a dead node, "
                        "or one the vehicle lacks), repeatable: WSN_Lat, BGN_Lat, BDN_Lat")
    p.add_argument("--sweep-particles", type=particle_counts,
                   default=SWEEP_PARTICLES, metavar="M,M,...",
                   help="sweep: particle counts (" + ",".join(map(str, SWEEP_PARTICLES)) + ")")
    p.add_argument("--sweep-exact-max", type=integer(0, 1_000_000), default=8000,
                   metavar="M", help="sweep: exact mode only up to this m (8000)")
    p.add_argument("--plot", type=output_path, metavar="OUT.png", default=None,
                   help="sweep: write the cost curve as a PNG")
    p.add_argument("--seed", type=SEED, default=0, help="data and filter seed (0)")
    p.add_argument("--ar-paper", type=config_value("estimator", "track_roughness"),
                   default=2 * 0.33e-3, help=argparse.SUPPRESS)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:

    from gateway.errors import InputError
    from gateway.estimator.threads import configure, kernel_threads

    if args.particles < 2 or args.seconds <= 0 or args.naive_steps < 1:
        raise InputError(f"expected particles >= 2, seconds > 0, naive steps >= 1, got "
                         f"{args.particles}, {args.seconds}, {args.naive_steps}")
    what = tuple(dict.fromkeys(args.what or DEFAULT_BENCHES))
    if args.silent_node:
        from gateway.frontend.resample import LATERAL_MESSAGES

        if not set(args.silent_node) <= set(LATERAL_MESSAGES):
            raise InputError(f"expected --silent-node from {list(LATERAL_MESSAGES)}, got "
                             f"{args.silent_node}")
    if args.plot and "sweep" not in what:
        raise InputError(f"expected --what sweep with --plot, got --what {','.join(what)}")
    if args.fast_warmup_s is not None:        # its one check, before any run
        from gateway.estimator.rbpf_config import RBPFConfig

        RBPFConfig(fs_hz=1000.0, fast_warmup_s=args.fast_warmup_s)
    configure(kernel_threads(args.particles, args.threads))
    results = {name: BENCHES[name](args) for name in what}
    if args.json:
        print(json.dumps(results, indent=1))
        return 0
    for name, r in results.items():
        print(f"[{name}]")
        if isinstance(r, list):
            _table(r)
            continue
        for key, value in r.items():
            print(f"  {key:>24}: {value:.4g}" if isinstance(value, float)
                  else f"  {key:>24}: {value}")
    if args.plot:
        print(f"wrote {args.plot}")
    return 0


def _table(rows: list[dict[str, Any]]) -> None:
    """Records as aligned columns (None as "-")."""
    if not rows:
        return
    keys = list(rows[0])
    cells = [[f"{r[k]:.4g}" if isinstance(r[k], float) else "-" if r[k] is None
              else str(r[k]) for k in keys] for r in rows]
    widths = [max(len(k), *(len(c[i]) for c in cells)) for i, k in enumerate(keys)]
    print("  " + "  ".join(k.rjust(w) for k, w in zip(keys, widths, strict=True)))
    for c in cells:
        print("  " + "  ".join(v.rjust(w) for v, w in zip(c, widths, strict=True)))
