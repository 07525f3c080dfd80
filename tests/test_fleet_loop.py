"""The fleet loop on a tiny simulated fleet: simulate, ingest, replay on a LocalCluster, report."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("distributed")
pytest.importorskip("pyarrow")

from firmware_sim.fleet import FleetSpec, simulate_fleet  # noqa: E402
from gateway.config import Config, with_overrides  # noqa: E402
from gateway.fleet.replay import dask_client, replay_store, result_path  # noqa: E402
from gateway.fleet.report import build_report  # noqa: E402
from gateway.fleet.runs import PARAMS, estimator_version  # noqa: E402
from gateway.fleet.store import Store  # noqa: E402

pytestmark = pytest.mark.slow   # the everyday tier is -m "not slow"; CI runs all

SPEC = FleetSpec(vehicles=3, days=6, runs_per_day=1, run_s=6.0, degrade_days=10.0,
                 fail_frac=0.5, seed=3)
CFG = with_overrides(Config(), {"estimator.particles": 100})


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("fleet")
    simulate_fleet(SPEC, root / "sim")
    store = Store(root / "store")
    attempts = root / "attempts"
    attempts.mkdir()
    with dask_client(workers=2) as client:     # ingest and replay, one log/run per task
        first = store.ingest([root / "sim" / "logs"], CFG, client=client)
        assert len(first.added) == SPEC.vehicles * SPEC.days and not first.skipped
        rep = replay_store(store, CFG, client, attempts_dir=str(attempts), progress=False)
    assert (rep.ran, rep.done_before, rep.workers) == (len(first.added), 0, 2)
    build_report(store, estimator_version(CFG), root / "report")
    return {"root": root, "store": root / "store", "report": root / "report",
            "attempts": attempts}


def test_ingest_is_idempotent(fleet: dict[str, Path]) -> None:
    store = Store(fleet["store"])
    before = store.runs()
    files = sorted((fleet["store"] / "samples").rglob("*.parquet"))
    again = store.ingest([fleet["root"] / "sim" / "logs"], CFG)
    assert again.added == () and len(again.skipped) == len(before)
    assert store.runs() == before
    assert sorted((fleet["store"] / "samples").rglob("*.parquet")) == files
    assert {(r.vehicle, r.bogie) for r in before} == {("V01", "B1"), ("V02", "B1"),
                                                       ("V03", "B1")}
    assert all(r.grid_points > 5000 and r.day.startswith("2026-01-") for r in before)


def test_ingest_in_this_process_stores_what_the_dask_tasks_stored(
        fleet: dict[str, Path], tmp_path: Path) -> None:
    # one contract, two ways to run it: the same manifest lines, equal tables and metadata
    import pyarrow.parquet as pq

    dask_store = Store(fleet["store"])
    here = Store(tmp_path / "store")
    rep = here.ingest([fleet["root"] / "sim" / "logs"], CFG)
    key = {r.run_id: r for r in dask_store.runs()}
    assert len(rep.added) == len(key) and not rep.skipped
    assert sorted(r.run_id for r in here.runs()) == sorted(key)
    for r in here.runs():
        assert r == key[r.run_id]
        a = pq.read_table(here.root / r.samples_path)
        b = pq.read_table(dask_store.root / r.samples_path)
        assert a.schema.equals(b.schema, check_metadata=True), r.run_id
        for col in a.column_names:          # NaN marks a missing sample: equal here
            assert np.array_equal(a.column(col).to_numpy(), b.column(col).to_numpy(),
                                  equal_nan=col != "update"), (r.run_id, col)


def test_each_run_replayed_once_with_one_result(fleet: dict[str, Path]) -> None:
    store = Store(fleet["store"])
    runs = store.runs()
    version = estimator_version(CFG)
    assert all(result_path(fleet["store"].resolve(), version, r).is_file() for r in runs)
    results = list((fleet["store"] / "results").rglob("*.parquet"))
    assert len(results) == len(runs)
    attempts = [p.name.split(".")[0] for p in fleet["attempts"].iterdir()]
    assert sorted(attempts) == sorted(r.run_id for r in runs)
    assert not list((fleet["store"]).rglob("*.tmp"))


def test_report_ranks_failed_and_degrading_first(fleet: dict[str, Path]) -> None:
    truth = json.loads((fleet["root"] / "sim" / "truth.json").read_text())
    lines = (fleet["report"] / "ranking.csv").read_text().splitlines()
    header = lines[0].split(",")
    rows = [dict(zip(header, line.split(","), strict=True)) for line in lines[1:]]
    roles = [truth["units"][f"{r['vehicle']}/{r['bogie']}"]["role"] for r in rows]
    assert roles[-1] == "nominal", roles
    assert set(roles[:2]) == {"csy-failing", "csy-degrading"}, roles


def test_failed_damper_crossing_interval_brackets_truth(fleet: dict[str, Path]) -> None:
    truth = json.loads((fleet["root"] / "sim" / "truth.json").read_text())
    lines = (fleet["report"] / "trends.csv").read_text().splitlines()
    header = lines[0].split(",")
    rows = [dict(zip(header, line.split(","), strict=True)) for line in lines[1:]]
    failing = [u for u, v in truth["units"].items() if v["role"] == "csy-failing"]
    assert len(failing) == 1
    veh, bog = failing[0].split("/")
    row = next(r for r in rows if (r["vehicle"], r["bogie"], r["parameter"]) == (veh, bog,
                                                                                 "Csy"))
    true_s = truth["units"][failing[0]]["crossings"]["csy_ns_per_m"]["advisory"]
    assert row["status"] == "crossed"
    assert float(row["crossing_lo_s"]) <= true_s <= float(row["crossing_hi_s"])
    for r in rows:                      # a predicted crossing must bracket the true one
        if r["crossing_s"] not in ("", "nan") and r["status"] == "trending":
            unit = truth["units"][f"{r['vehicle']}/{r['bogie']}"]
            key = {"Csy": "csy_ns_per_m", "Csay": "csay_ns_per_m", "λ": "conicity"}
            t_true = unit["crossings"][key[r["parameter"]]]["advisory"]
            assert t_true is not None, r
            assert float(r["crossing_lo_s"]) <= t_true <= float(r["crossing_hi_s"]), r


def test_report_files_and_self_contained_html(fleet: dict[str, Path]) -> None:
    out = fleet["report"]
    for name in ("ranking.csv", "trends.csv", "runs.csv", "alerts.csv", "fleet.png",
                 "unit-V01-B1.png", "report.html"):
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
    page = (out / "report.html").read_text()
    assert page.count("data:image/png;base64,") == 4
    assert "src='http" not in page and 'src="http' not in page


def test_sql_over_the_store(fleet: dict[str, Path]) -> None:
    duckdb = pytest.importorskip("duckdb")
    store = Store(fleet["store"])
    q = (f"SELECT vehicle, count(*) AS n FROM read_parquet("
         f"'{fleet['store']}/samples/**/*.parquet', hive_partitioning=true) "
         f"GROUP BY vehicle ORDER BY vehicle")
    got = dict(duckdb.sql(q).fetchall())
    want: dict[str, int] = {}
    for r in store.runs():
        want[r.vehicle] = want.get(r.vehicle, 0) + r.grid_points
    assert got == want


def _csv(path: Path) -> list[dict[str, str]]:
    import csv

    with open(path, encoding="utf-8", newline="") as f:
        return list(csv.DictReader(f))


def test_alert_history_runs_on_across_runs(fleet: dict[str, Path]) -> None:
    # one policy per unit over all its runs, as on the vehicle: a damper that has failed
    # is raised once, not again at the start of every later run
    truth = json.loads((fleet["root"] / "sim" / "truth.json").read_text())
    alerts = [a for a in _csv(fleet["report"] / "alerts.csv") if a["source"] == "replay"]
    states: dict[tuple[str, ...], str] = {}
    for a in alerts:
        key = (a["vehicle"], a["bogie"], a["parameter"], a["severity"])
        assert states.get(key, "cleared") != a["state"] or a["state"] == "acknowledged", a
        states[key] = a["state"]
    failing = next(u for u, v in truth["units"].items() if v["role"] == "csy-failing")
    veh, bog = failing.split("/")
    t_fail = truth["units"][failing]["crossings"]["csy_ns_per_m"]["advisory"]
    raised = [a for a in alerts if (a["vehicle"], a["bogie"], a["parameter"], a["state"])
              == (veh, bog, "csy_ns_per_m", "raised")]
    assert raised and all(a["time"] >= _iso(t_fail) for a in raised), raised


def _iso(t_s: float) -> str:
    import datetime as dt

    return dt.datetime.fromtimestamp(t_s, dt.UTC).strftime("%Y-%m-%d %H:%M")


def test_report_shows_an_ingested_state_directory(fleet: dict[str, Path],
                                                  tmp_path: Path) -> None:
    # the vehicle's own history, written by the service's StateStore from V01's replayed
    # estimates, lands beside the replay in the same report
    import pyarrow.parquet as pq

    from gateway.records import Alert, AlertState, Estimate, Severity
    from gateway.sinks.store import StateStore

    store = Store(fleet["store"])
    runs = [r for r in store.runs() if r.vehicle == "V01"]
    now = [0.0]
    state = tmp_path / "copy" / "V01" / "B1" / "state"
    with StateStore(state, clock=lambda: now[0]) as st:
        for r in runs:
            t = pq.read_table(result_path(fleet["store"].resolve(), estimator_version(CFG), r))
            for row in t.to_pylist():
                now[0] = row["t_s"]
                st.record_estimate(Estimate(row["t_s"], tuple(row[f"{p}_mean"] for p in PARAMS),
                                            tuple(row[f"{p}_std"] for p in PARAMS), row["ess"]))
        st.append_alert(Alert(7, now[0], PARAMS[1], Severity.WARNING, AlertState.RAISED,
                              0x202, 0.6, "Csay low"))
    rep = store.ingest([tmp_path / "copy"], CFG)
    assert [(s.vehicle, s.alerts) for s in rep.states] == [("V01", 1)]
    assert rep.states[0].estimates >= len(runs)
    build_report(store, estimator_version(CFG), tmp_path / "report")
    onboard = [a for a in _csv(tmp_path / "report" / "alerts.csv") if a["source"] == "onboard"]
    assert [(a["vehicle"], a["seq"], a["parameter"], a["severity"], a["state"])
            for a in onboard] == [("V01", "7", PARAMS[1], "warning", "raised")]
    replay = [a for a in _csv(tmp_path / "report" / "alerts.csv") if a["source"] == "replay"]
    assert replay == [a for a in _csv(fleet["report"] / "alerts.csv")
                      if a["source"] == "replay"]


def test_the_truth_study_matches_every_run_to_its_truth(fleet: dict[str, Path]) -> None:
    # firmware_sim.studies.fleet_truth reads a demo directory (sim/ and store/), as this
    # fixture lays it out: every replayed run matched to its own true θ
    from firmware_sim.studies.fleet_truth import errors

    rel, z = errors(fleet["root"], estimator_version(CFG))
    assert rel.shape == z.shape == (SPEC.vehicles * SPEC.days, len(PARAMS))
    # a run matched to another run's truth would be off by the failed damper's 75 %
    assert np.all(np.median(np.abs(rel), axis=0) < 0.1), np.median(np.abs(rel), axis=0)
