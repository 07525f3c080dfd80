"""The plan-view half-vehicle model of Li et al. (2007): A(theta, v), G, H, noise, modes.

One module, used by the simulator, the estimator and the offline identification.
The equations are those rebuilt in ``shared/model-notes.md`` (reconstructed eq. (1)).

State vector, shape ``(17,)``, SI units (m, rad, m/s, rad/s)::

    0 y_w1   1 psi_w1   2 y_w2   3 psi_w2   4 y_b   5 psi_b   6 y_bd
    7..13    the seven rates of 0..6, in the same order
    14 y_sr  (massless node between Ksry and Csy)
    15 delta1, 16 delta2  (wheelset lateral displacement relative to the track)

Input ``b = [y_t1', y_t2']`` (track lateral velocities), continuous white noise.

Track-roughness convention (documented in README "Model"): the paper's
``Q = 4 pi^2 Ar v^2`` is used as the *intensity* of continuous white noise and the
discretisation is exact (Van Loan), with Ar in the paper's printed units, which are
millimetre based: ``Ar_SI = Ar_paper * 1e-6``. At T = 1 ms this equals the paper's
literal zero-order-hold form to first order and gives physical vibration (about
0.4 m/s^2 RMS bogie lateral acceleration at 42.5 m/s with Ar = 2 x 0.33e-3).

Unknown parameters ``theta = (Csy [N s/m], Csay [N s/m], lambda [-])`` enter A
affinely in the basis ``(1, 1/Csy, Csay, lambda)``; see :func:`a_matrix_terms`.
The core does no I/O.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace
from typing import Literal

import numpy as np

from gateway.errors import ModelError
from gateway.model.discretisation import van_loan, zero_order_hold

NX = 17
"""Number of states."""
NW = 2
"""Number of process-noise inputs (the two track lateral velocities)."""

STATE_NAMES: tuple[str, ...] = (
    "y_w1", "psi_w1", "y_w2", "psi_w2", "y_b", "psi_b", "y_bd",
    "dy_w1", "dpsi_w1", "dy_w2", "dpsi_w2", "dy_b", "dpsi_b", "dy_bd",
    "y_sr", "delta1", "delta2",
)
IDX = {name: i for i, name in enumerate(STATE_NAMES)}

PARAM_NAMES: tuple[str, str, str] = ("csy_ns_per_m", "csay_ns_per_m", "conicity")
"""Names of the estimated parameters theta, in theta order."""

SENSORS_5: tuple[str, ...] = ("acc_w1", "acc_w2", "acc_b", "gyro_b", "acc_bd")
SENSORS_3: tuple[str, ...] = ("acc_b", "gyro_b", "acc_bd")
SENSOR_UNITS = {"acc_w1": "m/s^2", "acc_w2": "m/s^2", "acc_b": "m/s^2",
                "gyro_b": "rad/s", "acc_bd": "m/s^2"}

AR_PAPER_DEFAULT = 2 * 0.33e-3
"""Track roughness factor Ar of the paper's Sec. 4.2, as printed."""
AR_PAPER_TO_SI = 1e-6
"""Scale from the paper's printed Ar to the SI intensity convention (mm^2 -> m^2)."""

# Measurement-noise variances of the paper's Sec. 4.2 (Qv), per sensor, SI units^2.
SENSOR_NOISE_VAR: dict[str, float] = {
    "acc_w1": 1e-4, "acc_w2": 1e-4, "acc_b": 4.11e-4, "gyro_b": 3.75e-7, "acc_bd": 7.62e-3,
}


@dataclass(frozen=True)
class VehicleParams:
    """Fixed vehicle parameters (Appendix of Li et al. 2007), SI units.

    Stiffnesses are per wheelset / per bogie as the model uses them; see the notes
    for how the garbled Appendix entries were read.
    """

    mw_kg: float = 1530.0
    iw_kgm2: float = 1017.0
    mb_kg: float = 2698.0
    ib_kgm2: float = 2138.0
    mbd_kg: float = 0.5 * 37637.0
    ky_n_per_m: float = 2 * 554e3
    kray_n_per_m: float = 2 * 11500e3
    kx_n_per_m: float = 2 * (554e3 + 23000e3)
    ksy_n_per_m: float = 2 * 88.927e3 + 197e3
    ksry_n_per_m: float = 10e6
    ksarb_n_per_m: float = 83e3
    ksyaw_nm_per_rad: float = 10e3
    f11_n: float = 10e6
    f22_n: float = 8.8e6
    a_m: float = 1.25
    b_m: float = 1.02
    c_m: float = 0.47
    d_m: float = 0.80
    e_m: float = 0.26
    l_m: float = 0.75
    lbw_m: float = 1.20
    r0_m: float = 0.42

    def with_values(self, **changes: float) -> VehicleParams:
        """A copy with some fields changed (names as the dataclass fields)."""
        unknown = set(changes) - set(asdict(self))
        if unknown:
            raise ModelError(f"expected vehicle parameter names from {sorted(asdict(self))}, "
                             f"got unknown {sorted(unknown)}")
        return replace(self, **changes)


@dataclass(frozen=True)
class Theta:
    """The monitored parameters: Csy, Csay [N s/m per bogie] and conicity lambda [-]."""

    csy_ns_per_m: float
    csay_ns_per_m: float
    conicity: float

    def as_array(self) -> np.ndarray:
        """Shape (3,), in :data:`PARAM_NAMES` order."""
        return np.array([self.csy_ns_per_m, self.csay_ns_per_m, self.conicity])

    @classmethod
    def from_array(cls, values: np.ndarray) -> Theta:
        v = np.asarray(values, dtype=float).reshape(-1)
        if v.shape != (3,):
            raise ModelError(f"expected theta of shape (3,), got {v.shape}")
        return cls(float(v[0]), float(v[1]), float(v[2]))


THETA_NOMINAL = Theta(csy_ns_per_m=40e3, csay_ns_per_m=2 * 2057e3, conicity=0.15)
"""Appendix nominal dampers (these reproduce the paper's Table 1)."""
THETA_SEC42 = Theta(csy_ns_per_m=20e3, csay_ns_per_m=3000e3, conicity=0.15)
"""The values used to generate the paper's Sec. 4.2 simulation data."""


def _check_inputs(theta: np.ndarray, v_mps: float) -> None:
    if not np.all(np.isfinite(theta)) or np.any(theta <= 0):
        raise ModelError(f"expected finite positive theta (Csy, Csay, lambda), got {theta}")
    if not np.isfinite(v_mps) or v_mps <= 0:
        raise ModelError(f"expected a positive finite speed in m/s, got {v_mps}")


def a_matrix_terms(params: VehicleParams, v_mps: float) -> np.ndarray:
    """The affine pieces of A at speed v: ``A = T0 + T1/Csy + T2*Csay + T3*lambda``.

    Returns shape (4, 17, 17): ``[T0, T1, T2, T3]``. Exact, not a linearisation.
    """
    if not np.isfinite(v_mps) or v_mps <= 0:
        raise ModelError(f"expected a positive finite speed in m/s, got {v_mps}")
    p = params
    n = NX
    e = np.eye(n)
    y_w1, psi_w1, y_w2, psi_w2, y_b, psi_b, y_bd = (e[i] for i in range(7))
    dy = [e[7 + i] for i in range(7)]
    y_sr, d1, d2 = e[14], e[15], e[16]
    amd = p.a_m - p.d_m
    kxb2 = p.kx_n_per_m * p.b_m**2

    D1y = y_w1 - y_b - p.a_m * psi_b
    D1r = y_w1 - amd * psi_w1 - y_b - p.d_m * psi_b
    D2y = y_w2 - y_b + p.a_m * psi_b
    D2r = y_w2 + amd * psi_w2 - y_b + p.d_m * psi_b
    Dsy = y_b - y_bd
    Darb = y_b + p.e_m * psi_b - y_bd
    Dsr = y_b + p.c_m * psi_b - y_sr

    T = np.zeros((4, n, n))
    T0, T1, T2, T3 = T
    for i in range(7):
        T0[i] = dy[i]                                   # kinematics q' = rates
    creep_lat = 2 * p.f22_n / v_mps
    creep_yaw = 2 * p.f11_n * p.l_m**2 / v_mps
    grav = 2 * p.f11_n * p.l_m / p.r0_m                 # times lambda times delta
    ky, kr = p.ky_n_per_m, p.kray_n_per_m
    # leading wheelset
    T0[7] = (-creep_lat * dy[0] + 2 * p.f22_n * psi_w1 - ky * D1y - kr * D1r) / p.mw_kg
    T0[8] = (-creep_yaw * dy[1] - kxb2 * (psi_w1 - psi_b) + kr * amd * D1r) / p.iw_kgm2
    T3[8] = -grav * d1 / p.iw_kgm2
    # trailing wheelset
    T0[9] = (-creep_lat * dy[2] + 2 * p.f22_n * psi_w2 - ky * D2y - kr * D2r) / p.mw_kg
    T0[10] = (-creep_yaw * dy[3] - kxb2 * (psi_w2 - psi_b) - kr * amd * D2r) / p.iw_kgm2
    T3[10] = -grav * d2 / p.iw_kgm2
    # bogie
    ksec = p.ksy_n_per_m * Dsy + p.ksarb_n_per_m * Darb + p.ksry_n_per_m * Dsr
    T0[11] = (ky * (D1y + D2y) + kr * (D1r + D2r) - ksec) / p.mb_kg
    T0[12] = (p.a_m * ky * (D1y - D2y) + p.d_m * kr * (D1r - D2r)
              + kxb2 * (psi_w1 + psi_w2 - 2 * psi_b)
              - p.e_m * p.ksarb_n_per_m * Darb - p.c_m * p.ksry_n_per_m * Dsr
              - p.ksyaw_nm_per_rad * psi_b) / p.ib_kgm2
    T2[12] = -(p.lbw_m**2) * dy[5] / p.ib_kgm2
    # half body (lateral only)
    T0[13] = ksec / p.mbd_kg
    # series node: Csy (y_sr' - y_bd') = Ksry Dsr
    T0[14] = dy[6]
    T1[14] = p.ksry_n_per_m * Dsr
    # track-relative displacements: delta_i' = y_wi' - y_ti'
    T0[15] = dy[0]
    T0[16] = dy[2]
    return T


def theta_basis(theta: np.ndarray) -> np.ndarray:
    """Coefficients of :func:`a_matrix_terms` for theta; shape (..., 4)."""
    th = np.asarray(theta, dtype=float)
    return np.stack([np.ones_like(th[..., 0]), 1.0 / th[..., 0], th[..., 1], th[..., 2]], axis=-1)


def system_matrix(params: VehicleParams, theta: Theta | np.ndarray, v_mps: float) -> np.ndarray:
    """Continuous-time A(theta, v), shape (17, 17), units 1/s."""
    th = theta.as_array() if isinstance(theta, Theta) else np.asarray(theta, dtype=float)
    _check_inputs(th, v_mps)
    terms = a_matrix_terms(params, v_mps)
    return np.tensordot(theta_basis(th), terms, axes=1)


def input_matrix() -> np.ndarray:
    """G, shape (17, 2): the track velocities drive the delta rows with sign -1."""
    G = np.zeros((NX, NW))
    G[IDX["delta1"], 0] = -1.0
    G[IDX["delta2"], 1] = -1.0
    return G


def sensor_set(n_sensors: int) -> tuple[str, ...]:
    """The sensor names of the 5- or 3-sensor set, in measurement order."""
    if n_sensors == 5:
        return SENSORS_5
    if n_sensors == 3:
        return SENSORS_3
    raise ModelError(f"expected a sensor set of 3 or 5 sensors, got {n_sensors}")


_ACC_ROW = {"acc_w1": 7, "acc_w2": 9, "acc_b": 11, "acc_bd": 13}


def output_matrix(A: np.ndarray, sensors: tuple[str, ...] | int) -> np.ndarray:
    """H for the given sensors, shape (ny, 17): accelerations are rows of A, gyro is a state."""
    names = sensor_set(sensors) if isinstance(sensors, int) else sensors
    H = np.zeros((len(names), NX))
    for k, name in enumerate(names):
        if name == "gyro_b":
            H[k, IDX["dpsi_b"]] = 1.0
        elif name in _ACC_ROW:
            H[k] = A[..., _ACC_ROW[name], :]
        else:
            raise ModelError(f"expected a sensor from {SENSORS_5}, got {name!r}")
    return H


def frequency_response(A: np.ndarray, G: np.ndarray, H: np.ndarray,
                       f_hz: np.ndarray) -> np.ndarray:
    """``H (i 2 pi f I - A)^-1 G`` at each frequency, shape (nf, ny, nw): the outputs'
    response to the noise inputs (any state coordinates; ``f`` must avoid A's
    eigenvalues on the imaginary axis, e.g. f = 0 for a model with a static mode)."""
    M = (2j * np.pi * np.asarray(f_hz, dtype=float))[:, None, None] * np.eye(A.shape[0]) - A
    return H @ np.linalg.solve(M, np.broadcast_to(G.astype(complex), (len(M), *G.shape)))


def output_rows(sensors: tuple[str, ...] | int) -> tuple[list[int], list[int]]:
    """For batched use: (positions in the sensor set that are accelerations, their A rows)."""
    names = sensor_set(sensors) if isinstance(sensors, int) else sensors
    pos = [k for k, s in enumerate(names) if s in _ACC_ROW]
    return pos, [_ACC_ROW[names[k]] for k in pos]


def track_intensity(ar_paper: float, v_mps: float) -> float:
    """Continuous white-noise intensity of each track lateral velocity, m^2/s.

    ``Q = 4 pi^2 (Ar_paper * 1e-6) v^2`` (see the module docstring).
    """
    if not np.isfinite(ar_paper) or ar_paper <= 0:
        raise ModelError(f"expected a positive track roughness Ar, got {ar_paper}")
    return 4 * np.pi**2 * ar_paper * AR_PAPER_TO_SI * v_mps**2


def measurement_noise(sensors: tuple[str, ...] | int) -> np.ndarray:
    """R = Qv of the paper for the sensor set, shape (ny, ny), SI units^2."""
    names = sensor_set(sensors) if isinstance(sensors, int) else sensors
    return np.diag([SENSOR_NOISE_VAR[s] for s in names])


@dataclass(frozen=True)
class Discrete:
    """Exact zero-order discretisation: x[k+1] = phi x[k] + w[k], w ~ N(0, qd).

    ``phi`` (17, 17); ``qd`` (17, 17) symmetric PSD; ``gamma`` (17, 2) = int_0^T e^{As} ds G.
    """

    phi: np.ndarray
    qd: np.ndarray
    gamma: np.ndarray
    dt_s: float


def discretize(A: np.ndarray, G: np.ndarray, q_intensity: float | np.ndarray,
               dt_s: float) -> Discrete:
    """Exact discretisation (:mod:`gateway.model.discretisation`): Phi and Qd by Van
    Loan's method, Gamma by the zero-order-hold augmentation.

    ``q_intensity`` is the white-noise intensity of each input (scalar or (nw,)).
    """
    if not dt_s > 0:
        raise ModelError(f"expected a positive sample period, got {dt_s} s")
    m = G.shape[1]
    Qc = np.diag(np.broadcast_to(np.asarray(q_intensity, dtype=float), (m,)))
    phi, qd = van_loan(A, G @ Qc @ G.T, dt_s)
    _, gamma = zero_order_hold(A, G, dt_s)
    return Discrete(phi=phi, qd=qd, gamma=gamma, dt_s=dt_s)


@dataclass(frozen=True)
class Mode:
    """One vibration mode: natural frequency |s|/2pi and damping ratio -Re(s)/|s|."""

    frequency_hz: float
    damping_ratio: float
    eigenvalue: complex = field(compare=False)


def eigenvalues(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Split eig(A) into (structural zeros, the rest); the 2 zeros are the track random walks."""
    lam = np.linalg.eigvals(A)
    scale = max(1.0, float(np.max(np.abs(lam))))
    zero = np.abs(lam) < 1e-7 * scale
    return lam[zero], lam[~zero]


def modes(A: np.ndarray) -> list[Mode]:
    """Modes of A, highest frequency first; one entry per real root or complex pair."""
    _, lam = eigenvalues(A)
    out = [Mode(float(abs(s) / (2 * np.pi)), float(-s.real / abs(s)), complex(s))
           for s in lam if s.imag >= 0]
    return sorted(out, key=lambda m: -m.frequency_hz)


def max_growth_rate(A: np.ndarray) -> float:
    """Largest real part [1/s] among the non-structural eigenvalues; > 0 means unstable."""
    _, lam = eigenvalues(A)
    return float(np.max(lam.real))


@dataclass(frozen=True)
class Stability:
    """Whether theta gives a stable vehicle at speed v, and by how much."""

    stable: bool
    max_growth_rate_per_s: float


def stability(params: VehicleParams, theta: Theta | np.ndarray, v_mps: float) -> Stability:
    """Report (never raise on) instability of the model at theta, v."""
    rate = max_growth_rate(system_matrix(params, theta, v_mps))
    return Stability(stable=rate < 0.0, max_growth_rate_per_s=rate)


SensorSet = Literal[3, 5]
