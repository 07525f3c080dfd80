"""The RBPF against simulator truth, plus checkpoints, unstable particles and bad input."""

from __future__ import annotations

import numpy as np
import pytest

from firmware_sim.studies.accuracy import FS_HZ, V_MPS, make_data, run_filter
from gateway.errors import EstimatorError
from gateway.estimator import checkpoint as ckpt
from gateway.estimator.rbpf import RBPF, RBPFConfig
from gateway.model.vehicle import THETA_NOMINAL, THETA_SEC42
from gateway.records import Estimate, Sample


def samples(Y: np.ndarray, start: int = 0) -> list[Sample]:
    return [Sample(t_s=(start + k + 1) / FS_HZ, values=Y[k], speed_mps=V_MPS)
            for k in range(len(Y))]


@pytest.fixture(scope="module")
def data3() -> np.ndarray:
    return make_data(np.repeat(THETA_SEC42.as_array()[None], 5000, 0), 3, seed=0)


@pytest.mark.slow
def test_paper_scenario_five_sensors() -> None:
    """Sec. 4.2, 5 sensors: within 5 % and sigma/theta < 2 % after 3 s (seed 0).

    With the paper's floor: 0.1 % of its nominal values, which were the values that
    generated the data (``floor_reference="value"``). With the floor taken from the
    Appendix nominal instead (the default), sigma(Csy)/Csy sits at 1.7-2.04 % (docs).
    """
    Y = make_data(np.repeat(THETA_SEC42.as_array()[None], 5000, 0), 5, seed=0)
    est, _, _ = run_filter(Y, RBPFConfig(fs_hz=FS_HZ, sensors=5, seed=0,
                                         floor_reference="value"))
    truth = THETA_SEC42.as_array()
    for e in est:
        if e.t_s >= 3.0:
            m, s = np.array(e.mean), np.array(e.std)
            assert np.all(s / m < 0.02), (e.t_s, s / m)
    final = np.array(est[-1].mean)
    assert np.all(np.abs(final - truth) <= 0.05 * truth), final


@pytest.mark.slow
def test_paper_scenario_three_sensors(data3: np.ndarray) -> None:
    """Sec. 4.2, 3 sensors: within 10 % at 5 s (seed 0)."""
    est, filt, _ = run_filter(data3, RBPFConfig(fs_hz=FS_HZ, sensors=3, seed=0))
    truth = THETA_SEC42.as_array()
    final = np.array(est[-1].mean)
    assert np.all(np.abs(final - truth) <= 0.10 * truth), final
    assert filt.n_detections == 0
    assert est[-1].v_sy_mps == est[-1].v_sy_mps and est[-1].v_say_mps == est[-1].v_say_mps


@pytest.mark.slow
def test_three_sensor_start_up_does_not_lock_in() -> None:
    """The data on which the cloud used to lock onto a wrong Csy in the first 0.3 s.

    3 sensors, 1000 particles, the noise realisation of ``accuracy paper --seconds 20``
    seed 2, filter seeds 0-4. With resampling at ESS < 0.5 m, filter seed 2 ended at
    Csy +50 % at 5 s (4 of filter seeds 0-9 beyond 10 %), while the exact posterior (a
    24^3 grid of exact Kalman filters) was at -5 % +- 1.5 % from 3 s on. Fewer
    resample-moves in the fast start-up contraction (ESS < 0.2 m) keep the cloud on the
    posterior (docs/estimator.md, "Start-up lock-in").
    """
    truth = THETA_SEC42.as_array()
    Y = make_data(np.repeat(truth[None], 20000, 0), 3, seed=2)[:5000]
    for filter_seed in range(5):
        est, _, _ = run_filter(Y, RBPFConfig(fs_hz=FS_HZ, sensors=3, seed=filter_seed),
                               every=5000)
        err = np.array(est[-1].mean) / truth - 1.0
        assert np.all(np.abs(err) < 0.10), (filter_seed, err)


def test_checkpoint_restore_is_bit_exact(data3: np.ndarray) -> None:
    """A restored filter produces byte-identical estimates, incl. through resampling."""
    cfg = RBPFConfig(fs_hz=FS_HZ, n_particles=64, sensors=3, seed=5)
    a = RBPF(cfg)
    for s in samples(data3[:300]):
        a.step(s)
    blob = a.checkpoint()
    b = RBPF.restore(blob)
    rest = samples(data3[300:700], start=300)
    ea = [a.step(s) for s in rest]
    eb = [b.step(s) for s in rest]
    assert a.n_resamples > 0
    assert ea == eb
    assert a.checkpoint() == b.checkpoint()


def test_a_checkpoint_keeps_its_own_move_setting(data3: np.ndarray) -> None:
    """The static-yaw step of the moves (``moves_drop_null``) is on by default. A filter
    restored from a checkpoint keeps the setting it ran with, and a checkpoint written
    before the option existed (no such key) moved whole states, so it continues so: its
    estimates equal those of a filter that ran with the option off all along."""
    assert RBPFConfig(fs_hz=FS_HZ).moves_drop_null
    off = RBPFConfig(fs_hz=FS_HZ, n_particles=64, sensors=3, seed=5, moves_drop_null=False)
    a = RBPF(off)
    for s in samples(data3[:300]):
        a.step(s)
    meta, arrays = ckpt.unpack(a.checkpoint())
    assert meta["config"].pop("moves_drop_null") is False
    old = RBPF.restore(ckpt.pack(meta, arrays))
    assert not old.config.moves_drop_null
    rest = samples(data3[300:700], start=300)
    assert a.n_resamples > 0
    assert [a.step(s) for s in rest] == [old.step(s) for s in rest]
    assert RBPF.restore(RBPF(RBPFConfig(fs_hz=FS_HZ, n_particles=64)).checkpoint()
                        ).config.moves_drop_null


def test_same_seed_same_result(data3: np.ndarray) -> None:
    cfg = RBPFConfig(fs_hz=FS_HZ, n_particles=32, sensors=3, seed=11)
    runs = [RBPF(cfg).run(samples(data3[:200]), output_every=50) for _ in range(2)]
    assert runs[0] == runs[1]


def test_corrupt_checkpoint_is_an_estimator_error() -> None:
    with pytest.raises(EstimatorError, match="expected"):
        RBPF.restore(b"not a checkpoint")


def test_unstable_particles_give_no_nan(data3: np.ndarray) -> None:
    """All particles in unstable corners: finite output, dead ones re-seeded, no warnings."""
    cfg = RBPFConfig(fs_hz=FS_HZ, n_particles=16, sensors=3, seed=1)
    f = RBPF(cfg)
    theta = np.array([[6e3, 3e6, 0.045]] * 8 + [[2e3, 2e5, 0.0075]] * 8)
    f.set_particles(theta)
    with np.errstate(over="raise", invalid="raise"):
        for s in samples(data3[:3000]):
            e = f.step(s)
            assert all(np.isfinite(e.mean)) and all(np.isfinite(e.std))
    assert np.all(np.isfinite(f._P)) and np.all(np.isfinite(f._X))


def test_huge_input_kills_particles_then_reseeds(data3: np.ndarray) -> None:
    """Absurd measurements: every particle fails; the filter re-seeds from the prior."""
    f = RBPF(RBPFConfig(fs_hz=FS_HZ, n_particles=16, sensors=3, seed=2))
    f.step(Sample(t_s=0.0, values=np.array([1e300, 1e300, 1e300]), speed_mps=V_MPS))
    e = f.step(Sample(t_s=0.001, values=data3[0], speed_mps=V_MPS))
    assert f.n_reseeds >= 1 and all(np.isfinite(e.mean))


def test_bad_input(data3: np.ndarray) -> None:
    f = RBPF(RBPFConfig(fs_hz=FS_HZ, n_particles=16, sensors=3, seed=2))
    with pytest.raises(EstimatorError, match="expected 3 sensor values.*got 5"):
        f.step(Sample(t_s=0.0, values=np.zeros(5), speed_mps=V_MPS))
    with pytest.raises(EstimatorError, match="expected a positive finite speed"):
        f.step(Sample(t_s=0.0, values=data3[0], speed_mps=float("nan")))
    # NaN values: update with the others; all NaN or update=False: predict only
    e1 = f.step(Sample(t_s=0.0, values=np.array([np.nan, data3[0, 1], np.nan]),
                       speed_mps=V_MPS))
    assert e1.updated
    before = f.logw.copy()
    e2 = f.step(Sample(t_s=0.001, values=np.full(3, np.nan), speed_mps=V_MPS))
    e3 = f.step(Sample(t_s=0.002, values=data3[1], speed_mps=V_MPS, update=False))
    assert not e2.updated and not e3.updated
    assert np.array_equal(f.logw, before)          # no likelihood from a skipped sample


def test_speed_change_recomputes_model(data3: np.ndarray) -> None:
    f = RBPF(RBPFConfig(fs_hz=FS_HZ, n_particles=16, sensors=3, seed=3))
    f.step(Sample(t_s=0.0, values=data3[0], speed_mps=42.5))
    f.step(Sample(t_s=0.001, values=data3[1], speed_mps=42.5 * 1.001))   # within tolerance
    assert f._v_ref == 42.5
    f.step(Sample(t_s=0.002, values=data3[2], speed_mps=40.0))
    assert f._v_ref == 40.0


def test_estimate_ar_gives_four_parameters(data3: np.ndarray) -> None:
    f = RBPF(RBPFConfig(fs_hz=FS_HZ, n_particles=16, sensors=3, seed=4, estimate_ar=True))
    e: Estimate = f.run(samples(data3[:50]))[-1]
    assert e.names[-1] == "ar_paper" and len(e.mean) == 4


@pytest.mark.slow
def test_step_in_csy_is_tracked() -> None:
    """Csy 40 -> 10 kNs/m at 8 s: within 15 % of 10 kNs/m within 10 s, 3 sensors.

    The fault bank (:mod:`gateway.estimator.faultbank`) watches from 3 s on and finds it
    on Csy; the innovation monitor stays as the fallback.
    """
    fault_s, n = 8.0, 18000
    th = np.repeat(THETA_NOMINAL.as_array()[None], n, 0)
    th[int(fault_s * FS_HZ):, 0] = 10e3
    Y = make_data(th, 3, seed=0)
    est, filt, _ = run_filter(Y, RBPFConfig(fs_hz=FS_HZ, sensors=3, seed=0))
    last = filt.last_fault()
    assert filt.n_fault_detections >= 1 and last is not None and last[1] == "csy_ns_per_m"
    late = [e for e in est if e.t_s >= fault_s + 10.0 - 1e-9]
    assert late and abs(late[0].mean[0] - 10e3) <= 0.15 * 10e3, late[0].mean


def test_move_survives_a_degenerate_cloud() -> None:
    """Two distinct particles in 3-D (rank-1 covariance): the move still works."""
    from gateway.estimator.particles import liu_west_move

    z = np.log(np.array([[2e4, 3e6, 0.15]] * 5 + [[3e4, 4e6, 0.2]] * 5))
    w = np.full(10, 0.1)
    out = liu_west_move(np.random.default_rng(0), z, w, np.arange(10), delta=0.99,
                        steps=50, floor_log=np.full(3, 1e-9))
    assert out.shape == z.shape and np.all(np.isfinite(out))
