"""Exact-posterior study: the static-theta posterior on a grid around the truth (a measuring tool).

Issue 15 asks whether the filter's stated sigma is honest, checked "against the exact
grid posterior". On the calibration study's records
(:func:`firmware_sim.studies.calibration.record`: the paper's Sec. 4.2 point, 42.5 m/s,
data seed ``3000 + seed``, so rows pair with that study's), this study weighs a
``points``^3 grid of theta values, ``truth * exp(u)``
with ``u`` evenly spaced over ``[-half_log, +half_log]`` per parameter, by the exact
log-likelihood of the record: one Kalman filter per grid point
(:class:`gateway.estimator.rbpf.RBPF` with ``resample=False``, no monitor, no fault
bank, no start ramp, the model's sensor noise, fast mode: the exact recursion for the
first 2 s, then the steady gains, which equal the exact filter's once P has converged,
``tests/test_fast_mode.py``). The prior is flat in log theta over the window (the
filter's prior box is far wider than any 5 s posterior). A window of about six
posterior sigma each way holds the posterior: each row reports the mass on the window's
faces, so a truncated posterior shows.

Rows (JSON lines): the posterior mean and sd of theta, the truth's z, and ``below``,
the marginal posterior probability that each parameter lies below the truth (the truth
is inside the central 95 % interval when it is in (0.025, 0.975)). ``summary`` gives per
(sensors, start, time) the share within 2 sd and within the central 95 % interval, and
the largest |z|. This is the reference for the filter's stated sigma: if the exact
posterior covers the truth in 95 % of records and the filter does not, the filter's
approximation is the cause; if neither does, the record's information is. Not used by
the service.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from firmware_sim.studies.calibration import SEED_OFFSET, record
from firmware_sim.studies.filtering import FS_HZ, V_MPS, run
from firmware_sim.studies.rows import emit
from gateway.estimator.rbpf import RBPF
from gateway.estimator.rbpf_config import RBPFConfig
from gateway.model.vehicle import PARAM_NAMES, THETA_SEC42

HALF_LOG_5S: dict[int, tuple[float, float, float]] = {3: (0.20, 0.16, 0.13),
                                                       5: (0.12, 0.07, 0.10)}
"""Default window half-widths in log units at 5 s: about six of the filter's median
stated sigma per parameter (3 sensors 3.2 / 2.6 / 2.1 %, 5 sensors 1.8 / 1.0 / 1.6 %);
scale by sqrt(5 s / t) for other times (:func:`half_log_for`)."""
WIDEN_BELOW_40_MPS = 1.3
"""Below 40 m/s the posterior is wider than HALF_LOG_5S assumes (measured: the faces
held less than 1e-5 of the mass at 30 m/s with this widening)."""


def half_log_for(sensors: int, at_s: float, speed_mps: float = V_MPS) -> list[float]:
    """The default window half-widths (3,) in log units for a record of ``at_s``
    seconds at ``speed_mps``."""
    half = np.array(HALF_LOG_5S[sensors]) * np.sqrt(5.0 / at_s)
    return (half * WIDEN_BELOW_40_MPS if speed_mps < 40.0 else half).tolist()


@dataclass(frozen=True)
class GridPosterior:
    """The exact posterior on the grid: mean and sd of theta (3,), SI; ``below`` (3,):
    the marginal probability of each parameter below ``centre``; ``face_mass`` (3,): the
    marginal mass on the two outermost grid values of each parameter."""

    mean: np.ndarray
    std: np.ndarray
    below: np.ndarray
    face_mass: np.ndarray


def grid_posterior(Y: np.ndarray, sensors: int, centre: np.ndarray,
                   half_log: Sequence[float], points: int,
                   speed_mps: float = V_MPS) -> GridPosterior:
    """Weigh the grid ``centre * exp(u)`` (``points``^3 values, ``u`` evenly over
    ``[-half_log, half_log]``, (3,) in log units; ``points`` even, so ``centre`` lies
    between the two middle values) by the exact log-likelihood of ``Y`` (T, ny) at 1 kHz
    and ``speed_mps``."""
    if points < 2 or points % 2:
        raise ValueError(f"expected an even number of grid points >= 2, got {points}")
    centre = np.asarray(centre, dtype=float)
    axes = [np.linspace(-h, h, points) for h in half_log]
    u = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    theta = centre * np.exp(u)
    cfg = RBPFConfig(fs_hz=FS_HZ, n_particles=len(theta), sensors=sensors, mode="fast",
                     resample=False, monitor=None, faults=None, start_ramp_s=0.0, seed=0)
    filt = RBPF(cfg)
    filt.set_particles(theta)
    run(Y, filt, speed_mps=speed_mps)
    w = np.exp(filt.logw - filt.logw.max())
    w /= w.sum()
    mean = w @ theta
    std = np.sqrt(w @ np.square(theta - mean))
    cube = w.reshape((points,) * 3)
    below, face = np.empty(3), np.empty(3)
    for j in range(3):
        marginal = cube.sum(axis=tuple(k for k in range(3) if k != j))
        below[j] = marginal[: points // 2].sum()
        face[j] = marginal[0] + marginal[-1]
    return GridPosterior(mean, std, below, face)


def row_for(seed: int, sensors: int, at_s: float, from_rest: bool,
            half_log: Sequence[float], points: int) -> dict[str, Any]:
    """One record of the calibration study's paper scenario: its exact grid posterior."""
    theta = THETA_SEC42.as_array()
    Y = record(theta, sensors, SEED_OFFSET["paper"] + seed, at_s, from_rest)
    post = grid_posterior(Y, sensors, theta, half_log, points)
    return {"study": "grid", "sensors": sensors, "seed": seed, "t_s": at_s,
            "from_rest": from_rest, "points": points, "half_log": list(half_log),
            "truth": theta.tolist(), "mean": post.mean.tolist(), "std": post.std.tolist(),
            "z": np.round((post.mean - theta) / post.std, 3).tolist(),
            "below": np.round(post.below, 4).tolist(),
            "face_mass": [float(f"{f:.3g}") for f in post.face_mass]}


def summary(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per (sensors, from_rest, t_s): records; per parameter the share within 2 sd, the
    share inside the central 95 % interval, the largest |z| and the largest face mass."""
    def key_of(r: dict[str, Any]) -> tuple[int, bool, float]:
        return r["sensors"], bool(r["from_rest"]), float(r["t_s"])

    out = []
    for key in sorted({key_of(r) for r in rows}):
        case = [r for r in rows if key_of(r) == key]
        z = np.abs(np.array([r["z"] for r in case]))
        below = np.array([r["below"] for r in case])
        face = np.array([r["face_mass"] for r in case])
        row: dict[str, Any] = {"sensors": key[0], "from_rest": key[1], "t_s": key[2],
                               "records": len(case)}
        for i, name in enumerate(PARAM_NAMES):
            row[f"{name}_within_2sd"] = round(float(np.mean(z[:, i] <= 2.0)), 3)
            row[f"{name}_within_95"] = round(float(np.mean(
                (below[:, i] > 0.025) & (below[:, i] < 0.975))), 3)
            row[f"{name}_max_abs_z"] = round(float(z[:, i].max()), 2)
            row[f"{name}_max_face_mass"] = float(f"{face[:, i].max():.3g}")
        out.append(row)
    return out


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m firmware_sim.studies.grid_posterior",
                                 description=__doc__.split("\n")[0])
    ap.add_argument("what", choices=("run", "summary"),
                    help="summary: read the rows (JSON lines) from stdin")
    ap.add_argument("--seeds", type=int, nargs="+", default=list(range(101, 141)))
    ap.add_argument("--sensors", type=int, choices=(3, 5), default=3)
    ap.add_argument("--at-s", type=float, default=5.0, help="record length, s")
    ap.add_argument("--from-rest", action="store_true",
                    help="the truth starts at rest (default: in stationary vibration)")
    ap.add_argument("--half-log", type=float, nargs=3, default=None,
                    help="window half-widths in log units (default: HALF_LOG_5S scaled "
                    "by sqrt(5 s / at_s))")
    ap.add_argument("--points", type=int, default=24, help="grid values per parameter")
    args = ap.parse_args(argv)
    if args.points < 2 or args.points % 2:
        ap.error(f"expected an even --points >= 2 (the truth sits between the two middle "
                 f"values), got {args.points}")
    if not args.at_s > 0:
        ap.error(f"expected --at-s > 0 s, got {args.at_s}")
    if args.half_log is not None and not all(h > 0 for h in args.half_log):
        ap.error(f"expected three positive --half-log values, got {args.half_log}")
    if args.what == "summary":
        for row in summary([json.loads(line) for line in sys.stdin if line.strip()]):
            print(json.dumps(row))
        return 0
    half = args.half_log or half_log_for(args.sensors, args.at_s)
    for seed in args.seeds:
        emit(row_for(seed, args.sensors, args.at_s, args.from_rest, half,
                     args.points))
    return 0


if __name__ == "__main__":
    sys.exit(main())
