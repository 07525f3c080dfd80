"""The fleet report: per-unit trends, crossing predictions, a ranking; CSV, PNG and one HTML page.

Reads the replay results of one estimator version from the store, and the on-board
histories of any state directories ingested. A unit is a (vehicle, bogie). Per run the
summary is the run's last estimate (the posterior after all its data); the alert history
is the gateway's policy over all the unit's runs in order, beside the vehicle's own
alerts. Outputs in ``out_dir``: ``runs.csv``, ``alerts.csv``, ``trends.csv``,
``ranking.csv`` (worst first), ``unit-<vehicle>-<bogie>.png`` (Csy, Csay and lambda
relative to nominal against calendar time, +-2 sigma bars, the fitted trend and its band,
the threshold, the predicted crossing with its interval, alert events, the on-board
estimate history), ``fleet.png``
and ``report.html`` (figures embedded as base64: one self-contained file).
"""

from __future__ import annotations

import base64
import csv
import datetime as dt
import html
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

from gateway.errors import InputError
from gateway.fleet.onboard import OnboardHistory, daily_points, onboard_units, read_onboard
from gateway.fleet.replay import result_path
from gateway.fleet.runs import NOMINAL, PARAMS, RunEstimates, thresholds, unit_alerts
from gateway.fleet.store import Store
from gateway.fleet.trend import DAY_S, Trend, fit_trend

LEVELS = ("advisory", "warning", "alarm")
LABELS = {"csy_ns_per_m": "Csy", "csay_ns_per_m": "Csay", "conicity": "λ"}


@dataclass(frozen=True)
class RunRow:
    """One run's final estimate, relative to nominal."""

    vehicle: str
    bogie: str
    run_id: str
    t_s: float
    rel: tuple[float, float, float]
    std_rel: tuple[float, float, float]
    alerts: tuple[dict[str, object], ...]
    unresolved: tuple[str, ...] = ()
    """Parameters the final estimate's sensors could not resolve (a dead node, a low
    speed): kept here and in the plots, left out of the unit's trend."""


@dataclass(frozen=True)
class UnitTrends:
    vehicle: str
    bogie: str
    trends: dict[str, Trend]
    unresolved: dict[str, int] = field(default_factory=dict)
    """Per parameter, the unit's runs whose final estimate left it unresolved (not in
    its trend), where there are any."""

    def key(self, now_s: float) -> tuple[float, float]:
        """Sort key, worst first: days to the soonest crossing (negative once crossed),
        then the smallest margin to a threshold."""
        days = min((tr.crossing_s - now_s) / DAY_S if math.isfinite(tr.crossing_s)
                   else (-1e6 if tr.status == "crossed" else math.inf)
                   for tr in self.trends.values())
        margin = min(abs(tr.current_rel - tr.threshold_rel) if math.isfinite(tr.current_rel)
                     else math.inf for tr in self.trends.values())
        return days, margin


def level_thresholds(level: str) -> dict[str, tuple[float, str]]:
    """Per parameter (threshold relative to nominal, side) at ``level``, the gateway's."""
    k = LEVELS.index(level)
    out = {}
    for name, pol in thresholds().items():
        for side in ("low", "high"):
            thr = pol.levels(side)[k]
            if thr is not None:
                out[name] = (float(thr), side)
    return out


def load_runs(store: Store, version: str) -> list[RunRow]:
    """Each replayed run's final estimate, with the alert events raised during the run by
    the gateway's policy run over the unit's runs in calendar order
    (:func:`gateway.fleet.runs.unit_alerts`); then :func:`onboard_rows`."""
    finals = []
    series: dict[tuple[str, str], list[RunEstimates]] = {}
    root = store.root.resolve()
    for info in sorted(store.runs(), key=lambda i: i.t0_s):
        path = result_path(root, version, info)
        if info.grid_points == 0 or not path.is_file():
            continue
        table = pq.read_table(path)
        if table.num_rows == 0:
            continue
        t = table.column("t_s").to_numpy()
        mean = np.column_stack([table.column(f"{p}_mean").to_numpy() for p in PARAMS])
        std = np.column_stack([table.column(f"{p}_std").to_numpy() for p in PARAMS])
        ess = table.column("ess").to_numpy()
        names = set(table.column_names)        # results from before 2026-11-28: none
        weak = np.column_stack([table.column(f"{p}_unresolved").to_numpy()
                                if f"{p}_unresolved" in names else np.zeros(len(t), bool)
                                for p in PARAMS])
        series.setdefault((info.vehicle, info.bogie), []).append(
            RunEstimates(t, mean, std, ess, (), weak))
        finals.append((info, float(t[-1]), mean[-1], std[-1],
                       tuple(p for j, p in enumerate(PARAMS) if weak[-1, j])))
    alerts = {unit: unit_alerts(runs) for unit, runs in series.items()}
    rows = []
    for info, t_end, m, sd, unresolved in finals:
        unit = (info.vehicle, info.bogie)
        t_start = info.t0_s
        rows.append(RunRow(info.vehicle, info.bogie, info.run_id, t_end,
                           tuple(m[j] / NOMINAL[p] for j, p in enumerate(PARAMS)),
                           tuple(sd[j] / NOMINAL[p] for j, p in enumerate(PARAMS)),
                           tuple(a for a in alerts[unit]
                                 if t_start <= float(a["t_s"]) <= t_end),  # type: ignore[arg-type]
                           unresolved))
    rows += onboard_rows(store, {(r.vehicle, r.bogie) for r in rows})
    if not rows:
        raise InputError(f"expected replay results for estimator {version} or ingested state "
                         f"directories in {store.root}, got neither (run 'railgw fleet "
                         f"replay' first)")
    return sorted(rows, key=lambda r: (r.vehicle, r.bogie, r.t_s))


def onboard_rows(store: Store, replayed: set[tuple[str, str]]) -> list[RunRow]:
    """For units known only from state directories (no replayed run), one row per day
    from the vehicle's own estimates (run id ``onboard-<day>``)."""
    rows = []
    for veh, bog in onboard_units(store.root):
        if (veh, bog) in replayed:
            continue
        for wall_s, mean, std, weak in daily_points(read_onboard(store.root, veh, bog)):
            rows.append(RunRow(veh, bog, f"onboard-{iso(wall_s)[:10]}", wall_s,
                               tuple(mean[j] / NOMINAL[p] for j, p in enumerate(PARAMS)),
                               tuple(std[j] / NOMINAL[p] for j, p in enumerate(PARAMS)), (),
                               tuple(p for j, p in enumerate(PARAMS) if weak[j])))
    return rows


def unit_trends(rows: list[RunRow], level: str) -> list[UnitTrends]:
    thr = level_thresholds(level)
    units: dict[tuple[str, str], list[RunRow]] = {}
    for r in rows:
        units.setdefault((r.vehicle, r.bogie), []).append(r)
    out = []
    for (veh, bog), rs in sorted(units.items()):
        t = np.array([r.t_s for r in rs])
        trends = {}
        for j, p in enumerate(PARAMS):      # an unresolved value is no measurement of it
            trends[p] = fit_trend(t, np.array([math.nan if p in r.unresolved else r.rel[j]
                                               for r in rs]),
                                  np.array([r.std_rel[j] for r in rs]), *thr[p])
        weak = {p: k for p in PARAMS if (k := sum(p in r.unresolved for r in rs))}
        out.append(UnitTrends(veh, bog, trends, weak))
    return out


def iso(t_s: float) -> str:
    if not math.isfinite(t_s):
        return "" if math.isnan(t_s) else "open"
    return dt.datetime.fromtimestamp(t_s, dt.UTC).strftime("%Y-%m-%d %H:%M")


def ranking(units: list[UnitTrends], now_s: float) -> list[dict[str, object]]:
    """The fleet ranking, worst first (one row per unit, its worst parameter)."""
    out = []
    for rank, u in enumerate(sorted(units, key=lambda u: u.key(now_s)), 1):
        p, tr = min(u.trends.items(), key=lambda kv: UnitTrends(
            u.vehicle, u.bogie, {kv[0]: kv[1]}).key(now_s))
        days, _ = u.key(now_s)
        out.append({"rank": rank, "vehicle": u.vehicle, "bogie": u.bogie,
                    "parameter": LABELS[p], "status": tr.status, "model": tr.model,
                    "current_rel": round(tr.current_rel, 4), "threshold_rel": tr.threshold_rel,
                    "crossing": iso(tr.crossing_s), "crossing_lo": iso(tr.crossing_lo_s),
                    "crossing_hi": iso(tr.crossing_hi_s),
                    "days_to_crossing": round(days, 1) if abs(days) < 1e5 else "",
                    "unresolved_runs": ", ".join(f"{LABELS[q]} {k}"
                                                 for q, k in u.unresolved.items())})
    return out


def _write_csv(path: Path, rows: list[dict[str, object]]) -> None:
    with open(path, "w", newline="", encoding="utf-8") as f:
        if not rows:
            return
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


def _plot_unit(path: Path, u: UnitTrends, rs: list[RunRow], board: OnboardHistory) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.dates as mdates
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 1, figsize=(8, 7), sharex=True)
    t = np.array([r.t_s for r in rs])
    when = [dt.datetime.fromtimestamp(x, dt.UTC) for x in t]
    for j, (ax, p) in enumerate(zip(axes, PARAMS, strict=True)):
        tr = u.trends[p]
        y = np.array([r.rel[j] for r in rs])
        s = np.array([r.std_rel[j] for r in rs])
        if len(board.wall_s):
            ax.plot([dt.datetime.fromtimestamp(x, dt.UTC) for x in board.wall_s],
                    board.mean[:, j] / NOMINAL[p], ".", color="0.6", ms=2,
                    label="on board (state directory)")
        ax.errorbar(when, y, yerr=2 * s, fmt="o", ms=3, lw=0.8, label="run estimate ±2σ")
        weak = [k for k, r in enumerate(rs) if p in r.unresolved]
        if weak:
            ax.plot([when[k] for k in weak], y[weak], "x", color="C3", ms=7,
                    label="unresolved (not in the trend)")
        t_end = max(t[-1], tr.crossing_hi_s if math.isfinite(tr.crossing_hi_s) else t[-1],
                    tr.crossing_s if math.isfinite(tr.crossing_s) else t[-1])
        tt = np.linspace(t[0], t_end, 200)
        if tr.model == "line":
            t_ref, a, b = tr.line
            ax.plot([dt.datetime.fromtimestamp(x, dt.UTC) for x in tt],
                    a + b * (tt - t_ref) / DAY_S, "C1-", lw=1, label="trend")
        ax.axhline(tr.threshold_rel, color="C3", ls="--", lw=1, label="threshold")
        if math.isfinite(tr.crossing_s):
            lo = tr.crossing_lo_s
            hi = tr.crossing_hi_s if math.isfinite(tr.crossing_hi_s) else t_end
            ax.axvspan(dt.datetime.fromtimestamp(lo, dt.UTC), dt.datetime.fromtimestamp(
                hi, dt.UTC), color="C3", alpha=0.12, label="crossing interval")
            ax.axvline(dt.datetime.fromtimestamp(tr.crossing_s, dt.UTC), color="C3", lw=1)
        for r in rs:
            for a_ in r.alerts:
                if a_.get("parameter") == p and a_.get("state") == "raised":
                    ax.plot(dt.datetime.fromtimestamp(float(a_["t_s"]), dt.UTC),  # type: ignore[arg-type]
                            float(a_["value_rel"]), "rv", ms=6)  # type: ignore[arg-type]
        for a_ in board.alerts:
            if a_.get("parameter") == p and a_.get("state") == "RAISED":
                ax.plot(dt.datetime.fromtimestamp(float(a_["wall_time_s"]), dt.UTC),  # type: ignore[arg-type]
                        float(a_["value_rel"]), "v", color="C4", ms=6)  # type: ignore[arg-type]
        ax.set_ylabel(f"{LABELS[p]} / nominal")
        ax.grid(alpha=0.3)
    axes[0].set_title(f"{u.vehicle} {u.bogie}: estimates per run "
                      "(▽ alert raised: red replay, purple on board)")
    axes[0].legend(fontsize=7, loc="best")
    loc = mdates.AutoDateLocator()
    axes[-1].xaxis.set_major_locator(loc)
    axes[-1].xaxis.set_major_formatter(mdates.ConciseDateFormatter(loc))
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def _plot_fleet(path: Path, rows: list[RunRow]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(11, 3.4))
    units = sorted({(r.vehicle, r.bogie) for r in rows})
    t0 = min(r.t_s for r in rows)
    for veh, bog in units:
        rs = [r for r in rows if (r.vehicle, r.bogie) == (veh, bog)]
        d = [(r.t_s - t0) / DAY_S for r in rs]
        for j, ax in enumerate(axes):
            ax.plot(d, [r.rel[j] for r in rs], ".-", lw=0.7, ms=3, label=f"{veh}/{bog}")
    for j, (ax, p) in enumerate(zip(axes, PARAMS, strict=True)):
        thr, _ = level_thresholds("advisory")[p]
        ax.axhline(thr, color="C3", ls="--", lw=1)
        ax.set_title(f"{LABELS[p]} / nominal")
        ax.set_xlabel("days")
        ax.grid(alpha=0.3)
        if j == 2 and len(units) <= 16:
            ax.legend(fontsize=6, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def build_report(store: Store, version: str, out_dir: str | Path, *,
                 level: str = "advisory") -> list[dict[str, object]]:
    """Write every output; returns the ranking rows (worst first)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rows = load_runs(store, version)
    units = unit_trends(rows, level)
    now_s = max(r.t_s for r in rows)
    rank = ranking(units, now_s)
    _write_csv(out / "ranking.csv", rank)
    _write_csv(out / "runs.csv", [
        {"vehicle": r.vehicle, "bogie": r.bogie, "run_id": r.run_id, "time": iso(r.t_s),
         "t_s": r.t_s, **{f"{LABELS[p]}_rel": round(r.rel[j], 5) for j, p in enumerate(PARAMS)},
         **{f"{LABELS[p]}_std_rel": round(r.std_rel[j], 5) for j, p in enumerate(PARAMS)},
         "alerts": len(r.alerts)} for r in rows])
    boards = {(u.vehicle, u.bogie): read_onboard(store.root, u.vehicle, u.bogie) for u in units}
    _write_csv(out / "alerts.csv", alert_rows(rows, boards))
    _write_csv(out / "trends.csv", [
        {"vehicle": u.vehicle, "bogie": u.bogie, "parameter": LABELS[p], "level": level,
         "threshold_rel": tr.threshold_rel, "status": tr.status, "model": tr.model,
         "runs": tr.n, "current_rel": round(tr.current_rel, 4),
         "slope_per_day": round(tr.slope_per_day, 6), "crossing": iso(tr.crossing_s),
         "crossing_lo": iso(tr.crossing_lo_s), "crossing_hi": iso(tr.crossing_hi_s),
         "crossing_s": tr.crossing_s, "crossing_lo_s": tr.crossing_lo_s,
         "crossing_hi_s": tr.crossing_hi_s} for u in units for p, tr in u.trends.items()])
    figures = [("fleet.png", "All units, estimate per run relative to nominal; dashed: the "
                "advisory threshold")]
    _plot_fleet(out / "fleet.png", rows)
    for u in units:
        name = f"unit-{u.vehicle}-{u.bogie}.png"
        _plot_unit(out / name, u, [r for r in rows if (r.vehicle, r.bogie) == (u.vehicle,
                                                                                 u.bogie)],
                   boards[(u.vehicle, u.bogie)])
        figures.append((name, f"{u.vehicle} {u.bogie}"))
    _write_html(out / "report.html", version, level, rank, rows, alert_rows(rows, boards),
                figures, out)
    return rank


def _table(rows: list[dict[str, object]]) -> str:
    if not rows:
        return "<p>none</p>"
    head = "".join(f"<th>{html.escape(str(k))}</th>" for k in rows[0])
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(v))}</td>" for v in r.values())
                   + "</tr>" for r in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def alert_rows(rows: list[RunRow], boards: dict[tuple[str, str], OnboardHistory]
               ) -> list[dict[str, object]]:
    """The alert history, per unit in time order: ``replay`` events (the policy over the
    replayed runs) and ``onboard`` events (what the vehicle raised, from state directories;
    time is when the vehicle wrote them)."""
    out: list[dict[str, object]] = []
    for r in rows:
        out += [{"source": "replay", "vehicle": r.vehicle, "bogie": r.bogie,
                 "time": iso(float(a["t_s"])), "seq": a.get("seq"),  # type: ignore[arg-type]
                 "parameter": a.get("parameter"), "severity": a.get("severity"),
                 "state": a.get("state"), "value_rel": a.get("value_rel"),
                 "run_id": r.run_id} for a in r.alerts]
    for (veh, bog), b in boards.items():
        out += [{"source": "onboard", "vehicle": veh, "bogie": bog,
                 "time": iso(float(a["wall_time_s"])), "seq": a.get("seq"),  # type: ignore[arg-type]
                 "parameter": a.get("parameter"),
                 "severity": str(a.get("severity", "")).lower(),
                 "state": str(a.get("state", "")).lower(), "value_rel": a.get("value_rel"),
                 "run_id": ""} for a in b.alerts]
    return sorted(out, key=lambda a: (str(a["vehicle"]), str(a["bogie"]), str(a["time"])))


def _write_html(path: Path, version: str, level: str, rank: list[dict[str, object]],
                rows: list[RunRow], alerts: list[dict[str, object]],
                figures: list[tuple[str, str]], out: Path) -> None:
    imgs = "".join(
        f"<figure><img alt='{html.escape(name)}' src='data:image/png;base64,"
        f"{base64.b64encode((out / name).read_bytes()).decode()}'>"
        f"<figcaption>{html.escape(cap)}</figcaption></figure>" for name, cap in figures)
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>railgw fleet report</title>
<style>body{{font-family:sans-serif;margin:1.5em}}table{{border-collapse:collapse;font-size:90%}}
td,th{{border:1px solid #bbb;padding:2px 6px}}img{{max-width:100%}}</style></head><body>
<h1>Fleet report</h1><p>Estimator {html.escape(version)}; {len(rows)} runs; thresholds: the
gateway's {html.escape(level)} level. Crossing intervals: {int(100 * 0.95)} % band of the
fitted trend (line), or between the runs around the change (step).</p>
<h2>Ranking, worst first</h2>{_table(rank)}
<h2>Alert history</h2>{_table(alerts)}
<h2>Figures</h2>{imgs}</body></html>"""
    path.write_text(page, encoding="utf-8")
