"""What a set of sensors can tell about each parameter: the Cramér-Rao bound of the data.

With a node's sensors left out (a dead node, :mod:`gateway.estimator.sensormask`) the
filters go on with the sensors left, and the particles keep what they knew. Where those
sensors carry little of a parameter, the cloud stays narrow around its old value: with
the body node out of a 3-sensor vehicle, Csy's stated σ stayed at 6-10 % while a halved
damper went unseen (docs/estimator.md "Dead sensors"). The same holds, less so, at low
speed with every sensor (the track excites the vehicle less). The posterior cannot say
so itself (its parameters are static), so the estimator asks the model.

:func:`bound_rel` is the Cramér-Rao bound of the parameters from ``horizon_s`` of data,
relative (σ / θ), from the Whittle information rate of the stationary output process:
``J_ij = ∫_0^{fs/2} Re tr(S⁻¹ ∂_i S S⁻¹ ∂_j S) df`` per second, with
``S(f) = H (i2πf I − A)⁻¹ Q (…)ᴴ Hᴴ + R / fs`` the outputs' two-sided spectral density
(``Q`` the track's white-noise intensity, ``R`` the sensors' per-sample variances, white
up to the Nyquist frequency) and ``∂_i`` by central differences in ``log θ_i``; the bound
is ``sqrt(diag(J⁻¹) / horizon_s)``, each parameter's with the others unknown too.
At the paper's 3-sensor set, 42.5 m/s, it gives λ ±1.0 % over 20 s (the issue's
independent figure: 0.94 %).

:func:`unresolved` names the parameters whose bound over :data:`HORIZON_S` is above
:data:`LIMIT_REL`. The estimate frames then say ``Unresolved`` for them instead of Valid
(:func:`gateway.sinks.outputs.estimate_status`). Shapes: ``theta`` (3,), ``H`` (ny, 16),
``noise_var`` (ny,). No I/O.
"""

from __future__ import annotations

import numpy as np

from gateway.model.coordinates import FilterCoords
from gateway.model.vehicle import frequency_response

__all__ = ["HORIZON_S", "LIMIT_REL", "SPEED_BAND_REL", "band_speed", "bound_rel",
           "information_rate", "unresolved"]

HORIZON_S = 5.0
"""Data over which a parameter must be resolvable: the worst first alert the detection
targets allow (issue 15: +5 s)."""
LIMIT_REL = 0.0625
"""Largest relative bound over :data:`HORIZON_S` of a resolved parameter: a change of a
quarter (the dampers' ADVISORY threshold, 0.75 of nominal) is then at least 4 σ."""
FREQS_N = 600
"""Frequencies of the integral, log-spaced from :data:`F_LOW_HZ` to fs/2 (the bound moves
by under 0.1 % against 2400)."""
F_LOW_HZ = 1e-3
"""The integral's lower end: A has the static-yaw zero eigenvalue (H is blind to it), so
f = 0 itself is singular; below 1 mHz there is no information to speak of."""
STEP_REL = 1e-4
"""Relative step of the central differences in each parameter."""
SPEED_BAND_REL = 0.05
"""The filter asks at the centre of a speed band this wide (relative; :func:`band_speed`):
the bound moves a few per cent over it, and one solve costs about 30 ms, so a train
that changes speed does not pay it at every one of the filter's 0.2 % speed steps."""


def band_speed(v_mps: float) -> float:
    """The centre of the :data:`SPEED_BAND_REL` band (log-spaced) that holds ``v_mps``."""
    step = np.log1p(SPEED_BAND_REL)
    return float(np.exp(np.round(np.log(v_mps) / step) * step))


def _spectra(A: np.ndarray, g: np.ndarray, H: np.ndarray, q: float, R: np.ndarray,
             f_hz: np.ndarray) -> np.ndarray:
    """S(f) (nf, ny, ny) for the noise input ``g`` (16, 2) of intensity ``q``."""
    T = frequency_response(A, g, H, f_hz)
    return q * (T @ T.conj().transpose(0, 2, 1)) + R


def information_rate(coords: FilterCoords, theta: np.ndarray, v_mps: float, H: np.ndarray,
                     noise_var: np.ndarray, q: float, fs_hz: float) -> np.ndarray:
    """Fisher information (3, 3) per second of data about ``log`` (Csy, Csay, λ), from the
    sensors whose rows are ``H`` (ny, 16) and whose per-sample variances at ``fs_hz`` are
    ``noise_var`` (ny,), at ``theta`` (3,), speed ``v_mps`` and track intensity ``q``
    (m²/s): the Whittle integral of the module docstring."""
    th = np.asarray(theta, dtype=float)[:3]
    f_hz = np.geomspace(F_LOW_HZ, fs_hz / 2.0, FREQS_N)
    g = coords.noise_input()
    R = np.diag(np.asarray(noise_var, dtype=float) / fs_hz)
    S_inv = np.linalg.inv(_spectra(coords.system(th, v_mps), g, H, q, R, f_hz))
    dS = []
    for i in range(3):
        up, down = th.copy(), th.copy()
        up[i] *= 1.0 + STEP_REL
        down[i] *= 1.0 - STEP_REL
        dS.append(S_inv @ (_spectra(coords.system(up, v_mps), g, H, q, R, f_hz)
                           - _spectra(coords.system(down, v_mps), g, H, q, R, f_hz))
                  / (2.0 * STEP_REL))
    J = np.empty((3, 3))
    for i in range(3):
        for j in range(i, 3):
            J[i, j] = J[j, i] = np.trapezoid(
                np.einsum("fab,fba->f", dS[i], dS[j]).real, f_hz)
    return J


def bound_rel(coords: FilterCoords, theta: np.ndarray, v_mps: float, H: np.ndarray,
              noise_var: np.ndarray, q: float, fs_hz: float,
              horizon_s: float = HORIZON_S) -> np.ndarray:
    """Relative Cramér-Rao bound (3,) of (Csy, Csay, λ) from ``horizon_s`` of data, each
    with the other two unknown too (arguments as :func:`information_rate`). Infinite
    where the information matrix is singular."""
    J = information_rate(coords, theta, v_mps, H, noise_var, q, fs_hz)
    try:
        var = np.diag(np.linalg.inv(J))
    except np.linalg.LinAlgError:
        return np.full(3, np.inf)
    return np.where(var > 0, np.sqrt(np.maximum(var, 0.0) / horizon_s), np.inf)


def unresolved(names: tuple[str, ...], bound: np.ndarray,
               limit_rel: float = LIMIT_REL) -> tuple[str, ...]:
    """The names (of the first ``len(bound)``) whose relative bound is above
    ``limit_rel``."""
    return tuple(n for n, b in zip(names, bound, strict=False) if not b <= limit_rel)
