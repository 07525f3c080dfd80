"""A replayed simulated fleet against its truth (``-m firmware_sim.studies.fleet_truth DIR``).

``DEMO_DIR`` is what ``railgw fleet demo --out DEMO_DIR`` made (``sim/truth.csv``, the
store in ``store/``). For every run with a result under the configuration's estimator
version: the final estimate's error against the run's true θ (``truth.csv``, matched by
log file name) and its z. Prints per parameter the median and mean ± s.e. of the error,
the median z and the share of runs with the truth within ±2σ, and the runs with a
parameter more than 25 % off (start-up lock-ins). The figures of docs/fleet.md. A
measuring tool; the product never imports it.
"""

from __future__ import annotations

import argparse
import csv
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from gateway.config import Config, load_config, with_overrides
from gateway.model.vehicle import PARAM_NAMES

FAR_OFF_REL = 0.25


def errors(demo: Path, version: str) -> tuple[np.ndarray, np.ndarray]:
    """Relative error and z of every run's final estimate under estimator ``version``:
    (n, 3) each. Needs the ``fleet`` extra (imported here, so that the plain install
    imports this module)."""
    import pyarrow.parquet as pq

    from gateway.fleet.replay import result_path
    from gateway.fleet.store import Store

    with open(demo / "sim" / "truth.csv", newline="") as f:
        truth = {Path(r["file"]).name: r for r in csv.DictReader(f)}
    store = Store(demo / "store")
    rel, z = [], []
    for info in store.runs():
        path = result_path(store.root.resolve(), version, info)
        if not path.is_file():
            continue
        table = pq.read_table(path)
        if table.num_rows == 0:
            continue
        row = truth[Path(info.source).name]
        mean = np.array([table.column(f"{p}_mean").to_numpy()[-1] for p in PARAM_NAMES])
        std = np.array([table.column(f"{p}_std").to_numpy()[-1] for p in PARAM_NAMES])
        true = np.array([float(row[p]) for p in PARAM_NAMES])
        rel.append(mean / true - 1)
        z.append((mean - true) / std)
    return np.array(rel).reshape(-1, len(PARAM_NAMES)), np.array(z).reshape(-1, len(PARAM_NAMES))


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m firmware_sim.studies.fleet_truth",
                                description=__doc__.splitlines()[0])
    p.add_argument("demo", type=Path, help="the directory of railgw fleet demo --out")
    p.add_argument("--config", help="TOML configuration the demo used (default: built-in)")
    p.add_argument("--particles", type=int, help="the demo's --particles, if given")
    p.add_argument("--estimator", metavar="VERSION",
                   help="the results of this estimator version (default: the configuration's)")
    args = p.parse_args(argv)
    from gateway.fleet.runs import estimator_version

    cfg = load_config(args.config) if args.config else Config()
    if args.particles:
        cfg = with_overrides(cfg, {"estimator.particles": args.particles})
    version = args.estimator or estimator_version(cfg)
    rel, z = errors(args.demo, version)
    if len(rel) < 2:
        found = sorted(d.name.removeprefix("estimator=")
                       for d in (args.demo / "store" / "results").glob("estimator=*"))
        print(f"expected results of estimator {version} in {args.demo / 'store'}, got "
              f"{len(rel)} (versions there: {found}; --estimator picks one)", file=sys.stderr)
        return 2
    print(f"runs {len(rel)} (estimator {version})")
    for j, name in enumerate(PARAM_NAMES):
        r = 100 * rel[:, j]
        print(f"{name}: median {np.median(r):+.2f} %, mean {r.mean():+.2f} ± "
              f"{r.std(ddof=1) / np.sqrt(len(r)):.2f} %, median z {np.median(z[:, j]):+.2f}, "
              f"truth within 2σ {100 * np.mean(np.abs(z[:, j]) < 2):.0f} %")
    far = int((np.abs(rel) > FAR_OFF_REL).any(axis=1).sum())
    print(f"runs with a parameter more than {100 * FAR_OFF_REL:.0f} % off: {far}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
