"""Oracle change detection: how soon the data alone allow a fault to be detected (issue 15).

For a record of the detection study (:func:`firmware_sim.studies.detection.fault_data`,
same data seeds), exact Kalman filters of the *true* model: one of the pre-fault theta
over the whole record and, from the known fault instant, one per hypothesis (the faulty
parameter times a factor), each started from the pre-fault filter's state and
covariance. The log-likelihood ratio of a hypothesis to the pre-fault model, summed from
the fault, is what a CUSUM that knew the change time and the new value would accumulate.
Its first crossing of ``h`` nats is the reference for the fault bank's CUSUM crossing
(``confirmed_s`` less ``confirm_s`` in the detection study's rows) at the same threshold.
It is not a strict bound: a CUSUM can cross earlier than the oracle by chance.

The filters are textbook numpy (17 physical states, Joseph-form update, the truth's
sensor-noise variances times ``noise_scale``²), independent of the estimator's kernels.

``--against F`` sums the ratio against the model with the faulty parameter at ``F`` times
its old value instead (from the same state): with the true factor as the hypothesis and
an alert threshold as ``F``, the first crossing of ``h / 2`` is how soon the data alone
allow the alert's decision (the value is past the threshold) at the bank's Wald level.

``python -m firmware_sim.studies.oracle --cases csy:0.5 --sensors 3 --seeds 91 92
--noise-scale 2 --hypotheses 0.4 0.5 0.6`` prints one JSON line per record and hypothesis.
A measuring tool, not used by the service.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from typing import Any

import numpy as np

from firmware_sim.studies.arguments import fault_case
from firmware_sim.studies.detection import fault_data
from firmware_sim.studies.filtering import FS_HZ, V_MPS
from firmware_sim.studies.rows import emit
from firmware_sim.truth import SENSOR_NOISE_VAR
from gateway.estimator.faultbank import FaultBankConfig
from gateway.model.vehicle import (
    AR_PAPER_DEFAULT,
    PARAM_NAMES,
    VehicleParams,
    discretize,
    input_matrix,
    output_matrix,
    sensor_set,
    system_matrix,
    track_intensity,
)

H_NATS = FaultBankConfig.h_nats
"""The fault bank's default CUSUM threshold, nats."""
P0_SCALE = 1e3
"""The pre-fault filter starts at x = 0 with this multiple of one sample's Qd."""


def model(theta: np.ndarray, sensors: tuple[str, ...], noise_scale: float,
          speed_mps: float = V_MPS) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Phi, Qd (17, 17), H (ny, 17) and the sensor-noise variances (ny,) of the truth at
    ``theta`` (3,), ``speed_mps`` and the study's rate."""
    A = system_matrix(VehicleParams(), theta, speed_mps)
    d = discretize(A, input_matrix(), track_intensity(AR_PAPER_DEFAULT, speed_mps),
                   1.0 / FS_HZ)
    r = np.array([SENSOR_NOISE_VAR[s] for s in sensors]) * noise_scale**2
    return d.phi, d.qd, output_matrix(A, sensors), r


def exact_filter(phi: np.ndarray, qd: np.ndarray, H: np.ndarray, r: np.ndarray,
                 x: np.ndarray, P: np.ndarray, Y: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The exact filter over ``Y (T, ny)`` from ``x (17,)``, ``P (17, 17)``: the final
    state and covariance, and each sample's predictive log-likelihood (T,), nats."""
    R = np.diag(r)
    eye = np.eye(len(x))
    ll = np.empty(len(Y))
    for k, y in enumerate(Y):
        x = phi @ x
        P = phi @ P @ phi.T + qd
        S = H @ P @ H.T + R
        e = y - H @ x
        K = np.linalg.solve(S, H @ P).T
        x = x + K @ e
        IKH = eye - K @ H
        P = IKH @ P @ IKH.T + K @ R @ K.T
        P = 0.5 * (P + P.T)
        ll[k] = -0.5 * (np.linalg.slogdet(2 * np.pi * S)[1] + e @ np.linalg.solve(S, e))
    return x, P, ll


def oracle_rows(parameter: int, factor: float, sensors: int, seed: int, *,
                hypotheses: Sequence[float], fault_at_s: float, after_s: float,
                noise_scale: float = 1.0, h_nats: float = H_NATS,
                speed_mps: float = V_MPS, against: float = 1.0) -> list[dict[str, Any]]:
    """One row per hypothesis: ``cross_s`` (first time after the fault at which the
    summed log-likelihood ratio to the model at ``against`` times the old value (1: the
    pre-fault model) exceeds ``h_nats``; None: not within ``after_s``), ``llr_1s`` and
    ``llr_end`` (the sum 1 s and ``after_s`` after the fault, nats)."""
    th, Y = fault_data(parameter, factor, sensors, seed, fault_at_s + after_s, fault_at_s,
                       noise_scale, speed_mps)
    names = sensor_set(sensors)
    k0 = int(round(fault_at_s * FS_HZ))
    phi, qd, H, r = model(th[0], names, noise_scale, speed_mps)
    x, P, _ = exact_filter(phi, qd, H, r, np.zeros(len(phi)), qd * P0_SCALE, Y[:k0])
    base = th[0].copy()
    base[parameter] *= against
    _, _, ll_pre = exact_filter(*model(base, names, noise_scale, speed_mps), x, P, Y[k0:])
    rows = []
    for f in hypotheses:
        theta = th[0].copy()
        theta[parameter] *= f
        _, _, ll = exact_filter(*model(theta, names, noise_scale, speed_mps), x, P, Y[k0:])
        llr = np.cumsum(ll - ll_pre)
        over = np.nonzero(llr > h_nats)[0]
        n1 = min(len(llr), int(round(FS_HZ))) - 1
        rows.append({"what": "oracle", "parameter": PARAM_NAMES[parameter], "factor": factor,
                     "hypothesis": f, "against": against, "sensors": sensors,
                     "speed_mps": speed_mps, "seed": seed,
                     "noise_scale": noise_scale, "fault_at_s": fault_at_s, "h_nats": h_nats,
                     "cross_s": float((over[0] + 1) / FS_HZ) if len(over) else None,
                     "llr_1s": float(llr[n1]), "llr_end": float(llr[-1]),
                     "after_s": after_s})
    return rows


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m firmware_sim.studies.oracle",
                                 description=__doc__.split("\n")[0])
    ap.add_argument("--cases", type=fault_case, nargs="+", default=[(0, 0.5)],
                    metavar="PARAMETER:FACTOR", help="the faults (default: csy:0.5)")
    ap.add_argument("--hypotheses", type=float, nargs="+", default=None,
                    help="factors of the post-fault filters (default: each case's own)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--sensors", type=int, nargs="+", default=[3, 5])
    ap.add_argument("--noise-scale", type=float, default=1.0,
                    help="sensor noise std of the data relative to the model's")
    ap.add_argument("--fault-at", type=float, default=8.0)
    ap.add_argument("--after", type=float, default=4.0,
                    help="seconds of data after the fault (4)")
    ap.add_argument("--h-nats", type=float, default=H_NATS)
    ap.add_argument("--against", type=float, default=1.0,
                    help="the factor of the model the ratios are summed against (1: the "
                         "pre-fault model)")
    ap.add_argument("--speed-mps", type=float, default=V_MPS,
                    help="the vehicle's constant speed, m/s (default: the paper's 42.5)")
    args = ap.parse_args(argv)
    if not 0 < args.speed_mps <= 150:
        ap.error(f"expected 0 < --speed-mps <= 150 m/s, got {args.speed_mps}")
    if not (args.fault_at > 0 and args.after > 0 and args.h_nats > 0
            and args.noise_scale > 0):
        ap.error(f"expected --fault-at, --after, --h-nats and --noise-scale > 0, got "
                 f"{args.fault_at}, {args.after}, {args.h_nats}, {args.noise_scale}")
    if not args.against > 0:
        ap.error(f"expected --against > 0, got {args.against}")
    if args.hypotheses is not None and not all(f > 0 for f in args.hypotheses):
        ap.error(f"expected positive --hypotheses, got {args.hypotheses}")
    for seed in args.seeds:
        for ns in args.sensors:
            for p, f in args.cases:
                for row in oracle_rows(p, f, ns, seed, hypotheses=args.hypotheses or [f],
                                       fault_at_s=args.fault_at, after_s=args.after,
                                       noise_scale=args.noise_scale, h_nats=args.h_nats,
                                       speed_mps=args.speed_mps, against=args.against):
                    emit(row)
    return 0


if __name__ == "__main__":
    sys.exit(main())
