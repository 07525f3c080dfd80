"""Pair the detection study's rows with the likelihood interval's ends snapped to the grid
(the rule before 2026-11-28's sixth session) and between grid values (the rule since).

    python docs/data/scripts/interval_pairing_2026-11-28.py BEFORE.jsonl AFTER.jsonl

Per case (parameter, factor, sensors): runs; the first alert's median / worst (s after
the fault) before and after; first alerts earlier / the same / later after (paired by
seed; None, no alert, counts as infinitely late); the worst ALARM before and after; the
truth inside the first and the last located interval the estimates carried (after);
alerts on a healthy parameter or before the fault (after); runs whose highest level is
above what the truth warrants (a damper at f of nominal warrants ALARM at f <= 0.35,
WARNING at <= 0.55, ADVISORY at <= 0.75), before and after. A measuring tool.
"""

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np

_spec = importlib.util.spec_from_file_location(
    "refine_pairing", Path(__file__).with_name("refine_pairing_2026-11-28.py"))
_refine = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_refine)
load, late = _refine.load, _refine.late      # the rows by case and seed; None as never

LEVELS = {None: 0, "ADVISORY": 1, "WARNING": 2, "ALARM": 3}


def warranted(factor: float) -> int:
    return 3 if factor <= 0.35 else 2 if factor <= 0.55 else 1 if factor <= 0.75 else 0


def inside(interval: list | None, truth: float) -> bool | None:
    return None if interval is None else interval[0] <= truth <= interval[1]


def main() -> None:
    old, new = load(sys.argv[1]), load(sys.argv[2])
    for case, keys in _refine.by_case(old, new).items():
        a0 = np.array([late(old[k]["alert_s"]) for k in keys])
        a1 = np.array([late(new[k]["alert_s"]) for k in keys])
        first = [inside(new[k]["located_like"], case[1]) for k in keys]
        last = [inside(new[k]["located_like_last"], case[1]) for k in keys]
        over = [sum(LEVELS[r[k]["severity_max"]] > warranted(case[1]) for k in keys)
                for r in (old, new)]
        print(json.dumps({
            "case": f"{case[0][:4]} x{case[1]} {case[2]}s", "runs": len(keys),
            "alert_before_median_worst": [float(np.median(a0)), float(a0.max())],
            "alert_after_median_worst": [float(np.median(a1)), float(a1.max())],
            "earlier_same_later": [int((a1 < a0 - 1e-9).sum()),
                                   int(((a1 == a0) | np.isclose(a1, a0, rtol=0, atol=1e-9)).sum()),
                                   int((a1 > a0 + 1e-9).sum())],
            "alarm_worst_before_after": [max(late(old[k]["alarm_s"]) for k in keys),
                                         max(late(new[k]["alarm_s"]) for k in keys)],
            "truth_in_first_last_interval": [
                f"{sum(x is True for x in first)}/{sum(x is not None for x in first)}",
                f"{sum(x is True for x in last)}/{sum(x is not None for x in last)}"],
            "healthy_or_before_after": sum(new[k]["alerts_healthy"] + new[k]["alerts_before"]
                                           for k in keys),
            "above_warranted_before_after": over}))


if __name__ == "__main__":
    main()
