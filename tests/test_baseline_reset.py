"""Baseline reset after a damper replacement: the estimate re-converges faster with it."""

from __future__ import annotations

import numpy as np
import pytest

from firmware_sim.truth import add_sensor_noise, select, simulate
from gateway.estimator.rbpf import RBPF, RBPFConfig
from gateway.model.vehicle import SENSORS_3, THETA_NOMINAL
from gateway.records import Sample

FS = 1000.0


def _data(seed: int) -> np.ndarray:
    """15 s with a failed lateral damper (10 kNs/m), then 15 s with a new one (40 kNs/m)."""
    n = int(30 * FS)
    theta = np.tile(THETA_NOMINAL.as_array(), (n, 1))
    theta[: n // 2, 0] = 10e3
    rng = np.random.default_rng(seed)
    run = simulate(theta, np.full(n, 42.5), FS, rng)
    return add_sensor_noise(select(run.outputs, SENSORS_3), SENSORS_3, rng)


def _time_to_reconverge(y: np.ndarray, reset: bool) -> float:
    f = RBPF(RBPFConfig(fs_hz=FS, n_particles=300, seed=1))
    n = len(y)
    inside_since = None
    for k in range(n):
        if reset and k == n // 2:
            f.reset_parameter(0)                  # the fitter: "baseline reset csy"
        est = f.step(Sample(k / FS, y[k], 42.5, True))
        if k >= n // 2:
            ok = abs(est.mean[0] / 40e3 - 1) < 0.15
            inside_since = (inside_since if inside_since is not None else k) if ok else None
    assert inside_since is not None, "never re-converged"
    return (inside_since - n // 2) / FS


@pytest.mark.slow
def test_reset_reconverges_faster_than_without():
    y = _data(7)
    with_reset = _time_to_reconverge(y, reset=True)
    without = _time_to_reconverge(y, reset=False)
    assert with_reset < without, (with_reset, without)
    assert with_reset < 5.0


def test_reset_parameter_redraws_only_that_parameter():
    f = RBPF(RBPFConfig(fs_hz=FS, n_particles=64, seed=3))
    before = f.theta.copy()
    f.reset_parameter(1)
    after = f.theta
    np.testing.assert_array_equal(after[:, 0], before[:, 0])
    np.testing.assert_array_equal(after[:, 2], before[:, 2])
    assert not np.array_equal(after[:, 1], before[:, 1])
    lo, hi = (edge[1] for edge in f.config.box(f.config.prior_lo, f.config.prior_hi))
    assert np.all((after[:, 1] >= lo * 0.999) & (after[:, 1] <= hi * 1.001))
    with pytest.raises(Exception, match="expected a parameter index"):
        f.reset_parameter(7)


class _RecordingLink:
    """What the pipeline hands its worker link, in order (the link's own ordering is
    tested on a real worker in tests/test_worker_messages.py)."""

    def __init__(self, *args: object, **kwargs: object) -> None:
        self.sent: list[tuple[str, int]] = []

    def send(self, block: list[Sample]) -> None:
        self.sent.append(("samples", len(block)))

    def baseline_reset(self, index: int) -> None:
        self.sent.append(("reset", index))


def test_a_reset_applies_after_every_sample_the_pipeline_has_made(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The pipeline hands samples on in blocks of 20; a console reset at data time t
    re-learns from the samples after t, so the partly filled block goes first (until
    2026-11-29's thirteenth session it reached the worker after the reset)."""
    from firmware_sim.scenarios import get_scenario
    from firmware_sim.simulation import SimConfig, Simulation
    from gateway.alerts.policy import AlertPolicy
    from gateway.can.codec import default_codec
    from gateway.config import Config
    from gateway.runtime import pipeline as pipeline_module
    from gateway.runtime.worker import BLOCK_SAMPLES

    monkeypatch.setattr(pipeline_module, "WorkerLink", _RecordingLink)
    pipe = pipeline_module.Pipeline(Config(), default_codec(), policy=AlertPolicy())
    link = pipe.worker
    assert isinstance(link, _RecordingLink)
    for msg in Simulation(get_scenario("nominal"), SimConfig(duration_s=1.0, seed=3)).messages():
        pipe.on_frame(msg)
        if pipe.samples_out > 3 * BLOCK_SAMPLES and pipe.samples_out % BLOCK_SAMPLES:
            break
    made = pipe.samples_out
    assert made % BLOCK_SAMPLES and sum(n for kind, n in link.sent if kind == "samples") < made
    pipe.baseline_reset(2)
    assert link.sent[-1] == ("reset", 2)
    assert sum(n for kind, n in link.sent if kind == "samples") == made
