"""Pair the detection study's rows without and with the refinement (--refine-s 0, default).

    python docs/data/scripts/refine_pairing_2026-11-28.py WITHOUT.jsonl WITH.jsonl

Per case (parameter, factor, sensors): runs, the first alert's median / worst (s after
the fault) without and with the refinement, how many first alerts came earlier / the
same / later with it (paired by seed), its worst ALARM and worst tracking (within 15 %
and staying there), its alerts on a healthy parameter or before the fault, and whether
the truth lies in the last located interval its estimates carried. None (no alert)
counts as infinitely late. A measuring tool.
"""

import json
import sys
from collections import defaultdict

import numpy as np


def load(path: str) -> dict[tuple, dict]:
    with open(path) as f:
        rows = [json.loads(line) for line in f if line.strip()]
    return {(r["parameter"], r["factor"], r["sensors"], r["seed"]): r for r in rows}


def late(v: float | None) -> float:
    return np.inf if v is None else float(v)


def by_case(old: dict[tuple, dict], new: dict[tuple, dict]) -> dict[tuple, list[tuple]]:
    """The keys both sets of rows have, by case (parameter, factor, sensors)."""
    cases: dict[tuple, list[tuple]] = defaultdict(list)
    for key in sorted(set(old) & set(new)):
        cases[key[:3]].append(key)
    return cases


def main() -> None:
    old, new = load(sys.argv[1]), load(sys.argv[2])
    for case, keys in by_case(old, new).items():
        a0 = np.array([late(old[k]["alert_s"]) for k in keys])
        a3 = np.array([late(new[k]["alert_s"]) for k in keys])
        al3 = np.array([late(new[k]["alarm_s"]) for k in keys])
        tr3 = np.array([late(new[k]["track_s"]) for k in keys])
        healthy = sum(new[k]["alerts_healthy"] + new[k]["alerts_before"] for k in keys)
        inside = sum(1 for k in keys if new[k]["located_like_last"] is not None
                     and new[k]["located_like_last"][0] < case[1]
                     < new[k]["located_like_last"][1])
        located = sum(1 for k in keys if new[k]["located_like_last"] is not None)
        print(json.dumps({
            "case": f"{case[0][:4]} x{case[1]} {case[2]}s", "runs": len(keys),
            "alert_without_median_worst": [float(np.median(a0)), float(a0.max())],
            "alert_with_median_worst": [float(np.median(a3)), float(a3.max())],
            "over_5s_without_with": [int((a0 > 5).sum()), int((a3 > 5).sum())],
            "earlier_same_later": [int((a3 < a0 - 1e-9).sum()),
                                   int((np.abs(a3 - a0) <= 1e-9).sum()),
                                   int((a3 > a0 + 1e-9).sum())],
            "alarm_with_worst": float(al3.max()), "track_with_worst": float(tr3.max()),
            "healthy_or_before_with": healthy,
            "truth_in_last_interval": f"{inside}/{located}"}))


if __name__ == "__main__":
    main()
