"""Fast mode's steady-state Kalman gains per particle: a batched DARE solve, and its step.

Over 400 lines: the generators of two lane kernels (the doubling with its Newton
step and warm start, the block of steady steps) and their typed wrappers, one concern.

A particle's covariance and gains depend only on its theta and the speed, never on the
data, and theta is fixed between resample-moves. Fast mode therefore gives each particle
the steady state of its Riccati recursion, computed once when its theta or the speed band
changes, and then steps only the mean::

    x <- Phi x;  for each sensor s:  e_s = y_s - h_s x;  x <- x + g_s e_s / S_s
    loglik = -(c0 + sum_s e_s^2 / S_s) / 2,     c0 = sum_s log(2 pi S_s)

``g_s = P_s h_s'`` and ``S_s = h_s P_s h_s' + r_s`` are the sequential (scalar, R
diagonal) update quantities of the exact kernel (:mod:`gateway.estimator.kalman`) at the
steady predicted covariance ``P-``; their product is the joint update
``x <- Phi x + K (y - H Phi x)``. About 750 flop per particle and sample, against
15.7 kflop for the exact recursion.

Why a DARE solve and not "run the recursion until it converges, then freeze": this
model's Riccati recursion has a closed-loop mode at 0.99987 per sample (3 sensors; 5
sensors 0.99996), a weakly observed position drift, so P converges at about 0.26 1/s
and a particle freezes only after 45 s, while resample-moves come every 0.3-2 s
(measured on branch ``fast``, docs/estimator.md "Fast mode"). Structure-preserving
doubling (SDA, Chu et al. 2004; Anderson & Moore's doubling) squares the horizon at each
iteration: 17-19 iterations reach the fixed point to 1e-10, whatever the slow mode.

The unobservable static-yaw set-up (model notes section 2): A(theta) keeps one zero
eigenvalue with null vector ``v0`` and ``H v0 = 0``; the track's random walks drive it, so
P grows along ``v0 v0'`` without bound (the exact filter's P does too). The gains do not
depend on that component, but doubling makes it grow as 2**k and its rounding then
pollutes ``P h'`` (1e-8 at 17 iterations). Each iteration therefore removes the
``v0 v0'`` component of the iterate, which provably leaves every other component and the
gains unchanged (``G_k v0 = 0``, ``v0' A_k = v0'``, so the recursion carries it apart).

SDA for the filter DARE ``P = Phi P Phi' - Phi P H' (H P H' + R)^-1 H P Phi' + Q``:
``A0 = Phi'``, ``G0 = H' R^-1 H``, ``H0 = Qd``; with ``W = I + G_k H_k``::

    A_k+1 = A_k W^-1 A_k,   G_k+1 = G_k + A_k W^-1 G_k A_k',   H_k+1 = H_k + A_k' H_k W^-1 A_k

``H_k`` is the predicted covariance after ``2**k`` samples from ``Qd``; ``W`` is solved by
Gauss-Jordan elimination with partial pivoting, per particle. A particle whose iteration
does not converge within ``MAX_ITER`` or turns non-finite is *dead* for the band: log-
likelihood -inf and state 0, as in the exact kernel.

Warm start (a move): a moved particle's theta is a jitter away from its ancestor's, so
its DARE starts from the ancestor's ``P-`` and takes Newton steps (each a Stein solve,
as in the polish) until a step changes ``P- H'`` by less than ``DARE_TOL`` of its
largest element: 2-4 steps instead of the doubling's 17-19 iterations plus one step,
and the same solution (to 1e-9, tests/test_fast_mode.py). A particle for which the
Newton steps do not converge within ``NEWTON_MAX`` (or turn non-finite: its ancestor's
gain no longer stabilises it) is solved cold. A new speed band always solves cold (its
start, the last band's ``P-``, gave an unstable closed loop: measured). The gains then
depend on the history, so a fast-mode checkpoint keeps them.

Arrays use the lane layout of :mod:`gateway.estimator.lanecode`: ``Phi, Qd, P-`` are
``(n_chunks, 256 * LANES)``, null vectors ``(n_chunks, 16 * LANES)``, gains ``g``
``(n_chunks, ny * 16 * LANES)``, ``S`` ``(n_chunks, ny * LANES)``, ``c0`` and per-particle
outputs ``(n_chunks * LANES,)``. No I/O.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gateway.estimator.kalman import _LOG_2PI, from_lanes, n_chunks, to_lanes
from gateway.estimator.lanecode import LANES, block_product, compile_kernel, stmt
from gateway.model.coordinates import NZ

BLOCK_ROWS = 8
"""Rows of ``Phi x`` computed together in the steady step (16 vector accumulators with
8 lanes: 8 was fastest of 2, 4, 8 and 16, measured 2026-11-25)."""
MAX_ITER = 40
"""Doubling iterations before a particle is declared dead (2**40 samples)."""
SMITH_ITER = 20
"""Squarings in the Newton step's Stein solve: the closed loop to the power 2**22 (the
slowest decaying mode, 0.99996 per sample with 5 sensors, is then below 1e-19)."""
NEWTON_MAX = 4
"""Newton steps of a warm start before the particle is solved cold (from a move's
jitter, 2-3 steps reach ``DARE_TOL``; measured 2026-11-26)."""
DARE_TOL = 1e-6
"""A particle's doubling has converged when an iteration changes no element of P- H' by
more than this times its largest (quadratic convergence: the iterate is then far closer)."""


def _mat(n: int, cols: int | None = None) -> str:
    return f"(({{i}}) * {cols or n} + ({{j}})) * {LANES}"


def _deflate(indent: int, arr: str, n: int) -> list[str]:
    """Lines removing the ``v0 v0'`` component (unit ``Vc``) of the symmetric ``arr``."""
    C, pad = LANES, "    " * indent
    L = stmt(indent, "b_{l} = 0.0")
    L += [f"{pad}for i in range({n}):"]
    L += stmt(indent + 1, "u_{l} = 0.0")
    L += [f"{pad}    for j in range({n}):"]
    L += stmt(indent + 2, f"u_{{l}} += {arr}[(i * {n} + j) * {C} + {{l}}] * Vc[j * {C} + {{l}}]")
    L += stmt(indent + 1, f"b_{{l}} += Vc[i * {C} + {{l}}] * u_{{l}}")
    L += [f"{pad}for i in range({n}):", f"{pad}    for j in range({n}):"]
    L += stmt(indent + 2, f"{arr}[(i * {n} + j) * {C} + {{l}}] -= b_{{l}} * Vc[i * {C} + {{l}}] "
                          f"* Vc[j * {C} + {{l}}]")
    return L


def _newton(n: int) -> list[str]:
    """Lines of one Newton step on the DARE at ``Hm`` (the doubling's P-): its correction
    into ``Xs`` (the caller adds it).

    The Riccati map R linearised at P is ``R(P + D) = R(P) + M D M'`` with ``M`` the
    closed loop ``Phi (I - K H)``; the step solves the Stein equation
    ``D - M D M' = R(P) - P`` by Smith's doubling (``SMITH_ITER`` squarings of M, the
    v0 v0' component removed as in the main loop). The doubling alone leaves a
    fixed-point residual of about 1e-10 per Riccati step, which the exact recursion
    integrates along the slow mode; after this step the steady filter and the exact
    one agree to about 1e-11 (tests/test_fast_mode.py).
    """
    C = LANES
    m = _mat(n)
    mirror = m.replace("{i}", "{tmp}").replace("{j}", "{i}").replace("{tmp}", "{j}")
    loops = [f"        for ib in range(0, {n}, 2):", f"            for jb in range(0, {n}, 2):"]
    upper = loops + ["                if jb + 1 < ib:", "                    continue"]
    L = [f"        for i in range({n * n * C}):", "            Pu[i] = Hm[i]",
         f"        for i in range({n}):", f"            for j in range({n}):",
         f"                for l in range({C}):",
         f"                    Lm[(i * {n} + j) * {C} + l] = 1.0 if i == j else 0.0",
         "        for s in range(ny):", f"            for i in range({n}):"]
    L += stmt(4, "u_{l} = 0.0")
    L += [f"                for k in range({n}):", "                    hk = H[s, k]"]
    L += stmt(5, f"u_{{l}} += Pu[(i * {n} + k) * {C} + {{l}}] * hk")
    L += stmt(4, f"ph[i * {C} + {{l}}] = u_{{l}}")
    L += stmt(3, "e_{l} = r[s]")
    L += [f"            for k in range({n}):", "                hk = H[s, k]"]
    L += stmt(4, f"e_{{l}} += hk * ph[k * {C} + {{l}}]")
    L += stmt(3, "e_{l} = 1.0 / e_{l}")
    L += [f"            for j in range({n}):"]
    L += stmt(4, "u_{l} = 0.0")
    L += [f"                for k in range({n}):", "                    hk = H[s, k]"]
    L += stmt(5, f"u_{{l}} += hk * Lm[(k * {n} + j) * {C} + {{l}}]")
    L += stmt(4, f"hl[j * {C} + {{l}}] = u_{{l}}")
    L += [f"            for i in range({n}):"]
    L += stmt(4, f"zk_{{l}} = ph[i * {C} + {{l}}] * e_{{l}}")
    L += [f"                for j in range({n}):"]
    L += stmt(5, f"Lm[(i * {n} + j) * {C} + {{l}}] -= zk_{{l}} * hl[j * {C} + {{l}}]")
    L += stmt(5, f"Pu[(i * {n} + j) * {C} + {{l}}] -= zk_{{l}} * ph[j * {C} + {{l}}]")
    # Mk = Phi L, T = Phi Pu, Xs = T Phi' + Q - Hm (the residual R(P) - P)
    L += loops
    L += block_product(4, a="Fc", a_row=f"({{r}} * {n} + k) * {C}", b="Lm",
                       b_row=f"(k * {n} + {{r}}) * {C}", n=n, bi=2, bj=2, init=None,
                       out=[("Mk", m)])
    L += loops
    L += block_product(4, a="Fc", a_row=f"({{r}} * {n} + k) * {C}", b="Pu",
                       b_row=f"(k * {n} + {{r}}) * {C}", n=n, bi=2, bj=2, init=None,
                       out=[("T", m)])
    L += upper
    L += block_product(4, a="T", a_row=f"({{r}} * {n} + k) * {C}", b="Fc",
                       b_row=f"({{r}} * {n} + k) * {C}", n=n, bi=2, bj=2,
                       init="Qc[" + m + " + {l}] - Hm[" + m + " + {l}]",
                       out=[("Xs", m), ("Xs", mirror)], guard="{j} >= {i}")
    L += _deflate(2, "Xs", n)
    L += [f"        for it2 in range({SMITH_ITER}):"]
    inner = ["    " + line for line in loops]
    L += inner
    L += block_product(5, a="Mk", a_row=f"({{r}} * {n} + k) * {C}", b="Xs",
                       b_row=f"(k * {n} + {{r}}) * {C}", n=n, bi=2, bj=2, init=None,
                       out=[("T", m)])
    L += ["    " + line for line in upper]
    L += block_product(5, a="T", a_row=f"({{r}} * {n} + k) * {C}", b="Mk",
                       b_row=f"({{r}} * {n} + k) * {C}", n=n, bi=2, bj=2,
                       init="Xs[" + m + " + {l}]", out=[("Xn", m), ("Xn", mirror)],
                       guard="{j} >= {i}")
    L += _deflate(3, "Xn", n)
    L += inner
    L += block_product(5, a="Mk", a_row=f"({{r}} * {n} + k) * {C}", b="Mk",
                       b_row=f"(k * {n} + {{r}}) * {C}", n=n, bi=2, bj=2, init=None,
                       out=[("Mn", m)])
    L += ["            Xs, Xn = Xn, Xs", "            Mk, Mn = Mn, Mk"]
    return L


def _polish(n: int) -> list[str]:
    """Lines of one Newton step on the DARE at ``Hm``, in place (:func:`_newton`)."""
    return _newton(n) + [f"        for i in range({n * n * LANES}):", "            Hm[i] += Xs[i]"]


def _ph_change(indent: int, new: str, old: str, n: int) -> list[str]:
    """Lines setting ``dm_l``, the largest change of ``P- H'`` from ``old`` to ``new``,
    and ``hm_l``, the largest element of ``new H'`` (per lane): how far an iteration (the
    doubling's, or a warm start's Newton step) still moves what the filter uses (the v0
    direction is in no gain)."""
    C, pad = LANES, "    " * indent
    L = stmt(indent, "dm_{l} = 0.0") + stmt(indent, "hm_{l} = 0.0")
    L += [f"{pad}for s in range(ny):", f"{pad}    for i in range({n}):"]
    L += stmt(indent + 2, "u_{l} = 0.0") + stmt(indent + 2, "w_{l} = 0.0")
    L += [f"{pad}        for j in range({n}):", f"{pad}            hk = H[s, j]"]
    L += stmt(indent + 3, f"u_{{l}} += {new}[(i * {n} + j) * {C} + {{l}}] * hk")
    L += stmt(indent + 3, f"w_{{l}} += {old}[(i * {n} + j) * {C} + {{l}}] * hk")
    L += stmt(indent + 2, "dm_{l} = max(dm_{l}, abs(u_{l} - w_{l}))")
    L += stmt(indent + 2, "hm_{l} = max(hm_{l}, abs(u_{l}))")
    return L


def _warm_start(n: int) -> list[str]:
    """Lines of the warm start: Newton steps on the DARE from ``P0`` (a nearby solution:
    the resampled ancestor's P- before a move's jitter), each lane until its correction
    to ``P- H'`` is below ``tol`` times its largest element (:func:`_ph_change`, as the
    doubling measures its own); quadratic convergence then leaves it within about
    ``tol**2`` (measured: 2-3 steps from a 1 % jitter, docs/estimator.md "Fast mode").
    A converged lane keeps its ``P-`` while the others go on, so that a particle's result
    does not depend on its chunk. A lane still moving after ``newton_max`` steps, or not
    finite, is marked not converged (``iters`` 0) for the caller to solve cold; one that
    converged gets ``iters`` = -(its Newton steps)."""
    C = LANES
    step = ["        " + line for line in _newton(n)]
    L = ["        if warm:", "            Pw = P0[ch]",
         f"            for i in range({n * n * C}):", "                Hm[i] = Pw[i]"]
    L += ["    " + line for line in _deflate(2, "Hm", n)]
    L += ["            for itn in range(newton_max):"]
    L += step
    L += [f"                for i in range({n * n * C}):",
          "                    Hn[i] = Hm[i] + Xs[i]"]
    L += _ph_change(4, "Hn", "Hm", n)
    L += [f"                for l in range({C}):",
          f"                    if iters[ch * {C} + l] == 0:",
          f"                        for i in range({n * n}):",
          f"                            Hm[i * {C} + l] = Hn[i * {C} + l]",
          "                wdone = True"]
    for lane in range(C):
        p = f"ch * {C} + {lane}"
        L += [f"                if iters[{p}] == 0:",
              f"                    if dm_{lane} <= tol * hm_{lane} and hm_{lane} < np.inf:",
              f"                        iters[{p}] = -(itn + 1)",
              "                    else:",
              "                        wdone = False"]
    L += ["                if wdone:", "                    break",
          f"            for l in range({C}):",
          f"                if iters[ch * {C} + l] == 0:",
          "                    ok[l] = False",
          "            done = True"]
    return L


def _sda_source(n: int) -> list[str]:
    C = LANES
    m = _mat(n)
    z = 3 * n                                   # columns of the augmented [W | A | G]
    L = ["def sda(F, Q, G0, V, H, r, tol, maxit, P0, warm, newton_max, P, Gs, Ss, c0, iters):",
         "    nch = F.shape[0]",
         "    ny = H.shape[0]",
         "    for ch in prange(nch):",
         f"        A = np.empty({n * n * C})",
         f"        Gm = np.empty({n * n * C})",
         f"        Hm = np.empty({n * n * C})",
         f"        An = np.empty({n * n * C})",
         f"        Gn = np.empty({n * n * C})",
         f"        Hn = np.empty({n * n * C})",
         f"        T = np.empty({n * n * C})",
         f"        Z = np.empty({n * z * C})",
         f"        ph = np.empty({n * C})",
         f"        hl = np.empty({n * C})",
         f"        Pu = np.empty({n * n * C})",
         f"        Lm = np.empty({n * n * C})",
         f"        Mk = np.empty({n * n * C})",
         f"        Mn = np.empty({n * n * C})",
         f"        Xs = np.empty({n * n * C})",
         f"        Xn = np.empty({n * n * C})",
         f"        ok = np.ones({C}, np.bool_)",
         "        Fc = F[ch]",
         "        Qc = Q[ch]",
         "        Vc = V[ch]",
         f"        for i in range({n}):",
         f"            for j in range({n}):",
         f"                for l in range({C}):",
         f"                    A[(i * {n} + j) * {C} + l] = Fc[(j * {n} + i) * {C} + l]",
         f"                    Gm[(i * {n} + j) * {C} + l] = G0[i, j]",
         f"                    Hm[(i * {n} + j) * {C} + l] = Qc[(i * {n} + j) * {C} + l]",
         f"        for l in range({C}):",
         f"            iters[ch * {C} + l] = 0",
         "        it = 0",
         "        done = False"]
    L += _warm_start(n)
    L += ["        while not done and it < maxit:",
         "            it += 1"]
    loops = [f"            for ib in range(0, {n}, 2):",
             f"                for jb in range(0, {n}, 2):"]
    upper = loops + ["                    if jb + 1 < ib:", "                        continue"]
    mirror = m.replace("{i}", "{tmp}").replace("{j}", "{i}").replace("{tmp}", "{j}")
    zoff = f"(({{i}}) * {z} + ({{j}})) * {C}"
    # W = I + Gm Hm into Z[:, 0:n]
    L += loops
    L += block_product(5, a="Gm", a_row=f"({{r}} * {n} + k) * {C}", b="Hm",
                       b_row=f"(k * {n} + {{r}}) * {C}", n=n, bi=2, bj=2, init=None,
                       out=[("Z", zoff)])
    L += [f"            for i in range({n}):"]
    L += stmt(4, f"Z[(i * {z} + i) * {C} + {{l}}] += 1.0")
    L += [f"                for j in range({n}):"]
    L += stmt(5, f"Z[(i * {z} + {n} + j) * {C} + {{l}}] = A[(i * {n} + j) * {C} + {{l}}]")
    L += stmt(5, f"Z[(i * {z} + {2 * n} + j) * {C} + {{l}}] = Gm[(i * {n} + j) * {C} + {{l}}]")
    # Gauss-Jordan with partial pivoting, per lane
    L += [f"            for c in range({n}):",
          f"                for l in range({C}):",
          "                    best = -1.0",
          "                    piv = c",
          f"                    for rr in range(c, {n}):",
          f"                        a = abs(Z[(rr * {z} + c) * {C} + l])",
          "                        if a > best:",
          "                            best = a",
          "                            piv = rr",
          "                    if not (best > 0.0):",
          "                        ok[l] = False",
          "                    if piv != c:",
          f"                        for j in range(c, {z}):",
          f"                            t1 = Z[(c * {z} + j) * {C} + l]",
          f"                            Z[(c * {z} + j) * {C} + l] = Z[(piv * {z} + j) * {C} + l]",
          f"                            Z[(piv * {z} + j) * {C} + l] = t1"]
    L += stmt(4, f"d_{{l}} = 1.0 / Z[(c * {z} + c) * {C} + {{l}}]")
    L += [f"                for j in range(c + 1, {z}):"]
    L += stmt(5, f"Z[(c * {z} + j) * {C} + {{l}}] *= d_{{l}}")
    L += [f"                for rr in range({n}):", "                    if rr == c:",
          "                        continue"]
    L += stmt(5, f"f_{{l}} = Z[(rr * {z} + c) * {C} + {{l}}]")
    L += [f"                    for j in range(c + 1, {z}):"]
    L += stmt(6, f"Z[(rr * {z} + j) * {C} + {{l}}] -= f_{{l}} * Z[(c * {z} + j) * {C} + {{l}}]")
    # An = A X1, T = A X2 (X1 = Z[:, n:2n], X2 = Z[:, 2n:3n])
    L += loops
    L += block_product(5, a="A", a_row=f"({{r}} * {n} + k) * {C}", b="Z",
                       b_row=f"(k * {z} + {n} + {{r}}) * {C}", n=n, bi=2, bj=2, init=None,
                       out=[("An", m)])
    L += loops
    L += block_product(5, a="A", a_row=f"({{r}} * {n} + k) * {C}", b="Z",
                       b_row=f"(k * {z} + {2 * n} + {{r}}) * {C}", n=n, bi=2, bj=2,
                       init=None, out=[("T", m)])
    # Gn = Gm + T A' (symmetric: upper triangle, mirrored)
    L += upper
    L += block_product(5, a="T", a_row=f"({{r}} * {n} + k) * {C}", b="A",
                       b_row=f"({{r}} * {n} + k) * {C}", n=n, bi=2, bj=2,
                       init="Gm[" + m + " + {l}]", out=[("Gn", m), ("Gn", mirror)],
                       guard="{j} >= {i}")
    # T = A' Hm, Hn = Hm + T X1 (symmetric)
    L += loops
    L += block_product(5, a="A", a_row=f"(k * {n} + {{r}}) * {C}", b="Hm",
                       b_row=f"(k * {n} + {{r}}) * {C}", n=n, bi=2, bj=2, init=None,
                       out=[("T", m)])
    L += upper
    L += block_product(5, a="T", a_row=f"({{r}} * {n} + k) * {C}", b="Z",
                       b_row=f"(k * {z} + {n} + {{r}}) * {C}", n=n, bi=2, bj=2,
                       init="Hm[" + m + " + {l}]", out=[("Hn", m), ("Hn", mirror)],
                       guard="{j} >= {i}")
    # a particle that has converged keeps its P- (later iterations only add rounding)
    L += [f"            for l in range({C}):",
          f"                if iters[ch * {C} + l] > 0:",
          f"                    for i in range({n * n}):",
          f"                        Hn[i * {C} + l] = Hm[i * {C} + l]"]
    # remove the v0 v0' component (unit v0), then measure the change
    L += _deflate(3, "Hn", n)
    L += _ph_change(3, "Hn", "Hm", n)
    # converged: the doubling converges quadratically, so once an iteration changes P- H'
    # by less than tol the iterate is within about tol**2 (then the Newton step polishes)
    L += ["            done = True"]
    for lane in range(C):
        p = f"ch * {C} + {lane}"
        L += [f"            if iters[{p}] == 0:",
              f"                if not (dm_{lane} == dm_{lane} and hm_{lane} == hm_{lane}):",
              f"                    ok[{lane}] = False",
              f"                elif dm_{lane} <= tol * hm_{lane}:",
              f"                    iters[{p}] = it",
              "                else:",
              "                    done = False"]
    L += ["            A, An = An, A", "            Gm, Gn = Gn, Gm", "            Hm, Hn = Hn, Hm"]
    L += ["        if not done:", f"            for l in range({C}):",
          "                ok[l] = False"]
    L += ["        if not warm:"] + ["    " + line for line in _polish(n)]
    L += ["        Pc = P[ch]",
          f"        for i in range({n * n * C}):",
          "            Pc[i] = Hm[i]"]
    # the sequential scalar updates at P-: gains, pivots and log det, on a copy (Hm)
    L += stmt(2, "q_{l} = 0.0")
    L += ["        for s in range(ny):", f"            for i in range({n}):"]
    L += stmt(4, "u_{l} = 0.0")
    L += [f"                for k in range({n}):", "                    hk = H[s, k]"]
    L += stmt(5, f"u_{{l}} += Hm[(i * {n} + k) * {C} + {{l}}] * hk")
    L += stmt(4, f"ph[i * {C} + {{l}}] = u_{{l}}")
    L += stmt(3, "e_{l} = r[s]")
    L += [f"            for k in range({n}):", "                hk = H[s, k]"]
    L += stmt(4, f"e_{{l}} += hk * ph[k * {C} + {{l}}]")
    L += stmt(3, f"Ss[ch, s * {C} + {{l}}] = e_{{l}}")
    L += stmt(3, "q_{l} += np.log(e_{l})")
    L += stmt(3, "e_{l} = 1.0 / e_{l}")
    L += [f"            for i in range({n}):"]
    L += stmt(4, f"Gs[ch, (s * {n} + i) * {C} + {{l}}] = ph[i * {C} + {{l}}]")
    L += stmt(4, f"zk_{{l}} = ph[i * {C} + {{l}}] * e_{{l}}")
    L += [f"                for j in range({n}):"]
    L += stmt(5, f"Hm[(i * {n} + j) * {C} + {{l}}] -= zk_{{l}} * ph[j * {C} + {{l}}]")
    for lane in range(C):
        p = f"ch * {C} + {lane}"
        L += [f"        c0[{p}] = q_{lane} + ny * {_LOG_2PI!r}",
              f"        if not (ok[{lane}] and np.isfinite(c0[{p}])):",
              f"            c0[{p}] = np.inf",
              "            for s in range(ny):",
              f"                Ss[ch, s * {C} + {lane}] = 1.0",
              f"                for i in range({n}):",
              f"                    Gs[ch, (s * {n} + i) * {C} + {lane}] = 0.0"]
    return L


def _block_source(n: int, rows: int = BLOCK_ROWS) -> list[str]:
    """The steady step for K samples at once: each chunk runs all of them in turn (its
    state stays in cache), writing each sample's log-likelihood and NIS.

    Written for instruction-level parallelism (each FMA chain used to wait on the one
    before it: 4 cycles a step): ``Phi x`` takes ``rows`` rows at once (2 * rows
    independent vector accumulators), each row block feeds every sensor's innovation
    ``y_s - h_s Phi x`` as soon as it is done, and the sequential updates are replayed
    through the cross terms ``h_s g_s2`` (s2 < s, computed once per call)::

        e_s = y_s - h_s Phi x - sum_{s2 < s} (h_s g_s2) e_s2 / S_s2

    the same algebra as updating ``x`` after each sensor, to rounding; ``x`` then takes
    every sensor's correction at once. 2.5-3.5x the single-chain kernel (measured
    2026-11-25, m = 1000, 3 and 5 sensors).
    """
    C = LANES
    L = ["def kf_steady_block(X, F, H, Y, full, Gs, Ss, c0, LL, NIS):",
         "    nch = X.shape[0]",
         "    ny = H.shape[0]",
         "    nt = Y.shape[0]",
         "    for ch in prange(nch):",
         f"        xn = np.empty({n * C})",
         f"        E = np.empty(ny * {C})",
         f"        Et = np.empty(ny * {C})",
         f"        Si = np.empty(ny * {C})",
         f"        cc = np.zeros(ny * ny * {C})",
         "        Fc = F[ch]",
         "        Xc = X[ch]",
         "        Gc = Gs[ch]",
         # cross terms c[s, s2] = h_s . g_s2 / S_s2 (s2 < s), and 1 / S_s
         "        for s in range(ny):"]
    L += stmt(3, f"Si[s * {C} + {{l}}] = 1.0 / Ss[ch, s * {C} + {{l}}]")
    L += ["            for s2 in range(s):"]
    L += stmt(4, "a_{l} = 0.0")
    L += [f"                for k in range({n}):", "                    hk = H[s, k]"]
    L += stmt(5, f"a_{{l}} += hk * Gc[(s2 * {n} + k) * {C} + {{l}}]")
    L += stmt(4, f"cc[(s * ny + s2) * {C} + {{l}}] = a_{{l}}")
    L += ["        for t in range(nt):",
          "            ft = full[t]",
          "            if ft:",
          "                for s in range(ny):"]
    L += stmt(5, f"E[s * {C} + {{l}}] = Y[t, s]")
    L += [f"            for ib in range(0, {n}, {rows}):"]
    for p in range(rows):
        L += stmt(4, f"a{p}_{{l}} = 0.0")
    L += [f"                for k in range({n}):"]
    L += stmt(5, f"w_{{l}} = Xc[k * {C} + {{l}}]")
    for p in range(rows):
        L += stmt(5, f"a{p}_{{l}} += Fc[((ib + {p}) * {n} + k) * {C} + {{l}}] * w_{{l}}")
    for p in range(rows):
        L += stmt(4, f"xn[(ib + {p}) * {C} + {{l}}] = a{p}_{{l}}")
    L += ["                if ft:", "                    for s in range(ny):"]
    for p in range(rows):
        L += [f"                        h{p} = H[s, ib + {p}]"]
    L += stmt(6, f"E[s * {C} + {{l}}] -= " + " + ".join(f"h{p} * a{p}_{{l}}" for p in range(rows)))
    L += stmt(3, "q_{l} = 0.0")
    L += ["            if ft:", "                for s in range(ny):"]
    L += stmt(5, f"e_{{l}} = E[s * {C} + {{l}}]")
    L += ["                    for s2 in range(s):"]
    L += stmt(6, f"e_{{l}} -= cc[(s * ny + s2) * {C} + {{l}}] * Et[s2 * {C} + {{l}}]")
    L += stmt(5, f"g_{{l}} = Si[s * {C} + {{l}}]")
    L += stmt(5, "q_{l} += e_{l} * e_{l} * g_{l}")
    L += stmt(5, f"Et[s * {C} + {{l}}] = e_{{l}} * g_{{l}}")
    L += [f"                for i in range({n}):"]
    L += stmt(5, f"b_{{l}} = xn[i * {C} + {{l}}]")
    L += ["                    for s in range(ny):"]
    L += stmt(6, f"b_{{l}} += Gc[(s * {n} + i) * {C} + {{l}}] * Et[s * {C} + {{l}}]")
    L += stmt(5, f"xn[i * {C} + {{l}}] = b_{{l}}")
    for lane in range(C):
        at = f"ch * {C} + {lane}"
        L += ["            if ft:",
              f"                LL[t, {at}] = 0.0 - 0.5 * (c0[{at}] + q_{lane})",
              f"                NIS[t, {at}] = q_{lane}",
              "            else:",
              f"                LL[t, {at}] = 0.0",
              f"                NIS[t, {at}] = 0.0",
              f"            if c0[{at}] == np.inf:",
              f"                LL[t, {at}] = -np.inf",
              f"                for i in range({n}):",
              f"                    xn[i * {C} + {lane}] = 0.0"]
    L += [f"            for i in range({n * C}):", "                Xc[i] = xn[i]"]
    return L


_SDA_SIG = ("void(f8[:, ::1], f8[:, ::1], f8[:, ::1], f8[:, ::1], f8[:, ::1], f8[::1], f8, "
            "i8, f8[:, ::1], b1, i8, f8[:, ::1], f8[:, ::1], f8[:, ::1], f8[::1], i8[::1])")
_BLOCK_SIG = ("void(f8[:, ::1], f8[:, ::1], f8[:, ::1], f8[:, ::1], b1[::1], f8[:, ::1], "
              "f8[:, ::1], f8[::1], f8[:, ::1], f8[:, ::1])")
_sda_kernel = compile_kernel("sda", _sda_source(NZ), _SDA_SIG, module=__name__,
                             source_file=__file__, parallel=True, chunk_function=True)
_block_kernel = compile_kernel("kf_steady_block", _block_source(NZ), _BLOCK_SIG,
                               module=__name__, source_file=__file__, parallel=True)


@dataclass
class SteadyGains:
    """The steady-state filter of every particle, lane layout (module docstring).

    ``p_pred`` (n_chunks, 256 * LANES) the steady predicted covariance P-; ``g``
    (n_chunks, ny * 16 * LANES) the sequential gains P h_s'; ``s`` (n_chunks, ny * LANES)
    the sequential innovation variances; ``c0`` (n_chunks * LANES,) log det(2 pi S), +inf
    for a dead particle; ``iters`` (n_chunks * LANES,) the doubling iteration at which
    each particle converged, or minus the Newton steps a warm start took (0: it did not
    converge).
    """

    p_pred: np.ndarray
    g: np.ndarray
    s: np.ndarray
    c0: np.ndarray
    iters: np.ndarray

    def take(self, particles: np.ndarray) -> np.ndarray:
        """The P- of ``particles`` (flat indices, in order), lane layout: a warm start
        for :func:`steady_gains` (a move's ancestors)."""
        return take_lanes(self.p_pred, np.asarray(particles, dtype=np.int64))

    @classmethod
    def empty(cls, n_chunks: int, ny: int) -> SteadyGains:
        return cls(np.zeros((n_chunks, NZ * NZ * LANES)), np.zeros((n_chunks, ny * NZ * LANES)),
                   np.ones((n_chunks, ny * LANES)), np.full(n_chunks * LANES, np.inf),
                   np.zeros(n_chunks * LANES, dtype=np.int64))


class NullVectors:
    """Unit null vectors v0 (m, 16) of A(theta) in filter coordinates, batched.

    A(theta) has rank 15 for every theta (the static yawed set-up, model notes section 2).
    One component of v0 (the largest at nominal theta) is fixed to 1 and one equation
    (the one the left null vector weighs most) dropped; the remaining 15 x 15 systems are
    solved at once, then v0 is normalised.
    """

    def __init__(self, terms: np.ndarray, theta_nominal: np.ndarray) -> None:
        from gateway.model.vehicle import theta_basis

        self._terms = np.asarray(terms, dtype=float)
        self._basis = theta_basis
        a = np.tensordot(theta_basis(np.asarray(theta_nominal, dtype=float)), self._terms, 1)
        u, _, vt = np.linalg.svd(a)
        self._col = int(np.argmax(np.abs(vt[-1])))
        self._row = int(np.argmax(np.abs(u[:, -1])))
        self._cols = np.array([j for j in range(NZ) if j != self._col])
        self._rows = np.array([i for i in range(NZ) if i != self._row])

    def __call__(self, theta: np.ndarray) -> np.ndarray:
        a = np.einsum("mt,tij->mij", self._basis(theta[:, :3]), self._terms)
        sub = a[:, self._rows][:, :, self._cols]
        rhs = -a[:, self._rows, self._col]
        v = np.empty((len(theta), NZ))
        v[:, self._col] = 1.0
        v[:, self._cols] = np.linalg.solve(sub, rhs[..., None])[..., 0]
        return v / np.linalg.norm(v, axis=1, keepdims=True)


def without_null(x: np.ndarray, v0: np.ndarray) -> np.ndarray:
    """States ``x`` (m, 16) less their component along the unit null vectors ``v0``
    (m, 16) of the theta they were estimated under.

    Under that theta the static yawed set-up v0 is unobservable (H v0 = 0, Phi v0 = v0),
    so a filter's component along it is arbitrary. Under another theta (a resample-move's
    jitter, a fault hypothesis) A v0 is no longer 0 and that component would predict a
    transient the data never had, larger for a larger change of conicity. Every state
    that passes to a filter at another theta passes through here (docs/estimator.md,
    "Change detection" and "Start-up lock-in").
    """
    return x - np.einsum("mi,mi->m", x, v0)[:, None] * v0


def steady_gains(phi: np.ndarray, qd: np.ndarray, v0: np.ndarray, H: np.ndarray,
                 r: np.ndarray, out: SteadyGains, tol: float = DARE_TOL,
                 start: np.ndarray | None = None) -> None:
    """Solve every particle's filter DARE and fill ``out`` in place.

    ``phi``, ``qd`` lane layout (n_chunks, 256 * LANES); ``v0`` lane layout (n_chunks,
    16 * LANES) unit null vectors; ``H`` (ny, 16); ``r`` (ny,) measurement variances.
    ``start``: None solves cold (the doubling, then one Newton step); else a nearby
    solution P- per particle, lane layout (n_chunks, 256 * LANES), from which Newton
    steps start (up to ``NEWTON_MAX``); a particle they do not converge for is then
    solved cold, so the result is a particle's own and never a worse one.
    """
    g0 = np.ascontiguousarray(H.T @ (H / r[:, None]))
    Hc, rc = np.ascontiguousarray(H), np.ascontiguousarray(r)
    warm = start is not None
    p0 = np.ascontiguousarray(start) if warm else out.p_pred
    _sda_kernel(phi, qd, g0, v0, Hc, rc, float(tol), MAX_ITER, p0, warm, NEWTON_MAX,
                out.p_pred, out.g, out.s, out.c0, out.iters)
    if not warm:
        return
    cold = np.flatnonzero(out.iters == 0)
    if len(cold):
        sub = SteadyGains.empty(n_chunks(len(cold)), len(r))
        _sda_kernel(take_lanes(phi, cold), take_lanes(qd, cold), g0, take_lanes(v0, cold), Hc, rc,
                    float(tol), MAX_ITER, sub.p_pred, False, 0, sub.p_pred, sub.g, sub.s,
                    sub.c0, sub.iters)
        for name in ("p_pred", "g", "s"):
            put_lanes(getattr(out, name), cold, getattr(sub, name))
        out.c0[cold] = sub.c0[:len(cold)]
        out.iters[cold] = sub.iters[:len(cold)]


def take_lanes(a: np.ndarray, lanes: np.ndarray) -> np.ndarray:
    """The lanes ``lanes`` (flat particle indices) of the lane-layout ``a`` (n_chunks,
    k * LANES), as a lane-layout batch of their own."""
    per = a.reshape(a.shape[0], -1, LANES)
    return to_lanes(per[lanes // LANES, :, lanes % LANES])


def put_lanes(a: np.ndarray, lanes: np.ndarray, sub: np.ndarray) -> None:
    """Write the first ``len(lanes)`` particles of the lane-layout ``sub`` into lanes
    ``lanes`` of ``a``, in place."""
    per = a.reshape(a.shape[0], -1, LANES)
    inner = per.shape[1]
    per[lanes // LANES, :, lanes % LANES] = from_lanes(sub, len(lanes), (inner,))


def kf_steady(x: np.ndarray, phi: np.ndarray, H: np.ndarray, y: np.ndarray,
              use: np.ndarray, gains: SteadyGains, ll: np.ndarray, nis: np.ndarray,
              dead: np.ndarray) -> None:
    """One steady-gain step for all particles, in place (module docstring): the block
    kernel with one sample.

    ``use`` must select every sensor or none (predict only; the estimator hands a sample
    without every sensor to the exact recursion instead, :meth:`RBPF._leave_steady`).
    ``ll``, ``nis`` are added to and ``dead`` is set, as in the exact kernel.
    """
    LL = np.empty((1, ll.shape[0]))
    NIS = np.empty_like(LL)
    _block_kernel(x, phi, H, np.ascontiguousarray(y, dtype=float)[None, :],
                  np.array([bool(use.all())]), gains.g, gains.s, gains.c0, LL, NIS)
    ll += LL[0]
    nis += NIS[0]
    dead |= gains.c0 == np.inf


def kf_steady_block(x: np.ndarray, phi: np.ndarray, H: np.ndarray, Y: np.ndarray,
                    full: np.ndarray, gains: SteadyGains, LL: np.ndarray, NIS: np.ndarray
                    ) -> None:
    """:func:`kf_steady` for K samples in one call, in place: ``Y`` (K, ny) with ``full``
    (K,) True where every sensor is used, False for predict-only samples; ``LL``, ``NIS``
    (K, n_chunks * LANES) receive each sample's log-likelihood and NIS (set, not added).
    Bit-identical to K calls of :func:`kf_steady`."""
    _block_kernel(x, phi, H, Y, full, gains.g, gains.s, gains.c0, LL, NIS)


def steady_posterior(gains: SteadyGains, v0: np.ndarray, H: np.ndarray, r: np.ndarray,
                     n_particles: int) -> np.ndarray:
    """The steady updated covariance P+ (N, 16, 16), positive semi-definite: where the
    exact recursion takes over from the steady gains (a long sensor outage).

    The doubling keeps no variance along the unobservable v0 (``v0`` (N, 16) unit), so
    P- is indefinite there; the smallest variance along v0 that makes P+ positive
    semi-definite (the Schur complement of the rest), times 1.01, is put back. No gain
    or likelihood depends on it (H v0 = 0).
    """
    P = from_lanes(gains.p_pred, n_particles, (NZ, NZ))
    for s in range(H.shape[0]):
        ph = P @ H[s]
        S = ph @ H[s] + r[s]
        P = P - np.einsum("mi,mj->mij", ph, ph) / S[:, None, None]
    P = 0.5 * (P + P.transpose(0, 2, 1))
    vv = v0[:, :, None] * v0[:, None, :]
    proj = np.eye(NZ)[None] - vv
    rest = proj @ P @ proj
    pv = (P @ v0[:, :, None])[:, :, 0]
    c = (proj @ pv[:, :, None])[:, :, 0]
    a = np.einsum("mi,mi->m", v0, pv)
    # c' rest^+ c: rest's null space is v0 and c is orthogonal to it, so rest + v0 v0' is
    # regular and gives the same form (a solve: a sixth of the pseudo-inverse's time)
    need = np.einsum("mi,mi->m", c, np.linalg.solve(rest + vv, c[:, :, None])[:, :, 0])
    add = np.maximum(1.01 * need + 1e-300 - a, 0.0)
    return P + add[:, None, None] * vv
