"""railgw fleet ingest of gateway state directories: written by the service's own StateStore,
copied off the vehicle twice with overlap, stored once per entry, the copy left untouched."""

from __future__ import annotations

import dataclasses
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("pyarrow")

from gateway.config import Config  # noqa: E402
from gateway.fleet.onboard import read_onboard, state_infos  # noqa: E402
from gateway.fleet.runs import NOMINAL, PARAMS  # noqa: E402
from gateway.fleet.store import Store  # noqa: E402
from gateway.records import Alert, AlertState, Estimate, Severity  # noqa: E402
from gateway.sinks.store import StateStore  # noqa: E402

T0_S = 1_767_225_600.0          # 2026-01-01 00:00 UTC
DAY_S = 86_400.0


class Clock:
    def __init__(self) -> None:
        self.now_s = T0_S

    def __call__(self) -> float:
        return self.now_s


def _estimate(t_s: float, csy_rel: float) -> Estimate:
    mean = (NOMINAL[PARAMS[0]] * csy_rel, NOMINAL[PARAMS[1]], NOMINAL[PARAMS[2]])
    return Estimate(t_s, mean, tuple(0.02 * m for m in mean), 500.0)


def _write_days(state: Path, clock: Clock, days: range, seq0: int) -> None:
    """One 60 s run a day (an estimate kept every 10 s); Csy falls 5 % a day; an advisory
    raised on day 5."""
    with StateStore(state, clock=clock) as st:
        for d in days:
            for k in range(7):
                clock.now_s = T0_S + d * DAY_S + 10.0 * k
                st.record_estimate(_estimate(clock.now_s, 1.0 - 0.05 * d))
            if d == 5:
                st.append_alert(Alert(seq0, clock.now_s, PARAMS[0], Severity.ADVISORY,
                                      AlertState.RAISED, 0x101, 0.75, "Csy low"))


def _listing(d: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(d.iterdir())}


def test_overlapping_copies_store_each_entry_once(tmp_path: Path) -> None:
    live = tmp_path / "vehicle" / "state"
    clock = Clock()
    _write_days(live, clock, range(0, 4), 1)
    copy1 = tmp_path / "copies" / "V07" / "B2" / "2026-01-04"
    shutil.copytree(live, copy1)
    _write_days(live, clock, range(4, 7), 1)          # the vehicle goes on writing
    copy2 = tmp_path / "copies" / "V07" / "B2" / "2026-01-07"
    shutil.copytree(live, copy2)
    before = _listing(copy1)

    store = Store(tmp_path / "store")
    rep = store.ingest([tmp_path / "copies"], Config())
    assert rep.added == ()
    assert [(s.vehicle, s.bogie, s.estimates, s.alerts) for s in rep.states] == [
        ("V07", "B2", 28, 0), ("V07", "B2", 21, 1)]    # copy 2 adds only days 4-6
    assert _listing(copy1) == before                   # read only: no lock, no repair

    board = read_onboard(store.root, "V07", "B2")
    assert len(board.wall_s) == 49 and (board.wall_s[1:] > board.wall_s[:-1]).all()
    csy_rel = board.mean[:, 0] / NOMINAL[PARAMS[0]]
    assert csy_rel[0] == pytest.approx(1.0) and csy_rel[-1] == pytest.approx(0.70)
    assert [(a["seq"], a["severity"], a["state"]) for a in board.alerts] == [
        (1, "ADVISORY", "RAISED")]
    days = sorted(p.name for p in (store.root / "onboard" / "estimates" / "vehicle=V07"
                                   / "bogie=B2").iterdir())
    assert days == [f"day=2026-01-0{d}" for d in range(1, 8)]

    again = store.ingest([tmp_path / "copies"], Config())   # same bytes: skipped
    assert again.states == () and len(again.skipped) == 2
    assert len(state_infos(store.root)) == 2
    copy3 = tmp_path / "copies" / "V07" / "B2" / "2026-01-07b"   # touched, same entries
    shutil.copytree(copy2, copy3)
    with open(copy3 / "estimates.jsonl", "a", encoding="utf-8") as f:
        f.write("\n")
    third = store.ingest([copy3], Config(), vehicle="V07", bogie="B2")
    assert [(s.estimates, s.alerts) for s in third.states] == [(0, 0)]
    assert len(read_onboard(store.root, "V07", "B2").wall_s) == 49


def test_sql_over_the_onboard_history(tmp_path: Path) -> None:
    duckdb = pytest.importorskip("duckdb")
    clock = Clock()
    _write_days(tmp_path / "in" / "V01" / "B1" / "state", clock, range(0, 3), 10)
    store = Store(tmp_path / "store")
    store.ingest([tmp_path / "in"], Config())
    got = duckdb.sql(
        f"SELECT day, count(*) FROM read_parquet('{store.root}/onboard/estimates/**/*.parquet',"
        f" hive_partitioning=true) WHERE vehicle = 'V01' GROUP BY day ORDER BY day").fetchall()
    assert [(str(d), n) for d, n in got] == [("2026-01-01", 7), ("2026-01-02", 7),
                                            ("2026-01-03", 7)]


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "gateway", "fleet", "ingest", *args],
                          capture_output=True, text=True, timeout=120)


def test_a_loose_state_directory_needs_its_unit(tmp_path: Path) -> None:
    _write_days(tmp_path / "state", Clock(), range(0, 1), 1)
    out = _cli(str(tmp_path / "store"), str(tmp_path / "state"))
    assert out.returncode == 2
    assert len(out.stderr.strip().splitlines()) == 1
    assert "--vehicle and --bogie" in out.stderr
    ok = _cli(str(tmp_path / "store"), str(tmp_path / "state"), "--vehicle", "V01",
              "--bogie", "B1")
    assert ok.returncode == 0, ok.stderr
    assert "1 state directories (7 estimates, 0 alert events new)" in ok.stdout


def test_a_corrupt_record_is_one_line_naming_file_and_line(tmp_path: Path) -> None:
    state = tmp_path / "V01" / "B1" / "state"
    _write_days(state, Clock(), range(0, 1), 1)
    lines = (state / "estimates.jsonl").read_text().splitlines()
    lines[2] = '{"t_s": "soon"}'
    (state / "estimates.jsonl").write_text("\n".join(lines) + "\n")
    out = _cli(str(tmp_path / "store"), str(tmp_path))
    assert out.returncode != 0
    err = out.stderr.strip().splitlines()
    assert len(err) == 1 and "estimates.jsonl:3: expected an estimate-history record" in err[0]
    assert not (tmp_path / "store" / "onboard").exists()


def test_a_unit_known_only_from_its_state_directory_is_trended(tmp_path: Path) -> None:
    # no logs kept: the report trends the vehicle's own estimates, one point a day
    import csv

    from gateway.fleet.report import build_report

    _write_days(tmp_path / "in" / "V03" / "B1" / "state", Clock(), range(0, 7), 1)
    store = Store(tmp_path / "store")
    store.ingest([tmp_path / "in"], Config())
    rank = build_report(store, "none-replayed", tmp_path / "report")
    assert [(r["vehicle"], r["parameter"], r["status"]) for r in rank] == [
        ("V03", "Csy", "crossed")]
    with open(tmp_path / "report" / "trends.csv", encoding="utf-8", newline="") as f:
        csy = next(r for r in csv.DictReader(f) if r["parameter"] == "Csy")
    true_s = T0_S + 5 * DAY_S + 60.0       # 1 - 0.05 d meets the advisory 0.75 at day 5
    assert float(csy["crossing_lo_s"]) <= true_s <= float(csy["crossing_hi_s"]), csy
    assert int(csy["runs"]) == 7
    with open(tmp_path / "report" / "alerts.csv", encoding="utf-8", newline="") as f:
        alerts = list(csv.DictReader(f))
    assert [(a["source"], a["severity"], a["state"]) for a in alerts] == [
        ("onboard", "advisory", "raised")]
    assert (tmp_path / "report" / "unit-V03-B1.png").stat().st_size > 0


def test_unresolved_on_board_estimates_stay_out_of_the_trend(tmp_path: Path) -> None:
    """The vehicle's own history says when its sensors could not resolve Csy (the
    estimate-history line's ``unresolved``, since 2026-11-28): those days' Csy is kept
    but left out of the trend, and the ranking counts them. Lines written before carry
    none and read as resolved."""
    import csv

    from gateway.fleet.report import build_report
    from gateway.sinks.store.codec import estimate_from_json, estimate_to_json

    state, clock = tmp_path / "in" / "V05" / "B1" / "state", Clock()
    with StateStore(state, clock=clock) as st:
        for d in range(6):                  # healthy Csy; the body node dead from day 3
            for k in range(3):
                clock.now_s = T0_S + d * DAY_S + 10.0 * k
                est = _estimate(clock.now_s, 1.0)
                if d >= 3:
                    est = dataclasses.replace(est, left_out=("acc_bd",),
                                              unresolved=(PARAMS[0],))
                st.record_estimate(est)
    store = Store(tmp_path / "store")
    store.ingest([tmp_path / "in"], Config())
    board = read_onboard(store.root, "V05", "B1")
    assert board.unresolved[:, 0].tolist() == [False] * 9 + [True] * 9
    assert not board.unresolved[:, 1:].any()
    rank = build_report(store, "none-replayed", tmp_path / "report")
    assert [r["unresolved_runs"] for r in rank] == ["Csy 3"]
    with open(tmp_path / "report" / "trends.csv", encoding="utf-8", newline="") as f:
        runs = {r["parameter"]: int(r["runs"]) for r in csv.DictReader(f)}
    assert runs == {"Csy": 3, "Csay": 6, "λ": 6}
    line = estimate_to_json(_estimate(1.0, 1.0), T0_S)
    assert "unresolved" not in line and estimate_from_json(line).unresolved == ()
    weak = estimate_to_json(dataclasses.replace(_estimate(1.0, 1.0), unresolved=(PARAMS[0],)),
                            T0_S)
    assert estimate_from_json(weak).unresolved == (PARAMS[0],)
