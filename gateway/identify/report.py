"""The identification report: one JSON document plus PNG figures (matplotlib, Agg).

Figures of the known-track path: ``signals.png`` (measured against simulated before and
after), ``parameters.png`` (change of each identified parameter relative to nominal,
per method, and the truth when known), ``convergence.png`` (best J against
evaluations, per method) and ``morris.png`` (mu* against sigma, one panel per signal).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from gateway.errors import InputError  # noqa: E402
from gateway.identify.optimise import METHODS  # noqa: E402
from gateway.identify.params import SHORT_NAMES, ParamPoint  # noqa: E402
from gateway.identify.pipeline import PredictionErrorResult, TrackResult  # noqa: E402
from gateway.identify.screening import MorrisResult  # noqa: E402


def _round(x: float, digits: int = 6) -> float:
    return float(f"{x:.{digits}g}") if math.isfinite(x) else float("nan")


def table1(result: TrackResult) -> list[dict[str, Any]]:
    """Kraft's Table 1 for this run: reduction and final value of J, per method, in %."""
    return [{"method": METHODS[m.method], "key": m.method,
             "reduction_pct": _round(m.reduction_pct, 4), "final_pct": _round(m.final_pct, 4),
             "evaluations": m.n_evals, "wall_s": _round(m.wall_s, 3), "message": m.message}
            for m in result.methods]


def _free_offset(result: TrackResult, truth_offset_m: float | None) -> dict[str, Any]:
    """The identified track offset per method, in m, against the given one (and the truth)."""
    assert result.space.offset is not None
    doc: dict[str, Any] = {"given_m": result.space.offset.base_m,
                           "half_width_m": result.space.offset.half_width_m,
                           "identified_m": {m.method: _round(result.offset_m(m), 9)
                                            for m in result.methods}}
    if truth_offset_m is not None:
        doc["truth_m"] = truth_offset_m
        doc["error_vs_truth_m"] = {m.method: _round(result.offset_m(m) - truth_offset_m, 6)
                                   for m in result.methods}
    return doc


def track_report(result: TrackResult, truth: ParamPoint | None = None,
                 truth_offset_m: float | None = None) -> dict[str, Any]:
    """The JSON document of a known-track identification.

    ``truth_offset_m`` (m), the true track offset of a synthetic run, is reported against
    the identified one when the offset was free.
    """
    nominal = result.space.base.as_dict()
    methods = {}
    for m in result.methods:
        p = result.space.point(np.array(m.u)).as_dict()
        entry: dict[str, Any] = {
            n: {"value": _round(p[n]), "relative_to_nominal": _round(p[n] / nominal[n] - 1)}
            for n in result.space.names}
        if truth is not None:
            t = truth.as_dict()
            for n in result.space.names:
                entry[n]["error_vs_truth"] = _round(p[n] / t[n] - 1)
        methods[m.method] = entry
    doc: dict[str, Any] = {
        "path": "known track: time-domain least squares (Kraft et al. eq. 2)",
        "misfit": result.misfit.describe(),
        "synchronisation": [{"section": s.label(), "lag_samples": e.lag_samples,
                             "subsample": _round(e.refined, 4), "peak": _round(e.peak, 4)}
                            for s, e in zip(result.misfit.sections, result.lags, strict=False)],
        "lags_at_identified_point": [e.lag_samples for e in result.lags_after],
        "identified": list(result.space.names),
        "tolerance": list(result.space.tolerance),
        "j_nominal": _round(result.j_nominal),
        "table1": table1(result),
        "best_method": result.best.method,
        "parameters": methods,
        "speed": {"evaluations_per_s_one_core": _round(result.evals_per_s_one_core, 4),
                  "wall_s": _round(result.wall_s, 4)},
    }
    if result.space.offset is not None:
        doc["free_track_offset"] = _free_offset(result, truth_offset_m)
    if truth is not None:
        doc["truth"] = {n: _round(truth.as_dict()[n]) for n in result.space.names}
    if result.morris is not None:
        doc["morris"] = {"trajectories": result.morris.trajectories,
                         "evaluations": result.morris.n_evals,
                         "tolerance": result.morris.tolerance,
                         "ranking": list(result.morris.ranking()),
                         "table": result.morris.table()}
    return doc


def prediction_error_report(result: PredictionErrorResult,
                            truth: ParamPoint | None = None) -> dict[str, Any]:
    """The JSON document of a no-track maximum-likelihood identification."""
    est = {n: {"value": _round(v), "std": _round(s)}
           for n, v, s in zip(result.names, result.values, result.std, strict=True)}
    if truth is not None:
        for n in result.names:
            est[n]["error_vs_truth"] = _round(est[n]["value"] / truth.as_dict()[n] - 1)
    return {"path": "no track: Kalman prediction-error maximum likelihood",
            "settings": result.settings, "estimates": est,
            "mean_nll_nominal": _round(result.nll_nominal),
            "mean_nll_final": _round(result.nll_final), "evaluations": result.n_evals,
            "speed": {"evaluations_per_s_one_core": _round(result.evals_per_s_one_core, 4),
                      "wall_s": _round(result.wall_s, 4)}}


def write_json(path: Path, doc: dict[str, Any]) -> None:
    path.write_text(json.dumps(doc, indent=2, allow_nan=True) + "\n", encoding="utf-8")


def plot_morris(morris: MorrisResult, path: Path) -> None:
    n = len(morris.signals)
    cols = min(n, 3)
    rows = math.ceil(n / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(5 * cols, 4 * rows), squeeze=False)
    for i, sig in enumerate(morris.signals):
        ax = axes[i // cols][i % cols]
        ax.scatter(morris.mu_star[i], morris.sigma[i], s=12)
        top = np.argsort(-morris.mu_star[i])[:8]
        for j in top:
            ax.annotate(SHORT_NAMES[morris.names[j]], (morris.mu_star[i, j], morris.sigma[i, j]),
                        fontsize=8)
        ax.set_title(sig)
        ax.set_xlabel("mu*")
        ax.set_ylabel("sigma")
    for j in range(n, rows * cols):
        axes[j // cols][j % cols].axis("off")
    fig.suptitle(f"Morris screening, +-{morris.tolerance:.0%}, {morris.trajectories} "
                 "trajectories")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_signals(result: TrackResult, path: Path, window_s: float = 5.0) -> None:
    mf = result.misfit.at_offset(result.offset_m())       # the identified registration
    nominal = mf.section_response(result.space.base, 0)
    fitted = mf.section_response(result.point(), 0)
    meas = mf.meas_sections[0]
    t = mf.dataset.t_s[mf.index[0]]
    keep = t < t[0] + window_s
    sensors = mf.dataset.sensors
    fig, axes = plt.subplots(len(sensors), 1, figsize=(10, 2.2 * len(sensors)), sharex=True,
                             squeeze=False)
    for i, s in enumerate(sensors):
        ax = axes[i][0]
        ax.plot(t[keep], meas[keep, i], "k", lw=1.0, label="measured")
        ax.plot(t[keep], nominal[keep, i], "C1", lw=0.9, label="nominal model")
        ax.plot(t[keep], fitted[keep, i], "C0--", lw=0.9,
                label=f"identified ({result.best.method})")
        ax.set_ylabel(s)
    axes[0][0].legend(loc="upper right", fontsize=8)
    axes[-1][0].set_xlabel("time [s] (band-limited)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_parameters(result: TrackResult, path: Path, truth: ParamPoint | None) -> None:
    names = result.space.names
    x = np.arange(len(names))
    width = 0.8 / (len(result.methods) + (truth is not None))
    fig, ax = plt.subplots(figsize=(max(6, 1.4 * len(names)), 4))
    for k, m in enumerate(result.methods):
        ax.bar(x + k * width, 100 * np.array(m.u)[:len(names)], width, label=m.method)
    if truth is not None:
        ax.bar(x + len(result.methods) * width,
               100 * result.space.relative(truth, result.misfit.offset_m)[:len(names)], width,
               label="truth", color="k")
    ax.set_xticks(x + 0.4 - width / 2, [SHORT_NAMES[n] for n in names])
    ax.set_ylabel("change from nominal [%]")
    ax.axhline(0, color="grey", lw=0.5)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_convergence(result: TrackResult, path: Path) -> None:
    fig, ax = plt.subplots(figsize=(7, 4))
    for m in result.methods:
        if m.history:
            n, j = zip(*m.history, strict=True)
            ax.step(n, j, where="post", label=f"{m.method} (final {m.j_final:.4g})")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("misfit evaluations")
    ax.set_ylabel("best J so far")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_track_report(result: TrackResult, out_dir: Path, truth: ParamPoint | None = None,
                       truth_offset_m: float | None = None) -> list[Path]:
    """Write report.json and the figures into ``out_dir``; returns the files written."""
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise InputError(f"expected a writable output directory, got {out_dir}: "
                         f"{err.strerror}") from err
    files = [out_dir / "report.json", out_dir / "signals.png", out_dir / "parameters.png",
             out_dir / "convergence.png"]
    write_json(files[0], track_report(result, truth, truth_offset_m))
    plot_signals(result, files[1])
    plot_parameters(result, files[2], truth)
    plot_convergence(result, files[3])
    if result.morris is not None:
        files.append(out_dir / "morris.png")
        plot_morris(result.morris, files[-1])
    return files
