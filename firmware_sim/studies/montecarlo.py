"""Monte Carlo error study: how far apart the filter lands on one record with other seeds.

The stated sigma is the particle cloud's spread: the posterior's width as the filter
sees it. It does not contain the filter's own Monte Carlo error, the spread of its
estimate between runs on the same data with other random draws. This study measures
that error: it runs the service's filter
(:func:`firmware_sim.studies.filtering.service_filter`) on one record of the
calibration study's paper scenario (:func:`firmware_sim.studies.calibration.record`,
data seed ``3000 + seed``) with ``--filter-seeds`` seeds, and weighs the same record on
the exact grid posterior (:func:`firmware_sim.studies.grid_posterior.grid_posterior`,
the reference without Monte Carlo error).

``python -m firmware_sim.studies.montecarlo run --seeds 1301 1302 --sensors 3
--speed-mps 30 --kernel-delta 0.99 0.999`` gives one JSON line per record, sensor set
and delta: per parameter the mean estimate and the spread between filter seeds, both
relative to the mean stated sigma (``mc_over_sigma``), the stated sigma over the grid
posterior's sd (``sigma_over_grid``), and the mean estimate's offset from the grid
posterior's mean in its sd (``offset_over_grid``), and the stated sigma over the total
error a run's estimate carries about the truth, the posterior's sd and the Monte Carlo
error together (``sigma_over_total``, :func:`sigma_over_total`: 1 or more where the
stated sigma covers both). ``summary < rows.jsonl`` averages them per (sensors, speed,
delta), with the smallest ``sigma_over_total``. Filter seed ``1000 * seed + k``
(k = 1 ..). ``--prior-edge 0.3 0.1`` runs each record with the prior box's damper edge
at each value (thirteenth session; default: the service's, ``prior_lo_for``). A
measuring tool, not used by the service.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from typing import Any

import numpy as np

from firmware_sim.studies.arguments import kernel_delta_arg
from firmware_sim.studies.calibration import SEED_OFFSET, record
from firmware_sim.studies.filtering import V_MPS, FilterOptions, run, service_filter
from firmware_sim.studies.grid_posterior import grid_posterior, half_log_for
from firmware_sim.studies.rows import emit
from gateway.estimator.rbpf_config import PAPER_PRIOR_LO
from gateway.model.vehicle import PARAM_NAMES, THETA_SEC42

GRID_POINTS = 16
"""Grid values per parameter (16^3 filters: a few seconds per 5 s record)."""


def sigma_over_total(row: dict[str, Any]) -> np.ndarray:
    """The stated sigma over ``sqrt(grid_sd**2 + mc_sd**2)``, per parameter, shape (3,).

    A run's estimate differs from the truth by the posterior's spread (the grid's sd, over
    realisations of the data) plus its own Monte Carlo error (the spread between filter
    seeds, independent of the data's noise), so its error sd is about the root sum of
    squares. Computed from a row's ``sigma``, ``grid_sd`` and ``mc_sd``, so rows written
    before this column existed give it too."""
    return np.array(row["sigma"]) / np.hypot(np.array(row["grid_sd"]), np.array(row["mc_sd"]))


def row_for(seed: int, sensors: int, at_s: float, speed_mps: float, delta: float,
            filter_seeds: int, particles: int,
            prior_edge: float | None = None,
            fast_warmup_s: float | None = None) -> dict[str, Any]:
    """One record: the service's filter with ``filter_seeds`` seeds and the exact grid
    posterior, read at the record's end ``at_s``; ``prior_edge``: the prior box's lower
    edge for both dampers, x nominal (None: the service's); ``fast_warmup_s``: fast
    mode's warm-up, s (None: the filter's)."""
    theta = THETA_SEC42.as_array()
    Y = record(theta, sensors, SEED_OFFSET["paper"] + seed, at_s, speed_mps=speed_mps)
    ends = []
    for k in range(1, filter_seeds + 1):
        filt = service_filter(sensors, 1000 * seed + k, FilterOptions(
            particles=particles, kernel_delta=delta, fast_warmup_s=fast_warmup_s,
            prior_lo=None if prior_edge is None else (prior_edge, prior_edge,
                                                      PAPER_PRIOR_LO[2])))
        est, _, _ = run(Y, filt, speed_mps=speed_mps)
        ends.append((np.array(est[-1].mean[:3]), np.array(est[-1].std[:3])))
        ran = filt.config.delta                     # 0 (auto) resolved for this m
        edge = filt.config.prior_lo[0]
    means = np.array([m for m, _ in ends])          # (filter_seeds, 3)
    sigma = np.array([s for _, s in ends]).mean(0)
    grid = grid_posterior(Y, sensors, theta, half_log_for(sensors, at_s, speed_mps),
                          GRID_POINTS, speed_mps)
    mc = means.std(0, ddof=1)
    offset = (means.mean(0) - grid.mean) / grid.std
    row: dict[str, Any] = {
        "study": "montecarlo", "seed": seed, "sensors": sensors, "t_s": at_s,
        "speed_mps": speed_mps, "kernel_delta": ran, "particles": particles,
        "prior_damper_edge": edge, "filter_seeds": filter_seeds, "truth": theta.tolist(),
        "mean": means.mean(0).tolist(), "sigma": sigma.tolist(), "mc_sd": mc.tolist(),
        "grid_mean": grid.mean.tolist(), "grid_sd": grid.std.tolist(),
        "grid_face_mass": [float(f"{f:.3g}") for f in grid.face_mass],
        "mc_over_sigma": np.round(mc / sigma, 3).tolist(),
        "sigma_over_grid": np.round(sigma / grid.std, 3).tolist(),
        "offset_over_grid": np.round(offset, 3).tolist()}
    row["sigma_over_total"] = np.round(sigma_over_total(row), 3).tolist()
    return row


def summary(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per (sensors, speed, delta, particles, the prior's damper edge): records, and per
    parameter the mean of
    ``mc_over_sigma``, ``sigma_over_grid``, ``offset_over_grid`` and ``sigma_over_total``
    over the records, and the smallest ``sigma_over_total`` (``..._min``)."""
    def key_of(r: dict[str, Any]) -> tuple[int, float, float, int, float]:
        return (r["sensors"], float(r["speed_mps"]), float(r["kernel_delta"]),
                int(r.get("particles", 1000)), float(r.get("prior_damper_edge", 0.3)))

    out = []
    for key in sorted({key_of(r) for r in rows}):
        case = [r for r in rows if key_of(r) == key]
        row: dict[str, Any] = {"sensors": key[0], "speed_mps": key[1],
                               "kernel_delta": key[2], "particles": key[3],
                               "prior_damper_edge": key[4], "records": len(case)}
        for col in ("mc_over_sigma", "sigma_over_grid", "offset_over_grid"):
            values = np.array([r[col] for r in case])
            for i, name in enumerate(PARAM_NAMES):
                row[f"{name}_{col}"] = round(float(values[:, i].mean()), 3)
        total = np.array([sigma_over_total(r) for r in case])     # (records, 3)
        for i, name in enumerate(PARAM_NAMES):
            row[f"{name}_sigma_over_total"] = round(float(total[:, i].mean()), 3)
            row[f"{name}_sigma_over_total_min"] = round(float(total[:, i].min()), 3)
        out.append(row)
    return out


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m firmware_sim.studies.montecarlo",
                                 description=__doc__.split("\n")[0])
    ap.add_argument("what", choices=("run", "summary"),
                    help="summary: read the rows (JSON lines) from stdin")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1301, 1302, 1303])
    ap.add_argument("--sensors", type=int, nargs="+", choices=(3, 5), default=[3])
    ap.add_argument("--speed-mps", type=float, default=V_MPS,
                    help="the vehicle's constant speed, m/s (default: the paper's 42.5)")
    ap.add_argument("--at-s", type=float, default=5.0, help="record length, s")
    ap.add_argument("--kernel-delta", type=kernel_delta_arg, nargs="+",
                    default=[0.99, 0.999],
                    help="the service's [estimator] kernel_delta values to compare "
                         "(default: the paper's 0.99 and auto's 0.999)")
    ap.add_argument("--filter-seeds", type=int, default=6,
                    help="filter runs per record and delta (at least 2)")
    ap.add_argument("--particles", type=int, default=1000)
    ap.add_argument("--prior-edge", type=float, nargs="+", default=[None],
                    help="the prior box's lower edge for both dampers, x nominal, one run "
                         "per value (default: the service's)")
    args = ap.parse_args(argv)
    if args.what == "summary":
        for row in summary([json.loads(line) for line in sys.stdin if line.strip()]):
            print(json.dumps(row))
        return 0
    if args.filter_seeds < 2:
        ap.error(f"expected --filter-seeds >= 2 (a spread needs two runs), got "
                 f"{args.filter_seeds}")
    if not 0 < args.speed_mps <= 150:
        ap.error(f"expected 0 < --speed-mps <= 150 m/s, got {args.speed_mps}")
    if not args.at_s > 0:
        ap.error(f"expected --at-s > 0 s, got {args.at_s}")
    for seed in args.seeds:
        for ns in args.sensors:
            for delta in args.kernel_delta:
                for edge in args.prior_edge:
                    emit(row_for(seed, ns, args.at_s, args.speed_mps, delta,
                                 args.filter_seeds, args.particles, edge))
    return 0


if __name__ == "__main__":
    sys.exit(main())
