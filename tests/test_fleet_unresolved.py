"""A unit whose body node died: the fleet view keeps its runs' Csy out of the trend.

With the body node out of a 3-sensor set the estimates cannot resolve Csy
(gateway.estimator.observability): the value is the last one the data told, with a
narrow σ. Before 2026-11-28 such runs entered the unit's trend as measurements, so a
blind unit looked healthy and stable. Now each replayed run's result keeps the
per-estimate ``*_unresolved`` columns, the report leaves those runs' value out of that
parameter's trend (kept in the plot, marked), and the ranking says how many runs.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("distributed")
pytest.importorskip("pyarrow")

import pyarrow.parquet as pq  # noqa: E402

from firmware_sim.fleet import FleetSpec, plan, simulate_fleet  # noqa: E402
from firmware_sim.output import write_log  # noqa: E402
from gateway.can.codec import default_codec  # noqa: E402
from gateway.can.logs import read_log  # noqa: E402
from gateway.config import Config, with_overrides  # noqa: E402
from gateway.fleet.replay import dask_client, replay_store, result_path  # noqa: E402
from gateway.fleet.report import build_report, load_runs, unit_trends  # noqa: E402
from gateway.fleet.runs import estimator_version  # noqa: E402
from gateway.fleet.store import Store  # noqa: E402

pytestmark = pytest.mark.slow   # the everyday tier is -m "not slow"; CI runs all

SPEC = FleetSpec(vehicles=2, days=3, runs_per_day=1, run_s=6.0, seed=11)
CFG = with_overrides(Config(), {"estimator.particles": 100})


def test_runs_with_the_body_node_dead_stay_out_of_the_csy_trend(tmp_path: Path) -> None:
    simulate_fleet(SPEC, tmp_path / "sim")
    runs = list(plan(SPEC))
    blind = {p.file for p in runs if p.vehicle == runs[0].vehicle and p.t0_s > runs[0].t0_s}
    assert len(blind) == 2
    bdn = default_codec().message("BDN_Lat").frame_id
    for name in blind:                         # the body node dead in days 2 and 3
        path = tmp_path / "sim" / name
        frames = [m for m in read_log(path) if m.arbitration_id != bdn]
        write_log(frames, path)
    store = Store(tmp_path / "store")
    with dask_client(workers=2) as client:
        store.ingest([tmp_path / "sim" / "logs"], CFG, client=client)
        replay_store(store, CFG, client, progress=False)
    version = estimator_version(CFG)
    stored = list(store.runs())
    assert len(stored) == len(runs)
    for p in runs:                             # the stored run of each planned one
        info = min((i for i in stored if i.vehicle == p.vehicle),
                   key=lambda i: abs(i.t0_s - p.t0_s))
        table = pq.read_table(result_path(store.root.resolve(), version, info))
        weak = table.column("csy_ns_per_m_unresolved").to_numpy()
        assert bool(weak[-1]) == (p.file in blind), (p.file, weak[-5:])
        assert not table.column("conicity_unresolved").to_numpy().any(), p.file
    rows = load_runs(store, version)
    trends = {u.vehicle: u for u in unit_trends(rows, "advisory")}
    other = runs[-1].vehicle
    assert other != runs[0].vehicle
    dead, alive = trends[runs[0].vehicle], trends[other]
    assert dead.unresolved == {"csy_ns_per_m": 2} and alive.unresolved == {}
    assert dead.trends["csy_ns_per_m"].n == 1 and dead.trends["conicity"].n == 3
    assert alive.trends["csy_ns_per_m"].n == 3
    rank = build_report(store, version, tmp_path / "report")
    said = {r["vehicle"]: r["unresolved_runs"] for r in rank}
    assert said == {runs[0].vehicle: "Csy 2", other: ""}
    assert np.isfinite([r.rel[0] for r in rows]).all()     # kept for the plot


def test_the_fleet_view_does_not_judge_an_unresolved_parameter() -> None:
    """The report's alert events (:func:`gateway.fleet.runs.unit_alerts`) follow the
    vehicle's policy: a run whose Csy sat at 0.2 of nominal with a narrow sigma while the
    sensors could not resolve it raises nothing on Csy; the next run, resolved, raises
    the ALARM."""
    from gateway.fleet.runs import NOMINAL, PARAMS, RunEstimates, unit_alerts

    t = np.arange(0.0, 30.0, 0.1)
    nominal = np.array([NOMINAL[p] for p in PARAMS])
    mean = np.repeat((nominal * [0.2, 1.0, 1.0])[None], len(t), 0)
    std = 0.01 * np.repeat(nominal[None], len(t), 0)
    weak = np.zeros((len(t), 3), bool)
    weak[:, 0] = True
    blind = RunEstimates(t, mean, std, np.full(len(t), 500.0), (), weak)
    seen = RunEstimates(t + 100.0, mean, std, np.full(len(t), 500.0), (),
                        np.zeros_like(weak))
    assert unit_alerts([blind]) == []
    events = unit_alerts([blind, seen])
    assert [(e["parameter"], e["severity"], e["state"]) for e in events] == [
        ("csy_ns_per_m", "alarm", "raised")], events
    assert float(events[0]["t_s"]) >= 100.0           # from the resolved run
