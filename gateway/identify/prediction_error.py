"""Maximum likelihood without a track record: the Kalman one-step prediction-error misfit.

With no track input the two track velocities are the model's white noise of
intensity ``Q = 4 pi^2 Ar v^2`` (:func:`gateway.model.vehicle.track_intensity`, Ar in the
paper's printed units, default 2 x 0.33e-3) and the sensors carry white noise R
(the paper's Qv). The exact (Van Loan) discrete model at the data rate gives, through
the stationary Kalman filter, innovations ``nu_k`` with covariance S, and

    NLL(p) = 1/2 sum_k [ nu_k' S^-1 nu_k + log det S + ny log 2 pi ]

is minimised over p. The filter starts exactly, from the stationary distribution of the
state (x = 0, P0 = the stationary covariance), and runs time-varying until its
covariance has reached the stationary (Riccati) one; from there on the gain is
constant. The model's two zero eigenvalues (rigid lateral translation and
the static yawed set-up) are unobservable random walks; they are split off first: with
N the null space of A, L (15, 17) an orthonormal basis of its complement, the outputs
follow exactly from ``A_r = L A L'``, ``G_r = L G``, ``H_r = H L'``.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from gateway.errors import InputError, ModelError
from gateway.identify.data import Dataset
from gateway.identify.linalg import dare_filter, expm
from gateway.identify.misfit import Section, check_sections
from gateway.identify.params import ParamPoint
from gateway.model.vehicle import (
    AR_PAPER_DEFAULT,
    SENSOR_NOISE_VAR,
    input_matrix,
    output_matrix,
    system_matrix,
    track_intensity,
)

NLL_PENALTY = 1e6
"""Mean NLL per sample returned where the filter does not exist (non-detectable model)."""


def reduced_model(point: ParamPoint, sensors: tuple[str, ...],
                  speed_mps: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(A_r (15, 15), G_r (15, 2), H_r (ny, 15)) with the null space of A removed."""
    A = system_matrix(point.vehicle(), point.theta(), speed_mps)
    _, s, vt = np.linalg.svd(A)
    if s[-2] > 1e-9 * s[0] or s[-3] < 1e-6 * s[0]:
        raise ModelError(f"expected A to have exactly 2 zero singular values, got "
                         f"{s[-3:].tolist()}")
    N = vt[-2:].T
    Q, _ = np.linalg.qr(np.hstack([N, np.eye(A.shape[0])]))
    L = Q[:, 2:A.shape[0]].T
    return L @ A @ L.T, L @ input_matrix(), output_matrix(A, sensors) @ L.T


def van_loan(A: np.ndarray, G: np.ndarray, q: float, dt_s: float) -> tuple[np.ndarray,
                                                                          np.ndarray]:
    """Exact discretisation (Phi, Qd) of x' = A x + G w, w white of intensity q per input."""
    n = A.shape[0]
    M = np.zeros((2 * n, 2 * n))
    M[:n, :n] = -A
    M[:n, n:] = q * (G @ G.T)
    M[n:, n:] = A.T
    F = expm(M * dt_s)
    phi = F[n:, n:].T
    qd = phi @ F[:n, n:]
    return np.ascontiguousarray(phi), np.ascontiguousarray(0.5 * (qd + qd.T))


@numba.njit(cache=True)
def _chol(S: np.ndarray) -> np.ndarray:
    """Lower Cholesky factor of a small SPD matrix (NaN if not positive definite)."""
    m = S.shape[0]
    L = np.zeros((m, m))
    for i in range(m):
        for j in range(i + 1):
            acc = S[i, j]
            for k in range(j):
                acc -= L[i, k] * L[j, k]
            if i == j:
                L[i, i] = np.sqrt(acc) if acc > 0 else np.nan
            else:
                L[i, j] = acc / L[j, j]
    return L


@numba.njit(cache=True)
def _transient(phi: np.ndarray, H: np.ndarray, qd: np.ndarray, R: np.ndarray,
               P0: np.ndarray, p_ss: np.ndarray, y: np.ndarray,
               x: np.ndarray) -> tuple[float, int]:
    """The exact time-varying filter from (x = 0, P0) until its gain reaches the stationary one.

    Switches once ``max |(P - p_ss) H'| <= 1e-3 max |p_ss H'|``; the innovation
    covariance is then within about 1e-4 of S. Returns (sum of nu' S_k^-1 nu +
    log det S_k, samples used); ``x`` (n,) is left holding the next prediction.
    """
    n = phi.shape[0]
    ny = H.shape[0]
    P = P0.copy()
    ref = p_ss @ H.T
    scale = np.max(np.abs(ref))
    PHt = np.zeros((n, ny))
    S = np.zeros((ny, ny))
    K = np.zeros((n, ny))
    M = np.zeros((n, n))
    xn = np.zeros(n)
    w = np.zeros(ny)
    nu = np.zeros(ny)
    total = 0.0
    for k in range(y.shape[0]):
        for i in range(n):
            for j in range(ny):
                acc = 0.0
                for m in range(n):
                    acc += P[i, m] * H[j, m]
                PHt[i, j] = acc
        if k % 8 == 0 and np.max(np.abs(PHt - ref)) <= 1e-3 * scale:
            return total, k
        for i in range(ny):
            for j in range(ny):
                acc = R[i, j]
                for m in range(n):
                    acc += H[i, m] * PHt[m, j]
                S[i, j] = acc
        L = _chol(S)
        for i in range(ny):
            acc = y[k, i]
            for m in range(n):
                acc -= H[i, m] * x[m]
            nu[i] = acc
        for i in range(ny):             # w = L^-1 nu
            acc = nu[i]
            for j in range(i):
                acc -= L[i, j] * w[j]
            w[i] = acc / L[i, i]
            total += w[i] * w[i] + 2.0 * np.log(L[i, i])
        Sinv = np.linalg.inv(S)
        for i in range(n):
            for j in range(ny):
                acc = 0.0
                for m in range(ny):
                    acc += PHt[i, m] * Sinv[m, j]
                K[i, j] = acc
        for i in range(n):              # x+ = phi (x + K nu); M = P - K PHt'
            acc = x[i]
            for j in range(ny):
                acc += K[i, j] * nu[j]
            xn[i] = acc
            for j in range(n):
                acc = P[i, j]
                for m in range(ny):
                    acc -= K[i, m] * PHt[j, m]
                M[i, j] = acc
        for i in range(n):
            acc = 0.0
            for j in range(n):
                acc += phi[i, j] * xn[j]
            x[i] = acc
        T = phi @ M
        for i in range(n):              # P = phi M phi' + qd, symmetrised
            for j in range(i + 1):
                acc = qd[i, j]
                for m in range(n):
                    acc += T[i, m] * phi[j, m]
                P[i, j] = acc
                P[j, i] = acc
    return total, y.shape[0]


def lyapunov(phi: np.ndarray, qd: np.ndarray, max_iter: int = 64) -> np.ndarray | None:
    """Stationary covariance X = phi X phi' + qd by doubling; None if phi is not stable."""
    A, X = phi.copy(), qd.copy()
    for _ in range(max_iter):
        X_new = X + A @ X @ A.T
        A = A @ A
        if not np.all(np.isfinite(X_new)):
            return None
        if float(np.max(np.abs(X_new - X))) <= 1e-14 * float(np.max(np.abs(X_new))):
            return 0.5 * (X_new + X_new.T)
        X = X_new
    return None


@numba.njit(cache=True)
def _innovations(phi: np.ndarray, phik: np.ndarray, H: np.ndarray, s_inv: np.ndarray,
                 y: np.ndarray, x0: np.ndarray) -> float:
    """Sum of nu' S^-1 nu over y (T, ny); x+ = phi x + phik nu, nu = y - H x, from x0."""
    n = phi.shape[0]
    ny = H.shape[0]
    x = x0.copy()
    xn = np.zeros(n)
    nu = np.zeros(ny)
    total = 0.0
    for k in range(y.shape[0]):
        for i in range(ny):
            s = y[k, i]
            for j in range(n):
                s -= H[i, j] * x[j]
            nu[i] = s
        for i in range(ny):
            for j in range(ny):
                total += nu[i] * s_inv[i, j] * nu[j]
        for i in range(n):
            s = 0.0
            for j in range(n):
                s += phi[i, j] * x[j]
            for j in range(ny):
                s += phik[i, j] * nu[j]
            xn[i] = s
        for i in range(n):
            x[i] = xn[i]
    return total


class PredictionErrorMisfit:
    """Mean negative log-likelihood per sample, NLL(p) / T; picklable for workers.

    ``decimation`` keeps every d-th sample (exact for this model: a sampled
    Gauss-Markov process is one at the lower rate). Sections restart the filter.
    """

    def __init__(self, dataset: Dataset, sections: list[Section],
                 ar_paper: float = AR_PAPER_DEFAULT, noise_var: dict[str, float] | None = None,
                 decimation: int = 1) -> None:
        check_sections(dataset, sections)
        if decimation < 1:
            raise InputError(f"expected a decimation of at least 1, got {decimation}")
        self.dataset, self.sections, self.decimation = dataset, list(sections), int(decimation)
        self.ar_paper = float(ar_paper)
        var = noise_var or SENSOR_NOISE_VAR
        self.R = np.diag([var[s] for s in dataset.sensors])
        self.dt_s = decimation / dataset.fs_hz
        self.speed_mps = float(np.mean(dataset.speed_mps))
        self.q = track_intensity(self.ar_paper, self.speed_mps)
        t = dataset.t_s
        self.blocks = []
        for s in sections:
            i0 = int(np.searchsorted(t, s.start_s - 1e-9))
            i1 = int(np.searchsorted(t, s.stop_s - 1e-9))
            self.blocks.append(np.ascontiguousarray(dataset.measured[i0:i1:decimation]))
        self.n_samples = sum(len(b) for b in self.blocks)

    def total_nll(self, point: ParamPoint) -> float:
        """NLL summed over all samples of all sections."""
        try:
            Ar, Gr, Hr = reduced_model(point, self.dataset.sensors, self.speed_mps)
            phi, qd = van_loan(Ar, Gr, self.q, self.dt_s)
            P = dare_filter(phi, Hr, qd, self.R)
        except (ModelError, np.linalg.LinAlgError):
            return NLL_PENALTY * self.n_samples
        S = Hr @ P @ Hr.T + self.R
        s_inv = np.linalg.inv(S)
        phik = phi @ P @ Hr.T @ s_inv
        sign, logdet = np.linalg.slogdet(S)
        if sign <= 0:
            return NLL_PENALTY * self.n_samples
        P0 = lyapunov(phi, qd)
        quad = 0.0
        n_steady = 0
        for y in self.blocks:
            x = np.zeros(phi.shape[0])
            used = 0
            if P0 is not None:       # exact start from the stationary state distribution
                part, used = _transient(phi, Hr, qd, self.R, P0, P, y, x)
                quad += part
            quad += _innovations(phi, phik, Hr, s_inv, y[used:], x)
            n_steady += len(y) - used
        ny = len(self.dataset.sensors)
        total = 0.5 * (quad + n_steady * logdet + self.n_samples * ny * math.log(2 * math.pi))
        return total if math.isfinite(total) else NLL_PENALTY * self.n_samples

    def __call__(self, point: ParamPoint) -> float:
        return self.total_nll(point) / self.n_samples

    def describe(self) -> dict[str, object]:
        return {"ar_paper": self.ar_paper, "track_intensity_m2_per_s": self.q,
                "speed_mps": self.speed_mps, "sample_period_s": self.dt_s,
                "noise_var": dict(zip(self.dataset.sensors, np.diag(self.R).tolist(),
                                      strict=True)),
                "sections": [s.label() for s in self.sections], "samples": self.n_samples}


def standard_errors(total_nll: object, u_hat: np.ndarray, step: float = 0.02) -> np.ndarray:
    """Standard errors (k,) of the relative offsets from the observed information.

    Central second differences of the total NLL in ``u``; ``total_nll`` maps u to NLL.
    Returns NaN where the Hessian is not positive definite.
    """
    f = total_nll
    k = len(u_hat)
    Hm = np.zeros((k, k))
    f0 = f(u_hat)  # type: ignore[operator]
    e = np.eye(k) * step
    for i in range(k):
        fp, fm = f(u_hat + e[i]), f(u_hat - e[i])  # type: ignore[operator]
        Hm[i, i] = (fp - 2 * f0 + fm) / step**2
        for j in range(i):
            fpp = f(u_hat + e[i] + e[j])  # type: ignore[operator]
            fpm = f(u_hat + e[i] - e[j])  # type: ignore[operator]
            fmp = f(u_hat - e[i] + e[j])  # type: ignore[operator]
            fmm = f(u_hat - e[i] - e[j])  # type: ignore[operator]
            Hm[i, j] = Hm[j, i] = (fpp - fpm - fmp + fmm) / (4 * step**2)
    try:
        cov = np.linalg.inv(Hm)
    except np.linalg.LinAlgError:
        return np.full(k, np.nan)
    d = np.diag(cov)
    return np.where(d > 0, np.sqrt(np.abs(d)), np.nan)
