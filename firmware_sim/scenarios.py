"""Named test scenarios: the truth's theta(t) and v(t), and the sensor faults to inject.

Times are relative to the start of the run and scale with its duration, so every
scenario works for a short test and for a long demo. theta(t) changes in 0.1 s steps,
so the truth's exact discretisation is recomputed at most ten times a second.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from gateway.errors import InputError
from gateway.model.vehicle import THETA_NOMINAL, THETA_SEC42

FAULT_KINDS = ("stuck", "dropout", "noise_burst", "frozen_counter", "bad_crc", "out_of_order")
"""What a fault does to a node's frames inside its window:

- ``stuck``: every signal repeats its value at the window start (counter, CRC valid);
- ``dropout``: the node sends nothing (counters keep counting inside the node);
- ``noise_burst``: noise 20x its normal standard deviation;
- ``frozen_counter``: the alive counter stops changing (CRC still valid);
- ``bad_crc``: the CRC byte is corrupted on every frame;
- ``out_of_order``: consecutive frames of the node swap places on the bus.
"""


@dataclass(frozen=True)
class Fault:
    """A sensor fault on one node over a fraction [start, stop) of the run."""

    kind: str
    node: str
    start_frac: float
    stop_frac: float


@dataclass(frozen=True)
class Scenario:
    """A named run: theta(t) (T, 3), speed(t) (T,), faults; ``t_frac`` is t / duration."""

    name: str
    description: str
    default_duration_s: float
    theta_at: Callable[[np.ndarray], np.ndarray]
    speed_at: Callable[[np.ndarray], np.ndarray]
    faults: tuple[Fault, ...] = ()

    def theta(self, t_s: np.ndarray, duration_s: float) -> np.ndarray:
        """theta at times t_s (quantised to 0.1 s), shape (T, 3)."""
        tq = np.floor(np.asarray(t_s) * 10.0) / 10.0
        return self.theta_at(tq / duration_s)

    def speed(self, t_s: np.ndarray, duration_s: float) -> np.ndarray:
        """Speed in m/s at times t_s (quantised to 0.1 s), shape (T,)."""
        tq = np.floor(np.asarray(t_s) * 10.0) / 10.0
        return self.speed_at(tq / duration_s)


V_PAPER = 42.5
NOM = THETA_NOMINAL.as_array()


def _const(theta: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    return lambda f: np.tile(theta, (len(f), 1))


def _scaled(index: int, profile: Callable[[np.ndarray], np.ndarray]
            ) -> Callable[[np.ndarray], np.ndarray]:
    """Nominal theta with one component multiplied by profile(t / duration)."""
    def theta(f: np.ndarray) -> np.ndarray:
        out = np.tile(NOM, (len(f), 1))
        out[:, index] *= profile(f)
        return out
    return theta


def _ramp(f0: float, f1: float, r0: float, r1: float) -> Callable[[np.ndarray], np.ndarray]:
    return lambda f: np.interp(f, [f0, f1], [r0, r1])


def _step(f0: float, after: float) -> Callable[[np.ndarray], np.ndarray]:
    return lambda f: np.where(f >= f0, after, 1.0)


def _speed(v: float) -> Callable[[np.ndarray], np.ndarray]:
    return lambda f: np.full(len(f), v)


def _fault_scenario(kind: str, node: str) -> Scenario:
    return Scenario(kind.replace("_", "-"), f"nominal vehicle; {kind.replace('_', ' ')} on {node} "
                    "from 40 % to 60 % of the run", 30.0, _const(NOM), _speed(V_PAPER),
                    (Fault(kind, node, 0.4, 0.6),))


SCENARIOS: dict[str, Scenario] = {s.name: s for s in (
    Scenario("nominal", "Appendix nominal vehicle at 42.5 m/s", 60.0, _const(NOM), _speed(V_PAPER)),
    Scenario("paper", "the paper's Sec. 4.2 data: Csy 20 kNs/m, Csay 3000 kNs/m, conicity 0.15",
             5.0, _const(THETA_SEC42.as_array()), _speed(V_PAPER)),
    Scenario("lateral-degrading", "lateral damper Csy ramps from nominal to 40 % of nominal "
             "between 20 % and 80 % of the run", 120.0, _scaled(0, _ramp(0.2, 0.8, 1.0, 0.4)),
             _speed(V_PAPER)),
    Scenario("lateral-failing", "lateral damper fails at half-time: Csy steps 40 -> 10 kNs/m",
             60.0, _scaled(0, _step(0.5, 0.25)), _speed(V_PAPER)),
    Scenario("lateral-failing-accelerating", "lateral damper fails at half-time while the "
             "train accelerates from 25 to 40 m/s over the run (0.5 m/s2 over 30 s): Csy steps "
             "40 -> 10 kNs/m", 30.0, _scaled(0, _step(0.5, 0.25)),
             lambda f: 25.0 + 15.0 * np.asarray(f)),
    Scenario("antiyaw-failing", "anti-yaw dampers fail at half-time: Csay steps to 25 % of "
             "nominal", 60.0, _scaled(1, _step(0.5, 0.25)), _speed(V_PAPER)),
    Scenario("conicity-rising", "worn wheels: conicity ramps 0.15 -> 0.40 between 20 % and "
             "80 % of the run", 120.0, _scaled(2, _ramp(0.2, 0.8, 1.0, 0.4 / 0.15)),
             _speed(V_PAPER)),
    Scenario("speed-profile", "nominal vehicle; speed 20 -> 42.5 m/s, cruise, then down to "
             "30 m/s", 120.0, _const(NOM),
             lambda f: np.interp(f, [0.0, 0.3, 0.7, 1.0], [20.0, 42.5, 42.5, 30.0])),
    _fault_scenario("stuck", "BGN"),
    _fault_scenario("dropout", "BDN"),
    _fault_scenario("noise_burst", "BGN"),
    _fault_scenario("frozen_counter", "WSN"),
    _fault_scenario("bad_crc", "BGN"),
    _fault_scenario("out_of_order", "BDN"),
)}


def get_scenario(name: str) -> Scenario:
    """The scenario called ``name``; InputError naming the known ones otherwise."""
    try:
        return SCENARIOS[name]
    except KeyError:
        raise InputError(f"expected a scenario from {sorted(SCENARIOS)}, got {name!r}") from None
