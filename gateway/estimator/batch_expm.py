"""Exact (Phi, Qd) for many parameter vectors at once: scaling, Taylor and joint doubling.

For each particle, with A = B0 + B1/Csy + B2*Csay + B3*lambda in filter coordinates
(:mod:`gateway.model.coordinates`, balanced so that ``||A T||_1`` is about 3 at 1 ms) and the
track-noise intensity ``q`` (m^2/s, times the fixed unit noise matrix W)::

    Phi = expm(A T),       Qd = int_0^T expm(A s) q W expm(A s)' ds    (Van Loan)

Method, per chunk of LANES particles:

1. scale: ``h = T / 2**s`` with the smallest s such that ``||A h||_1 <= 1`` for every
   lane in the chunk;
2. ``Phi(h)`` by the degree-18 Taylor polynomial (Horner), truncation below 1e-17;
   the products with A use its fixed sparsity pattern (54 non-zeros of 256);
3. ``Qd(h) = sum_k h^(k+1)/(k+1)! L^k(qW)`` with ``L(X) = A X + X A'`` (degree 24,
   terms below 1e-18 of the first);
4. s exact doublings: ``Qd(2h) = Qd(h) + Phi(h) Qd(h) Phi(h)'``, ``Phi(2h) = Phi(h)^2``.

The reference is :func:`gateway.model.discretisation.van_loan` (scipy expm of the
Van Loan block); agreement about 1e-13 relative at one sample and 1e-11 after 13
doublings (tests/test_discretisation.py, tests/test_kalman.py), including unstable and
extreme parameter vectors. Lane layout as in
:mod:`gateway.estimator.lanecode`; inputs ``coef (n_chunks, 4 * LANES)`` (basis coefficients
``1, 1/Csy, Csay, lambda``), ``q (n_chunks, LANES)``; outputs ``(n_chunks, 256 * LANES)``.
No I/O.
"""

from __future__ import annotations

import numpy as np

from gateway.estimator.kalman import BLOCK, to_lanes
from gateway.estimator.lanecode import LANES, block_product, compile_kernel, stmt
from gateway.model.coordinates import NZ, FilterCoords
from gateway.model.vehicle import theta_basis

TAYLOR_DEGREE = 18
SERIES_DEGREE = 24
NORM_MAX = 1.0


def _sparse_product(indent: int, out: str, mat: str, n: int) -> list[str]:
    """``out = B mat`` over the CSR pattern (rp, ci) of B; lanes unrolled."""
    C = LANES
    pad = "    " * indent
    L = [f"{pad}for i in range({n}):", f"{pad}    for j in range({n}):"]
    L += stmt(indent + 2, "s_{l} = 0.0")
    L += [f"{pad}        for q in range(rp[i], rp[i + 1]):", f"{pad}            k = ci[q]"]
    L += stmt(indent + 3, f"s_{{l}} += B[(i * {n} + k) * {C} + {{l}}] * "
                          f"{mat}[(k * {n} + j) * {C} + {{l}}]")
    L += stmt(indent + 2, f"{out}[(i * {n} + j) * {C} + {{l}}] = s_{{l}}")
    return L


def _source(n: int) -> list[str]:
    C = LANES
    nn = n * n * C
    mat = f"(({{i}}) * {n} + ({{j}})) * {C}"
    mir = f"(({{j}}) * {n} + ({{i}})) * {C}"
    bi, bj = BLOCK
    loops = [f"for ib in range(0, {n}, {bi}):", f"    for jb in range(0, {n}, {bj}):"]
    L = ["def phi_qd(terms, nzr, nzc, rp, ci, W, coef, qv, dt, PHI, QD):",
         "    nch = coef.shape[0]",
         "    for ch in prange(nch):",
         f"        B = np.zeros({nn})", f"        E = np.zeros({nn})",
         f"        Y = np.empty({nn})", f"        X = np.empty({nn})",
         f"        S = np.empty({nn})", f"        M = np.empty({nn})",
         "        for z in range(nzr.shape[0]):",
         "            i = nzr[z]", "            j = nzc[z]"]
    L += stmt(3, f"B[(i * {n} + j) * {C} + {{l}}] = (terms[0, i, j] "
                 f"+ terms[1, i, j] * coef[ch, {C} + {{l}}] "
                 f"+ terms[2, i, j] * coef[ch, {2 * C} + {{l}}] "
                 f"+ terms[3, i, j] * coef[ch, {3 * C} + {{l}}]) * dt")
    # 1-norm of A*dt, max over lanes; scaling exponent
    L += ["        nrm = 0.0", f"        for l in range({C}):",
          f"            for j in range({n}):", "                c = 0.0",
          f"                for i in range({n}):",
          f"                    c += abs(B[(i * {n} + j) * {C} + l])",
          "                if c > nrm:", "                    nrm = c",
          "        s = 0", "        h = 1.0",
          f"        while nrm * h > {NORM_MAX!r} and s < 60:", "            h *= 0.5",
          "            s += 1",
          f"        for z in range({nn}):", "            B[z] *= h"]
    # Taylor / Horner: E = I + B/kk E
    L += [f"        for i in range({n}):"]
    L += stmt(3, f"E[(i * {n} + i) * {C} + {{l}}] = 1.0")
    L += [f"        for kk in range({TAYLOR_DEGREE}, 0, -1):", "            c = 1.0 / kk"]
    L += _sparse_product(3, "Y", "E", n)
    L += [f"            for z in range({nn}):", "                E[z] = c * Y[z]",
          f"            for i in range({n}):"]
    L += stmt(4, f"E[(i * {n} + i) * {C} + {{l}}] += 1.0")
    # Qd series: X_0 = q W h, X_k = L(X_{k-1}) h/(k+1)
    L += [f"        for i in range({n}):", f"            for j in range({n}):"]
    L += stmt(4, f"X[(i * {n} + j) * {C} + {{l}}] = W[i, j] * qv[ch, {{l}}] * dt * h")
    L += [f"        for z in range({nn}):", "            S[z] = X[z]",
          f"        for kk in range(1, {SERIES_DEGREE + 1}):", "            c = 1.0 / (kk + 1)"]
    L += _sparse_product(3, "Y", "X", n)
    L += [f"            for i in range({n}):", f"                for j in range({n}):"]
    L += stmt(5, f"X[(i * {n} + j) * {C} + {{l}}] = c * (Y[(i * {n} + j) * {C} + {{l}}] "
                 f"+ Y[(j * {n} + i) * {C} + {{l}}])")
    L += [f"            for z in range({nn}):", "                S[z] += X[z]"]
    # doublings
    L += ["        for _ in range(s):"] + ["            " + s for s in loops]
    L += block_product(5, a="E", a_row=f"({{r}} * {n} + k) * {C}", b="S",
                       b_row=f"(k * {n} + {{r}}) * {C}", n=n, bi=bi, bj=bj, init=None,
                       out=[("M", mat)])
    L += ["            " + s for s in loops]
    L += [f"                    if jb + {bj - 1} < ib:", "                        continue"]
    L += block_product(5, a="M", a_row=f"({{r}} * {n} + k) * {C}", b="E",
                       b_row=f"({{r}} * {n} + k) * {C}", n=n, bi=bi, bj=bj,
                       init="S[" + mat + " + {l}]", out=[("X", mat), ("X", mir)],
                       guard="{j} >= {i}")
    L += ["            " + s for s in loops]
    L += block_product(5, a="E", a_row=f"({{r}} * {n} + k) * {C}", b="E",
                       b_row=f"(k * {n} + {{r}}) * {C}", n=n, bi=bi, bj=bj, init=None,
                       out=[("Y", mat)])
    L += [f"            for z in range({nn}):", "                S[z] = X[z]",
          "                E[z] = Y[z]"]
    L += [f"        for z in range({nn}):", "            PHI[ch, z] = E[z]",
          "            QD[ch, z] = S[z]"]
    return L


_SIG = ("void(f8[:, :, ::1], i8[::1], i8[::1], i8[::1], i8[::1], f8[:, ::1], f8[:, ::1], "
        "f8[:, ::1], f8, f8[:, ::1], f8[:, ::1])")
_kernel = compile_kernel("phi_qd", _source(NZ), _SIG, module=__name__, source_file=__file__,
                         parallel=True)


class DiscreteBatch:
    """Batched exact discretisation for one coordinate system and speed.

    ``compute(theta (N, 3), q (N,), phi_out, qd_out)`` fills lane-layout arrays
    ``(n_chunks, 256 * LANES)`` with Phi and Qd for every particle.
    """

    def __init__(self, coords: FilterCoords, v_mps: float, dt_s: float) -> None:
        self.v_mps = float(v_mps)
        self.dt_s = float(dt_s)
        self.terms = np.ascontiguousarray(coords.terms(v_mps))
        nz = coords.sparsity()
        rows, cols = np.nonzero(nz)
        self._nzr = rows.astype(np.int64)
        self._nzc = cols.astype(np.int64)
        self._rp = np.concatenate([[0], np.cumsum(nz.sum(axis=1))]).astype(np.int64)
        self._ci = cols.astype(np.int64)
        self._w = np.ascontiguousarray(coords.noise_unit())

    def compute(self, theta: np.ndarray, q: np.ndarray, phi_out: np.ndarray,
                qd_out: np.ndarray) -> None:
        """theta (N, 3) [N s/m, N s/m, -]; q (N,) noise intensity [m^2/s]."""
        coef = to_lanes(theta_basis(np.asarray(theta, dtype=float)))
        qv = to_lanes(np.asarray(q, dtype=float)[:, None])
        _kernel(self.terms, self._nzr, self._nzc, self._rp, self._ci, self._w, coef, qv,
                self.dt_s, phi_out, qd_out)
