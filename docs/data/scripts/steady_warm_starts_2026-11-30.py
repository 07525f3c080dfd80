"""Two cheaper steady-gain solves, measured and not adopted (2026-11-30, seventeenth session).

1. The first solve after the exact warm-up, warm-started by Newton steps from the exact
   recursion's covariance (predicted once more) instead of solved cold, with up to
   ``NEWTON_MAX`` steps: prints both times and the Newton steps taken.
2. A move's warm starts with a looser Newton tolerance (1e-3, 1e-4 instead of 1e-6):
   prints each solve's time and the largest relative change of the gains.

The bench's bare filter at m = 1000 over the bench's data. Usage:
``OPENBLAS_CORETYPE=Haswell python docs/data/scripts/steady_warm_starts_2026-11-30.py``.
docs/estimator.md "The seventeenth session".
"""

from __future__ import annotations

import collections
import time

import numpy as np

from firmware_sim.studies.sweep import bench_data, filter_config
from gateway.estimator import rbpf as rbpf_module
from gateway.estimator import steady
from gateway.estimator.kalman import from_lanes, to_lanes
from gateway.estimator.rbpf import RBPF
from gateway.model.vehicle import AR_PAPER_DEFAULT

M = 1000


def first_solve() -> None:
    data = bench_data(1.0, 0)
    filt = RBPF(filter_config("fast", M, 0, AR_PAPER_DEFAULT))
    seen: dict[str, np.ndarray] = {}
    enter = RBPF._enter_steady

    def keep(self: RBPF, solve: bool = True) -> None:
        seen["P"] = self._P.copy()
        enter(self, solve)

    RBPF._enter_steady = keep            # type: ignore[method-assign]
    filt.step(data.samples[0])
    filt.run(data.samples[1:600], output_every=50)
    RBPF._enter_steady = enter           # type: ignore[method-assign]
    post = from_lanes(seen["P"], M, (16, 16))
    phi, qd = from_lanes(filt._phi, M, (16, 16)), from_lanes(filt._qd, M, (16, 16))
    start = to_lanes((np.einsum("mij,mjk,mlk->mil", phi, post, phi) + qd).reshape(M, -1))
    v0 = to_lanes(filt._particle_null())
    for newton_max in (4, 6, 8):
        steady.NEWTON_MAX = newton_max
        warm, cold = (steady.SteadyGains.empty(filt._phi.shape[0], 3) for _ in range(2))
        t0 = time.perf_counter()
        steady.steady_gains(filt._phi, filt._qd, v0, filt._H, filt._r, warm, start=start)
        t1 = time.perf_counter()
        steady.steady_gains(filt._phi, filt._qd, v0, filt._H, filt._r, cold)
        t2 = time.perf_counter()
        print(f"first solve, NEWTON_MAX {newton_max}: warm {1e3 * (t1 - t0):.1f} ms, cold "
              f"{1e3 * (t2 - t1):.1f} ms, iterations "
              f"{sorted(collections.Counter(warm.iters[:M].tolist()).items())}")


def loose_tolerance() -> None:
    solve = steady.steady_gains

    def compare(phi, qd, v0, H, r, out, tol=steady.DARE_TOL, start=None):  # type: ignore[no-untyped-def]
        t0 = time.perf_counter()
        solve(phi, qd, v0, H, r, out, tol=tol, start=start)
        if start is None:
            return
        print(f"move, tolerance {tol:g}: {1e3 * (time.perf_counter() - t0):.1f} ms")
        for loose in (1e-3, 1e-4):
            other = steady.SteadyGains.empty(phi.shape[0], len(r))
            t0 = time.perf_counter()
            solve(phi, qd, v0, H, r, other, tol=loose, start=start)
            dt = time.perf_counter() - t0
            dg = np.max(np.abs(other.g - out.g)) / np.max(np.abs(out.g))
            print(f"move, tolerance {loose:g}: {1e3 * dt:.1f} ms, gains within {dg:.1e}")

    rbpf_module.steady_gains = compare    # type: ignore[assignment]
    data = bench_data(3.0, 0)
    filt = RBPF(filter_config("fast", M, 0, AR_PAPER_DEFAULT))
    filt.step(data.samples[0])
    filt.run(data.samples[1:], output_every=50)
    rbpf_module.steady_gains = solve      # type: ignore[assignment]


if __name__ == "__main__":
    first_solve()
    loose_tolerance()
