"""At each confirmation, what the change-time search sums for both sides of every parameter.

Logs (stderr), at every first location the fault bank starts (the watch's confirmed
crossing), the crossing's parameter, hypothesis and largest CUSUM, and the location
grid's change-time search (``FaultBank._glr_best``) over the look-back for the drop and
the rise of Csy, Csay and the conicity, in that order. The patch sits at module level so
that a spawned worker (the whole replay path), which re-imports this file as
``__mp_main__``, logs too. Fifteenth session (2026-11-30), docs/estimator.md "The
fifteenth session". Run from a directory without ``gateway/`` in it:

    python search_at_confirmation_2026-11-30.py detection faults --cases csy:0.25 \\
        --sensors 3 --seeds 4902 --fault-at 8.025
    python search_at_confirmation_2026-11-30.py replay 6501 lateral-failing 3
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path
from typing import Any

import gateway.estimator.faultbank as fb

_locate_now = fb.FaultBank._locate_now


def searches(bank: Any, at: int) -> list[float]:
    """The search's sum for (Csy drop, Csy rise, Csay drop, Csay rise, lambda drop,
    lambda rise) over the look-back before count ``at``; the bank's state is kept."""
    starts = bank.lookback.starts(at)
    x0, vec0 = bank.x.copy(), bank.vec.copy()
    out = []
    for q in range(fb.N_THETA):
        for side in (-1.0, 1.0):
            bank.vec[fb._MODE], bank.vec[fb._LOC_P], bank.vec[fb._LOC_SIDE] = fb._LOCATE, q, side
            bank._solve()
            out.append(round(float(bank._glr_best(starts)[1]), 1))
    bank.x, bank.vec = x0, vec0
    bank._solve()
    return out


def _logged(bank: Any, best: int, t_s: float, runner_at: Any = None) -> Any:
    if runner_at is None and bank.lookback.starts(bank.lookback.count):
        print(f"confirmation t={t_s:.3f} parameter {best // len(bank.factors)} hypothesis "
              f"{best} CUSUM {bank.g.max():.1f} searches {searches(bank, bank.lookback.count)}",
              file=sys.stderr, flush=True)
    return _locate_now(bank, best, t_s, runner_at)


fb.FaultBank._locate_now = _logged  # type: ignore[method-assign,assignment]


def main(argv: list[str]) -> int:
    if argv[:1] == ["detection"]:
        from firmware_sim.studies.detection import main as detection
        return detection(argv[1:])
    from firmware_sim.studies.timing import run_case
    seed, scenario, sensors = int(argv[1]), argv[2], int(argv[3])
    row = run_case(seed, "aligned", "sinc", sensors, 20.0, 1000, scenario,
                   Path(tempfile.mkdtemp()))
    print("alerts", row["alerts"], "at the end, relative to the truth",
          [round(float(r), 3) for r in row["rel_end"]])
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
