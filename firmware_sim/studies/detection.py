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
  instead of its likelihood interval (``located_like``, relative to nominal;
  ``located_like_last``: the last one the estimates carried, with its data time: a
  refinement's, since 2026-11-28's fifth session);
  ``severity_max`` / ``severity_max_on_range``: the highest level raised on the
  parameter by either rule (a fault just short of a threshold, e.g. ``csy:0.6``, tells
  whether a rule raises past what the truth warrants);
  ``alert_severity``: the first alert's level (the alert columns:
  :mod:`firmware_sim.studies.detection_alerts`);
- ``wrong``: detections on a healthy parameter; ``before``: detections before the fault;
  ``alerts_healthy`` / ``alerts_before`` the same for alerts; ``replaced_detections``:
  detections of a filter that the sensor-noise test then replaced (its estimates were
  provisional; none of the columns above counts them; since 2026-11-29's ninth session).

``nominal --seconds 600`` runs healthy data and counts detections (false alarms);
``--hold-every-s 30 --hold-s 3`` holds the updates for 3 s every 30 s, as the gate does in
a curve and its straight hold (nominal runs); ``--hold-at-s 7 10`` holds them for
``--hold-s`` from each of those times (fault runs);
``--dead acc_w1 acc_w2`` runs either with those sensors' values missing throughout (a
dead node); ``summary < rows.jsonl`` gives the per-case medians and worst cases and
``plot`` the figure (both in :mod:`firmware_sim.studies.detection_report`).
Data seed ``2000 + seed`` (fresh: the accuracy study uses ``1000 + seed``), filter seed
``seed``; the filter is the service's with the study's overrides
(:mod:`firmware_sim.studies.filtering`: fast mode, drift 0.01/sqrt(s), the innovation
monitor and the fault bank; ``--particles``, ``--mode``, ``--replay-cov-scale``, ...).
This module makes the records and the rows and holds the command line; the alert columns,
the summary and the plot are its own modules. A measuring tool, not used by the service.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from firmware_sim.studies.arguments import (
    add_filter_options,
    add_track_input,
    fault_case,
    filter_options,
)
from firmware_sim.studies.detection_alerts import alert_columns, alerts
from firmware_sim.studies.detection_report import plot, summary
from firmware_sim.studies.filtering import (
    FS_HZ,
    V_MPS,
    FilterOptions,
    Found,
    filter_columns,
    run,
    service_filter,
)
from firmware_sim.studies.holds import holds, periodic_holds
from firmware_sim.studies.rows import emit
from firmware_sim.truth import SENSOR_NOISE_VAR, NonlinearDampers, measured
from gateway.errors import InputError
from gateway.model.vehicle import PARAM_NAMES, THETA_NOMINAL, sensor_set
from gateway.records import Estimate

TRACK_REL = 0.15
FAULTS: tuple[tuple[int, float], ...] = ((0, 0.25), (0, 0.5), (1, 0.3), (1, 0.5))
"""(parameter index, factor) of the abrupt faults."""
DATA_SEED_OFFSET = 2000


def fault_data(parameter: int | None, factor: float, sensors: int, seed: int,
               seconds: float, fault_at_s: float, noise_scale: float = 1.0,
               speed_mps: float = V_MPS, nonlinear: bool = False,
               track_input: str = "white") -> tuple[np.ndarray, np.ndarray]:
    """Truth theta (T, 3) and noisy measurements (T, ny) at 1 kHz and ``speed_mps``;
    ``noise_scale`` multiplies the sensor noise's std (the filter keeps the model's);
    ``nonlinear``: the dampers follow the saturating curves of the paper's Figs. 6-7
    (:class:`firmware_sim.truth.NonlinearDampers`, scaled with theta: a failed damper
    loses force at every velocity) instead of the linear model's; ``track_input``: how
    the truth's track velocities enter (:data:`firmware_sim.truth.TRACK_INPUTS`)."""
    n = int(round(seconds * FS_HZ))
    th = np.repeat(THETA_NOMINAL.as_array()[None], n, 0)
    if parameter is not None:
        th[int(round(fault_at_s * FS_HZ)):, parameter] *= factor
    var = {k: v * noise_scale**2 for k, v in SENSOR_NOISE_VAR.items()}
    return th, measured(th, np.full(n, speed_mps), FS_HZ, sensor_set(sensors),
                        np.random.default_rng(DATA_SEED_OFFSET + seed), noise_var=var,
                        dampers=NonlinearDampers() if nonlinear else None,
                        track_input=track_input)


def without(Y: np.ndarray, sensors: int, dead: Sequence[str]) -> np.ndarray:
    """``Y`` (T, ny) with the ``dead`` sensors' values NaN throughout (a dead node, or
    one the vehicle lacks), as the front end hands them on."""
    names = sensor_set(sensors)
    if not set(dead) <= set(names):
        raise InputError(f"expected dead sensors from {list(names)}, got {list(dead)}")
    Y = Y.copy()
    Y[:, [names.index(d) for d in dead]] = np.nan
    return Y


def _rounded(found: Sequence[Found]) -> list[tuple[float, str, float]]:
    """Detections as a row's column: (decision time s, parameter, located value relative
    to nominal), rounded."""
    return [(round(t, 3), n, round(v, 3)) for t, n, v, _ in found]


def _final_columns(last: Estimate, truth: np.ndarray) -> dict[str, Any]:
    """The last estimate's error and stated sigma against ``truth`` (3,), in %."""
    return {"final_err_pct": [round(100 * (m - t) / t, 2)
                              for m, t in zip(last.mean[:3], truth, strict=True)],
            "final_sigma_pct": [round(100 * s / m, 2)
                                for m, s in zip(last.mean[:3], last.std[:3], strict=True)]}


def fault_row(parameter: int, factor: float, sensors: int, seed: int, *, seconds: float,
              fault_at_s: float, options: FilterOptions | None = None,
              noise_scale: float = 1.0, hold_at_s: Sequence[float] = (), hold_s: float = 3.0,
              dead: Sequence[str] = (), speed_mps: float = V_MPS,
              nonlinear: bool = False, track_input: str = "white") -> dict[str, Any]:
    """One abrupt fault: ``parameter`` times ``factor`` at ``fault_at_s`` in a record of
    ``seconds`` (data seed ``2000 + seed``, at ``speed_mps``, the sensor noise's std times
    ``noise_scale``, the ``dead`` sensors missing, holds of ``hold_s`` from each of
    ``hold_at_s``) through the service's filter with ``options`` (filter seed ``seed``);
    the row's columns are the module's."""
    options = options or FilterOptions()
    th, Y = fault_data(parameter, factor, sensors, seed, seconds, fault_at_s, noise_scale,
                       speed_mps, nonlinear, track_input)
    Y = without(Y, sensors, dead)
    t0 = time.perf_counter()
    gone: list[Found] = []
    est, found, filt = run(Y, service_filter(sensors, seed, options),
                           held=holds(len(Y), FS_HZ, hold_at_s, hold_s) if hold_at_s else None,
                           speed_mps=speed_mps, replaced=gone)
    wall = time.perf_counter() - t0
    new = th[-1, parameter]
    ok = [abs(e.mean[parameter] - new) <= TRACK_REL * new for e in est]
    track = next((e.t_s - fault_at_s for i, e in enumerate(est)
                  if e.t_s > fault_at_s and all(ok[i:])), None)
    name = PARAM_NAMES[parameter]
    right = [f for f in found if f[0] > fault_at_s and f[1] == name]
    return {"what": "fault", "parameter": name, "factor": factor, "sensors": sensors,
            "speed_mps": speed_mps, "noise_scale": noise_scale, "nonlinear_dampers": nonlinear,
            "track_input": track_input, **filter_columns(filt),
            "hold_at_s": list(hold_at_s) or None, "hold_s": hold_s if hold_at_s else None,
            "seed": seed, "mode": options.mode, "particles": options.particles,
            "fault_at_s": fault_at_s, "dead": list(dead) or None,
            "confirmed_s": round(right[0][3] - fault_at_s, 3) if right else None,
            "detect_s": round(right[0][0] - fault_at_s, 3) if right else None,
            "located_rel": round(right[0][2] / factor, 3) if right else None,
            "track_s": None if track is None else round(track, 2),
            **alert_columns(est, name, fault_at_s),
            "located_like": next(([round(e.located.like_lo, 3), round(e.located.like_hi, 3)]
                                  for e in est if right and e.located is not None
                                  and e.located.t_s == right[0][0]), None),
            "located_like_last": next(([round(e.located.like_lo, 3),
                                        round(e.located.like_hi, 3), round(e.located.t_s, 3)]
                                       for e in reversed(est) if right and e.located is not None
                                       and e.located.parameter == name), None),
            "wrong": sum(f[1] != name for f in found if f[0] > fault_at_s),
            "before": sum(f[0] <= fault_at_s for f in found),
            "detections": _rounded(found),
            "replaced_detections": _rounded(gone),
            "monitor_alarms": filt.n_detections, **_final_columns(est[-1], th[-1]),
            "wall_s": round(wall, 1)}


def nominal_row(sensors: int, seed: int, *, seconds: float,
                options: FilterOptions | None = None, noise_scale: float = 1.0,
                hold_every_s: float | None = None, hold_s: float = 3.0,
                dead: Sequence[str] = (), speed_mps: float = V_MPS,
                nonlinear: bool = False, track_input: str = "white") -> dict[str, Any]:
    """Healthy running for ``seconds`` (the record as in :func:`fault_row`, holds of
    ``hold_s`` every ``hold_every_s``); counts the detections and alerts (false alarms)."""
    options = options or FilterOptions()
    th, Y = fault_data(None, 1.0, sensors, seed, seconds, 0.0, noise_scale, speed_mps,
                       nonlinear, track_input)
    Y = without(Y, sensors, dead)
    t0 = time.perf_counter()
    gone: list[Found] = []
    est, found, filt = run(Y, service_filter(sensors, seed, options),
                           held=periodic_holds(len(Y), FS_HZ, hold_every_s, hold_s),
                           speed_mps=speed_mps, replaced=gone)
    last = est[-1]
    return {"what": "nominal", "sensors": sensors, "speed_mps": speed_mps, "seed": seed,
            "mode": options.mode, "dead": list(dead) or None,
            "noise_scale": noise_scale, "nonlinear_dampers": nonlinear,
            "track_input": track_input, **filter_columns(filt),
            "hold_every_s": hold_every_s, "hold_s": hold_s if hold_every_s else None,
            "particles": options.particles, "seconds": seconds, "detections": len(found),
            "alerts": len(alerts(est)),
            "detail": _rounded(found), "replaced_detections": _rounded(gone),
            "monitor_alarms": filt.n_detections, **_final_columns(last, th[-1]),
            "final_z": [round((m - t) / s, 2)
                        for m, s, t in zip(last.mean[:3], last.std[:3], th[-1], strict=True)],
            "wall_s": round(time.perf_counter() - t0, 1)}


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
    ap.add_argument("--speed-mps", type=float, default=V_MPS,
                    help="the vehicle's constant speed, m/s (default: the paper's 42.5; the "
                         "gate runs the estimator at 15-70)")
    ap.add_argument("--nonlinear-dampers", action="store_true",
                    help="the truth's dampers saturate (the paper's Figs. 6-7 curves, scaled "
                         "with the parameter); the filter's model stays linear")
    add_track_input(ap)
    ap.add_argument("--dead", nargs="+", default=[], metavar="SENSOR",
                    help="sensors with no value at all (a dead node), e.g. acc_w1 acc_w2")
    add_filter_options(ap)
    args = ap.parse_args(argv)
    options = filter_options(ap, args)
    if args.hold_every_s is not None and not args.hold_every_s > args.hold_s > 0:
        ap.error(f"expected --hold-every-s > --hold-s > 0 s, got {args.hold_every_s} and "
                 f"{args.hold_s}")
    if not 0 < args.speed_mps <= 150:
        ap.error(f"expected 0 < --speed-mps <= 150 m/s, got {args.speed_mps}")
    if args.what in ("summary", "plot"):
        rows = [json.loads(line) for line in sys.stdin if line.strip()]
        if args.what == "plot":
            plot(rows, args.plot)
        for row in summary(rows) if args.what == "summary" else []:
            print(json.dumps(row))
        return 0
    record: dict[str, Any] = {"noise_scale": args.noise_scale, "hold_s": args.hold_s,
                              "dead": args.dead, "speed_mps": args.speed_mps,
                              "nonlinear": args.nonlinear_dampers,
                              "track_input": args.track_input}
    for seed in args.seeds:
        for ns in args.sensors:
            if args.what == "nominal":
                rows = [nominal_row(ns, seed, seconds=args.seconds or 600.0, options=options,
                                    hold_every_s=args.hold_every_s, **record)]
            else:
                rows = [fault_row(p, f, ns, seed, seconds=args.seconds or 18.0,
                                  fault_at_s=args.fault_at, options=options,
                                  hold_at_s=args.hold_at_s, **record)
                        for p, f in args.cases]
            for row in rows:
                emit(row)
    return 0


if __name__ == "__main__":
    sys.exit(main())
