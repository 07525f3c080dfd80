"""The estimate report: JSON document and the paper's Fig. 2-style plot (matplotlib Agg).

JSON layout::

    {"estimates": {"csy_ns_per_m": {"mean": .., "std": ..}, ...},   # at the end
     "history": [{"t_s": .., "csy_ns_per_m_mean": .., "csy_ns_per_m_std": .., ...,
                  "ess": .., "v_sy_mps": .., "v_say_mps": ..}, ...],
     "settings": {...}, "diagnostics": {...}}

``gateway replay`` puts the front end's counters in ``diagnostics``: ``frames``,
``rejected`` (by reason), ``grid_points`` and ``front_end``
(:class:`gateway.frontend.stats.FrontEndStats` as a dict: ``late`` and ``gaps`` by reason,
``gating`` with the ``updated`` count, ``clock_steps``, ``rx_offset_s``, ``resyncs``,
``retimed_frames``, ``outlier_frames``, ``sample_idx_jumps``, ``two_senders``,
``two_sender_events``, and ``nodes``: per message the node's ``drift_ppm``,
``grid_phase_us``, ``late_samples``, ``missing_samples`` and ``reordered_samples``,
:class:`gateway.frontend.stats.NodeTiming`).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from gateway.errors import InputError
from gateway.records import Estimate

_LABELS = {"csy_ns_per_m": ("C_sy", "N s/m"), "csay_ns_per_m": ("C_say", "N s/m"),
           "conicity": ("lambda", "-"), "ar_paper": ("Ar", "paper units")}


def build(final: Estimate, history: list[dict[str, float]], settings: dict[str, Any],
          diagnostics: dict[str, Any]) -> dict[str, Any]:
    """The report document (plain JSON types)."""
    return {"estimates": final.as_dict(), "history": history, "settings": settings,
            "diagnostics": diagnostics}


def write_json(path: str | Path, doc: dict[str, Any]) -> None:
    """Write the report; NaN becomes null so the file is strict JSON."""
    def clean(o: Any) -> Any:
        if isinstance(o, float) and not math.isfinite(o):
            return None
        if isinstance(o, dict):
            return {k: clean(v) for k, v in o.items()}
        if isinstance(o, list | tuple):
            return [clean(v) for v in o]
        return o
    try:
        with open(path, "w", encoding="utf-8") as handle:
            json.dump(clean(doc), handle, indent=1, allow_nan=False)
            handle.write("\n")
    except OSError as err:
        raise InputError(f"expected a writable report path, got {path}: {err.strerror}") \
            from err


def plot(path: str | Path, history: list[dict[str, float]], names: tuple[str, ...],
         truth: dict[str, float] | None = None) -> None:
    """Panels: each estimate with a +-2 sigma band against time, then sigma/|estimate|."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = [r["t_s"] for r in history]
    fig, axes = plt.subplots(len(names) + 1, 1, figsize=(7, 2.2 * (len(names) + 1)),
                             sharex=True)
    for ax, name in zip(axes, names, strict=False):
        m = [r[f"{name}_mean"] for r in history]
        s = [r[f"{name}_std"] for r in history]
        ax.plot(t, m, label="estimate")
        ax.fill_between(t, [a - 2 * b for a, b in zip(m, s, strict=True)],
                        [a + 2 * b for a, b in zip(m, s, strict=True)], alpha=0.3,
                        label="+-2 sigma")
        if truth and name in truth:
            ax.axhline(truth[name], color="k", ls="--", label="true value")
        label, unit = _LABELS.get(name, (name, ""))
        ax.set_ylabel(f"{label} [{unit}]")
        ax.legend(loc="upper right", fontsize=7)
    ax = axes[-1]
    for name in names:
        rel = [r[f"{name}_std"] / abs(r[f"{name}_mean"]) if r[f"{name}_mean"] else math.nan
               for r in history]
        ax.plot(t, rel, label=f"sigma/{_LABELS.get(name, (name,))[0]}")
    ax.set_ylim(0, 0.25)
    ax.set_ylabel("sigma / estimate")
    ax.set_xlabel("time [s]")
    ax.legend(loc="upper right", fontsize=7)
    fig.tight_layout()
    try:
        fig.savefig(path, dpi=100)
    except OSError as err:
        raise InputError(f"expected a writable plot path, got {path}: {err.strerror}") \
            from err
    finally:
        plt.close(fig)
