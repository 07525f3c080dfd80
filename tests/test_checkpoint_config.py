"""A checkpoint resumes only the estimator its configuration builds: the settings test.

A checkpoint carries its filter's settings and a restore keeps them, so without the test
a restart after an ``[estimator]`` change ran the old filter for good, and one with
another sensor set failed on every sample (the service stopped, and systemd started it
on the same checkpoint again). The live service's side is in tests/test_service.py.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from gateway.config import EstimatorConfig
from gateway.estimator import checkpoint as ckpt
from gateway.records import Sample
from gateway.runtime.pipeline import build_estimator, checkpoint_mismatch, restore_estimator

FS_HZ = 1000.0


def _run(cfg: EstimatorConfig, seconds: float) -> bytes:
    """The checkpoint of ``cfg``'s estimator after ``seconds`` of white data."""
    est = build_estimator(cfg, FS_HZ)
    rng = np.random.default_rng(4)
    ny = cfg.sensors
    est.run([Sample(k / FS_HZ, rng.normal(0.0, 0.02, ny), 42.5, True)
             for k in range(int(seconds * FS_HZ))], output_every=1000)
    return est.checkpoint()


@pytest.fixture(scope="module")
def base() -> EstimatorConfig:
    return replace(EstimatorConfig(), particles=32)


@pytest.mark.parametrize("seconds", [0.2, 6.0], ids=["in its noise test", "after it"])
def test_the_same_configuration_resumes_its_checkpoint(base, seconds):
    blob = _run(base, seconds)
    assert checkpoint_mismatch(base, FS_HZ, blob) is None
    assert restore_estimator(blob).checkpoint() == blob


@pytest.mark.parametrize(("change", "said"), [
    ({"particles": 48}, "n_particles 32 -> 48"),
    ({"sensors": 5}, "sensors 3 -> 5"),
    ({"mode": "exact"}, "mode 'fast' -> 'exact'"),
    ({"kernel_delta": 0.995}, "delta 0.99 -> 0.995"),
    ({"drift_per_sqrt_s": 0.02}, "walk_rel_per_sqrt_s (0.01, 0.01, 0.01) -> (0.02, 0.02, 0.02)"),
])
def test_another_setting_names_what_differs(base, change, said):
    blob = _run(base, 0.2)
    why = checkpoint_mismatch(replace(base, **change), FS_HZ, blob)
    assert why is not None and why.startswith("made with other settings: ") and said in why
    assert "\n" not in why
    assert "fs_hz 1000.0 -> 2000.0" in (checkpoint_mismatch(base, 2 * FS_HZ, blob) or "")


def test_a_nested_setting_is_named_field_by_field(base):
    """A default of the fault bank changed (as by an upgrade): the line names that field,
    not two whole configurations."""
    blob = _run(replace(base, sensor_noise="model"), 0.1)
    meta, arrays = ckpt.unpack(blob)
    meta["config"]["faults"]["replay_s"] = 0.5
    why = checkpoint_mismatch(replace(base, sensor_noise="model"), FS_HZ,
                              ckpt.pack(meta, arrays))
    assert why == "made with other settings: faults.replay_s 0.5 -> 2.0", why


def test_under_the_model_noise_a_filter_in_its_test_is_another_filter(base):
    model = replace(base, sensor_noise="model")
    assert "sensor_noise 'measured' (in its test) -> 'model'" in (
        checkpoint_mismatch(model, FS_HZ, _run(base, 0.2)) or "")
    assert checkpoint_mismatch(model, FS_HZ, _run(model, 0.2)) is None


def test_under_the_measured_noise_an_untested_filter_is_another_filter(base):
    """A filter made under "model" never tested its variances: after a switch to
    "measured" the service starts fresh (and tests them) instead of going on untested."""
    model = replace(base, sensor_noise="model")
    untested = _run(model, 0.2)
    why = checkpoint_mismatch(base, FS_HZ, untested)
    assert why == "made with other settings: sensor_noise 'model' -> 'measured' " \
                  "(its variances never tested)", why
    tested = _run(base, 6.0)
    assert checkpoint_mismatch(base, FS_HZ, tested) is None
    # a checkpoint from before the filters said whether they were tested resumes, as
    # it did before
    meta, arrays = ckpt.unpack(untested)
    del meta["config"]["noise_tested"]
    assert checkpoint_mismatch(base, FS_HZ, ckpt.pack(meta, arrays)) is None


@pytest.mark.parametrize("blob", [b"", b"RBPF-CKPT-1\n\x05\x00", b"not a checkpoint"])
def test_an_unreadable_checkpoint_says_so(base, blob):
    why = checkpoint_mismatch(base, FS_HZ, blob)
    assert why is not None and why.startswith("unreadable: expected ")


@pytest.mark.parametrize("config", [{"faults": [1, 2]}, {"nominal": 3}, {"sensors": None}],
                         ids=["faults a list", "nominal a number", "sensors null"])
def test_a_readable_checkpoint_with_a_malformed_configuration_says_so(base, config):
    meta, arrays = ckpt.unpack(_run(replace(base, sensor_noise="model"), 0.1))
    meta["config"].update(config)
    why = checkpoint_mismatch(base, FS_HZ, ckpt.pack(meta, arrays))
    assert why is not None and why.startswith("unreadable: expected "), why
