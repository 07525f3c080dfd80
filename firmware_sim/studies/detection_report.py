"""The detection study's report: the per-case table and the plot, from its rows.

Rows are the JSON lines of :mod:`firmware_sim.studies.detection` (``faults``); its
``summary`` and ``plot`` commands call these. No simulation, no filter.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from firmware_sim.scenarios import V_PAPER
from gateway.alerts.judge import beyond
from gateway.alerts.policy import default_params
from gateway.model.vehicle import PARAM_NAMES
from gateway.records import Severity


def summary(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per fault case (parameter, factor, sensors, speed): runs, median and worst detection and
    tracking delays (s), first alert and ALARM (and the first alert of the policy that
    judges the estimates alone, rows since 2026-11-26), runs detected on the right
    parameter, wrong and early detections. A case's worst is None when some run never
    detected, tracked or alerted. Rows since the night of 2026-11-27 add the range rule's
    first alert and ALARM (``*_on_range_s``), the runs whose located likelihood interval
    held the truth (``like_held`` of ``located``), and the runs that raised a level the
    truth does not warrant (past the default policy's thresholds: ``severity_past_truth``,
    and ``..._on_range``)."""
    out = []
    def key_of(r: dict[str, Any]) -> tuple[str, float, int, float]:
        # rows written before 2026-11-27 have no speed: they ran at the paper's
        return (r["parameter"], r["factor"], r["sensors"], r.get("speed_mps", V_PAPER))

    keys = sorted({key_of(r) for r in rows if r["what"] == "fault"})
    for key in keys:
        case = [r for r in rows if r["what"] == "fault" and key_of(r) == key]
        row: dict[str, Any] = {"parameter": key[0], "factor": key[1], "sensors": key[2],
                               "speed_mps": key[3], "runs": len(case)}
        for name in ("detect_s", "track_s", "alert_s", "alarm_s", "alert_estimates_only_s",
                     "alert_on_range_s", "alarm_on_range_s"):
            vals = [r.get(name) for r in case]
            got = [v for v in vals if v is not None]
            row[f"{name}_median"] = float(np.median(got)) if got else None
            row[f"{name}_worst"] = max(got) if len(got) == len(vals) else None
        row["detected"] = sum(r["detect_s"] is not None for r in case)
        row["wrong"] = sum(r["wrong"] for r in case)
        row["before"] = sum(r["before"] for r in case)
        row["alerts_healthy"] = sum(r.get("alerts_healthy", 0) for r in case)
        row["alerts_before"] = sum(r.get("alerts_before", 0) for r in case)
        like = [r["located_like"] for r in case if r.get("located_like")]
        row["located"] = len(like)
        row["like_held"] = sum(lo <= key[1] <= hi for lo, hi in like)
        warranted = _warranted(key[0], key[1])
        for col, name in (("severity_max", "severity_past_truth"),
                          ("severity_max_on_range", "severity_past_truth_on_range")):
            row[name] = sum(r.get(col) is not None and Severity[r[col]].value > warranted
                            for r in case)
        out.append(row)
    return out


def _warranted(parameter: str, factor: float) -> int:
    """The highest level (0: none) a parameter at ``factor`` of nominal warrants under
    the default policy's thresholds (either side)."""
    pp = default_params()[parameter]
    return max(sum(t is not None and beyond(side, factor, t) for t in pp.levels(side))
               for side in ("low", "high"))


def plot(rows: Sequence[dict[str, Any]], path: str) -> None:
    """Detection and tracking delay against fault size, one panel per parameter: the
    median over the realisations, bars from the best to the worst; 3 and 5 sensors."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    faults = [r for r in rows if r["what"] == "fault"]
    params = [p for p in PARAM_NAMES if any(r["parameter"] == p for r in faults)]
    fig, axes = plt.subplots(1, len(params), figsize=(4.2 * len(params), 3.6),
                             squeeze=False, sharey=True)
    styles = {("detect_s", 3): ("C0", "o"), ("detect_s", 5): ("C0", "s"),
              ("track_s", 3): ("C1", "o"), ("track_s", 5): ("C1", "s")}
    for ax, name in zip(axes[0], params, strict=True):
        for (key, ns), (colour, marker) in styles.items():
            sizes = sorted({r["factor"] for r in faults
                            if r["parameter"] == name and r["sensors"] == ns})
            pts = []
            for f in sizes:
                vals = [r[key] for r in faults if r["parameter"] == name
                        and r["sensors"] == ns and r["factor"] == f]
                got = [v for v in vals if v is not None]
                if got:
                    pts.append((f * (0.97 if ns == 3 else 1.03), float(np.median(got)),
                                min(got), max(got) if len(got) == len(vals) else np.nan))
            if pts:
                x, med, lo, hi = (np.array(c) for c in zip(*pts, strict=True))
                ax.errorbar(x, med, yerr=[med - lo, np.where(np.isnan(hi), 0, hi - med)],
                            color=colour, marker=marker, ls="none", capsize=3,
                            label=f"{'detect' if key == 'detect_s' else 'within 15 %'}, "
                                  f"{ns} sensors")
        ax.set_xscale("log")
        ticks = sorted({r["factor"] for r in faults if r["parameter"] == name})
        ax.minorticks_off()
        ax.set_xticks(ticks, [f"{t:g}" for t in ticks])
        ax.set_xlabel(f"{name}: new value / nominal")
        ax.grid(True, which="both", alpha=0.3)
    axes[0][0].set_ylabel("delay after the fault (s)")
    axes[0][-1].legend(fontsize=7)
    fig.suptitle("Abrupt faults: median, best to worst over realisations "
                 "(python -m firmware_sim.studies.detection)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
