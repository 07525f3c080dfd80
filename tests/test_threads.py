""":func:`gateway.estimator.threads.configure` in a fresh interpreter (numba's threading
layer is chosen once per process): OpenMP with passive waiting by default, workqueue
where numba has no OpenMP, and an explicit choice left alone. No timing assertions: the
layers' speed is measured by ``gateway bench`` (docs/estimator.md, "Speed")."""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys

import pytest

PROBE = """
import json, os, sys
import numpy as np
from gateway.estimator.threads import configure, threading_layer
configure(2)
from firmware_sim.studies.sweep import bench_data, filter_config
from gateway.estimator.rbpf import RBPF
data = bench_data(0.01, 0)
filt = RBPF(filter_config("exact", 128, 0, 6.6e-4))   # 16 chunks: a parallel launch
est = filt.run(data.samples, output_every=5)[-1]
print(json.dumps({"layer": threading_layer(), "wait": os.environ.get("OMP_WAIT_POLICY"),
                  "finite": bool(np.isfinite(np.asarray(est.mean)).all())}))
"""
HAS_OMP = importlib.util.find_spec("numba.np.ufunc.omppool") is not None


def probe(**env: str) -> dict[str, object]:
    """Run :data:`PROBE` in a fresh interpreter with ``env`` added (and numba's and
    OpenMP's own variables removed first)."""
    base = {k: v for k, v in os.environ.items()
            if not k.startswith(("NUMBA_THREADING_LAYER", "OMP_"))}
    out = subprocess.run([sys.executable, "-c", PROBE], env={**base, **env},
                         capture_output=True, text=True, timeout=600, check=True)
    result: dict[str, object] = json.loads(out.stdout.strip().splitlines()[-1])
    return result


def test_default_is_openmp_with_passive_waiting():
    got = probe()
    assert got["finite"] is True
    if HAS_OMP:
        assert got == {"layer": "omp", "wait": "PASSIVE", "finite": True}
    else:
        assert got["layer"] == "workqueue"


@pytest.mark.skipif(not HAS_OMP, reason="numba has no OpenMP layer here")
def test_an_explicit_wait_policy_is_kept():
    assert probe(OMP_WAIT_POLICY="ACTIVE")["wait"] == "ACTIVE"


def test_an_explicit_layer_is_kept():
    got = probe(NUMBA_THREADING_LAYER="workqueue")
    assert got["layer"] == "workqueue" and got["wait"] is None
