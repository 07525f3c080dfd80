"""Ground truth: integrate the vehicle model, linear or with saturating dampers.

The linear truth is the exact discrete model (Phi = expm(A T), Van Loan Qd), so data
generated at the estimator's rate match the paper's Sec. 4.2 set-up. Time-varying
theta(t) and v(t) are piecewise constant per sample; the discretisation is recomputed
(and cached) whenever they change.

The track input is continuous white noise by default (``track_input="white"``). An
independent implementation could follow the paper's literal eqs. (6)-(7) instead: the
track velocities held constant over each sample and entering through the zero-order-hold
Gamma. ``track_input="held"`` is that convention, with each held value's variance Q / T,
so that the track's spectrum below the sample rate is the same (at 1 kHz: the paper's
Qw = Q T with Ar as printed, model notes section 5); the filter's model stays white.

Optional non-linear dampers (paper Figs. 6-7): the damper force-velocity curves are
bilinear, steep up to a knee velocity and then "blow-off" with a smaller slope. The
deviation from the linear damper enters as an input held over a sub-step of T/10.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
import scipy.linalg

from gateway.errors import InputError
from gateway.model.vehicle import (
    AR_PAPER_DEFAULT,
    IDX,
    NX,
    SENSOR_NOISE_VAR,
    SENSORS_5,
    VehicleParams,
    discretize,
    input_matrix,
    output_matrix,
    system_matrix,
    track_intensity,
)


@dataclass(frozen=True)
class DamperCurve:
    """Bilinear force-velocity curve relative to the linear coefficient C.

    ``F(u) = C u`` for ``|u| <= knee``, then slope ``blowoff_ratio * C``.
    """

    knee_mps: float
    blowoff_ratio: float


@numba.njit(cache=True)
def _inverse_deviation(force_n: float, c_ns_per_m: float, knee_mps: float,
                       blowoff_ratio: float) -> float:
    """Damper velocity for a force, minus the linear velocity F/C (m/s), on the curve
    (``knee_mps``, ``blowoff_ratio``) of :class:`DamperCurve`."""
    f_knee = c_ns_per_m * knee_mps
    if abs(force_n) <= f_knee:
        return 0.0
    u = np.sign(force_n) * (knee_mps + (abs(force_n) - f_knee) / (blowoff_ratio * c_ns_per_m))
    return u - force_n / c_ns_per_m


@numba.njit(cache=True)
def _force_deviation(u_mps: float, c_ns_per_m: float, knee_mps: float,
                     blowoff_ratio: float) -> float:
    """Damper force at velocity u, minus the linear force C u (N), on the curve
    (``knee_mps``, ``blowoff_ratio``) of :class:`DamperCurve`."""
    if abs(u_mps) <= knee_mps:
        return 0.0
    f = np.sign(u_mps) * c_ns_per_m * (knee_mps + blowoff_ratio * (abs(u_mps) - knee_mps))
    return f - c_ns_per_m * u_mps


LATERAL_DAMPER_CURVE = DamperCurve(knee_mps=0.1, blowoff_ratio=0.25)
"""Secondary lateral damper: 40 kNs/m to 0.1 m/s, then about 8 kN at 0.5 m/s (Fig. 6)."""
ANTIYAW_DAMPER_CURVE = DamperCurve(knee_mps=0.0035, blowoff_ratio=0.025)
"""Anti-yaw damper: 2057 kNs/m each to 3.5 mm/s, then about 8 kN at 20 mm/s (Fig. 7)."""


@dataclass(frozen=True)
class NonlinearDampers:
    """Saturating damper curves for the truth; ``substeps`` per sample."""

    lateral: DamperCurve = LATERAL_DAMPER_CURVE
    antiyaw: DamperCurve = ANTIYAW_DAMPER_CURVE
    substeps: int = 10


@dataclass(frozen=True)
class TruthRun:
    """A simulated run at ``fs_hz``. Shapes: time first.

    t_s (T,); outputs (T, 5) noise-free, in SENSORS_5 order, SI units;
    states (T, 17); theta (T, 3); speed_mps (T,).
    """

    t_s: np.ndarray
    outputs: np.ndarray
    states: np.ndarray
    theta: np.ndarray
    speed_mps: np.ndarray
    fs_hz: float


@numba.njit(cache=True)
def _propagate(x0: np.ndarray, phi: np.ndarray, noise: np.ndarray, out: np.ndarray) -> None:
    """out[k] = x_k with x_{k+1} = phi x_k + noise[k]; out has the shape of noise."""
    n = x0.shape[0]
    x = x0.copy()
    for k in range(noise.shape[0]):
        for i in range(n):
            out[k, i] = x[i]
        y = np.zeros(n)
        for i in range(n):
            s = noise[k, i]
            for j in range(n):
                s += phi[i, j] * x[j]
            y[i] = s
        x = y


def _noise_factor(qd: np.ndarray) -> np.ndarray:
    """L with L L' = qd for a PSD (possibly singular) qd, shape (17, 17)."""
    w, V = np.linalg.eigh(qd)
    return V * np.sqrt(np.clip(w, 0.0, None))


def _segments(theta_t: np.ndarray, speed_t: np.ndarray) -> list[tuple[int, int]]:
    """Index ranges [start, stop) over which theta and speed are constant."""
    key = np.column_stack([theta_t, speed_t])
    change = np.any(np.diff(key, axis=0) != 0, axis=1)
    edges = np.concatenate([[0], np.nonzero(change)[0] + 1, [len(speed_t)]])
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:], strict=True)]


def _validate(theta_t: np.ndarray, speed_t: np.ndarray, fs_hz: float) -> None:
    if theta_t.ndim != 2 or theta_t.shape[1] != 3:
        raise InputError(f"expected theta_t of shape (T, 3), got {theta_t.shape}")
    if speed_t.shape != (theta_t.shape[0],):
        raise InputError(f"expected speed of shape ({theta_t.shape[0]},), got {speed_t.shape}")
    if not fs_hz > 0:
        raise InputError(f"expected a positive sample rate, got {fs_hz} Hz")
    if np.any(speed_t <= 0) or np.any(theta_t <= 0):
        raise InputError("expected positive speeds and parameters throughout the run")


TRACK_INPUTS = ("white", "held")
"""How the truth's track velocities enter (module docstring): continuous white noise
(the filter's model) or held over each sample (the paper's literal form)."""

BURN_IN_S = 10.0
"""Run-in (s) before a simulated run's first sample, so that it starts in (near)
stationary vibration."""


def simulate(theta_t: np.ndarray, speed_mps_t: np.ndarray, fs_hz: float,
             rng: np.random.Generator, *, params: VehicleParams | None = None,
             ar_paper: float = AR_PAPER_DEFAULT, burn_in_s: float = BURN_IN_S,
             dampers: NonlinearDampers | None = None,
             x0: np.ndarray | None = None, track_input: str = "white") -> TruthRun:
    """Simulate the truth at ``fs_hz`` for theta_t (T, 3) and speed (T,).

    Without ``x0`` the run starts from rest and first runs ``burn_in_s`` at the initial
    conditions so that it starts in (near) stationary vibration. With ``x0`` (17,) the
    first state is x0 and there is no burn-in: chain blocks by passing the last state
    of one block as x0 of the next (that sample then appears in both). ``track_input``:
    one of :data:`TRACK_INPUTS` (module docstring); "held" only with linear dampers.
    """
    p = params or VehicleParams()
    theta_t = np.asarray(theta_t, dtype=float)
    speed_t = np.asarray(speed_mps_t, dtype=float)
    _validate(theta_t, speed_t, fs_hz)
    if track_input not in TRACK_INPUTS or (track_input == "held" and dampers is not None):
        raise InputError(f"expected track_input from {TRACK_INPUTS} ('held' with linear "
                         f"dampers only), got {track_input!r}"
                         + (" with saturating dampers" if dampers is not None else ""))
    n_burn = 0 if x0 is not None else int(round(burn_in_s * fs_hz))
    theta_all = np.concatenate([np.repeat(theta_t[:1], n_burn, axis=0), theta_t])
    speed_all = np.concatenate([np.repeat(speed_t[:1], n_burn), speed_t])
    states = np.empty((len(speed_all), NX))
    x = np.zeros(NX) if x0 is None else np.asarray(x0, dtype=float).copy()
    G = input_matrix()
    for a, b in _segments(theta_all, speed_all):
        A = system_matrix(p, theta_all[a], float(speed_all[a]))
        q = track_intensity(ar_paper, float(speed_all[a]))
        if dampers is None:
            d = discretize(A, G, q, 1.0 / fs_hz)
            if track_input == "white":
                noise = rng.standard_normal((b - a, NX)) @ _noise_factor(d.qd).T
            else:         # each held value N(0, q fs): the same spectrum below fs / 2
                noise = rng.standard_normal((b - a, G.shape[1])) * np.sqrt(q * fs_hz) @ d.gamma.T
            _propagate(x, d.phi, noise, states[a:b])
            x = d.phi @ states[b - 1] + noise[-1]
        else:
            x = _run_nonlinear(x, A, q, theta_all[a], p, fs_hz, dampers, rng, states[a:b])
    outputs = np.empty((len(speed_all), 5))
    for a, b in _segments(np.zeros((len(speed_all), 3)) + 1, speed_all):
        H = output_matrix(system_matrix(p, theta_all[a], float(speed_all[a])), SENSORS_5)
        outputs[a:b] = states[a:b] @ H.T
    sl = slice(n_burn, None)
    t_s = np.arange(len(speed_t)) / fs_hz
    return TruthRun(t_s=t_s, outputs=outputs[sl], states=states[sl], theta=theta_t,
                    speed_mps=speed_t, fs_hz=float(fs_hz))


NONLINEAR_CHUNK = 1000
"""Samples whose sub-step noise :func:`_run_nonlinear` draws at once."""


def _run_nonlinear(x: np.ndarray, A: np.ndarray, q: float, theta: np.ndarray,
                   p: VehicleParams, fs_hz: float, dampers: NonlinearDampers,
                   rng: np.random.Generator, out: np.ndarray) -> np.ndarray:
    """Sub-stepped integration with the damper deviations as held inputs; fills out."""
    h = 1.0 / (fs_hz * dampers.substeps)
    d = discretize(A, input_matrix(), q, h)
    B = np.zeros((NX, 2))
    B[IDX["y_sr"], 0] = 1.0            # deviation of the series-node velocity
    B[IDX["dpsi_b"], 1] = 1.0 / p.ib_kgm2   # deviation of the anti-yaw moment
    aug = np.zeros((NX + 2, NX + 2))
    aug[:NX, :NX] = A
    aug[:NX, NX:] = B
    gamma_u = scipy.linalg.expm(aug * h)[:NX, NX:]
    L = _noise_factor(d.qd)
    csy, csay = float(theta[0]), float(theta[1])
    idx = np.array([IDX["y_b"], IDX["psi_b"], IDX["y_sr"], IDX["dpsi_b"]])
    curves = np.array([dampers.lateral.knee_mps, dampers.lateral.blowoff_ratio,
                       dampers.antiyaw.knee_mps, dampers.antiyaw.blowoff_ratio])
    consts = np.array([p.ksry_n_per_m, p.c_m, p.lbw_m, csy, 0.5 * csay])
    x = np.array(x, dtype=float)
    for a in range(0, out.shape[0], NONLINEAR_CHUNK):
        b = min(out.shape[0], a + NONLINEAR_CHUNK)
        # drawn in the order of one draw of NX per sub-step
        z = rng.standard_normal((b - a, dampers.substeps, NX))
        _nonlinear_steps(x, d.phi, gamma_u, L, z, idx, curves, consts, out[a:b])
    return x


@numba.njit(cache=True)
def _nonlinear_steps(x: np.ndarray, phi: np.ndarray, gamma_u: np.ndarray, L: np.ndarray,
                     z: np.ndarray, idx: np.ndarray, curves: np.ndarray, consts: np.ndarray,
                     out: np.ndarray) -> None:
    """Sub-steps of :func:`_run_nonlinear` over ``z`` (k, substeps, NX) unit normals, in
    place on the state ``x`` (NX,); ``out`` (k, NX) gets each sample's state before its
    sub-steps. ``idx``: y_b, psi_b, y_sr, dpsi_b; ``curves``: the lateral and anti-yaw
    knee and blow-off ratio; ``consts``: ksry, c_m, lbw, Csy, Csay / 2."""
    n = x.shape[0]
    ksry, c_m, lbw, csy, half_csay = consts[0], consts[1], consts[2], consts[3], consts[4]
    y = np.empty(n)
    for k in range(z.shape[0]):
        for i in range(n):
            out[k, i] = x[i]
        for s in range(z.shape[1]):
            force = ksry * (x[idx[0]] + c_m * x[idx[1]] - x[idx[2]])
            du = _inverse_deviation(force, csy, curves[0], curves[1])
            dm = -2 * lbw * _force_deviation(lbw * x[idx[3]], half_csay, curves[2], curves[3])
            for i in range(n):
                acc = gamma_u[i, 0] * du + gamma_u[i, 1] * dm
                for j in range(n):
                    acc += phi[i, j] * x[j] + L[i, j] * z[k, s, j]
                y[i] = acc
            for i in range(n):
                x[i] = y[i]


def add_sensor_noise(outputs: np.ndarray, sensors: tuple[str, ...], rng: np.random.Generator,
                     noise_var: dict[str, float] | None = None) -> np.ndarray:
    """Measured = true + white noise; outputs (T, ny) in the order of ``sensors``."""
    var = noise_var or SENSOR_NOISE_VAR
    std = np.sqrt(np.array([var[s] for s in sensors]))
    return outputs + rng.standard_normal(outputs.shape) * std


def measured(theta_t: np.ndarray, speed_mps_t: np.ndarray, fs_hz: float,
             sensors: tuple[str, ...], rng: np.random.Generator, *,
             ar_paper: float = AR_PAPER_DEFAULT,
             noise_var: dict[str, float] | None = None,
             burn_in_s: float = BURN_IN_S,
             dampers: NonlinearDampers | None = None,
             track_input: str = "white") -> np.ndarray:
    """What the sensors read (T, ny): :func:`simulate` from rest (after ``burn_in_s`` of
    run-in; 0: the first sample is at rest; ``dampers``: saturating damper curves, None:
    linear; ``track_input``: one of :data:`TRACK_INPUTS`), then :func:`add_sensor_noise`
    on the ``sensors`` columns, both drawing from ``rng``."""
    run = simulate(theta_t, speed_mps_t, fs_hz, rng, ar_paper=ar_paper, burn_in_s=burn_in_s,
                   dampers=dampers, track_input=track_input)
    return add_sensor_noise(select(run.outputs, sensors), sensors, rng, noise_var)


def lose_values(y: np.ndarray, loss: float, rng: np.random.Generator) -> np.ndarray:
    """``y`` (T, ny) with each value lost (NaN: a lost CAN frame, the front end's partial
    sample) independently with probability ``loss``; a copy."""
    out = np.array(y, dtype=float)
    out[rng.random(out.shape) < loss] = np.nan
    return out


def select(outputs: np.ndarray, sensors: tuple[str, ...]) -> np.ndarray:
    """Columns of a (T, 5) SENSORS_5 array for a sensor subset, shape (T, len(sensors))."""
    return outputs[:, [SENSORS_5.index(s) for s in sensors]]
