"""The estimator's cost curve: real-time factors of fast, exact and naive filters against m.

One benchmark data set (:func:`bench_data`: paper Sec. 4.2 theta, 42.5 m/s, 3 sensors,
1 kHz) is filtered by the RBPF in each mode (:func:`time_filter`) and by the naive
per-particle loop on a short slice (:func:`naive_rtf`); :func:`sweep_point` does all
three at one particle count and returns a :class:`SweepRecord`. ``gateway bench``
(``--what estimator`` and ``--what sweep``) wires these; :func:`plot_sweep` draws the
curve (RTF against m, log-log).

Real-time factor (RTF) = simulated seconds / wall seconds. "Whole run" is every sample
after the first (which is stepped outside the timing, so that thread pools and caches are
warm) and includes the convergence phase with its frequent resample-moves and, in fast
mode, the exact warm-up and the DARE solves; "steady" is the samples from
``steady_after_s`` on. The numba threads in effect are the caller's (set once per
process or per point, :mod:`gateway.estimator.threads`); each timing reads them back.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numba
import numpy as np

from firmware_sim.studies.naive import naive_steps
from firmware_sim.truth import lose_values, measured
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

FS_HZ = 1000.0
V_MPS = 42.5
SENSORS = 3
OUTPUT_EVERY = 10
"""Estimates summarised every this many samples while timing, and so the longest run the
filter takes in one call. The service summarises ten times less often (10 Hz at 1 kHz)
in runs of at most 20 samples (one queue block, :data:`gateway.runtime.worker.BLOCK_SAMPLES`),
so its per-call cost per sample is lower; the bench keeps 10 so that its figures stay
comparable from run to run (noticed 2026-12-01: this said "the service's decimation")."""


@dataclass(frozen=True)
class BenchData:
    """Measurements ``y (T, 3)`` [m/s^2, rad/s] of the Sec. 4.2 truth and their samples."""

    fs_hz: float
    speed_mps: float
    y: np.ndarray
    samples: tuple[Sample, ...]

    @property
    def n(self) -> int:
        return len(self.samples)


@dataclass(frozen=True)
class ModeTiming:
    """One filter run over a :class:`BenchData`: RTFs and resample-moves per phase."""

    mode: str
    particles: int
    threads: int
    rtf_whole_run: float
    rtf_steady: float
    resamples_convergence: int
    resamples_steady: int
    steady_wall_s: float


@dataclass(frozen=True)
class SweepRecord:
    """The cost at one particle count. ``exact_*`` is None where exact mode was skipped."""

    particles: int
    threads: int
    fast_rtf_whole_run: float
    fast_rtf_steady: float
    exact_rtf_whole_run: float | None
    exact_rtf_steady: float | None
    naive_rtf: float
    fast_resamples: int
    exact_resamples: int | None


def bench_data(seconds: float, seed: int) -> BenchData:
    """``seconds`` of paper Sec. 4.2 data at :data:`FS_HZ` (at least 2 samples).

    The truth and the sensor noise come from one generator seeded ``seed``.
    """
    n = max(2, int(round(seconds * FS_HZ)))
    y = measured(np.repeat(THETA_SEC42.as_array()[None], n, 0), np.full(n, V_MPS), FS_HZ,
                 sensor_set(SENSORS), np.random.default_rng(seed))
    samples = tuple(Sample(t_s=k / FS_HZ, values=y[k], speed_mps=V_MPS) for k in range(n))
    return BenchData(fs_hz=FS_HZ, speed_mps=V_MPS, y=y, samples=samples)


def lose_sensor_values(data: BenchData, loss: float, seed: int) -> BenchData:
    """``data`` with each sensor value lost (NaN: a lost CAN frame, the front end's
    partial sample) independently with probability ``loss``, drawn from ``seed``."""
    y = lose_values(data.y, loss, np.random.default_rng(seed))
    samples = tuple(Sample(t_s=k / data.fs_hz, values=y[k], speed_mps=data.speed_mps)
                    for k in range(len(y)))
    return BenchData(fs_hz=data.fs_hz, speed_mps=data.speed_mps, y=y, samples=samples)


def time_filter(data: BenchData, config: RBPFConfig, steady_after_s: float) -> ModeTiming:
    """Run a fresh ``RBPF(config)`` over ``data``; whole-run and steady RTFs.

    The first sample is stepped before the clock starts; the steady window is
    ``[steady_after_s, end]`` (at least the last sample).
    """
    fs, n = data.fs_hz, data.n
    filt = RBPF(config)
    filt.step(data.samples[0])
    split = max(1, min(n - 1, int(round(steady_after_s * fs))))
    t0 = time.perf_counter()
    filt.run(data.samples[1:split], output_every=OUTPUT_EVERY)
    t1 = time.perf_counter()
    before = filt.n_resamples
    filt.run(data.samples[split:], output_every=OUTPUT_EVERY)
    t2 = time.perf_counter()
    return ModeTiming(mode=config.mode, particles=config.n_particles,
                      threads=numba.get_num_threads(),
                      rtf_whole_run=(n - 1) / fs / (t2 - t0),
                      rtf_steady=(n - split) / fs / (t2 - t1),
                      resamples_convergence=before,
                      resamples_steady=filt.n_resamples - before, steady_wall_s=t2 - t1)


def naive_rtf(data: BenchData, particles: int, steps: int, ar_paper: float) -> float:
    """RTF of the naive loop (:mod:`firmware_sim.studies.naive`, 17 physical states) over
    the first ``steps`` samples, after one untimed step."""
    p = VehicleParams()
    sensors = sensor_set(SENSORS)
    A = system_matrix(p, THETA_SEC42, data.speed_mps)
    d = discretize(A, input_matrix(), track_intensity(ar_paper, data.speed_mps),
                   1.0 / data.fs_hz)
    H = output_matrix(A, sensors)
    R = measurement_noise(sensors)
    phi = np.repeat(d.phi[None], particles, 0)
    qd = np.repeat(d.qd[None], particles, 0)
    x = np.zeros((particles, phi.shape[1]))
    P = np.repeat((d.qd * 1e3)[None], particles, 0)
    y = np.resize(data.y, (steps, data.y.shape[1]))   # repeats the data if it is shorter
    naive_steps(phi, qd, H, R, x, P, y[:1])
    t0 = time.perf_counter()
    naive_steps(phi, qd, H, R, x, P, y)
    return steps / data.fs_hz / (time.perf_counter() - t0)


def filter_config(mode: str, particles: int, seed: int, ar_paper: float,
                  fast_warmup_s: float | None = None) -> RBPFConfig:
    """The benchmark's filter: 3 sensors at :data:`FS_HZ`, the given mode and seed;
    ``fast_warmup_s`` None keeps :class:`RBPFConfig`'s default."""
    config = RBPFConfig(fs_hz=FS_HZ, n_particles=particles, sensors=SENSORS, seed=seed,
                        ar_paper=ar_paper, mode=mode)
    return config if fast_warmup_s is None else replace(config, fast_warmup_s=fast_warmup_s)


def service_filter_config(particles: int, seed: int, ar_paper: float,
                          fast_warmup_s: float | None = None) -> RBPFConfig:
    """The filter the service builds from its default ``[estimator]`` table
    (:func:`gateway.runtime.pipeline.estimator_config`: fast mode, the kernel discount,
    floor, prior box and start ramp it chooses), at ``particles``, ``seed`` and the
    benchmark's ``ar_paper``, with the model's sensor noise (the service measures it at
    the start; the benchmark's data have the model's). :func:`filter_config` is the
    paper's bare filter."""
    from gateway.config import EstimatorConfig
    from gateway.runtime.pipeline import estimator_config

    config = estimator_config(EstimatorConfig(particles=particles, seed=seed,
                                              track_roughness=ar_paper), FS_HZ)
    return config if fast_warmup_s is None else replace(config, fast_warmup_s=fast_warmup_s)


def sweep_point(data: BenchData, particles: int, *, seed: int, steady_after_s: float,
                naive_steps_n: int, ar_paper: float, exact: bool = True,
                fast_warmup_s: float | None = None) -> SweepRecord:
    """Fast mode, then exact mode (unless ``exact`` is False), then the naive loop, all at
    ``particles`` over the same data with the same filter seed."""
    fast = time_filter(data, filter_config("fast", particles, seed, ar_paper, fast_warmup_s),
                       steady_after_s)
    ex = (time_filter(data, filter_config("exact", particles, seed, ar_paper), steady_after_s)
          if exact else None)
    return SweepRecord(
        particles=particles, threads=fast.threads,
        fast_rtf_whole_run=fast.rtf_whole_run, fast_rtf_steady=fast.rtf_steady,
        exact_rtf_whole_run=ex.rtf_whole_run if ex else None,
        exact_rtf_steady=ex.rtf_steady if ex else None,
        naive_rtf=naive_rtf(data, particles, naive_steps_n, ar_paper),
        fast_resamples=fast.resamples_convergence + fast.resamples_steady,
        exact_resamples=ex.resamples_convergence + ex.resamples_steady if ex else None)


def plot_sweep(records: Sequence[SweepRecord], path: str | Path, *, title: str = "") -> None:
    """RTF against m, log-log: fast and exact (whole run solid, steady dashed), the naive
    loop, and horizontal lines at real time (1) and the fast-mode target (10). PNG."""
    from matplotlib.figure import Figure  # Agg through savefig; no pyplot state

    recs = sorted(records, key=lambda r: r.particles)
    fig = Figure(figsize=(7.0, 4.6))
    ax = fig.add_subplot(1, 1, 1)
    curves: list[tuple[str, str, str, list[tuple[int, float | None]]]] = [
        ("fast, whole run", "C0", "-o", [(r.particles, r.fast_rtf_whole_run) for r in recs]),
        ("fast, steady", "C0", "--", [(r.particles, r.fast_rtf_steady) for r in recs]),
        ("exact, whole run", "C1", "-s", [(r.particles, r.exact_rtf_whole_run) for r in recs]),
        ("exact, steady", "C1", "--", [(r.particles, r.exact_rtf_steady) for r in recs]),
        ("naive loop", "C2", "-^", [(r.particles, r.naive_rtf) for r in recs]),
    ]
    for label, colour, style, points in curves:
        kept = [(m, v) for m, v in points if v is not None and v > 0 and np.isfinite(v)]
        if kept:
            ms, vs = zip(*kept, strict=True)
            ax.plot(ms, vs, style, color=colour, label=label,
                    lw=1.0 if style == "--" else 1.5, ms=4)
    ax.axhline(1.0, color="k", lw=1.0, label="real time (RTF 1)")
    ax.axhline(10.0, color="C3", lw=1.0, ls=":", label="fast-mode target (RTF 10)")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xticks([r.particles for r in recs], labels=[str(r.particles) for r in recs])
    ax.minorticks_off()
    ax.set_xlabel("particles m")
    ax.set_ylabel("real-time factor (simulated s / wall s)")
    threads = sorted({r.threads for r in recs})
    ax.set_title(title or f"RBPF cost, 3 sensors, 1 kHz, "
                 f"{'/'.join(map(str, threads))} numba thread(s)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    fig.savefig(path, dpi=100, format="png")
