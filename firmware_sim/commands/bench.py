"""``gateway bench``: measured real-time factors, in one run, on this machine.

Benchmarks are a registry (:data:`BENCHES`, name -> function returning a dict) so that
pipeline benchmarks can be added next to the estimator one; ``--what`` picks them.

``estimator``: the exact RBPF (m particles, 3 sensors, 1 kHz, paper Sec. 4.2 data) over
a whole run (including the convergence phase with frequent resampling) and over its
steady state, against the naive baseline (:mod:`firmware_sim.studies.naive`) measured on a short
slice. Real-time factor = simulated seconds / wall seconds.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from collections.abc import Callable
from typing import Any

from gateway.cli import SEED, config_value, integer, real

FLOP_PER_PARTICLE_STEP = 2 * (16**3 + 136 * 16 + 16**2 + 3 * (16**2 + 2 * 16 + 136 + 16))
"""Multiply-adds x 2 of one exact 16-state predict + 3-sensor update, upper-triangle
products counted as such (about 17 kflop)."""
PEAK_GFLOPS_PER_CORE = 62.5
"""Two 8-wide AVX-512 FMA units at about 2 GHz: the issue's ~125 GFLOP/s for 2 cores."""


def _cores() -> dict[str, int]:
    try:
        affinity = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not on Linux
        affinity = os.cpu_count() or 1
    return {"cpu_count": os.cpu_count() or 1, "available_cores": affinity}


def bench_estimator(args: argparse.Namespace) -> dict[str, Any]:
    import numba
    import numpy as np

    from firmware_sim.studies.naive import naive_steps
    from firmware_sim.truth import add_sensor_noise, select, simulate
    from gateway.estimator.rbpf import RBPF, RBPFConfig
    from gateway.model.vehicle import (
        THETA_SEC42,
        VehicleParams,
        discretize,
        input_matrix,
        measurement_noise,
        output_matrix,
        sensor_set,
        system_matrix,
        track_intensity,
    )
    from gateway.records import Sample

    fs, m, v = 1000.0, args.particles, 42.5
    n = int(round(args.seconds * fs))
    rng = np.random.default_rng(args.seed)
    truth = simulate(np.repeat(THETA_SEC42.as_array()[None], n, 0), np.full(n, v), fs, rng)
    sensors = sensor_set(3)
    Y = add_sensor_noise(select(truth.outputs, sensors), sensors, rng)
    samples = [Sample(t_s=k / fs, values=Y[k], speed_mps=v) for k in range(n)]
    filt = RBPF(RBPFConfig(fs_hz=fs, n_particles=m, sensors=3, seed=args.seed))
    filt.step(samples[0])                       # JIT / cache load outside the timing
    split = min(n - 1, int(round(args.steady_after_s * fs)))
    t0 = time.perf_counter()
    filt.run(samples[1:split], output_every=10)
    t1 = time.perf_counter()
    resamples_before = filt.n_resamples
    filt.run(samples[split:], output_every=10)
    t2 = time.perf_counter()
    whole_rtf = (n - 1) / fs / (t2 - t0)
    steady_rtf = (n - split) / fs / (t2 - t1)
    gflops = FLOP_PER_PARTICLE_STEP * m * (n - split) / (t2 - t1) / 1e9

    # naive baseline on a short slice (17 states, physical coordinates)
    p = VehicleParams()
    A = system_matrix(p, THETA_SEC42, v)
    d = discretize(A, input_matrix(), track_intensity(args.ar_paper, v), 1.0 / fs)
    H = output_matrix(A, sensors)
    phi = np.repeat(d.phi[None], m, 0)
    qd = np.repeat(d.qd[None], m, 0)
    x = np.zeros((m, 17))
    P = np.repeat((d.qd * 1e3)[None], m, 0)
    k = args.naive_steps
    naive_steps(phi, qd, H, measurement_noise(sensors), x, P, Y[:1])     # warm-up
    t3 = time.perf_counter()
    naive_steps(phi, qd, H, measurement_noise(sensors), x, P, Y[:k])
    naive_rtf = k / fs / (time.perf_counter() - t3)
    return {"particles": m, "sensors": 3, "rate_hz": fs, "seconds": args.seconds,
            "numba_threads": numba.get_num_threads(), **_cores(),
            "exact_rtf_whole_run": whole_rtf, "exact_rtf_steady": steady_rtf,
            "steady_after_s": args.steady_after_s,
            "resamples_convergence": resamples_before,
            "resamples_steady": filt.n_resamples - resamples_before,
            "naive_rtf": naive_rtf, "naive_steps_measured": k,
            "ratio_whole_run": whole_rtf / naive_rtf, "ratio_steady": steady_rtf / naive_rtf,
            "steady_gflops": gflops,
            "ceiling_rtf": PEAK_GFLOPS_PER_CORE * numba.get_num_threads() * 1e9
            / (FLOP_PER_PARTICLE_STEP * m * fs)}


def _pipeline(args: argparse.Namespace) -> dict[str, Any]:
    from firmware_sim.studies.bench_pipeline import bench_pipeline

    return {**bench_pipeline(args), **_cores()}


def _latency(args: argparse.Namespace) -> dict[str, Any]:
    from firmware_sim.studies.bench_pipeline import bench_latency

    return {**bench_latency(args), **_cores()}


BENCHES: dict[str, Callable[[argparse.Namespace], dict[str, Any]]] = {
    "estimator": bench_estimator,
    "pipeline": _pipeline,
    "latency": _latency,
}


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench", help="measure real-time factors on this machine")
    p.add_argument("--what", choices=sorted(BENCHES), action="append",
                   help="benchmark(s) to run (default: all)")
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
    configure(kernel_threads(args.particles, args.threads))
    results = {name: BENCHES[name](args) for name in (args.what or sorted(BENCHES))}
    if args.json:
        print(json.dumps(results, indent=1))
        return 0
    for name, r in results.items():
        print(f"[{name}]")
        for key, value in r.items():
            print(f"  {key:>24}: {value:.4g}" if isinstance(value, float)
                  else f"  {key:>24}: {value}")
    return 0
