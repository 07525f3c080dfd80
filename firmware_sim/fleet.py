"""A simulated fleet: N vehicles x D days x a few short runs a day, as CAN logs plus their truth.

Each run is a short log of one bogie's sensor nodes (the ``Simulation`` of any
scenario), stamped with Unix-epoch times so the fleet tool can date it, written to
``logs/<vehicle>/<bogie>/<YYYY-MM-DDTHHMMSS>.log``. Vehicles run at different speeds.
Within a run theta is constant; across days it follows the vehicle's role:

- ``csy-failing``: the lateral damper fails abruptly (Csy x0.25) at midnight before day
  ``fail_frac x days``;
- ``csy-degrading`` / ``csay-degrading``: that damper loses 30 % over ``degrade_days``;
- ``wheel-wear``: conicity doubles over ``degrade_days`` (worn wheels);
- ``nominal``; every vehicle's conicity also rises 10 % over ``degrade_days`` (wear).

``truth.csv`` lists every run with its true theta; ``truth.json`` per vehicle and bogie
the role and, per parameter and alert level (the gateway's own thresholds), the true
time the parameter first crosses it (Unix s) or null.
"""

from __future__ import annotations

import csv
import datetime as dt
import json
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from firmware_sim.output import write_log
from firmware_sim.scenarios import NOM, Scenario
from firmware_sim.simulation import SimConfig, Simulation
from gateway.alerts.policy import default_params
from gateway.errors import InputError
from gateway.model.vehicle import PARAM_NAMES

DAY_S = 86_400.0
SPEEDS_MPS = (25.0, 32.0, 38.0, 42.5, 50.0)
ROLES = ("csy-failing", "csy-degrading", "csay-degrading", "wheel-wear")
LEVELS = ("advisory", "warning", "alarm")


@dataclass(frozen=True)
class FleetSpec:
    """The fleet to simulate; ``start`` is the first day (UTC, ISO date)."""

    vehicles: int = 12
    days: int = 30
    runs_per_day: int = 2
    run_s: float = 8.0
    bogies: int = 1
    degrade_days: float = 60.0
    fail_frac: float = 0.5
    seed: int = 0
    start: str = "2026-01-05"

    def __post_init__(self) -> None:
        checks = ((1 <= self.vehicles <= 1000, "vehicles in [1, 1000]", self.vehicles),
                  (1 <= self.days <= 3650, "days in [1, 3650]", self.days),
                  (1 <= self.runs_per_day <= 24, "runs_per_day in [1, 24]", self.runs_per_day),
                  (2.0 <= self.run_s <= 3600.0, "run_s in [2, 3600]", self.run_s),
                  (1 <= self.bogies <= 4, "bogies in [1, 4]", self.bogies),
                  (1.0 <= self.degrade_days <= 3650.0, "degrade_days in [1, 3650]",
                   self.degrade_days),
                  (0.0 < self.fail_frac < 1.0, "fail_frac in (0, 1)", self.fail_frac))
        for ok, what, got in checks:
            if not ok:
                raise InputError(f"expected {what}, got {got!r}")
        try:
            dt.date.fromisoformat(self.start)
        except ValueError:
            raise InputError(f"expected --start as YYYY-MM-DD, got {self.start!r}") from None

    @property
    def t_start_s(self) -> float:
        """Midnight UTC of the first day, Unix s."""
        d = dt.date.fromisoformat(self.start)
        return dt.datetime(d.year, d.month, d.day, tzinfo=dt.UTC).timestamp()

    @property
    def fail_day(self) -> int:
        return max(1, round(self.fail_frac * self.days))


def vehicle_names(n: int) -> list[str]:
    return [f"V{k + 1:02d}" for k in range(n)]


def roles(n: int) -> dict[str, str]:
    """Role by vehicle: the special roles spread over the fleet (not the first names)."""
    names = vehicle_names(n)
    out = dict.fromkeys(names, "nominal")
    for role, k in zip(ROLES, (n // 2, n - 1, 1, n // 2 + 1), strict=True):
        if 0 < k < n and out[names[k]] == "nominal":
            out[names[k]] = role
    return out


def trajectory(role: str, spec: FleetSpec) -> Callable[[np.ndarray], np.ndarray]:
    """theta relative to nominal at days since the start, (T,) -> (T, 3)."""
    span = spec.degrade_days

    def rel(days: np.ndarray) -> np.ndarray:
        d = np.asarray(days, dtype=float)
        out = np.ones((len(d), 3))
        out[:, 2] = 1.0 + 0.1 * d / span
        if role == "csy-failing":
            out[:, 0] = np.where(d >= spec.fail_day, 0.25, 1.0)
        elif role == "csy-degrading":
            out[:, 0] = 1.0 - 0.3 * d / span
        elif role == "csay-degrading":
            out[:, 1] = 1.0 - 0.3 * d / span
        elif role == "wheel-wear":
            out[:, 2] = 1.0 + 1.0 * d / span
        return out

    return rel


def crossings(rel: Callable[[np.ndarray], np.ndarray], spec: FleetSpec,
              horizon_days: float) -> dict[str, dict[str, float | None]]:
    """True first crossing (Unix s) of every alert level, per parameter; None if none
    within ``horizon_days`` (found on a 1-minute grid)."""
    days = np.arange(0.0, horizon_days, 60.0 / DAY_S)
    r = rel(days)
    out: dict[str, dict[str, float | None]] = {}
    for j, name in enumerate(PARAM_NAMES):
        pol = default_params()[name]
        out[name] = {}
        for side in ("low", "high"):
            for level, thr in zip(LEVELS, pol.levels(side), strict=True):
                if thr is None:
                    continue
                hit = np.flatnonzero(r[:, j] <= thr if side == "low" else r[:, j] >= thr)
                out[name][level] = (spec.t_start_s + days[hit[0]] * DAY_S) if len(hit) else None
    return out


@dataclass(frozen=True)
class RunPlan:
    vehicle: str
    bogie: str
    role: str
    t0_s: float
    speed_mps: float
    theta: tuple[float, float, float]
    seed: int

    @property
    def file(self) -> str:
        stamp = dt.datetime.fromtimestamp(self.t0_s, dt.UTC).strftime("%Y-%m-%dT%H%M%S")
        return f"logs/{self.vehicle}/{self.bogie}/{stamp}.log"


def plan(spec: FleetSpec) -> Iterator[RunPlan]:
    """Every run of the fleet, in order; reproducible from ``spec.seed``."""
    rng = np.random.default_rng(spec.seed)
    for k, (vehicle, role) in enumerate(roles(spec.vehicles).items()):
        speed_base = SPEEDS_MPS[k % len(SPEEDS_MPS)]
        for b in range(spec.bogies):
            bogie_role = role if b == 0 else "nominal"
            rel = trajectory(bogie_role, spec)
            for day in range(spec.days):
                for r in range(spec.runs_per_day):
                    hour = 6.0 + r * 14.0 / spec.runs_per_day + rng.uniform(0.0, 1.0)
                    days = day + hour / 24.0
                    theta = NOM * rel(np.array([days]))[0]
                    speed = float(np.clip(speed_base + rng.normal(0.0, 3.0), 20.0, 60.0))
                    yield RunPlan(vehicle, f"B{b + 1}", bogie_role,
                                  round(spec.t_start_s + days * DAY_S, 3), round(speed, 2),
                                  (float(theta[0]), float(theta[1]), float(theta[2])),
                                  int(rng.integers(0, 2**32 - 1)))


def simulate_run(p: RunPlan, spec: FleetSpec, out_dir: Path) -> int:
    """Write one run's log; returns its frame count."""
    theta = np.array(p.theta)
    scenario = Scenario(f"fleet-{p.role}", "fleet run", spec.run_s,
                        lambda f: np.tile(theta, (len(f), 1)),
                        lambda f: np.full(len(f), p.speed_mps))
    sim = Simulation(scenario, SimConfig(duration_s=spec.run_s, seed=p.seed, t0_s=p.t0_s))
    path = out_dir / p.file
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_log(sim.messages(), path)


def simulate_fleet(spec: FleetSpec, out_dir: str | Path,
                   progress: Callable[[int, int], None] | None = None) -> int:
    """Write every log, ``truth.csv`` and ``truth.json``; returns the number of runs."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    runs = list(plan(spec))
    with open(out / "truth.csv", "w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(["vehicle", "bogie", "role", "t0_s", "speed_mps", *PARAM_NAMES, "file"])
        for k, p in enumerate(runs):
            simulate_run(p, spec, out)
            w.writerow([p.vehicle, p.bogie, p.role, f"{p.t0_s:.3f}", p.speed_mps,
                        *(f"{x:.6g}" for x in p.theta), p.file])
            if progress is not None:
                progress(k + 1, len(runs))
    units = {f"{p.vehicle}/{p.bogie}": p.role for p in runs}
    truth = {"spec": asdict(spec), "units": {
        key: {"role": role, "crossings": crossings(trajectory(role, spec), spec,
                                                   5.0 * max(spec.degrade_days, spec.days))}
        for key, role in units.items()}}
    (out / "truth.json").write_text(json.dumps(truth, indent=1, sort_keys=True) + "\n",
                                    encoding="utf-8")
    return len(runs)
