"""An improved front end re-processes the fleet store, as an improved estimator does.

Stored samples are the front end's output, so they carry the front end that made them
(``RunInfo.frontend``: gateway version, resampler and gating settings, the code of
``gateway/can`` and ``gateway/frontend``). Ingesting a log again with another front end
makes its samples again (the manifest's last line wins, nothing counted twice); replay
uses only runs whose samples the configuration's front end made, and names the others
as stale; the estimator version includes the front end, so results never mix.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("distributed")
pytest.importorskip("pyarrow")

from firmware_sim.fleet import FleetSpec, simulate_fleet  # noqa: E402
from gateway.config import Config, with_overrides  # noqa: E402
from gateway.fleet.replay import dask_client, replay_store  # noqa: E402
from gateway.fleet.runs import estimator_version, frontend_version  # noqa: E402
from gateway.fleet.store import Store  # noqa: E402

pytestmark = pytest.mark.slow

SPEC = FleetSpec(vehicles=1, days=2, runs_per_day=1, run_s=4.0, seed=5)
SINC = with_overrides(Config(), {"estimator.particles": 64})
LINEAR = with_overrides(SINC, {"resampler.interpolation": "linear",
                              "estimator.sensor_noise": "model"})


def test_a_new_front_end_makes_the_samples_again_and_replay_waits_for_it(
        tmp_path: Path) -> None:
    simulate_fleet(SPEC, tmp_path / "sim")
    logs = tmp_path / "sim" / "logs"
    store = Store(tmp_path / "store")
    first = store.ingest([logs], LINEAR)
    assert len(first.added) == 2 and first.replaced == ()
    ids = sorted(r.run_id for r in first.added)
    old = {r.run_id: store.samples(r) for r in store.runs()}
    again = store.ingest([logs], LINEAR)
    assert again.added == () and len(again.skipped) == 2

    assert frontend_version(SINC) != frontend_version(LINEAR)
    assert estimator_version(SINC) != estimator_version(LINEAR)
    new = store.ingest([logs], SINC)
    assert sorted(new.replaced) == ids and len(new.added) == 2
    runs = store.runs()
    assert sorted(r.run_id for r in runs) == ids                   # each run once
    assert {r.frontend for r in runs} == {frontend_version(SINC)}
    assert len(list((tmp_path / "store" / "samples").rglob("*.parquet"))) == 2
    for r in runs:
        a, b = old[r.run_id], store.samples(r)
        np.testing.assert_array_equal(a.t_s, b.t_s)               # the same grid ...
        assert not np.array_equal(a.values, b.values)              # ... new values

    with dask_client(workers=1) as client:
        stale = replay_store(store, LINEAR, client, progress=False)
        assert (stale.ran, stale.stale) == (0, 2)
        done = replay_store(store, SINC, client, progress=False)
        assert (done.ran, done.stale) == (2, 0)
