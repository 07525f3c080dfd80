"""Fast mode (steady-state gains, gateway/estimator/steady.py) against the exact filter.

* once P has converged, the steady-gain step is the exact step: states and per-sample
  log-likelihoods agree to rounding (issue 14's acceptance);
* the gains are the fixed point of the DARE, checked against scipy's independent solver;
* a sample without every sensor (the exact recursion takes over), a checkpoint and
  restore, the mode switch in the configuration, and the recovered parameters against
  the truth that made the data.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import scipy.linalg

from firmware_sim.truth import add_sensor_noise, select, simulate
from gateway.config import EstimatorConfig
from gateway.errors import EstimatorError
from gateway.estimator import steady as st
from gateway.estimator.batch_expm import DiscreteBatch
from gateway.estimator.kalman import from_lanes, kf_step, n_chunks, to_lanes
from gateway.estimator.lanecode import LANES
from gateway.estimator.rbpf import RBPF, RBPFConfig, block_prefix
from gateway.model.coordinates import NZ, FilterCoords
from gateway.model.vehicle import (
    AR_PAPER_DEFAULT,
    THETA_SEC42,
    measurement_noise,
    sensor_set,
    track_intensity,
)
from gateway.records import Sample
from gateway.runtime.pipeline import estimator_config

V_MPS, FS_HZ = 42.5, 1000.0
NOMINAL = THETA_SEC42.as_array()


class Bank:
    """m particles at given theta: Phi, Qd, null vectors and steady gains, lane layout."""

    def __init__(self, theta: np.ndarray, n_sensors: int) -> None:
        self.coords = FilterCoords.build()
        self.theta = theta
        self.m = len(theta)
        self.sensors = sensor_set(n_sensors)
        self.H = self.coords.output(self.sensors, V_MPS)
        self.r = np.diag(measurement_noise(self.sensors)).copy()
        nch = n_chunks(self.m)
        self.phi = np.empty((nch, NZ * NZ * LANES))
        self.qd = np.empty_like(self.phi)
        q = track_intensity(AR_PAPER_DEFAULT, V_MPS) * np.ones(self.m)
        DiscreteBatch(self.coords, V_MPS, 1.0 / FS_HZ).compute(theta, q, self.phi, self.qd)
        self.v0 = st.NullVectors(self.coords.terms(V_MPS), NOMINAL)(theta)
        self.gains = st.SteadyGains.empty(nch, len(self.sensors))
        st.steady_gains(self.phi, self.qd, to_lanes(self.v0), self.H, self.r, self.gains)
        self.p_pred = from_lanes(self.gains.p_pred, self.m, (NZ, NZ))

    def posterior(self) -> np.ndarray:
        """The steady updated covariance P+ (m, 16, 16), for the exact kernel.

        Fast mode keeps no variance along the unobservable v0 (the doubling removes it;
        no gain or likelihood sees it), so P- is indefinite there. The exact filter's P
        would carry a growing variance along v0: the smallest one that makes P+ positive
        semi-definite (Schur complement) is put back, times 1.01.
        """
        P = self.p_pred.copy()
        for s in range(len(self.sensors)):
            ph = P @ self.H[s]
            S = ph @ self.H[s] + self.r[s]
            P = P - np.einsum("mi,mj->mij", ph, ph) / S[:, None, None]
        out = np.empty_like(P)
        for p in range(self.m):
            v = self.v0[p]
            U = np.linalg.svd(np.eye(NZ) - np.outer(v, v))[0][:, :NZ - 1]   # v0's complement
            Pu, c = U.T @ P[p] @ U, U.T @ P[p] @ v
            a = 1.01 * float(c @ np.linalg.solve(Pu, c)) + 1e-12
            basis = np.column_stack([v, U])
            inner = np.block([[np.array([[a]]), c[None, :]], [c[:, None], Pu]])
            out[p] = basis @ inner @ basis.T
        return out


def _theta_box(rng: np.random.Generator, m: int, lo: float = 0.5, hi: float = 2.0
               ) -> np.ndarray:
    return NOMINAL * np.exp(rng.uniform(np.log(lo), np.log(hi), (m, 3)))


def _outputs(n: int, n_sensors: int, seed: int, theta: np.ndarray = NOMINAL) -> np.ndarray:
    rng = np.random.default_rng(seed)
    truth = simulate(np.repeat(theta[None], n, 0), np.full(n, V_MPS), FS_HZ, rng)
    sensors = sensor_set(n_sensors)
    return add_sensor_noise(select(truth.outputs, sensors), sensors, rng)


@pytest.mark.parametrize("n_sensors", [3, 5])
def test_steady_step_is_the_exact_step_once_p_has_converged(n_sensors: int) -> None:
    """The exact kernel started at the steady P and the steady-gain kernel, on the same
    measured data for 1000 samples: states within 1e-9 (relative to their size, outside
    the unobservable v0 direction), each sample's log-likelihood within 1e-6 (issue 14).

    Measured: states 5e-12, log-likelihood 1.3e-10 / 6.9e-9 (3 / 5 sensors). Without the
    Newton step after the doubling, 1.1e-8 and 2.2e-6: the doubling's fixed-point
    residual (1e-10 per Riccati step) is integrated by the exact recursion along the slow
    mode."""
    rng = np.random.default_rng(7)
    bank = Bank(_theta_box(rng, 16), n_sensors)
    Y = _outputs(1000, n_sensors, seed=11)
    nch = n_chunks(bank.m)
    Pe = to_lanes(bank.posterior())
    Xe = np.zeros((nch, NZ * LANES))
    Xf = np.zeros_like(Xe)
    use = np.ones(n_sensors, dtype=bool)
    proj = np.eye(NZ)[None] - np.einsum("mi,mj->mij", bank.v0, bank.v0)
    worst_x = worst_ll = 0.0
    for k in range(len(Y)):
        lle, llf = np.zeros(nch * LANES), np.zeros(nch * LANES)
        nis, dead = np.zeros(nch * LANES), np.zeros(nch * LANES, dtype=bool)
        kf_step(Xe, Pe, bank.phi, bank.qd, bank.H, bank.r, Y[k], use, np.eye(NZ), lle, nis,
                dead)
        st.kf_steady(Xf, bank.phi, bank.H, Y[k], use, bank.gains, llf, nis, dead)
        assert not dead.any()
        xe, xf = from_lanes(Xe, bank.m, (NZ,)), from_lanes(Xf, bank.m, (NZ,))
        d = np.einsum("mij,mj->mi", proj, xe - xf)
        worst_x = max(worst_x, float((np.abs(d).max(1) / np.abs(xe).max(1)).max()))
        worst_ll = max(worst_ll, float(np.abs(lle - llf)[:bank.m].max()))
    assert worst_x < 1e-9, worst_x
    assert worst_ll < 1e-6, worst_ll


@pytest.mark.parametrize("n_sensors", [3, 5])
def test_gains_are_the_dare_solution_of_scipy(n_sensors: int) -> None:
    """Independent check: scipy's solve_discrete_are on the observable 15-state part
    (v0 split off) gives the same innovation covariance and the same gains there."""
    rng = np.random.default_rng(3)
    bank = Bank(_theta_box(rng, 8, 0.3, 2.5), n_sensors)
    F = from_lanes(bank.phi, bank.m, (NZ, NZ))
    Q = from_lanes(bank.qd, bank.m, (NZ, NZ))
    R = np.diag(bank.r)
    for p in range(bank.m):
        A = bank.coords.system(bank.theta[p], V_MPS)
        u, _, vt = np.linalg.svd(A)
        v0, w0 = vt[-1], u[:, -1]
        proj = np.eye(NZ) - np.outer(v0, w0) / (w0 @ v0)          # onto the invariant rest
        B = np.linalg.svd(proj)[0][:, :NZ - 1]
        Bp = np.linalg.pinv(B)
        phis, qs, hs = Bp @ proj @ F[p] @ B, Bp @ proj @ Q[p] @ proj.T @ Bp.T, bank.H @ B
        Ps = scipy.linalg.solve_discrete_are(phis.T, hs.T, 0.5 * (qs + qs.T), R)
        S_ref = hs @ Ps @ hs.T + R
        S_ours = bank.H @ bank.p_pred[p] @ bank.H.T + R
        assert np.abs(S_ours - S_ref).max() < 1e-8 * np.abs(S_ref).max(), (p, S_ours, S_ref)
        g_ref = proj @ B @ Ps @ hs.T
        g_ours = proj @ bank.p_pred[p] @ bank.H.T
        assert np.abs(g_ours - g_ref).max() < 1e-6 * np.abs(g_ref).max()


@pytest.mark.parametrize("n_sensors", [3, 5])
def test_a_warm_start_from_the_ancestors_gives_the_cold_solution(n_sensors: int) -> None:
    """A move's DARE solves start from the ancestor's P- (Newton steps, steady.py): the
    particles jittered by 0.2-5 % from their ancestors get the gains, innovation variances
    and log det of the cold solve (doubling and Newton) to 1e-9, within a few Newton
    steps. A start that is no solution at all (P- = 0, which no Newton step of the four
    repairs) falls back to the cold solve for those particles, which then equals it bit
    for bit."""
    rng = np.random.default_rng(12)
    anc = Bank(_theta_box(rng, 32), n_sensors)
    pick = rng.integers(0, anc.m, 64)
    jitter = np.exp(rng.normal(0.0, rng.choice([0.002, 0.01, 0.05], 64)[:, None], (64, 3)))
    moved = Bank(anc.theta[pick] * jitter, n_sensors)       # its gains: the cold solve
    warm = st.SteadyGains.empty(n_chunks(moved.m), len(moved.sensors))
    st.steady_gains(moved.phi, moved.qd, to_lanes(moved.v0), moved.H, moved.r, warm,
                    start=anc.gains.take(pick))
    it = warm.iters[:moved.m]
    assert (it < 0).all() and (-it <= st.NEWTON_MAX).all(), it     # all converged warm
    cold, m = moved.gains, moved.m
    for a, b in ((warm.g, cold.g), (warm.s, cold.s), (warm.p_pred, cold.p_pred)):
        a, b = from_lanes(a, m, (-1,)), from_lanes(b, m, (-1,))
        assert (np.abs(a - b).max(1) / np.abs(b).max(1)).max() < 1e-9
    assert np.abs(warm.c0[:m] - cold.c0[:m]).max() < 1e-9
    bad = anc.gains.take(pick)
    bad[: n_chunks(moved.m) // 2] = 0.0                      # half the particles: P- = 0
    far = st.SteadyGains.empty(n_chunks(moved.m), len(moved.sensors))
    st.steady_gains(moved.phi, moved.qd, to_lanes(moved.v0), moved.H, moved.r, far,
                    start=bad)
    fell = far.iters[:m] > 0
    assert fell.sum() >= m // 2 - LANES
    for a, b in ((far.g, cold.g), (far.s, cold.s), (far.p_pred, cold.p_pred)):
        a, b = from_lanes(a, m, (-1,)), from_lanes(b, m, (-1,))
        assert np.array_equal(a[fell], b[fell])
    assert np.array_equal(far.c0[:m][fell], cold.c0[:m][fell])


def test_every_particle_converges_over_the_prior_box() -> None:
    rng = np.random.default_rng(5)
    bank = Bank(_theta_box(rng, 256, 0.3, 3.5), 3)
    it = bank.gains.iters[:bank.m]
    assert (it > 0).all() and np.isfinite(bank.gains.c0[:bank.m]).all()
    assert np.median(it) <= 22                       # doubling: 2**20 samples and more


class ExactTwin:
    """The exact recursion of the particles at ``theta`` from the steady P+ and the states
    of a filter in its steady phase: where fast mode hands a sample without every sensor."""

    def __init__(self, filt: RBPF, theta: np.ndarray, n_sensors: int) -> None:
        self.bank = Bank(theta, n_sensors)
        self.X, self.P = filt._X.copy(), to_lanes(self.bank.posterior())

    def step(self, y: np.ndarray) -> np.ndarray:
        """One sample ``y`` (ny,), NaN where missing; each particle's log-likelihood (m,)."""
        b, width = self.bank, n_chunks(self.bank.m) * LANES
        use = np.isfinite(y)
        ll, nis, dead = np.zeros(width), np.zeros(width), np.zeros(width, dtype=bool)
        kf_step(self.X, self.P, b.phi, b.qd, b.H, b.r, np.where(use, y, 0.0), use,
                np.eye(NZ), ll, nis, dead)
        return ll[:b.m]


def _steady_at(theta: np.ndarray, S: list[Sample], n_sensors: int, warmup_s: float
               ) -> RBPF:
    """A fast filter of 16 particles at ``theta`` (no resampling, monitor or bank) after the
    first 2000 samples of ``S``, in its steady phase."""
    cfg = RBPFConfig(fs_hz=FS_HZ, n_particles=16, sensors=n_sensors, mode="fast",
                     resample=False, monitor=None, faults=None, fast_warmup_s=warmup_s,
                     seed=0)
    filt = RBPF(cfg)
    filt.set_particles(theta)
    for smp in S[:2000]:
        filt.advance(smp)
    assert filt._steady
    return filt


@pytest.mark.parametrize("n_sensors", [3, 5])
def test_a_sample_without_every_sensor_hands_over_to_the_exact_recursion(
        n_sensors: int) -> None:
    """In the steady phase, a hold (0.3 s without data: a curve, a dropout) and, 0.15 s
    after it, one sensor out for 20 ms: from the hold's first sample on, every particle's
    filter is the exact recursion started from its steady P+, sample for sample
    (log-likelihoods within 1e-6, issue 14's bound; measured 2e-9 / 1.0e-8 with 3 / 5
    sensors), until ``fast_warmup_s`` of full data has passed after the outage (P is
    not back at the steady state before, after the hold); then the steady gains again.
    Measured before 2026-11-27, when steady gains predicted through the hold and a
    partial outage used the steady P- for up to 20 ms: 4-90 nats between particles 10 %
    apart after a 10-20 ms hold (docs/estimator.md "Samples without every sensor")."""
    rng = np.random.default_rng(3)
    theta = _theta_box(rng, 16, 0.7, 1.4)
    Y = _outputs(3300, n_sensors, seed=12)
    Y[2000:2300] = np.nan
    Y[2450:2470, 1] = np.nan
    S = _samples(Y)
    filt = _steady_at(theta, S, n_sensors, 0.3)
    twin = ExactTwin(filt, theta, n_sensors)
    worst = 0.0
    for k in range(2000, 2769):
        filt.advance(S[k])
        assert not filt._steady, k
        worst = max(worst, float(np.abs(filt._ll[:16] - twin.step(Y[k])).max()))
    assert worst < 1e-6, worst
    filt.advance(S[2769])
    assert filt._steady


@pytest.mark.parametrize("n_sensors", [3, 5])
def test_a_lost_frame_rejoins_the_steady_gains_once_p_is_back(n_sensors: int) -> None:
    """A lost frame (one sensor out for 1 ms, later another for 20 ms) hands the steady
    phase to the exact recursion, which rejoins the steady gains as soon as its P+ is
    back within REJOIN_TOL of the steady P+ (until 2026-11-27 a lossy bus kept it exact
    for ``fast_warmup_s`` after every lost frame): here within 100 samples of the 1 ms
    outage and 500 of the 20 ms one (measured 16-32 and 35-291), and every particle's
    log-likelihood over the 3.5 s from the first outage stays within 0.05 nats of the
    exact recursion from the steady P+ run throughout (measured 0.002-0.005)."""
    from gateway.estimator.rejoin import REJOIN_TOL, RejoinTarget

    rng = np.random.default_rng(3)
    theta = _theta_box(rng, 16, 0.9, 1.1)
    Y = _outputs(5500, n_sensors, seed=12)
    Y[2000, 1] = np.nan
    Y[3000:3020, n_sensors - 1] = np.nan
    S = _samples(Y)
    filt = _steady_at(theta, S, n_sensors, 2.0)
    twin = ExactTwin(filt, theta, n_sensors)
    b = twin.bank
    target = RejoinTarget(b.posterior(), b.v0, b.H, np.ones(b.m, dtype=bool))
    assert target.distance(twin.P) < 1e-9
    diff = np.zeros(b.m)
    exact_for = {2000: 0, 3000: 0}
    for k in range(2000, len(S)):
        filt.advance(S[k])
        diff += filt._ll[:b.m] - twin.step(Y[k])
        if not filt._steady:
            exact_for[2000 if k < 3000 else 3000] += 1
    assert 0 < exact_for[2000] <= 100 and 20 < exact_for[3000] <= 500, exact_for
    assert filt._steady
    assert np.abs(diff).max() < 0.05, diff
    assert target.distance(twin.P) < REJOIN_TOL


def test_moves_on_the_way_back_solve_the_gains_of_the_moved_particles() -> None:
    """Resample-moves while the exact recursion is on its way back from a lost frame
    (forced here for 5 samples: a resampling threshold above 1, so that the effective
    sample size, at most m, is always below it; others may come on their own) solve the moved
    particles' gains from their ancestors', as in the steady phase, and each moved
    particle keeps its ancestor's deviation from the steady P+ under its own: the
    recursion rejoins the steady gains as soon as without the moves (measured: 83
    samples after the outage either way; keeping the ancestor's P took over 900), and
    then every particle's gains are the cold DARE solution at its theta (to 1e-9)."""
    Y = _outputs(1400, 3, seed=8)
    Y[1000:1040, 1] = np.nan
    S = _samples(Y)
    cfg = RBPFConfig(fs_hz=FS_HZ, n_particles=32, sensors=3, seed=3, mode="fast",
                     fast_warmup_s=0.5, monitor=None, faults=None)
    filt = RBPF(cfg)
    filt.run(S[:1000])
    assert filt._steady
    usual = filt.config
    often = RBPFConfig(**{**usual.__dict__, "ess_threshold": 1.001})
    forced, back = 0, None
    for k in range(1000, len(S)):
        n = filt.n_resamples
        filt.config = often if 1040 <= k < 1045 else usual
        filt.step(S[k])
        forced += int(1040 <= k < 1045 and filt._rejoin and filt.n_resamples > n)
        if back is None and k >= 1040 and filt._steady:
            back = k
    assert forced == 5 and back is not None and back - 1040 < 200, (forced, back)
    bank = Bank(filt.theta, 3)
    m = bank.m
    for a, b in ((filt._gains.g, bank.gains.g), (filt._gains.p_pred, bank.gains.p_pred)):
        a, b = from_lanes(a, m, (-1,)), from_lanes(b, m, (-1,))
        assert (np.abs(a - b).max(1) / np.abs(b).max(1)).max() < 1e-9


def _samples(Y: np.ndarray) -> list[Sample]:
    return [Sample(t_s=k / FS_HZ, values=Y[k], speed_mps=V_MPS) for k in range(len(Y))]


def test_a_long_hold_restarts_the_filters_at_their_prior() -> None:
    """Fast mode through a 9 s hold (a standstill): after PRIOR_SAMPLES held samples every
    filter restarts at its prior, where it waits without a recursion, the same in run()
    and step(); the returning data's log-likelihood over the next second differs from
    the exact prediction through the whole hold (exact mode, the same particles) by at
    most 0.1 nats between particles (measured 0.04)."""
    from dataclasses import replace

    from gateway.estimator.rbpf import PRIOR_SAMPLES

    rng = np.random.default_rng(4)
    theta = _theta_box(rng, 16, 0.9, 1.1)
    Y = _outputs(12600, 3, seed=14)
    S = [Sample(s.t_s, s.values, V_MPS, not 2000 <= k < 11000)
         for k, s in enumerate(_samples(Y))]
    cfg = RBPFConfig(fs_hz=FS_HZ, n_particles=16, sensors=3, mode="fast", resample=False,
                     monitor=None, faults=None, fast_warmup_s=1.0, seed=0)
    runs = {}
    for name, c in (("fast", cfg), ("exact", replace(cfg, mode="exact"))):
        filt = RBPF(c)
        filt.set_particles(theta)
        ll = np.zeros((len(S), 16))
        for k, smp in enumerate(S):
            filt.advance(smp)
            ll[k] = filt._ll[:16]
            if name == "fast" and k == 2000 + PRIOR_SAMPLES - 2:
                assert not filt._at_prior
            if name == "fast" and k == 2000 + PRIOR_SAMPLES - 1:
                assert filt._at_prior and not filt._X.any()
        runs[name] = (filt, ll)
    d = runs["fast"][1][11000:12000].sum(0) - runs["exact"][1][11000:12000].sum(0)
    assert d.max() - d.min() < 0.1, d
    twin = RBPF(cfg)
    twin.set_particles(theta)
    twin.run(S, output_every=100)
    assert twin.checkpoint() == runs["fast"][0].checkpoint()


@pytest.mark.parametrize("start_ramp_s", [0.0, 0.2])
def test_checkpoint_and_restore_are_bit_exact_in_fast_mode(start_ramp_s: float) -> None:
    """Checkpoints in the exact warm-up (with ``start_ramp_s`` = 0.2: inside the start's
    likelihood ramp), in the steady phase, in the exact hand-over of a sensor outage
    (sensor 1 missing for 0.1 s) and on the way back after a lost frame (before it
    rejoins the steady gains) continue bit for bit."""
    Y = _outputs(2600, 3, seed=4)
    Y[1600:1700, 1] = np.nan
    Y[2000, 2] = np.nan
    S = _samples(Y)
    cfg = RBPFConfig(fs_hz=FS_HZ, n_particles=64, sensors=3, seed=1, mode="fast",
                     fast_warmup_s=0.3, start_ramp_s=start_ramp_s)
    filt = RBPF(cfg)
    for cut in (150, 1500, 1650, 2010):
        filt = RBPF(cfg)
        filt.run(S[:cut])
        assert filt._rejoin == (cut in (1650, 2010)) and filt._steady == (cut == 1500)
        twin = RBPF.restore(filt.checkpoint())
        a = filt.run(S[cut:])
        b = twin.run(S[cut:])
        assert [e.mean for e in a] == [e.mean for e in b]
        assert [e.std for e in a] == [e.std for e in b]
        assert filt.n_resamples == twin.n_resamples


@pytest.mark.parametrize("mode", ["fast", "exact"])
def test_a_checkpoint_keeps_no_derived_matrices(mode: str) -> None:
    """What a checkpoint writes (to flash, every checkpoint_interval_s): never Phi or Qd
    (functions of theta and the speed, computed again on restore), no P in fast mode's
    steady phase (never read there), the gains there (they depend on the history);
    the continuation is bit-exact (test above)."""
    from gateway.estimator import checkpoint as ckpt

    S = _samples(_outputs(1500, 3, seed=4))
    filt = RBPF(RBPFConfig(fs_hz=FS_HZ, n_particles=64, sensors=3, seed=1, mode=mode,
                           fast_warmup_s=0.3))
    filt.run(S)
    _, arrays = ckpt.unpack(filt.checkpoint())
    assert not {"_phi", "_qd"} & set(arrays)
    steady = mode == "fast"
    assert ("_P" in arrays) != steady and ("gains_p_pred" in arrays) == steady
    twin = RBPF.restore(filt.checkpoint())
    assert np.array_equal(twin._phi, filt._phi) and np.array_equal(twin._qd, filt._qd)


def test_mode_is_checked() -> None:
    with pytest.raises(EstimatorError, match="expected mode 'exact' or 'fast', got 'quick'"):
        RBPFConfig(fs_hz=FS_HZ, mode="quick")


PAIRED_SEEDS = (21, 22, 23, 24)


@pytest.mark.slow
def test_fast_mode_recovers_the_truth_like_the_exact_mode() -> None:
    """Paper scenario, 3 sensors, 5 s, 500 particles: fast and exact on the same data and
    filter seed, four realisations. Every run within 3 sigma (+1 %) of the truth; the
    median over the pairs of |fast - exact| / exact sigma below 0.5 for every parameter
    (the campaign in docs/estimator.md measures medians of 0.3 sigma or less).

    A median, not every pair: from 2 s on the two modes are different particle
    approximations, and one pair's gap is Monte Carlo noise of that size (two exact runs
    that differ only in the filter seed are 0.2-1.2 sigma apart in median, up to 9 sigma at
    worst); a bound of 0.5 sigma on each pair failed about one seed in five, with the
    moves' static-yaw step on or off (docs/estimator.md "Fast mode against exact mode").

    Both modes run the service's filter settings at m = 500 (``estimator_config``: the
    start's likelihood ramp, the kernel discount 0.999). Until 2026-11-29 (twelfth
    session) the test ran the RBPF's bare defaults, without the ramp, the start-up
    lock-in's fix: at m = 500 that filter lay beyond 4 sigma at 5 s on 10 of 60 fresh
    records (seeds 6350-6409) with either prior box, so its truth check held on these
    four seeds by chance, and failed on seed 24 (Csay at 0.82, 12 sigma, in both modes)
    with the prior's damper edge at 0.1 (docs/estimator.md "The twelfth session")."""
    gaps, seen = [], []
    for seed in PAIRED_SEEDS:
        S = _samples(_outputs(5000, 3, seed=seed))
        out = {}
        for mode in ("fast", "exact"):
            settings = replace(EstimatorConfig(), sensors=3, seed=seed, particles=500,
                               mode=mode)
            filt = RBPF(estimator_config(settings, FS_HZ))
            out[mode] = filt.run(S, output_every=500)[-1]
        for mode, est in out.items():
            mean, std = np.array(est.mean), np.array(est.std)
            assert (np.abs(mean - NOMINAL) < 3 * std + 0.01 * NOMINAL).all(), (
                seed, mode, mean / NOMINAL)
        fast, exact = np.array(out["fast"].mean), np.array(out["exact"].mean)
        gaps.append(np.abs(fast - exact) / np.array(out["exact"].std))
        seen.append((seed, np.round(gaps[-1], 2)))
    assert (np.median(gaps, axis=0) < 0.5).all(), seen


@pytest.mark.parametrize(("case", "taken"), [
    ("clean", 6), ("lost frame", 2), ("speed step", 3), ("left-out sensor has a value", 1),
    ("bad shape", 4), ("hold after data", 2), ("hold at the start", 0)])
def test_a_block_takes_the_samples_up_to_the_first_event(case: str, taken: int) -> None:
    """block_prefix: the leading samples one compiled call may take, each with its
    values (left-out sensors zeroed) and whether it updates with every sensor; it stops
    at the first sample the per-sample path must see."""
    rng = np.random.default_rng(0)
    left_out = np.array([False, False, True])
    S = [Sample(k / FS_HZ, np.where(left_out, np.nan, rng.normal(size=3)), V_MPS)
         for k in range(6)]
    y = S[2].values.copy()
    if case == "lost frame":
        S[2] = Sample(S[2].t_s, np.where(np.arange(3) == 0, np.nan, y), V_MPS)
    elif case == "speed step":
        S[3] = Sample(S[3].t_s, S[3].values, V_MPS * 1.2)
    elif case == "left-out sensor has a value":
        S[1] = Sample(S[1].t_s, np.ones(3), V_MPS)
    elif case == "bad shape":
        S[4] = Sample(S[4].t_s, np.ones(4), V_MPS)
    elif case == "hold after data":
        S[2:] = [Sample(s.t_s, s.values, V_MPS, False) for s in S[2:]]
    elif case == "hold at the start":
        S = [Sample(s.t_s, s.values, V_MPS, False) for s in S]
    Y, full = block_prefix(S, 3, V_MPS, 0.05 * V_MPS, left_out, steady=True,
                           data_last=True)
    assert Y.shape == (taken, 3) and full.shape == (taken,)
    assert full.all()
    assert (Y[:, 2] == 0.0).all()
    assert (Y[:, :2] == np.array([s.values[:2] for s in S[:taken]]).reshape(-1, 2)).all()
    held = [Sample(s.t_s, s.values, V_MPS, False) for s in S[:3]]
    Y, full = block_prefix(held, 3, V_MPS, 0.05 * V_MPS, left_out, steady=False,
                           data_last=False)     # warming up, a hold that had begun
    assert len(full) == 3 and not full.any() and (Y == 0.0).all()


@pytest.mark.parametrize(("mode", "n_sensors", "start_ramp_s"),
                         [("fast", 3, 0.0), ("fast", 5, 0.0), ("exact", 3, 0.0),
                          ("fast", 3, 0.25), ("exact", 3, 0.25)])
def test_blocks_of_samples_equal_stepping_one_by_one(mode: str, n_sensors: int,
                                                     start_ramp_s: float) -> None:
    """RBPF.run steps uneventful runs of samples in one compiled call (the steady kernel,
    or the exact one in exact mode and fast mode's warm-up); stepping every sample
    through step() gives the same floats: estimates, resamples, detections, the fault
    bank's start and the whole filter state at the end (its checkpoint), including a hold
    of predict-only samples (after which the bank starts again), one with a missing
    sensor and a speed step; also with the
    start's likelihood ramp (``start_ramp_s``), which ends inside a block."""
    Y = _outputs(7500, n_sensors, seed=8)
    S = _samples(Y)
    for k in (2600, 6600):        # the second stops the running fault bank, which restarts
        S[k] = Sample(S[k].t_s, np.where(np.arange(n_sensors) == 1, np.nan, Y[k]), V_MPS)
    for k in range(3000, 3050):   # a hold: the bank waits after_hold_s of data again
        S[k] = Sample(S[k].t_s, Y[k], V_MPS, False)
    for k in range(7000, 7500):
        S[k] = Sample(S[k].t_s, Y[k], V_MPS * 1.01)
    cfg = RBPFConfig(fs_hz=FS_HZ, n_particles=200, sensors=n_sensors, seed=3, mode=mode,
                     fast_warmup_s=0.5, start_ramp_s=start_ramp_s)
    a = RBPF(cfg).run(S, output_every=37)
    one = RBPF(cfg)
    b = [e for k, s in enumerate(S) if (e := one.step(s)) and (k + 1) % 37 == 0]
    assert [e.t_s for e in a[:-1]] == [e.t_s for e in b]
    assert [(e.mean, e.std, e.ess) for e in a[:-1]] == [(e.mean, e.std, e.ess) for e in b]
    twin = RBPF(cfg)
    twin.run(S, output_every=37)
    assert twin.n_resamples == one.n_resamples > 0
    assert twin.n_steps == one.n_steps == len(S)
    assert twin.checkpoint() == one.checkpoint()
    assert twin._bank is not None and one._bank is not None and one._bank.active
