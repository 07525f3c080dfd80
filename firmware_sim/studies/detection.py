"""Detection study: abrupt faults and nominal runs through the RBPF and its fault bank.

``python -m firmware_sim.studies.detection faults --seeds 1 2 3`` runs each abrupt fault
of issue 15 (Csy x0.25 and x0.5, Csay x0.3 and x0.5 at ``--fault-at`` s, other parameters
nominal, Sec. 4.2 speed or ``--speed-mps``) with 3 and 5 sensors and prints one JSON line per run:

- ``confirmed_s`` / ``detect_s``: fault to the bank's confirmed CUSUM crossing (0.25 s
  after the crossing) / to its located detection on the right parameter (None: none);
- ``track_s``: fault to the first estimate from which the parameter stays within 15 % of
  its new value to the end;
- ``alert_s`` / ``alarm_s``: fault to the first alert / ALARM on the parameter from the
  default alert policy fed the 10 Hz estimates (:class:`gateway.alerts.policy.AlertPolicy`,
  which acts on the bank's located changes); ``alert_estimates_only_s``: the same policy
  judging the estimates alone (``act_on_located=False``), on the same run;
  ``alert_on_range_s`` / ``alarm_on_range_s`` / ``alerts_healthy_on_range``: the same
  policy raising a located change at once on its redraw range, as before the night of 2026-11-27,
  instead of its likelihood interval (``located_like``, relative to nominal);
  ``severity_max`` / ``severity_max_on_range``: the highest level raised on the
  parameter by either rule (a fault just short of a threshold, e.g. ``csy:0.6``, tells
  whether a rule raises past what the truth warrants);
  ``alert_severity``: the first alert's level (the alert columns:
  :mod:`firmware_sim.studies.detection_alerts`);
- ``wrong``: detections on a healthy parameter; ``before``: detections before the fault;
  ``alerts_healthy`` / ``alerts_before`` the same for alerts.

``nominal --seconds 600`` runs healthy data and counts detections (false alarms);
``--hold-every-s 30 --hold-s 3`` holds the updates for 3 s every 30 s, as the gate does in
a curve and its straight hold (nominal runs); ``--hold-at-s 7 10`` holds them for
``--hold-s`` from each of those times (fault runs);
``--dead acc_w1 acc_w2`` runs either with those sensors' values missing throughout (a
dead node); ``summary < rows.jsonl`` gives the per-case medians and worst cases and
``plot`` the figure (both in :mod:`firmware_sim.studies.detection_report`).
Data seed ``2000 + seed`` (fresh: the accuracy study uses ``1000 + seed``), filter seed
``seed``; the filter is the service's (:func:`gateway.runtime.pipeline.build_estimator`
from the default ``[estimator]`` settings: fast mode, drift 0.01/sqrt(s), the innovation
monitor and the fault bank). A measuring tool, not used by the service.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Iterator, Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from firmware_sim.scenarios import V_PAPER
from firmware_sim.studies.detection_alerts import alert_columns, alerts
from firmware_sim.studies.detection_report import plot, summary
from firmware_sim.studies.holds import holds, periodic_holds
from firmware_sim.truth import SENSOR_NOISE_VAR, measured
from gateway.config import DOMAINS, EstimatorConfig, Range
from gateway.errors import InputError
from gateway.estimator.faultbank import REDRAWS, FaultBankConfig
from gateway.estimator.noisestart import NoiseCheckedStart
from gateway.estimator.rbpf import RBPF
from gateway.model.vehicle import PARAM_NAMES, THETA_NOMINAL, sensor_set
from gateway.records import Sample
from gateway.runtime.pipeline import build_estimator

FS_HZ = 1000.0
V_MPS = V_PAPER
TRACK_REL = 0.15
FAULTS: tuple[tuple[int, float], ...] = ((0, 0.25), (0, 0.5), (1, 0.3), (1, 0.5))
"""(parameter index, factor) of the abrupt faults."""
DATA_SEED_OFFSET = 2000


def fault_data(parameter: int | None, factor: float, sensors: int, seed: int,
               seconds: float, fault_at_s: float, noise_scale: float = 1.0,
               speed_mps: float = V_MPS) -> tuple[np.ndarray, np.ndarray]:
    """Truth theta (T, 3) and noisy measurements (T, ny) at 1 kHz and ``speed_mps``;
    ``noise_scale`` multiplies the sensor noise's std (the filter keeps the model's)."""
    n = int(round(seconds * FS_HZ))
    th = np.repeat(THETA_NOMINAL.as_array()[None], n, 0)
    if parameter is not None:
        th[int(round(fault_at_s * FS_HZ)):, parameter] *= factor
    var = {k: v * noise_scale**2 for k, v in SENSOR_NOISE_VAR.items()}
    return th, measured(th, np.full(n, speed_mps), FS_HZ, sensor_set(sensors),
                        np.random.default_rng(DATA_SEED_OFFSET + seed), noise_var=var)


def without(Y: np.ndarray, sensors: int, dead: Sequence[str]) -> np.ndarray:
    """``Y`` (T, ny) with the ``dead`` sensors' values NaN throughout (a dead node, or
    one the vehicle lacks), as the front end hands them on."""
    names = sensor_set(sensors)
    if not set(dead) <= set(names):
        raise InputError(f"expected dead sensors from {list(names)}, got {list(dead)}")
    Y = Y.copy()
    Y[:, [names.index(d) for d in dead]] = np.nan
    return Y


Filter = RBPF | NoiseCheckedStart
"""The service's filter: the RBPF, in its sensor-noise test or not."""


def service_filter(sensors: int, seed: int, particles: int, mode: str,
                   sensor_noise: str = "measured", moves_drop_null: bool | None = None,
                   start_ramp_s: float | None = None, locate_min_s: float | None = None,
                   locate_max_s: float | None = None, replay_s: float | None = None,
                   replay_cov_scale: float | None = None, redraw_from: str | None = None,
                   start_ramp_m: float | None = None,
                   kernel_delta: float | None = None) -> Filter:
    """The filter the service builds from its defaults (drift, monitor, fault bank, the
    sensor-noise test, the start's likelihood ramp); ``moves_drop_null``,
    ``start_ramp_s`` and ``start_ramp_m`` override those options of the filter, ``locate_min_s``,
    ``locate_max_s``, ``replay_s``, ``replay_cov_scale`` and ``redraw_from`` those of its
    fault bank
    (:class:`gateway.estimator.rbpf_config.RBPFConfig`,
    :class:`gateway.estimator.faultbank.FaultBankConfig`; None: the service's);
    ``kernel_delta`` the service's ``[estimator] kernel_delta`` (with its floor)."""
    cfg = replace(EstimatorConfig(), sensors=sensors, seed=seed, particles=particles,
                  mode=mode, sensor_noise=sensor_noise)
    if kernel_delta is not None:
        cfg = replace(cfg, kernel_delta=kernel_delta)
    filt = build_estimator(cfg, FS_HZ)
    assert isinstance(filt, (RBPF, NoiseCheckedStart))
    rbpf = replace(filt.config,
                   moves_drop_null=(filt.config.moves_drop_null if moves_drop_null is None
                                    else moves_drop_null),
                   start_ramp_s=(filt.config.start_ramp_s if start_ramp_s is None
                                 else start_ramp_s),
                   start_ramp_m=(filt.config.start_ramp_m if start_ramp_m is None
                                 else start_ramp_m))
    if rbpf.faults is not None:
        bank = rbpf.faults
        rbpf = replace(rbpf, faults=replace(
            bank, locate_min_s=bank.locate_min_s if locate_min_s is None else locate_min_s,
            locate_max_s=bank.locate_max_s if locate_max_s is None else locate_max_s,
            replay_s=bank.replay_s if replay_s is None else replay_s,
            replay_cov_scale=(bank.replay_cov_scale if replay_cov_scale is None
                              else replay_cov_scale),
            redraw_from=bank.redraw_from if redraw_from is None else redraw_from))
    if rbpf == filt.config:
        return filt
    return NoiseCheckedStart(rbpf) if isinstance(filt, NoiseCheckedStart) else RBPF(rbpf)


def run(Y: np.ndarray, filt: Filter, every: int = 100, held: np.ndarray | None = None,
        speed_mps: float = V_MPS
        ) -> tuple[list[Any], list[tuple[float, str, float, float]], Filter]:
    """Estimates every ``every`` samples and the bank's detections (decision time,
    parameter, located value relative to nominal, confirmation time) on ``Y`` (T, ny)
    recorded at ``speed_mps``; samples where ``held`` (T,) is True come without an update,
    as the gate sends them in a curve."""
    found: list[tuple[float, str, float, float]] = []

    def samples() -> Iterator[Sample]:
        seen = 0
        for k in range(len(Y)):
            if filt.n_fault_detections > seen:
                seen = filt.n_fault_detections
                found.append(_last(filt))
            yield Sample(t_s=(k + 1) / FS_HZ, values=Y[k], speed_mps=speed_mps,
                         update=held is None or not held[k])

    est = filt.run(samples(), output_every=every)
    if filt.n_fault_detections > len(found):
        found.append(_last(filt))
    return est, found, filt


def _noise_columns(filt: Filter) -> dict[str, Any]:
    """The sensor-noise test's outcome: the variances used relative to the model's."""
    res = filt.result if isinstance(filt, NoiseCheckedStart) else None
    return {"sensor_noise": "measured" if isinstance(filt, NoiseCheckedStart) else "model",
            "noise_used_rel": None if res is None else [
                round(u / m, 3) for u, m in zip(res.used_var, res.model_var, strict=True)]}


def _bank_columns(filt: Filter) -> dict[str, Any]:
    """The fault bank's location settings (None: no bank)."""
    bank = filt.config.faults
    return {"redraw_from": None if bank is None else bank.redraw_from,
            "locate_min_s": None if bank is None else bank.locate_min_s,
            "locate_s": None if bank is None else bank.locate_s,
            "locate_max_s": None if bank is None else bank.locate_max_s,
            "replay_s": None if bank is None else bank.replay_s,
            "replay_cov_scale": None if bank is None else bank.replay_cov_scale}


def _last(filt: Filter) -> tuple[float, str, float, float]:
    last = filt.last_fault()
    assert last is not None
    return last


def fault_row(parameter: int, factor: float, sensors: int, seed: int, *, seconds: float,
              fault_at_s: float, particles: int, mode: str, noise_scale: float = 1.0,
              sensor_noise: str = "measured", moves_drop_null: bool | None = None,
              locate_min_s: float | None = None, locate_max_s: float | None = None,
              replay_s: float | None = None, replay_cov_scale: float | None = None,
              hold_at_s: Sequence[float] = (), hold_s: float = 3.0,
              dead: Sequence[str] = (), speed_mps: float = V_MPS,
              redraw_from: str | None = None,
              kernel_delta: float | None = None) -> dict[str, Any]:
    th, Y = fault_data(parameter, factor, sensors, seed, seconds, fault_at_s, noise_scale,
                       speed_mps)
    Y = without(Y, sensors, dead)
    t0 = time.perf_counter()
    est, found, filt = run(Y, service_filter(sensors, seed, particles, mode, sensor_noise,
                                             moves_drop_null, locate_min_s=locate_min_s,
                                             locate_max_s=locate_max_s, replay_s=replay_s,
                                             replay_cov_scale=replay_cov_scale,
                                             redraw_from=redraw_from,
                                             kernel_delta=kernel_delta),
                           held=holds(len(Y), FS_HZ, hold_at_s, hold_s) if hold_at_s else None,
                           speed_mps=speed_mps)
    wall = time.perf_counter() - t0
    new = th[-1, parameter]
    ok = [abs(e.mean[parameter] - new) <= TRACK_REL * new for e in est]
    track = next((e.t_s - fault_at_s for i, e in enumerate(est)
                  if e.t_s > fault_at_s and all(ok[i:])), None)
    name = PARAM_NAMES[parameter]
    right = [f for f in found if f[0] > fault_at_s and f[1] == name]
    last = est[-1]
    return {"what": "fault", "parameter": name, "factor": factor, "sensors": sensors,
            "speed_mps": speed_mps, "noise_scale": noise_scale, **_noise_columns(filt),
            "moves_drop_null": filt.config.moves_drop_null, **_bank_columns(filt),
            "kernel_delta": filt.config.delta,
            "hold_at_s": list(hold_at_s) or None, "hold_s": hold_s if hold_at_s else None,
            "seed": seed, "mode": mode, "particles": particles, "fault_at_s": fault_at_s,
            "dead": list(dead) or None,
            "confirmed_s": round(right[0][3] - fault_at_s, 3) if right else None,
            "detect_s": round(right[0][0] - fault_at_s, 3) if right else None,
            "located_rel": round(right[0][2] / factor, 3) if right else None,
            "track_s": None if track is None else round(track, 2),
            **alert_columns(est, name, fault_at_s),
            "located_like": next(([round(e.located.like_lo, 3), round(e.located.like_hi, 3)]
                                  for e in est if right and e.located is not None
                                  and e.located.t_s == right[0][0]), None),
            "wrong": sum(f[1] != name for f in found if f[0] > fault_at_s),
            "before": sum(f[0] <= fault_at_s for f in found),
            "detections": [(round(t, 3), n, round(v, 3)) for t, n, v, _ in found],
            "monitor_alarms": filt.n_detections,
            "final_err_pct": [round(100 * (m - t) / t, 2)
                              for m, t in zip(last.mean[:3], th[-1], strict=True)],
            "final_sigma_pct": [round(100 * s / m, 2)
                                for m, s in zip(last.mean[:3], last.std[:3], strict=True)],
            "wall_s": round(wall, 1)}


def nominal_row(sensors: int, seed: int, *, seconds: float, particles: int, mode: str,
                noise_scale: float = 1.0, sensor_noise: str = "measured",
                moves_drop_null: bool | None = None, locate_min_s: float | None = None,
                locate_max_s: float | None = None, replay_s: float | None = None,
                replay_cov_scale: float | None = None, hold_every_s: float | None = None,
                hold_s: float = 3.0, dead: Sequence[str] = (),
                speed_mps: float = V_MPS, redraw_from: str | None = None,
                kernel_delta: float | None = None) -> dict[str, Any]:
    th, Y = fault_data(None, 1.0, sensors, seed, seconds, 0.0, noise_scale, speed_mps)
    Y = without(Y, sensors, dead)
    t0 = time.perf_counter()
    est, found, filt = run(Y, service_filter(sensors, seed, particles, mode, sensor_noise,
                                             moves_drop_null, locate_min_s=locate_min_s,
                                             locate_max_s=locate_max_s, replay_s=replay_s,
                                             replay_cov_scale=replay_cov_scale,
                                             redraw_from=redraw_from,
                                             kernel_delta=kernel_delta),
                           held=periodic_holds(len(Y), FS_HZ, hold_every_s, hold_s),
                           speed_mps=speed_mps)
    last = est[-1]
    return {"what": "nominal", "sensors": sensors, "speed_mps": speed_mps, "seed": seed,
            "mode": mode,
            "dead": list(dead) or None,
            "noise_scale": noise_scale, **_noise_columns(filt),
            "hold_every_s": hold_every_s, "hold_s": hold_s if hold_every_s else None,
            "moves_drop_null": filt.config.moves_drop_null, **_bank_columns(filt),
            "kernel_delta": filt.config.delta,
            "particles": particles, "seconds": seconds, "detections": len(found),
            "alerts": len(alerts(est)),
            "detail": [(round(t, 3), n, round(v, 3)) for t, n, v, _ in found],
            "monitor_alarms": filt.n_detections,
            "final_err_pct": [round(100 * (m - t) / t, 2)
                              for m, t in zip(last.mean[:3], th[-1], strict=True)],
            "final_sigma_pct": [round(100 * s / m, 2)
                                for m, s in zip(last.mean[:3], last.std[:3], strict=True)],
            "final_z": [round((m - t) / s, 2)
                        for m, s, t in zip(last.mean[:3], last.std[:3], th[-1], strict=True)],
            "wall_s": round(time.perf_counter() - t0, 1)}


def fault_case(text: str) -> tuple[int, float]:
    """An argparse type: ``PARAMETER:FACTOR`` (a parameter name or its prefix) as
    (parameter index, factor)."""
    name, _, factor = text.partition(":")
    matches = [i for i, p in enumerate(PARAM_NAMES) if p.startswith(name)]
    try:
        value = float(factor)
    except ValueError:
        value = float("nan")
    if len(matches) != 1 or not value > 0:
        raise argparse.ArgumentTypeError(f"expected PARAMETER:FACTOR with PARAMETER one of "
                                         f"{PARAM_NAMES} (a prefix will do) and FACTOR > 0, "
                                         f"got {text!r}")
    return matches[0], value


def kernel_delta_arg(text: str) -> float:
    """An argparse type: a value of the service's ``[estimator] kernel_delta`` (its
    configuration domain)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number for the kernel delta, got "
                                         f"{text!r}") from None
    domain = DOMAINS[("estimator", "kernel_delta")]
    assert isinstance(domain, Range)
    problem = domain.problem(value)
    if problem is not None:
        raise argparse.ArgumentTypeError(f"kernel delta: {problem}")
    return value


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m firmware_sim.studies.detection",
                                 description=__doc__.split("\n")[0])
    ap.add_argument("what", choices=("faults", "nominal", "summary", "plot"),
                    help="summary / plot: read the rows (JSON lines) from stdin and print "
                         "one per case / write the PNG --plot")
    ap.add_argument("--cases", type=fault_case, nargs="+", default=list(FAULTS),
                    metavar="PARAMETER:FACTOR", help="faults (default: csy:0.25 csy:0.5 "
                    "csay:0.3 csay:0.5)")
    ap.add_argument("--plot", default="detection.png", help="plot: the PNG to write")
    ap.add_argument("--noise-scale", type=float, default=1.0,
                    help="sensor noise std of the data relative to the model's (another "
                         "simulator's noise convention)")
    ap.add_argument("--sensor-noise", choices=("measured", "model"), default="measured",
                    help="the filter's sensor noise: tested against the data (the service's "
                         "default) or the model's")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--sensors", type=int, nargs="+", default=[3, 5])
    ap.add_argument("--seconds", type=float, default=None,
                    help="run length (faults: 18 s, nominal: 600 s)")
    ap.add_argument("--fault-at", type=float, default=8.0)
    ap.add_argument("--hold-at-s", type=float, nargs="+", default=[],
                    help="faults: holds of --hold-s starting at these times, s (default: "
                         "none)")
    ap.add_argument("--hold-every-s", type=float, default=None,
                    help="nominal: samples without an update (the gate's hold in a curve) "
                         "for --hold-s at every multiple of this, s (default: none)")
    ap.add_argument("--hold-s", type=float, default=3.0,
                    help="length of each hold, s (3: a 1 s curve and the 2 s straight hold)")
    ap.add_argument("--redraw-from", choices=REDRAWS, default=None,
                    help="how a detection redraws its parameter (default: the bank's own; "
                         "range: log-uniformly over the redraw range, as before "
                         "2026-11-27)")
    ap.add_argument("--speed-mps", type=float, default=V_MPS,
                    help="the vehicle's constant speed, m/s (default: the paper's 42.5; the "
                         "gate runs the estimator at 15-70)")
    ap.add_argument("--particles", type=int, default=1000)
    ap.add_argument("--dead", nargs="+", default=[], metavar="SENSOR",
                    help="sensors with no value at all (a dead node), e.g. acc_w1 acc_w2")
    ap.add_argument("--mode", choices=("fast", "exact"), default="fast")
    ap.add_argument("--moves-drop-null", action=argparse.BooleanOptionalAction,
                    default=None, help="the filter's moves_drop_null option (default: the "
                    "filter's own)")
    ap.add_argument("--locate-min-s", type=float, default=None,
                    help="the fault bank's shortest location phase, s (default: the bank's "
                         "own, its full location phase; below it: the early stop)")
    ap.add_argument("--locate-max-s", type=float, default=None,
                    help="the fault bank's longest location phase, s (default: the bank's "
                         "own; its locate_s: no extension of an inconclusive location)")
    ap.add_argument("--replay-s", type=float, default=None,
                    help="the fault bank's look-back, s (default: the bank's own; 0: the "
                         "location starts at the confirmation)")
    ap.add_argument("--replay-cov-scale", type=float, default=None,
                    help="the multiple of its steady covariance a replayed location starts "
                         "from (default: the bank's own)")
    ap.add_argument("--kernel-delta", type=kernel_delta_arg, default=None,
                    help="the service's [estimator] kernel_delta (default: the service's)")
    args = ap.parse_args(argv)
    if args.hold_every_s is not None and not args.hold_every_s > args.hold_s > 0:
        ap.error(f"expected --hold-every-s > --hold-s > 0 s, got {args.hold_every_s} and "
                 f"{args.hold_s}")
    if args.locate_min_s is not None and not args.locate_min_s >= 0:
        ap.error(f"expected --locate-min-s >= 0 s, got {args.locate_min_s}")
    if args.locate_max_s is not None and not args.locate_max_s >= FaultBankConfig.locate_s:
        ap.error(f"expected --locate-max-s >= {FaultBankConfig.locate_s} s (the location "
                 f"phase), got {args.locate_max_s}")
    if args.replay_s is not None and not args.replay_s >= 0:
        ap.error(f"expected --replay-s >= 0 s, got {args.replay_s}")
    if args.replay_cov_scale is not None and not args.replay_cov_scale >= 1:
        ap.error(f"expected --replay-cov-scale >= 1, got {args.replay_cov_scale}")
    if not 0 < args.speed_mps <= 150:
        ap.error(f"expected 0 < --speed-mps <= 150 m/s, got {args.speed_mps}")
    if args.what in ("summary", "plot"):
        rows = [json.loads(line) for line in sys.stdin if line.strip()]
        if args.what == "plot":
            plot(rows, args.plot)
        for row in summary(rows) if args.what == "summary" else []:
            print(json.dumps(row))
        return 0
    for seed in args.seeds:
        for ns in args.sensors:
            if args.what == "nominal":
                rows = [nominal_row(ns, seed, seconds=args.seconds or 600.0,
                                    particles=args.particles, mode=args.mode,
                                    noise_scale=args.noise_scale,
                                    sensor_noise=args.sensor_noise,
                                    moves_drop_null=args.moves_drop_null,
                                    locate_min_s=args.locate_min_s,
                                    locate_max_s=args.locate_max_s,
                                    replay_s=args.replay_s,
                                    replay_cov_scale=args.replay_cov_scale,
                                    hold_every_s=args.hold_every_s, hold_s=args.hold_s,
                                    dead=args.dead, speed_mps=args.speed_mps,
                                    redraw_from=args.redraw_from,
                                    kernel_delta=args.kernel_delta)]
            else:
                rows = [fault_row(p, f, ns, seed, seconds=args.seconds or 18.0,
                                  fault_at_s=args.fault_at, particles=args.particles,
                                  mode=args.mode, noise_scale=args.noise_scale,
                                  sensor_noise=args.sensor_noise,
                                  moves_drop_null=args.moves_drop_null,
                                  locate_min_s=args.locate_min_s,
                                  locate_max_s=args.locate_max_s,
                                  replay_s=args.replay_s,
                                  replay_cov_scale=args.replay_cov_scale,
                                  hold_at_s=args.hold_at_s, hold_s=args.hold_s,
                                  dead=args.dead, speed_mps=args.speed_mps,
                                  redraw_from=args.redraw_from,
                                  kernel_delta=args.kernel_delta)
                        for p, f in args.cases]
            for row in rows:
                print(json.dumps(row), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
