"""Exact Kalman filters for many particles at once: one predict + update step, batched.

Each particle ``p`` carries its own 16-state filter (``gateway.model.coordinates`` coordinates):
mean ``x_p`` and covariance ``P_p``, with its own ``Phi_p`` and ``Qd_p``; the output
matrix ``H`` (ny, 16) and the diagonal measurement noise ``r`` (ny,) are shared (H
does not depend on theta). One call does, for every particle::

    x <- Phi x,  P <- Phi P Phi' + Qd                       (predict)
    for each available sensor s (R diagonal, so sequential scalar updates are exact):
        e = y_s - h_s x,  S = h_s P h_s' + r_s,  k = P h_s' / S
        x <- x + k e,  P <- P - k S k',  loglik += -(log(2 pi S) + e^2 / S) / 2

It also returns the normalised innovation squared (sum of e^2/S) per particle for the
innovation monitor. A particle whose covariance becomes non-finite or larger than
``P_LIMIT`` (an unstable theta, or a numerical blow-up) gets log-likelihood -inf and
its filter is reset to (0, P0) so that no NaN or overflow ever propagates.

Arrays use the lane layout of :mod:`gateway.estimator.lanecode`: ``x (n_chunks, 16 * LANES)``,
``P, Phi, Qd (n_chunks, 256 * LANES)``, per-particle outputs ``(n_chunks * LANES,)``.
No I/O; numba kernel over chunks with ``prange`` (both cores).
"""

from __future__ import annotations

import re

import numpy as np

from gateway.estimator.lanecode import LANES, block_product, compile_kernel, stmt
from gateway.model.coordinates import NZ

BLOCK = (2, 2)
"""Register block (rows, columns) of the 16x16 products; any block gives bit-identical
results (each element keeps its own k-ordered FMA chain); 2 x 2 measured fastest."""
P_LIMIT = 1e12
"""Largest covariance diagonal (filter units) accepted before a particle is declared dead."""
_LOG_2PI = float(np.log(2 * np.pi))


def _kf_source(n: int) -> list[str]:
    """The one-sample kernel ``kf_step``: header, per-chunk set-up, then the step."""
    return ["def kf_step(X, P, F, Q, H, r, y, use, P0, ll, nis, dead):",
            "    nch = X.shape[0]",
            "    ny = H.shape[0]"] + _chunk_lines(n) + _step_lines(n)


def _chunk_lines(n: int) -> list[str]:
    """The loop over chunks and each chunk's scratch arrays and views."""
    C = LANES
    return ["    for ch in prange(nch):",
            f"        T = np.empty({n * n * C})",
            f"        xn = np.empty({n * C})",
            f"        ph = np.empty({n * C})",
            "        Fc = F[ch]",
            "        Pc = P[ch]",
            "        Qc = Q[ch]",
            "        Xc = X[ch]"]


def _block_source(n: int) -> list[str]:
    """The K-sample kernel ``kf_block``: the same step, each chunk taking all K samples
    in turn (its P, Phi and Qd stay in cache), every sensor used or none (``full[t]``),
    each sample's log-likelihood and NIS set in ``LL[t]``, ``NIS[t]``; a dead particle
    gets -inf there. Bit-identical to K calls of ``kf_step``: the step's lines with the
    sample's arrays renamed."""
    C = LANES
    rename = [(r"\by\[s\]", "Y[t, s]"), (r"\buse\[s\]", "full[t]"), (r"\bll\[", "LL[t, "),
              (r"\bnis\[", "NIS[t, ")]
    body = []
    for line in _step_lines(n):
        if line.strip() == "dead[p] = True":
            continue
        for a, b in rename:
            line = re.sub(a, b, line)
        body.append("    " + line)
    return ["def kf_block(X, P, F, Q, H, r, Y, full, P0, LL, NIS):",
            "    nch = X.shape[0]",
            "    ny = H.shape[0]",
            "    nt = Y.shape[0]"] + _chunk_lines(n) + [
            "        for t in range(nt):",
            f"            for l in range({C}):",
            f"                LL[t, ch * {C} + l] = 0.0",
            f"                NIS[t, ch * {C} + l] = 0.0"] + body


def _step_lines(n: int) -> list[str]:
    """One predict + update of chunk ``ch`` (8-space indent; sample ``y``, ``use``)."""
    C = LANES
    mat = f"(({{i}}) * {n} + ({{j}})) * {C}"
    L: list[str] = []
    bi, bj = BLOCK
    loops = [f"        for ib in range(0, {n}, {bi}):",
             f"            for jb in range(0, {n}, {bj}):"]
    # T = F P  (full), register-blocked
    L += loops
    L += block_product(4, a="Fc", a_row=f"({{r}} * {n} + k) * {C}", b="Pc",
                       b_row=f"(k * {n} + {{r}}) * {C}", n=n, bi=bi, bj=bj, init=None,
                       out=[("T", mat)])
    # P = T F' + Q, upper triangle, mirrored
    L += loops + [f"                if jb + {bj - 1} < ib:", "                    continue"]
    L += block_product(4, a="T", a_row=f"({{r}} * {n} + k) * {C}", b="Fc",
                       b_row=f"({{r}} * {n} + k) * {C}", n=n, bi=bi, bj=bj,
                       init="Qc[" + mat + " + {l}]", out=[("Pc", mat), ("Pc", mat.replace(
                           "{i}", "{tmp}").replace("{j}", "{i}").replace("{tmp}", "{j}"))],
                       guard="{j} >= {i}")
    # x = F x
    L += [f"        for i in range({n}):"]
    L += stmt(3, "s_{l} = 0.0")
    L += [f"            for k in range({n}):"]
    L += stmt(4, f"s_{{l}} += Fc[(i * {n} + k) * {C} + {{l}}] * Xc[k * {C} + {{l}}]")
    L += stmt(3, f"xn[i * {C} + {{l}}] = s_{{l}}")
    L += [f"        for i in range({n * C}):", "            Xc[i] = xn[i]"]
    L += stmt(2, "g_{l} = 0.0")
    L += stmt(2, "e_{l} = 0.0")
    L += stmt(2, "d_{l} = 1.0")
    L += stmt(2, "q_{l} = 0.0")
    # sequential scalar updates (one log per particle at the end)
    L += ["        for s in range(ny):", "            if not use[s]:", "                continue",
          f"            for i in range({n}):"]
    L += stmt(4, "s_{l} = 0.0")
    L += [f"                for k in range({n}):", "                    hk = H[s, k]"]
    L += stmt(5, f"s_{{l}} += Pc[(i * {n} + k) * {C} + {{l}}] * hk")
    L += stmt(4, f"ph[i * {C} + {{l}}] = s_{{l}}")
    L += stmt(3, "s_{l} = r[s]")
    L += stmt(3, "e_{l} = y[s]")
    L += [f"            for k in range({n}):", "                hk = H[s, k]"]
    L += stmt(4, f"s_{{l}} += hk * ph[k * {C} + {{l}}]")
    L += stmt(4, f"e_{{l}} -= hk * Xc[k * {C} + {{l}}]")
    L += stmt(3, "g_{l} = 1.0 / s_{l}")
    L += stmt(3, "d_{l} *= s_{l}")
    L += stmt(3, "q_{l} += e_{l} * e_{l} * g_{l}")
    L += stmt(3, "e_{l} = e_{l} * g_{l}")
    L += [f"            for i in range({n}):"]
    L += stmt(4, f"Xc[i * {C} + {{l}}] += ph[i * {C} + {{l}}] * e_{{l}}")
    L += stmt(4, f"k_{{l}} = ph[i * {C} + {{l}}] * g_{{l}}")
    L += [f"                for j in range(i, {n}):"]
    L += stmt(5, f"v_{{l}} = Pc[(i * {n} + j) * {C} + {{l}}] - k_{{l}} * ph[j * {C} + {{l}}]")
    L += stmt(5, f"Pc[(i * {n} + j) * {C} + {{l}}] = v_{{l}}")
    L += stmt(5, f"Pc[(j * {n} + i) * {C} + {{l}}] = v_{{l}}")
    L += ["        nused = 0", "        for s in range(ny):", "            if use[s]:",
          "                nused += 1",
          "        if nused > 0:"]
    L += stmt(3, f"ll[ch * {C} + {{l}}] -= 0.5 * (np.log(d_{{l}}) + nused * {_LOG_2PI!r} "
                 "+ q_{l})")
    L += stmt(3, f"nis[ch * {C} + {{l}}] += q_{{l}}")
    # health check and reset of dead lanes
    L += [f"        for l in range({C}):",
          f"            p = ch * {C} + l",
          "            ok = np.isfinite(ll[p])",
          f"            for i in range({n}):",
          f"                d = Pc[(i * {n} + i) * {C} + l]",
          f"                if not (d >= 0.0 and d <= {P_LIMIT!r}):",
          "                    ok = False",
          "            if not ok:",
          "                dead[p] = True",
          "                ll[p] = -np.inf",
          f"                for i in range({n}):",
          f"                    Xc[i * {C} + l] = 0.0",
          f"                    for j in range({n}):",
          f"                        Pc[(i * {n} + j) * {C} + l] = P0[i, j]"]
    return L


_SIG = ("void(f8[:, ::1], f8[:, ::1], f8[:, ::1], f8[:, ::1], f8[:, ::1], f8[::1], f8[::1], "
        "b1[::1], f8[:, ::1], f8[::1], f8[::1], b1[::1])")
_kf_kernel = compile_kernel("kf_step", _kf_source(NZ), _SIG, module=__name__,
                            source_file=__file__,
                            parallel=True)
_BLOCK_SIG = ("void(f8[:, ::1], f8[:, ::1], f8[:, ::1], f8[:, ::1], f8[:, ::1], f8[::1], "
              "f8[:, ::1], b1[::1], f8[:, ::1], f8[:, ::1], f8[:, ::1])")
_block_kernel = compile_kernel("kf_block", _block_source(NZ), _BLOCK_SIG, module=__name__,
                               source_file=__file__, parallel=True)


def kf_step(x: np.ndarray, P: np.ndarray, phi: np.ndarray, qd: np.ndarray, H: np.ndarray,
            r: np.ndarray, y: np.ndarray, use: np.ndarray, p0: np.ndarray,
            ll: np.ndarray, nis: np.ndarray, dead: np.ndarray) -> None:
    """One predict + update for all particles, in place (see the module docstring).

    ``x``, ``P`` are updated; ``ll`` and ``nis`` (n_particles_padded,) are *added to*
    (zero them first); ``dead`` is set True for particles that failed. ``y`` (ny,) with
    ``use`` (ny,) bool selecting the sensors to update with (none: predict only).
    """
    _kf_kernel(x, P, phi, qd, H, r, y, use, p0, ll, nis, dead)


def kf_block(x: np.ndarray, P: np.ndarray, phi: np.ndarray, qd: np.ndarray,
             H: np.ndarray, r: np.ndarray, Y: np.ndarray, full: np.ndarray, p0: np.ndarray,
             LL: np.ndarray, NIS: np.ndarray) -> None:
    """:func:`kf_step` for K samples in one call, in place: ``Y`` (K, ny) with ``full``
    (K,) True where every sensor is used, False for predict-only samples; ``LL``, ``NIS``
    (K, n_particles_padded) receive each sample's log-likelihood and NIS (set, not
    added; -inf for a particle that failed, whose filter is reset as in ``kf_step``).
    Bit-identical to K calls of :func:`kf_step`."""
    _block_kernel(x, P, phi, qd, H, r, Y, full, p0, LL, NIS)


def n_chunks(n_particles: int) -> int:
    """Chunks needed for ``n_particles`` (the last chunk is padded)."""
    return -(-n_particles // LANES)


def to_lanes(a: np.ndarray) -> np.ndarray:
    """(N, *shape) particle-first array -> lane layout (n_chunks, prod(shape) * LANES).

    Padding lanes repeat the last particle (so they stay finite); ignore them.
    """
    a = np.asarray(a, dtype=float)
    n = a.shape[0]
    m = n_chunks(n) * LANES
    if m != n:
        a = np.concatenate([a, np.repeat(a[-1:], m - n, axis=0)])
    inner = int(np.prod(a.shape[1:], dtype=int))
    out = a.reshape(m // LANES, LANES, inner).transpose(0, 2, 1)
    return np.ascontiguousarray(out).reshape(m // LANES, inner * LANES)


def from_lanes(a: np.ndarray, n_particles: int, shape: tuple[int, ...]) -> np.ndarray:
    """Inverse of :func:`to_lanes`: (n_chunks, prod(shape) * LANES) -> (N, *shape)."""
    nch = a.shape[0]
    inner = int(np.prod(shape, dtype=int))
    out = a.reshape(nch, inner, LANES).transpose(0, 2, 1).reshape(nch * LANES, *shape)
    return np.ascontiguousarray(out[:n_particles])
