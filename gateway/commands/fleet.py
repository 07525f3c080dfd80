"""``railgw fleet``: ingest logs into a Parquet store, replay it on Dask, report the trends.

Needs the ``fleet`` extra (``pip install '.[fleet]'``); dask and pyarrow are imported
only here, when a fleet command runs, never by the vehicle's service.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from gateway.cli import SEED, config_value, integer, output_dir, real
from gateway.config import Config, load_config, with_overrides
from gateway.errors import InputError

LEVELS = ("advisory", "warning", "alarm")


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", metavar="FILE", help="TOML configuration (default: built-in)")
    p.add_argument("--particles", type=config_value("estimator", "particles"),
                   help="override [estimator] particles")
    p.add_argument("--sensors", type=int, choices=(3, 5), help="override [estimator] sensors")
    p.add_argument("--seed", type=SEED, help="override [estimator] seed")


def _cluster_opts(p: argparse.ArgumentParser, default: str) -> None:
    p.add_argument("--scheduler", metavar="tcp://HOST:8786",
                   help=f"a running Dask scheduler (default: {default})")
    p.add_argument("--workers", type=integer(1, 1024),
                   help="LocalCluster worker processes (default: the machine's cores)")


def _replay_opts(p: argparse.ArgumentParser) -> None:
    _cluster_opts(p, "an embedded LocalCluster")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--attempts-dir", metavar="DIR",
                   help="write one file per task execution there (an audit of retries)")


def register(sub: argparse._SubParsersAction) -> None:
    fleet = sub.add_parser("fleet", help="fleet view: ingest, replay on Dask, report trends")
    fsub = fleet.add_subparsers(dest="fleet_command", metavar="STEP", required=True)
    p = fsub.add_parser("ingest", help="CAN logs (.log/.asc/.blf) into the Parquet store")
    p.add_argument("store", type=output_dir, help="store directory (created if missing)")
    p.add_argument("paths", nargs="+", help="logs, gateway state directories, or directories of "
                   "VEHICLE/BOGIE/ folders holding either")
    p.add_argument("--vehicle", help="vehicle name for every log given (default: its folder)")
    p.add_argument("--bogie", help="bogie name for every log given (default: its folder)")
    _cluster_opts(p, "this process; --workers N: an embedded LocalCluster, one log per task")
    _common(p)
    p.set_defaults(func=run_ingest)
    p = fsub.add_parser("replay", help="re-estimate every stored run, one Dask task per run")
    p.add_argument("store", help="store directory")
    _common(p)
    _replay_opts(p)
    p.set_defaults(func=run_replay)
    p = fsub.add_parser("report", help="trends, crossing dates, ranking: CSV, PNG, HTML")
    p.add_argument("store", help="store directory")
    p.add_argument("--out", required=True, type=output_dir, metavar="DIR")
    p.add_argument("--level", choices=LEVELS, default="advisory",
                   help="the gateway alert level whose crossing is predicted")
    _common(p)
    p.set_defaults(func=run_report)
    p = fsub.add_parser("demo", help="the whole loop on a simulated fleet: simulate, ingest, "
                        "replay (LocalCluster), report")
    p.add_argument("--out", type=output_dir, default="fleet-demo", metavar="DIR",
                   help="working directory (default ./fleet-demo)")
    p.add_argument("--vehicles", type=integer(1, 1000), default=4)
    p.add_argument("--days", type=integer(1, 3650), default=8)
    p.add_argument("--runs-per-day", type=integer(1, 24), default=1)
    p.add_argument("--run-seconds", type=real(2.0, 3600.0), default=8.0)
    p.add_argument("--degrade-days", type=real(1.0, 3650.0), default=12.0,
                   help="days over which a degrading damper loses 30 %% (default 12: "
                   "visible in a short demo)")
    _common(p)
    _replay_opts(p)
    p.set_defaults(func=run_demo, particles=None)


def _config(args: argparse.Namespace) -> Config:
    cfg = load_config(args.config)
    over: dict[str, Any] = {}
    for key, value in (("particles", args.particles), ("sensors", args.sensors),
                       ("seed", args.seed)):
        if value is not None:
            over[f"estimator.{key}"] = value
    return with_overrides(cfg, over) if over else cfg


def _store(path: str, must_exist: bool = True) -> Any:
    from gateway.fleet.store import Store

    if must_exist and not any(Path(path, m).is_file() for m in ("manifest.jsonl",
                                                                  "state-manifest.jsonl")):
        raise InputError(f"expected a fleet store (with manifest.jsonl), got {path!r}: run "
                         f"'railgw fleet ingest' first")
    return Store(path)


def run_ingest(args: argparse.Namespace) -> int:
    store = _store(args.store, must_exist=False)

    def progress(k: int, n: int) -> None:
        if k == n or k % 20 == 0:
            print(f"ingested {k}/{n} files", file=sys.stderr, flush=True)

    with contextlib.ExitStack() as stack:
        client = (stack.enter_context(_client(args)) if args.scheduler or args.workers
                  else None)
        rep = store.ingest(args.paths, _config(args), vehicle=args.vehicle, bogie=args.bogie,
                           client=client, progress=progress)
    _print_ingest(rep, args.store)
    return 0


def _print_ingest(rep: Any, store: str) -> None:
    points = sum(r.grid_points for r in rep.added)
    print(f"ingested {len(rep.added)} runs ({points} grid points) and {len(rep.states)} state "
          f"directories ({sum(s.estimates for s in rep.states)} estimates, "
          f"{sum(s.alerts for s in rep.states)} alert events new), skipped "
          f"{len(rep.skipped)} already in the store -> {store}")
    if rep.replaced:
        print(f"made the samples of {len(rep.replaced)} of those runs again: another front "
              f"end had made them")


@contextlib.contextmanager
def _client(args: argparse.Namespace) -> Iterator[Any]:
    """The Dask client of ``--scheduler``/``--workers``, the cluster's INFO chatter quiet."""
    import distributed  # noqa: F401 - sets its loggers' levels; quieten them after

    from gateway.fleet.replay import dask_client

    for name in list(logging.root.manager.loggerDict):
        if name.split(".")[0] in ("distributed", "tornado"):
            logging.getLogger(name).setLevel(logging.WARNING)
    with dask_client(args.scheduler, args.workers) as client:
        yield client


def _replay(store: Any, cfg: Config, args: argparse.Namespace, client: Any = None) -> Any:
    from gateway.fleet.replay import replay_store

    try:
        with contextlib.ExitStack() as stack:
            if client is None:
                client = stack.enter_context(_client(args))
            rep = replay_store(store, cfg, client, progress=not args.no_progress,
                               attempts_dir=args.attempts_dir)
    except KeyboardInterrupt:
        print("interrupted: finished runs are kept; the same command resumes",
              file=sys.stderr)
        raise SystemExit(130) from None
    print(f"replayed {rep.ran} runs on {rep.workers} Dask workers in {rep.wall_s:.1f} s "
          f"({rep.runs_per_s:.3f} runs/s); {rep.done_before} of {rep.runs} already done; "
          f"estimator {rep.version}")
    if rep.stale:
        print(f"{rep.stale} runs not replayed: their samples were made by another front end "
              f"(ingest their logs again with this configuration: railgw fleet ingest "
              f"{store.root} LOGS)", file=sys.stderr)
    return rep


def run_replay(args: argparse.Namespace) -> int:
    _replay(_store(args.store), _config(args), args)
    return 0


def _report(store: Any, cfg: Config, out: str, level: str) -> list[dict[str, object]]:
    from gateway.fleet.report import build_report
    from gateway.fleet.runs import estimator_version

    rank = build_report(store, estimator_version(cfg), out, level=level)
    print(f"report -> {Path(out) / 'report.html'} (+ ranking.csv, trends.csv, runs.csv, "
          f"alerts.csv, PNGs)")
    return rank


def run_report(args: argparse.Namespace) -> int:
    rank = _report(_store(args.store), _config(args), args.out, args.level)
    _print_ranking(rank, None)
    return 0


def _print_ranking(rank: list[dict[str, object]], truth: dict[str, Any] | None) -> None:
    print(f"{'#':>2} {'unit':8} {'param':5} {'status':12} {'now':>6} {'crossing':16} "
          f"{'interval':35}" + (" truth" if truth else ""))
    for r in rank:
        unit = f"{r['vehicle']}/{r['bogie']}"
        line = (f"{r['rank']:>2} {unit:8} {r['parameter']!s:5} {r['status']!s:12} "
                f"{r['current_rel']:>6} {r['crossing']!s:16} "
                f"{str(r['crossing_lo']) + ' .. ' + str(r['crossing_hi']):35}")
        if truth is not None:
            u = truth["units"].get(unit, {})
            line += f" {u.get('role', '?')}"
        print(line)


def run_demo(args: argparse.Namespace) -> int:
    """Simulate with the installed simulator in a subprocess (the product never imports
    it), then ingest and replay on one embedded LocalCluster, and report."""
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    sim = out / "sim"
    cmd = [sys.executable, "-m", "firmware_sim", "fleet", "--out", str(sim),
           "--vehicles", str(args.vehicles), "--days", str(args.days),
           "--runs-per-day", str(args.runs_per_day), "--run-seconds", str(args.run_seconds),
           "--degrade-days", str(args.degrade_days)]
    if not (sim / "truth.json").is_file():
        print("== simulate:", " ".join(cmd[1:]), flush=True)
        if subprocess.run(cmd, check=False).returncode != 0:
            raise InputError(f"expected the fleet simulator to succeed, got a failure of "
                             f"{' '.join(cmd[1:])}")
    cfg = _config(args)
    store = _store(str(out / "store"), must_exist=False)
    with _client(args) as client:
        print("== ingest (Dask)", flush=True)
        _print_ingest(store.ingest([sim / "logs"], cfg, client=client), str(out / "store"))
        print("== replay (Dask)", flush=True)
        _replay(store, cfg, args, client)
    print("== report", flush=True)
    rank = _report(store, cfg, str(out / "report"), "advisory")
    truth = json.loads((sim / "truth.json").read_text(encoding="utf-8"))
    _print_ranking(rank, truth)
    return 0
