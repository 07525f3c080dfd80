"""Summaries of the 2026-11-29 paired runs: resampling strata in index order against the
Hilbert order (branch ``try/hilbert-resampling``), and the fast-vs-exact campaign.

    python S phase ROWS.jsonl ...     # node-phase rows (node_phase_filter_seeds_2026-11-28.py)
    python S compare ROWS.jsonl ...   # accuracy compare rows (firmware_sim.studies.accuracy)

``phase``: per file, |case - aligned| in % (Csy, Csay, lambda) for each data seed, clock
case and filter seed (the same filter seed on both sides), and |k1 - k2| between the
first two filter seeds on the same data (the filter's own Monte Carlo spread): median and
largest. ``compare``: per file, the paired fast-vs-exact gap (median, largest, pairs
within 0.3 sigma) and the exact-vs-exact floor from its ``compare_summary`` rows, and
how many pairs resampled as often in both modes. A measuring tool.
"""

import json
import sys
from collections import defaultdict

import numpy as np


def rows_of(path: str) -> list[dict]:
    with open(path) as f:
        return [json.loads(line) for line in f if line.strip()]


def phase(path: str) -> None:
    rel = {(r["seed"], r["case"], r["filter_seed"]): 100 * np.array(r["rel"])
           for r in rows_of(path)}
    paired = [np.abs(v - rel[(s, "aligned", k)]) for (s, c, k), v in rel.items()
              if c != "aligned" and (s, "aligned", k) in rel]
    by_data: dict[tuple, list[np.ndarray]] = defaultdict(list)
    for (s, c, _), v in rel.items():
        by_data[(s, c)].append(v)
    spread = [np.abs(v[0] - v[1]) for v in by_data.values() if len(v) >= 2]
    p, m = np.array(paired), np.array(spread)
    print(f"{path}: case - aligned, {len(p)} pairs: median {np.round(np.median(p, 0), 2)} "
          f"largest {np.round(p.max(0), 2)}; filter seeds |k1 - k2|, {len(m)} records: "
          f"median {np.round(np.median(m, 0), 2)} largest {np.round(m.max(0), 2)}")


def compare(path: str) -> None:
    rows = rows_of(path)
    print(path)
    for r in rows:
        if r.get("what") == "compare_summary":
            g, f = r["gap_sigma"], r["reseed_gap_sigma"]
            print(f"  {r['sensors']} sensors {r['at']:>3}: gap median {g['median']} largest "
                  f"{np.round(g['max'], 2).tolist()} within 0.3 {g['within_0.3']}; floor "
                  f"median {f['median']}")
    counts: dict[tuple, dict[str, int]] = defaultdict(dict)
    for r in rows:
        if r.get("what") == "compare":
            counts[(r["seed"], r["sensors"])][r["role"]] = r["resamples"]
    same = sum(c.get("fast") == c.get("exact") for c in counts.values())
    print(f"  pairs with as many resamples in both modes: {same} of {len(counts)}")


if __name__ == "__main__":
    for name in sys.argv[2:]:
        {"phase": phase, "compare": compare}[sys.argv[1]](name)
