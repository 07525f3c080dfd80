"""Seed 6501 read at the fault bank: its calls logged from inside the replay's worker.

The timing study's ``lateral-failing`` log of seed 6501 (3 sensors, aligned, 20 s, Csy x
0.25 at 10 s) through ``gateway replay`` at m = 1000. The patches sit at module level so
that the spawned worker, which re-imports this file as ``__mp_main__``, logs too: every
scan block from 9.9 to 14 s that crosses a 100 ms mark (CUSUM maximum and its
hypothesis), each location (its best hypothesis, the CUSUMs or the grid's sums
before it) and each restart; then the alerts (``firmware_sim.studies.timing.run_case``).
Fourteenth session (2026-11-30), docs/estimator.md "The fourteenth session". Run from a
directory without ``gateway/`` in it, with ``PYTHONPATH`` the tree.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

import gateway.estimator.faultbank as fb

NOMINAL = (40e3, 4114e3, 0.15)
_T = {"t": 0.0}
_scan = fb.FaultBank.scan


def _logged_scan(self: Any, Y: Any, full: Any, t0_s: float, dt_s: float) -> Any:
    _T["t"] = t0_s
    det = _scan(self, Y, full, t0_s, dt_s)
    if 9.9 <= t0_s <= 14 and int(t0_s * 1000) % 100 < len(Y):
        mode = "locate" if self.vec[fb._MODE] == fb._LOCATE else "watch"
        print(f"scan t={t0_s:.3f} k={len(Y)} {mode} ref={np.round(self.ref[:3] / NOMINAL, 3)}"
              f" gmax={self.g.max():.1f} at {int(np.argmax(self.g))}", flush=True)
    if det is not None:
        print("detection", t0_s, det.parameter, det.factor, flush=True)
    return det


def _logged(name: str) -> Any:
    inner = getattr(fb.FaultBank, name)

    def call(self: Any, *a: Any, **k: Any) -> Any:
        if name == "_locate_now" and _T["t"] > 8:
            print("   CUSUMs (or grid sums) before:",
                  np.round(self.g.reshape(3, -1), 1).tolist(), flush=True)
        out = inner(self, *a, **k)
        if _T["t"] > 8:
            extra = f" best={a[0]} t={a[1]:.3f} -> {out}" if name == "_locate_now" else ""
            print(f"  {name} in the block from t={_T['t']:.3f}{extra}", flush=True)
        return out
    return call


fb.FaultBank.scan = _logged_scan  # type: ignore[method-assign]
for _name in ("start", "stop", "_locate_now", "_watch_again"):
    setattr(fb.FaultBank, _name, _logged(_name))


def main(seed: int) -> None:
    from firmware_sim.studies.timing import run_case

    row = run_case(seed, "aligned", "sinc", 3, 20.0, 1000, "lateral-failing",
                   Path(tempfile.mkdtemp()))
    print("alerts", row["alerts"], "at the end, relative to the truth",
          [round(r, 3) for r in row["rel_end"]])


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 6501)
