"""Fleet replay on Dask distributed: one stored run per task, results written atomically per run.

The same code path for the embedded ``LocalCluster`` (sized to the machine, one
process per core, one thread each) and a real cluster (``--scheduler tcp://host:8786``).
A task reads its run's samples from the store, runs the gateway's estimator worker and
alert policy over them (:func:`gateway.fleet.runs.estimate_run`) and renames one
Parquet file into ``results/estimator=<version>/...``, keyed by run id and estimator
version. So:

- resume: runs whose result file exists are not submitted again, and a task that finds
  its result already there returns at once;
- a worker lost mid-task: the scheduler reschedules the task on another worker
  (``distributed.scheduler.allowed-failures``); ``retries`` re-runs a task that raised.
  Its result is written once, whole, under one name: never lost, never doubled.

Each task spawns the gateway's estimator worker process (the service's own worker), so
Dask workers must not be daemonic: the LocalCluster is started with
``distributed.worker.daemon = False``; on a real cluster start workers with
``DASK_DISTRIBUTED__WORKER__DAEMON=False`` (``docs/fleet.md``).
"""

from __future__ import annotations

import contextlib
import json
import logging
import multiprocessing
import os
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pyarrow as pa

from gateway.config import Config
from gateway.errors import InputError
from gateway.fleet.runs import PARAMS, estimate_run, estimator_version, frontend_version
from gateway.fleet.store import RunInfo, Store, write_atomic_table

log = logging.getLogger(__name__)

TASK_RETRIES = 2
"""Re-runs of a task that raised (a lost worker is rescheduled by the scheduler anyway)."""


def result_path(root: Path, version: str, info: RunInfo) -> Path:
    """Where a run's result lives, for one estimator version."""
    return (root / "results" / f"estimator={version}" / f"vehicle={info.vehicle}"
            / f"bogie={info.bogie}" / f"day={info.day}" / f"run-{info.run_id}.parquet")


@dataclass(frozen=True)
class TaskResult:
    """What a task hands back to the client (the result itself is on disk)."""

    run_id: str
    estimates: int
    alerts: int
    wall_s: float
    reused: bool
    """The result file was already there (a retried or resubmitted task): nothing redone."""


def replay_task(store_root: str, info: RunInfo, cfg: Config, version: str,
                attempts_dir: str | None = None) -> TaskResult:
    """One run: estimate, then write its result atomically. Runs on a Dask worker."""
    wall0 = time.monotonic()
    if attempts_dir is not None:          # an audit trail of executions (tests count them)
        Path(attempts_dir, f"{info.run_id}.{os.getpid()}.{time.time_ns()}").write_text(
            str(os.getpid()))
    out = result_path(Path(store_root), version, info)
    if out.exists():
        return TaskResult(info.run_id, 0, 0, 0.0, True)
    if multiprocessing.current_process().daemon:
        raise InputError("expected Dask workers that may start processes, got a daemonic "
                         "worker: start them with DASK_DISTRIBUTED__WORKER__DAEMON=False")
    est = estimate_run(Store(store_root).samples(info), cfg)
    cols: dict[str, Any] = {"t_s": est.t_s, "ess": est.ess}
    for j, name in enumerate(PARAMS):
        cols[f"{name}_mean"] = est.mean[:, j]
        cols[f"{name}_std"] = est.std[:, j]
        cols[f"{name}_unresolved"] = est.unresolved[:, j]
    meta = {"railgw.run_id": info.run_id, "railgw.estimator": version,
            "railgw.alerts": json.dumps(list(est.alerts), sort_keys=True),
            "railgw.particles": str(cfg.estimator.particles)}
    write_atomic_table(pa.table(cols).replace_schema_metadata(meta), out)
    return TaskResult(info.run_id, len(est.t_s), len(est.alerts),
                      time.monotonic() - wall0, False)


@contextlib.contextmanager
def dask_client(scheduler: str | None = None, workers: int | None = None) -> Iterator[Any]:
    """A distributed Client: on ``scheduler`` (tcp://host:port), else on an embedded
    LocalCluster of ``workers`` processes (default: the machine's cores), 1 thread each."""
    import dask
    from distributed import Client, LocalCluster

    if scheduler:
        try:
            client = Client(scheduler, timeout="20s")
        except OSError as err:
            raise InputError(f"expected a Dask scheduler at {scheduler}, got {err}") from err
        with client:
            yield client
        return
    n = workers or os.cpu_count() or 1
    with dask.config.set({"distributed.worker.daemon": False}), \
            LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                         dashboard_address=None, silence_logs=logging.WARNING) as cluster, \
            Client(cluster) as client:
        yield client


@dataclass(frozen=True)
class ReplayReport:
    """One fleet replay: ``runs`` in the store with data, ``done_before`` found finished,
    ``ran`` computed now (``reused`` of them found their result already written);
    ``stale`` runs not replayed because another front end made their samples (ingest
    their logs again)."""

    version: str
    runs: int
    done_before: int
    ran: int
    reused: int
    wall_s: float
    workers: int
    stale: int = 0

    @property
    def runs_per_s(self) -> float:
        return self.ran / self.wall_s if self.wall_s > 0 else float("nan")


def replay_store(store: Store, cfg: Config, client: Any, *, attempts_dir: str | None = None,
                 progress: bool = True, retries: int = TASK_RETRIES) -> ReplayReport:
    """Replay every stored run without a result for this estimator version whose samples
    this configuration's front end made (the others are counted as ``stale``)."""
    from distributed import as_completed

    version = estimator_version(cfg)
    frontend = frontend_version(cfg)
    root = store.root.resolve()
    stored = [r for r in store.runs() if r.grid_points > 0]
    runs = [r for r in stored if r.frontend == frontend]
    todo = [r for r in runs if not result_path(root, version, r).exists()]
    # a direct call to the scheduler: Client.scheduler_info() returns a cached identity
    # that the client's periodic refresh can overwrite with an empty worker table
    workers = len(client.nthreads())
    wall0 = time.monotonic()
    futures = [client.submit(replay_task, str(root), r, cfg, version, attempts_dir,
                             key=f"railgw-replay-{version}-{r.run_id}", retries=retries,
                             pure=False) for r in todo]
    bar = None
    if progress and futures:
        from tqdm import tqdm

        bar = tqdm(total=len(futures), unit=" runs", file=sys.stderr, mininterval=0.5)
    reused = 0
    try:
        for fut in as_completed(futures):
            res: TaskResult = fut.result()
            reused += res.reused
            if bar is not None:
                bar.update(1)
    except BaseException:
        client.cancel(futures)
        raise
    finally:
        if bar is not None:
            bar.close()
    return ReplayReport(version, len(runs), len(runs) - len(todo), len(todo), reused,
                        time.monotonic() - wall0, workers, len(stored) - len(runs))
