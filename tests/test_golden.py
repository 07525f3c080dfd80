"""Golden outputs: a replay and an ``estimate`` report reproduced byte for byte.

Recorded before the package layout changed (issue 13) so that a move of code cannot
change behaviour unnoticed. Fixtures in ``tests/golden/``:

- ``replay.jsonl``: ``gateway replay --particles 64`` of the simulator's ``paper``
  scenario, 2 s, seed 11 (the log is made at test time: the simulator is deterministic,
  and ``replay_log.sha256`` pins its bytes, so a changed simulator is told apart from a
  changed gateway);
- ``replay_report.json``: that replay's report, the volatile fields masked;
- ``estimate.csv`` (1 s, 3 sensors, fixed) and ``estimate_report.json``: ``gateway
  estimate --particles 64 --seed 1`` on it, the volatile fields masked.

Volatile (machine- or path-dependent) fields are replaced by ``"<masked>"``:
:data:`MASKED`. Everything else, floats included, must match byte for byte.

The floats depend on the CPU in three places (OpenBLAS's kernels, numba's target,
numpy's dispatched loops), each pinned to AVX2 for these runs whatever the caller's
environment: ``tests/floatpin.py``, which ``tests/run.sh`` exports for the whole suite
(so these runs use the pre-compiled kernels). Before 2026-12-01 only OpenBLAS was
pinned, and fixtures recorded on hosts with AVX-512 failed on an AMD EPYC host without
it, every float moved by about 1e-10 (relative), the Monte Carlo path otherwise the same.
A deliberate behaviour change regenerates the fixtures:
``RAILGW_GOLDEN_UPDATE=1 pytest tests/test_golden.py`` (and says why in the commit).
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any

import pytest
from floatpin import reproducible_floats

GOLDEN = Path(__file__).resolve().parent / "golden"
UPDATE = os.environ.get("RAILGW_GOLDEN_UPDATE") == "1"
PARTICLES = "64"
MASKED = {("settings", "file"), ("diagnostics", "wall_s"),
          ("diagnostics", "real_time_factor"), ("settings", "source"),
          ("diagnostics", "wall_time_s")}


def _masked(doc: dict[str, Any]) -> bytes:
    for section, key in MASKED:
        if key in doc.get(section, {}):
            doc[section][key] = "<masked>"
    return (json.dumps(doc, sort_keys=True, indent=1) + "\n").encode()


def _check(name: str, got: bytes) -> None:
    path = GOLDEN / name
    if UPDATE:
        path.write_bytes(got)
    assert got == path.read_bytes(), f"{name} differs from the golden file"


@pytest.fixture(scope="module")
def sim_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from firmware_sim.output import write_log
    from firmware_sim.scenarios import get_scenario
    from firmware_sim.simulation import SimConfig, Simulation

    sim = Simulation(get_scenario("paper"), SimConfig(duration_s=2.0, seed=11))
    path = tmp_path_factory.mktemp("golden") / "paper.log"
    write_log(list(sim.messages()), path)
    digest = hashlib.sha256(path.read_bytes()).hexdigest() + "\n"
    _check("replay_log.sha256", digest.encode())
    return path


def test_replay_is_golden(cli, sim_log: Path, tmp_path: Path) -> None:
    proc = cli("gateway", "replay", str(sim_log), "--report", str(tmp_path / "r.json"),
               "--jsonl", str(tmp_path / "r.jsonl"), "--particles", PARTICLES,
               "--no-progress", timeout=600, env=reproducible_floats())
    assert proc.returncode == 0, proc.stderr[-3000:]
    lines = (tmp_path / "r.jsonl").read_bytes()
    assert lines.count(b"\n") >= 5
    _check("replay.jsonl", lines)
    _check("replay_report.json", _masked(json.loads((tmp_path / "r.json").read_text())))


def test_estimate_is_golden(cli, tmp_path: Path) -> None:
    proc = cli("gateway", "estimate", str(GOLDEN / "estimate.csv"), "--report",
               str(tmp_path / "e.json"), "--particles", PARTICLES, "--seed", "1",
               "--sensors", "3", "--history-every-s", "0.05", timeout=600,
               env=reproducible_floats())
    assert proc.returncode == 0, proc.stderr[-3000:]
    _check("estimate_report.json", _masked(json.loads((tmp_path / "e.json").read_text())))
