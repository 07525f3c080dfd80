"""The Rao-Blackwellized particle filter of Li et al. (2007): theta particles, their KFs.

Over 400 lines: the filter's step, its block path, resample-move and checkpoint
share its state; its kernels (exact, steady), config, particles, monitor, fault bank,
the rejoin test after a lost frame and the dead-sensor rule are already separate
modules.

Each of m particles carries theta = (Csy, Csay, lambda) [and optionally Ar] and its own
exact Kalman filter of the vehicle model (16 filter states, :mod:`gateway.model.coordinates`).
Per sample: every filter predicts and updates (:func:`gateway.estimator.kalman.kf_step`), the
log-weights add the filters' predictive log-likelihoods, and when the effective sample
size drops below ``ess_threshold * m`` the particles are resampled (systematic) and
moved by the Liu-West kernel compounded over the samples since the last move
(:func:`gateway.estimator.particles.liu_west_move`); a moved particle keeps its
ancestor's state less its static-yaw component (``moves_drop_null``, the default); only
then are Phi(theta, v) and Qd(theta, v) recomputed, exactly and batched
(:mod:`gateway.estimator.batch_expm`). Between moves each particle is an exact Kalman
filter for fixed theta. See docs/estimator.md.

Modes (``config.mode``): ``"exact"`` runs that recursion throughout; ``"fast"`` runs it
for ``fast_warmup_s`` after every filter start, then gives every particle the steady
state of its recursion (a DARE solve per move or speed band,
:mod:`gateway.estimator.steady`, fitted over the cloud at a move where the fit holds,
:mod:`gateway.estimator.gainfit`) and steps only the means; a sample without every sensor
(a hold, a lost frame) hands it back to the exact recursion, from the steady covariance,
for ``fast_warmup_s`` of full data (a lost frame inside it leaves at least ``SETTLE_S``
to go) or, after a lost frame, until P is back at the steady state
(:mod:`gateway.estimator.rejoin`), and a hold of :data:`PRIOR_SAMPLES` restarts the
filters at their prior; :meth:`RBPF.run` takes runs of uneventful samples in one
compiled call.

Speed: the model is evaluated at a reference speed v_ref; when a sample's speed differs
from v_ref by more than ``speed_tol`` (relative), v_ref becomes that speed and Phi, Qd
and H are recomputed for every particle.

Dead sensors: a sensor missing from half a second of samples with data is left out
(a zero row of H) until it has been back as long (:mod:`gateway.estimator.sensormask`).
Each estimate names the parameters the sensors in use cannot resolve at its speed band
(:mod:`gateway.estimator.observability`): Csy with the body node out of a 3-sensor set,
or below about 15 m/s with every sensor.

The core does no I/O and reads no clock; randomness comes from the Generator given to
:meth:`RBPF.reset` (or made from ``config.seed``). Checkpoints are bit-exact.
"""

from __future__ import annotations

import itertools
import logging
from collections.abc import Iterable
from dataclasses import asdict
from typing import Any

import numba
import numpy as np

from gateway.errors import EstimatorError, ModelError
from gateway.estimator import checkpoint as ckpt
from gateway.estimator import observability as obs
from gateway.estimator import particles as pt
from gateway.estimator.batch_expm import DiscreteBatch
from gateway.estimator.faultbank import Detection, FaultBank, FaultBankConfig
from gateway.estimator.gainfit import FITTED, fitted_gains
from gateway.estimator.kalman import from_lanes, kf_block, kf_step, n_chunks, to_lanes
from gateway.estimator.lanecode import LANES
from gateway.estimator.monitor import MonitorConfig, after_reseed, initial_state, update
from gateway.estimator.rbpf_config import AR_NAME, RBPFConfig
from gateway.estimator.rejoin import REJOIN_EVERY, SETTLE_S, RejoinTarget
from gateway.estimator.sensormask import BACK_AFTER_S, DEAD_AFTER_S, next_mask, tally
from gateway.estimator.steady import (
    NullVectors,
    SteadyGains,
    kf_steady,
    kf_steady_block,
    steady_gains,
    steady_posterior,
    without_null,
)
from gateway.model.coordinates import NZ, FilterCoords
from gateway.model.vehicle import (
    IDX,
    Theta,
    VehicleParams,
    sensor_set,
    track_intensity,
)
from gateway.records import Estimate, Located, NoiseCheck, Sample

__all__ = ["RBPF", "RBPFConfig", "AR_NAME", "PRIOR_SAMPLES"]

log = logging.getLogger(__name__)
MAX_WINDOW = 4096
"""Samples :meth:`RBPF.run` holds at once (outputs further apart are read in pieces)."""
BLOCK_MIN = 16
BLOCK_MAX = 1024
"""Samples one compiled block may take: BLOCK_MIN after an event, doubling up to
BLOCK_MAX while none comes. A block steps all its samples before the weights loop finds
the first event (a resample, an alarm), then steps again up to it; in the start-up
contraction, when exact mode resamples every few dozen samples, an unbounded block
stepped a whole 4096-sample window to keep 30 of them (10 ms per sample instead of
1). Block lengths change no result (:meth:`RBPF.run` equals :meth:`RBPF.step`)."""
PRIOR_SAMPLES = 2**13
"""The state prior is the covariance this many samples after a start from rest. A hold
(samples without data) this long restarts fast mode's filters at it, where they wait
without a recursion (a standstill costs nothing): the exact prediction has forgotten the
state by then (the log-likelihood of the returning data moves by at most 0.04 nats
between particles 10 % apart, measured after 9-12 s holds; docs/estimator.md "Samples
without every sensor")."""
_ARRAYS = ("z", "logw", "_X", "_P", "_phi", "_qd", "_P0", "monitor_state", "_left_out",
           "_absent", "_present")
LOCATED_FOR_S = 2.0
"""Data time (s) over which estimates carry the fault bank's latest detection
(:class:`gateway.records.Located`); the alert policy acts on each one once."""
_GAINS = ("p_pred", "g", "s", "c0", "iters")
"""The fields of :class:`SteadyGains` a fast-mode checkpoint keeps."""
_SCALARS = ("t_s", "n_steps", "n_resamples", "n_detections", "n_reseeds", "since_move",
            "updated_since_move", "_v_ref", "_p0_set", "_steady", "_warm_left",
            "_at_prior", "_prior_v", "_data_since_start", "_bank_check_at",
            "_ramp_from", "_ramp_n", "_bank_from", "_last_data_step", "_rejoin")


class RBPF:
    """Streaming RBPF implementing :class:`gateway.records.Estimator`."""

    def __init__(self, config: RBPFConfig, rng: np.random.Generator | None = None) -> None:
        self.config = config
        self.coords = FilterCoords.build(config.params)
        self.sensors = sensor_set(config.sensors)
        self.ny = len(self.sensors)
        self._r = np.ascontiguousarray(config.noise_variances)
        self._left_out = np.zeros(self.ny, dtype=bool)    # dead sensors (sensormask)
        self._absent = np.zeros(self.ny, dtype=np.int64)
        self._present = np.zeros(self.ny, dtype=np.int64)
        self._unresolved: tuple[str, ...] = ()    # what the sensors in use cannot resolve
        self._bounds: dict[tuple[bytes, float], tuple[str, ...]] = {}
        self._fast = config.mode == "fast"
        self._steady = False
        self._warm_left = 0
        self._rejoin = False    # fast mode: the exact recursion after a lost frame, which
        self._target: RejoinTarget | None = None    # rejoins the gains at this steady P+
        self._ramp_from = 0
        self._ramp_n = int(round(config.start_ramp_s * config.fs_hz))
        self._at_prior = False
        self._prior_v = float("nan")
        m = config.n_particles
        self._nch = n_chunks(m)
        self._ll = np.zeros(self._nch * LANES)
        self._nis = np.zeros(self._nch * LANES)
        self._dead = np.zeros(self._nch * LANES, dtype=bool)
        self._v_ref = float("nan")
        self._w_of: np.ndarray | None = None
        self._w_cache = np.zeros(m)
        self._data_since_start = 0
        self._bank_from = 0     # _data_since_start at the last sample without data: the
        self._bank_check_at = 0  # fault bank waits after_hold_s of data from there
        self._block_len = BLOCK_MIN
        self._v0_key: tuple[object, object] | None = None
        self._v0 = np.zeros((0, NZ))
        self._bank = (FaultBank(config.faults, len(config.names), config.fs_hz, config.ar_paper)
                      if config.faults is not None else None)
        self.reset(rng if rng is not None else np.random.default_rng(config.seed))

    # ----------------------------------------------------------------- state
    def reset(self, rng: np.random.Generator) -> None:
        """Start again from the prior, drawing from ``rng`` (kept for later draws)."""
        self.rng = rng
        self.z = self._draw_prior()
        self._start_filters()
        self.t_s = 0.0
        self.n_steps = 0
        self._last_data_step = 0    # n_steps at the last sample with data
        self.n_resamples = 0
        self.n_detections = 0
        self.n_reseeds = 0

    def _draw_prior(self) -> np.ndarray:
        """The paper's uniform box for theta; log-uniform for Ar (a scale over 16x)."""
        cfg = self.config
        lo, hi = cfg.box(cfg.prior_lo, cfg.prior_hi)
        if not cfg.estimate_ar:
            return pt.draw_uniform(self.rng, lo, hi, cfg.n_particles)
        return pt.draw_mixed(self.rng, lo, hi, cfg.n_particles,
                             np.array([False, False, False, True]))

    def set_particles(self, theta: np.ndarray) -> None:
        """Place the particles at given values (N, d) [SI, and Ar], restarting the filters."""
        th = np.asarray(theta, dtype=float)
        d = len(self.config.names)
        if th.shape != (self.config.n_particles, d) or np.any(~(th > 0)):
            raise EstimatorError(f"expected positive theta of shape "
                                 f"({self.config.n_particles}, {d}), got {th.shape}")
        self.z = np.log(th)
        self._start_filters()

    def _start_filters(self) -> None:
        m = self.config.n_particles
        self.logw = np.zeros(m)
        self.since_move = 0
        self.updated_since_move = 0
        self.monitor_state = initial_state()
        self._data_since_start = 0
        self._bank_from = 0
        if self._bank is not None:
            self._bank.stop()
        self._p0_set = False
        if np.isfinite(self._v_ref):
            self._set_speed(self._v_ref, restart=True)

    @property
    def theta(self) -> np.ndarray:
        """Particle values (N, d), SI units (and Ar in paper units)."""
        return np.exp(self.z)

    def _q(self) -> np.ndarray:
        """Track-noise intensity per particle (N,), m^2/s."""
        ar = self.theta[:, 3] if self.config.estimate_ar else self.config.ar_paper
        return track_intensity(1.0, self._v_ref) * np.broadcast_to(ar, (self.config.n_particles,))

    def _set_speed(self, v_mps: float, restart: bool = False) -> None:
        cfg = self.config
        self._v_ref = float(v_mps)
        self._disc = DiscreteBatch(self.coords, v_mps, 1.0 / cfg.fs_hz)
        if self._fast or self._bank is not None or cfg.moves_drop_null:
            self._null = NullVectors(self.coords.terms(v_mps), cfg.nominal.as_array())
        self._set_output()
        if restart or not self._p0_set:
            p0 = self.coords.initial_covariance(v_mps, cfg.ar_paper, 1.0 / cfg.fs_hz)
            self._P0 = np.ascontiguousarray(p0)
            self._X = np.zeros((self._nch, NZ * LANES))
            self._phi = np.empty((self._nch, NZ * NZ * LANES))
            self._qd = np.empty_like(self._phi)
            self._P = self._own_prior()
            self._gains = SteadyGains.empty(self._nch, self.ny)
            self._steady = False
            self._warm_left = self._warm_steps()
            self._start_ramp()
            self._p0_set = True
            self._at_prior, self._prior_v = True, self._v_ref
        # a new speed band solves cold: its filter coordinates are not the last band's
        self._end_rejoin()
        self._recompute()

    def _set_output(self) -> None:
        """H at v_ref, a left-out sensor's row zero (no information), for the filters
        and the fault bank."""
        H = self.coords.output(self.sensors, self._v_ref)
        H[self._left_out] = 0.0
        self._H = np.ascontiguousarray(H)
        self._unresolved = self._unresolved_now()
        if self._bank is not None:
            self._bank.set_model(self._disc, self._null, self._H, self._r,
                                 float(track_intensity(1.0, self._v_ref)))

    def _unresolved_now(self) -> tuple[str, ...]:
        """The parameters the sensors in use cannot resolve (:mod:`observability`), at the
        configured nominal and the centre of the speed band of v_ref. A function of the
        sensors left out and v_ref alone (a restored filter says the same), kept per set
        and band (about 30 ms each)."""
        if not np.isfinite(self._v_ref):
            return ()
        v = obs.band_speed(self._v_ref)
        key = (self._left_out.tobytes(), v)
        if key not in self._bounds:
            cfg, use = self.config, ~self._left_out
            names = tuple(s for s, u in zip(self.sensors, use, strict=True) if u)
            bound = obs.bound_rel(self.coords, cfg.nominal.as_array(), v,
                                  self.coords.output(names, v), self._r[use],
                                  float(track_intensity(cfg.ar_paper, v)), cfg.fs_hz)
            self._bounds[key] = obs.unresolved(cfg.names, bound)
        return self._bounds[key]

    def _own_prior(self) -> np.ndarray:
        """Each particle's state prior, lane layout: its covariance 2**13 samples from rest.

        Computed for the particle's own theta (the batched exact discretisation over
        8.2 s at 1 kHz), so that the start-up samples favour no particle; a prior taken at
        the nominal theta would pull the cloud towards nominal before the data can speak.
        """
        cfg = self.config
        horizon = DiscreteBatch(self.coords, self._v_ref, PRIOR_SAMPLES / cfg.fs_hz)
        P = np.empty((self._nch, NZ * NZ * LANES))
        horizon.compute(self.theta[:, :3], self._q(), np.empty_like(P), P)
        return P

    def _recompute(self, start: np.ndarray | None = None) -> None:
        """Phi and Qd at every particle's theta; in fast mode's steady phase its gains too,
        by Newton steps from ``start`` (lane layout P-, a nearby solution) where given, and
        after a lost frame the gains and the steady P+ the exact recursion rejoins."""
        self._disc.compute(self.theta[:, :3], self._q(), self._phi, self._qd)
        if self._steady:
            self._recompute_gains(start, fit=self.config.gain_fit)
            self._P = self._gains.p_pred
        elif self._rejoin:
            self._recompute_gains(start)
            self._target = self._rejoin_target(self._steady_post())
        elif self._fast and self._warm_left <= 0:
            self._enter_steady()

    def _enter_steady(self, solve: bool = True) -> None:
        """Fast mode, after the exact warm-up: every filter takes its steady-state gains,
        solved cold (``solve``) or, back from a lost frame, the ones it kept."""
        self._end_rejoin()
        self._steady = True
        if solve:
            self._recompute_gains()
        self._P = self._gains.p_pred

    def _fitted(self) -> bool:
        """Whether any particle's steady gains were fitted at the last move, not solved."""
        return bool((self._gains.iters[:self.config.n_particles] == FITTED).any())

    def _end_rejoin(self) -> None:
        """The exact recursion no longer rejoins the steady gains by distance (a hold, a
        new speed band, a restart): the time rule alone applies."""
        self._rejoin = False
        self._target = None

    def _steady_post(self) -> np.ndarray:
        """Every particle's steady P+ (N, 16, 16) from the current gains."""
        return steady_posterior(self._gains, self._particle_null(), self._H, self._r,
                                self.config.n_particles)

    def _rejoin_target(self, p_post: np.ndarray) -> RejoinTarget:
        alive = np.isfinite(self._gains.c0[:self.config.n_particles])
        return RejoinTarget(p_post, self._particle_null(), self._H, alive)

    def _leave_steady(self, partial: bool) -> None:
        """Fast mode, a sample without every sensor: the steady gains of the full sensor
        set no longer fit (the exact P widens while a sensor is missing, and the steady
        innovation variances would score the returning data too sharply: tens of nats
        between particles 10 % apart after 10-20 ms, measured), so the exact recursion
        takes over from the steady covariance, exactly, until ``fast_warmup_s`` of full
        data has passed; after a ``partial`` sample (some sensors: a lost frame) also as
        soon as P is back at that steady state (:mod:`gateway.estimator.rejoin`; the gains
        are kept for it, and a move solves them again from its ancestors', as in the
        steady phase) (docs/estimator.md "Samples without every sensor"). Fitted gains are
        solved first (from themselves): the rejoin is measured against this P+."""
        if self._fitted():
            self._recompute_gains(self._gains.p_pred.copy())
        P = self._steady_post()
        self._P = to_lanes(P.reshape(len(P), -1))
        self._steady = False
        self._warm_left = self._warm_steps()
        self._rejoin = partial
        self._target = self._rejoin_target(P) if partial else None

    def _warm_up(self, use: np.ndarray) -> None:
        """Fast mode's exact warm-up counts samples with every sensor: samples without
        data converge no state, and steady gains handed over before the states have seen
        ``fast_warmup_s`` of data score their start-up transient with the converged
        innovation variances, which favours the wrong particles (docs/estimator.md,
        "Start of every filter"). A sample with only some sensors (a lost frame) leaves
        at least ``SETTLE_S`` of full data to go, for its own perturbation of P to decay
        (restarting the whole warm-up kept a bus that loses a frame every few hundred
        samples in the exact recursion for good); one with none ends a rejoin after a
        lost frame (the hold widens P far more)."""
        if bool(use.any()) and not bool(use.all()):
            self._at_prior = False
            self._warm_left = max(self._warm_left, self._settle_steps)
        elif not use.any():
            self._end_rejoin()
        self._warmed(int(use.all()))

    def _warmed(self, n_full: int) -> None:
        """``n_full`` more samples with every sensor have passed the warm-up (a sample, or
        a block); the steady gains take over once it is done."""
        if n_full:
            self._at_prior = False
            self._warm_left -= n_full
        if self._warm_left <= 0:
            self._enter_steady()
        elif n_full and self._rejoin and self._warm_left % REJOIN_EVERY == 0:
            assert self._target is not None
            if self._target.reached(self._P):
                self._enter_steady(solve=False)

    def _warm_steps(self) -> int:
        return int(round(self.config.fast_warmup_s * self.config.fs_hz)) if self._fast else 0

    @property
    def _settle_steps(self) -> int:
        """Full samples the exact recursion runs at least after a lost frame."""
        return min(self._warm_steps(), int(round(SETTLE_S * self.config.fs_hz)))

    def _start_ramp(self) -> None:
        """A filter start: the ramp starts with the next data. Its length here is
        provisional (positive whenever a ramp is configured, so :attr:`_in_ramp` holds
        until the first data); :meth:`_ramp` sets it again at the first data's speed."""
        self._ramp_from = self._data_since_start
        self._ramp_n = self._ramp_steps()

    def _ramp_steps(self) -> int:
        """Samples with data in the ramp: ``start_ramp_s`` of data, or ``start_ramp_m`` of
        track at today's speed if that is longer (:class:`RBPFConfig`)."""
        cfg = self.config
        ramp_s = cfg.start_ramp_s
        if cfg.start_ramp_m > 0.0 and np.isfinite(self._v_ref) and self._v_ref > 0.0:
            ramp_s = max(ramp_s, cfg.start_ramp_m / self._v_ref)
        return int(round(ramp_s * cfg.fs_hz))

    @property
    def _in_ramp(self) -> bool:
        """Whether the data since the last filter start are still inside the ramp
        (:meth:`_start_ramp`)."""
        return self._data_since_start - self._ramp_from < self._ramp_n

    def _ramp(self, ll: np.ndarray, with_data: np.ndarray) -> None:
        """Scale the log-likelihoods ``ll`` (k, lanes) of the next samples, ``with_data``
        (k,), by c / n while inside the ramp (c-th sample with data since the filter
        start, n samples in the ramp). Its length is set at the speed of the first data
        after the start (a filter that starts while the gate holds the updates, below
        its lowest speed, would otherwise take the holding speed's)."""
        if self._data_since_start == self._ramp_from:
            self._ramp_n = self._ramp_steps()
        c = self._data_since_start - self._ramp_from + np.cumsum(with_data)
        ll *= np.minimum(c / self._ramp_n, 1.0)[:, None]

    def _particle_null(self) -> np.ndarray:
        """Every particle's unit static-yaw null vector (N, 16) at its theta and v_ref,
        solved once per cloud and speed: the steady gains and the next move's ancestors
        share it (each row is its own solve, so a row is the same in any batch)."""
        if self._v0_key is None or self._v0_key[0] is not self.z \
                or self._v0_key[1] is not self._null:
            self._v0 = self._null(self.theta)
            self._v0_key = (self.z, self._null)
        return self._v0

    def _recompute_gains(self, start: np.ndarray | None = None, fit: bool = False) -> None:
        """Fast mode: every particle's steady-state filter at its theta and v_ref, solved
        cold or from ``start`` (:func:`gateway.estimator.steady.steady_gains`); with
        ``fit`` (a move in the steady phase) fitted over the cloud where the fit holds
        (:mod:`gateway.estimator.gainfit`). The exact recursion's way back after a lost
        frame solves every particle: it rejoins the steady P+ at a distance of
        ``REJOIN_TOL``, the fit's own tolerance, so a fitted target could stay out of
        reach (measured: the bench's lossy run stayed in the exact recursion)."""
        v0 = to_lanes(self._particle_null())
        if fit and start is not None and fitted_gains(self.theta, self._phi, self._qd, v0,
                                                      self._H, self._r, self._gains, start):
            return
        steady_gains(self._phi, self._qd, v0, self._H, self._r, self._gains, start=start)

    # ------------------------------------------------------------------ step
    def step(self, sample: Sample) -> Estimate:
        """Consume one grid sample; returns the posterior after it."""
        return self._advance(sample, summarize=True) or self._summary(sample.t_s, False)

    def advance(self, sample: Sample) -> None:
        """Consume one grid sample without summarising (same evolution as :meth:`step`)."""
        self._advance(sample, summarize=False)

    def _validate(self, sample: Sample) -> np.ndarray:
        y = np.asarray(sample.values, dtype=float).reshape(-1)
        if y.shape != (self.ny,):
            raise EstimatorError(f"expected {self.ny} sensor values {self.sensors}, "
                                 f"got {y.shape[0]}")
        v = float(sample.speed_mps)
        if not (np.isfinite(v) and v > 0):
            raise EstimatorError(f"expected a positive finite speed in m/s, got {v}")
        return y

    def _weights(self) -> np.ndarray:
        """Normalised weights of ``self.logw``, cached per logw array (it is never mutated
        in place, only replaced), so each sample normalises once."""
        if self._w_of is not self.logw:
            self._w_cache, _ = pt.normalise_log(self.logw)
            self._w_of = self.logw
        return self._w_cache

    def _advance(self, sample: Sample, summarize: bool) -> Estimate | None:
        y = self._validate(sample)
        v = float(sample.speed_mps)
        if not np.isfinite(self._v_ref) or abs(v - self._v_ref) > self.config.speed_tol \
                * self._v_ref:
            self._set_speed(v)
        finite = np.isfinite(y)
        data = bool(sample.update) and bool((finite & ~self._left_out).any())
        if data:
            self._count_sensors(finite)
        use = (finite | self._left_out) & data
        y = np.where(finite & ~self._left_out, y, 0.0)
        self._ll[:] = 0.0
        self._nis[:] = 0.0
        self._dead[:] = False
        waiting = not self._steady and self._fast and self._at_prior and not use.any()
        if waiting:
            pass     # the filters wait at their prior (x = 0, P0) for their first data
        elif not self._steady:
            if self._fast and self._at_prior and self._prior_v != self._v_ref:
                self._set_speed(self._v_ref, restart=True)    # the prior at today's speed
            kf_step(self._X, self._P, self._phi, self._qd, self._H, self._r, y, use,
                    self._P0, self._ll, self._nis, self._dead)
            if self._fast:
                self._warm_up(use)
        elif use.all():
            kf_steady(self._X, self._phi, self._H, y, use, self._gains, self._ll, self._nis,
                      self._dead)
        else:
            self._leave_steady(partial=bool(use.any()))
            kf_step(self._X, self._P, self._phi, self._qd, self._H, self._r, y, use,
                    self._P0, self._ll, self._nis, self._dead)
        used = bool(use.any())
        if self._in_ramp:
            self._ramp(self._ll[None], np.array([used]))
        m = self.config.n_particles
        self.logw, w, total, ess, nis = pt.absorb(self.logw, self._ll, self._nis,
                                                   self._weights())
        self.t_s = float(sample.t_s)
        self.n_steps += 1
        if used:
            self._last_data_step = self.n_steps
        self.since_move += int(not waiting)
        self.updated_since_move += int(used)
        self._w_cache, self._w_of = w, self.logw
        if not np.isfinite(total):
            self._reseed_all()
            w = self._weights()
            ess = pt.effective_sample_size(w)
        est = self._summary(sample.t_s, used, w) if summarize else None
        self._data_since_start += int(used)
        if not used:
            self._bank_from = self._data_since_start
        fault = self._bank_step(y, use, float(sample.t_s)) if self._bank is not None else None
        alarm = False
        if self.config.monitor is not None and used and fault is None:
            alarm = update(self.config.monitor, self.monitor_state, nis,
                           int((use & ~self._left_out).sum()))
            if alarm and self._bank is not None and self._bank.busy:
                alarm = False             # the bank is locating a change: it answers
                after_reseed(self.monitor_state)
        if fault is not None:
            self._resample_move(w, False, fault)
        elif self.config.resample and (alarm or ess < self.config.ess_threshold * m):
            self._resample_move(w, alarm)
        if self._held_long():
            self.restart_filters()
        return est

    def _held_long(self) -> bool:
        """Fast mode: a hold of :data:`PRIOR_SAMPLES` since the last data has run through
        filters that are not at their prior."""
        return self._fast and not self._at_prior \
            and self.n_steps - self._last_data_step >= PRIOR_SAMPLES

    def _count_sensors(self, finite: np.ndarray) -> None:
        """A sample with data, values where ``finite`` (ny,): count each sensor's run of
        samples without and with a value, and leave out (or take back) the sensors
        :mod:`gateway.estimator.sensormask` says. A change works like a hold: fast mode
        goes back to the exact recursion from the steady covariance (whose gains were
        for the old sensor set) for ``fast_warmup_s`` of data, and the fault bank stops
        and waits ``after_hold_s``."""
        tally(self._absent, self._present, finite)
        fs = self.config.fs_hz
        new = next_mask(self._left_out, self._absent, self._present,
                        int(round(DEAD_AFTER_S * fs)), int(round(BACK_AFTER_S * fs)))
        if np.array_equal(new, self._left_out):
            return
        if self._steady:
            self._leave_steady(partial=False)
        elif self._fast:                  # inside a warm-up: the whole warm-up again
            self._warm_left = max(self._warm_left, self._warm_steps())
        if self._bank is not None:
            self._bank.stop()
        self._bank_from = self._data_since_start
        self._left_out = new
        self._end_rejoin()                # its target was the old set's steady P+
        self._set_output()                # H without the dead rows; the bank's model too

    def _bank_step(self, y: np.ndarray, use: np.ndarray, t_s: float) -> Detection | None:
        """The fault bank's view of one sample (after the particles took it): scored
        when every sensor is used. A sample with only some sensors stops it; so does one
        with none, and the bank then waits ``after_hold_s`` of data before it starts
        again: its steady-gain filters would score the data after a hold (a curve, a
        dropout) too sharply, and the cloud's states must first converge again
        (docs/estimator.md "Samples without every sensor")."""
        bank = self._bank
        assert bank is not None
        if not use.all():
            bank.stop()
            return None
        if not bank.active:
            self._maybe_start_bank()
            return None
        return bank.scan(y[None], np.array([bool(use.all())]), t_s, 1.0 / self.config.fs_hz)

    def _maybe_start_bank(self) -> None:
        """Start the fault bank once the cloud has settled (:mod:`faultbank`); checked
        every 0.1 s of samples."""
        bank, cfg = self._bank, self.config
        assert bank is not None and cfg.faults is not None
        if self.n_steps < self._bank_check_at or self._bank_wait(cfg.faults) > 0:
            return
        self._bank_check_at = self.n_steps + max(1, int(round(0.1 * cfg.fs_hz)))
        mean, std, xs, _, _ = _posterior(self._weights(), self.z, self._X)
        if np.all(std[:3] <= cfg.faults.max_rel_std * mean[:3]):
            bank.start(mean, xs)

    def run(self, samples: Iterable[Sample], output_every: int | None = None) -> list[Estimate]:
        """Feed samples; returns an estimate every ``output_every`` samples (and the last).

        Same filter evolution as calling :meth:`step` on each sample; only the outputs
        in between are not summarised. Default: ``config.output_every``. Once the
        filters have started, runs of uneventful samples (every sensor or none, speed in
        band, no resampling, no alarm) go through one compiled call (:meth:`_run_block`),
        bit-identical to stepping them one by one.
        """
        every = self.config.output_every if output_every is None else int(output_every)
        if every < 1:
            raise EstimatorError(f"expected output_every >= 1, got {every}")
        out: list[Estimate] = []
        source = iter(samples)
        k = 0                                   # samples consumed
        last: Sample | None = None
        while window := list(itertools.islice(source, min(every - k % every, MAX_WINDOW))):
            j = 0
            while j < len(window):
                took = self._run_block(window[j:]) if self._blocks() else 0
                if took:
                    j, k = j + took, k + took
                    if k % every == 0:
                        out.append(self._summary(window[j - 1].t_s, self._was_used(window[j - 1])))
                    continue
                est = self._advance(window[j], summarize=(k + 1) % every == 0)
                if est is not None:
                    out.append(est)
                j, k = j + 1, k + 1
            last = window[-1]
        if last is not None and (not out or out[-1].t_s != last.t_s):
            out.append(self._summary(last.t_s, self._was_used(last)))
        return out

    @staticmethod
    def _was_used(sample: Sample) -> bool:
        return bool(sample.update) and bool(np.isfinite(np.asarray(sample.values)).any())

    def _blocks(self) -> bool:
        """Whether :meth:`_run_block` may take the next samples: not while fast mode's
        filters wait at their prior for their first data (the per-sample path starts
        them)."""
        return self._steady or not (self._fast and self._at_prior)

    def _run_block(self, samples: list[Sample]) -> int:
        """Step the leading uneventful samples in one compiled call: the steady kernel
        (fast mode), or the exact one (exact mode, fast mode's warm-up).

        Returns how many were taken (0: the first needs the full per-sample path). A
        sample is eligible when its sensors are all used or none, its speed is in the
        current band and it is well formed; the weights loop
        (:func:`gateway.estimator.particles.absorb_block`) then stops before the first
        sample that resamples, raises an alarm or empties the weights, and the states
        are stepped again up to there from a copy.
        """
        cfg = self.config
        out = self._left_out
        Y, full = block_prefix(samples[:self._block_len], self.ny, self._v_ref,
                               cfg.speed_tol * self._v_ref, out, self._steady,
                               self._last_data_step == self.n_steps)
        k = len(Y)
        warming = self._fast and not self._steady
        if warming:                       # the block ends where the warm-up does, and
            left = self._warm_left        # at the next rejoin check after a lost frame
            if self._rejoin:
                left = min(left, self._warm_left % REJOIN_EVERY or REJOIN_EVERY)
            k = min(k, int(np.searchsorted(np.cumsum(full[:k]), left)) + 1)
        if self._fast:                    # ... and where a hold grows long (only a block's
            held = self.n_steps - self._last_data_step     # leading samples can be held)
            left = max(0, PRIOR_SAMPLES - held)
            if not full[:min(k, left)].any():
                k = min(k, left)
        bank = self._bank
        if bank is not None and not bank.active:  # ... and at the bank's next start check
            k = min(k, self._until_bank_check(full[:k]))
        if k == 0:
            return 0
        Y, full = Y[:k], full[:k]
        snap, scanned = None, 0
        if bank is not None and bank.active:
            snap = bank.snapshot()
            det = bank.scan(Y, full, samples[0].t_s, 1.0 / cfg.fs_hz)
            scanned = k
            if det is not None:          # the detecting sample takes the per-sample path
                k = bank.taken - 1
                if k == 0:
                    bank.rewind(snap)
                    return 0
                Y, full = Y[:k], full[:k]
        m = cfg.n_particles
        width = self._nch * LANES
        LL, NIS = np.empty((k, width)), np.empty((k, width))
        x0, p0 = self._X.copy(), (None if self._steady else self._P.copy())
        self._step_block(Y, full, LL, NIS)
        mon = cfg.monitor
        ess_min = cfg.ess_threshold * m if cfg.resample else -1.0
        dof = np.where(full, self.ny - int(out.sum()), 0).astype(np.int64)
        if mon is None:
            took, logw, w = pt.absorb_block(self.logw, LL, NIS, self._weights(), ess_min,
                                            False, dof, 1, 0.0, 0.0, 0, 0,
                                            self.monitor_state)
        else:
            took, logw, w = pt.absorb_block(self.logw, LL, NIS, self._weights(), ess_min,
                                            True, dof, mon.block_len, mon.k_sigma,
                                            mon.h_sigma, mon.warmup_blocks, mon.learn_blocks,
                                            self.monitor_state)
        self._block_len = BLOCK_MIN if took < k else min(2 * self._block_len, BLOCK_MAX)
        if took < k:                      # step the states again up to the event
            self._X = x0
            if p0 is not None:
                self._P = p0
            if took:
                self._step_block(Y[:took], full[:took], LL[:took], NIS[:took])
        if snap is not None and took != scanned:   # the bank steps again up to the event
            assert bank is not None
            bank.rewind(snap)
            if took:
                bank.scan(Y[:took], full[:took], samples[0].t_s, 1.0 / cfg.fs_hz)
        if took:
            self._data_since_start += int(full[:took].sum())
            if full[:took].any():         # each with every sensor in use, none left out
                tally(self._absent, self._present, ~out, int(full[:took].sum()))
            self.logw = logw
            self._w_cache, self._w_of = w, logw
            self.t_s = float(samples[took - 1].t_s)
            if full[:took].any():
                self._last_data_step = self.n_steps + int(np.flatnonzero(full[:took])[-1]) + 1
            self.n_steps += took
            self.since_move += took
            self.updated_since_move += int(full[:took].sum())
            if warming:
                self._warmed(int(full[:took].sum()))
            if bank is not None and not bank.active:
                self._maybe_start_bank()      # as after the block's last sample
            if self._held_long():
                self.restart_filters()
        return took

    def _bank_wait(self, faults: FaultBankConfig) -> float:
        """Samples with data still needed before the fault bank may start:
        ``start_after_s`` of data since the filter start and ``after_hold_s`` since the
        last hold (<= 0: none)."""
        fs = self.config.fs_hz
        return max(faults.start_after_s * fs - self._data_since_start,
                   faults.after_hold_s * fs - (self._data_since_start - self._bank_from))

    def _until_bank_check(self, full: np.ndarray) -> int:
        """Samples of a block with ``full`` (k,) up to and including the one after which
        the per-sample path would next check whether to start the fault bank
        (:meth:`_maybe_start_bank`: every 0.1 s once ``start_after_s`` of data has
        passed); k if none."""
        cfg = self.config
        assert cfg.faults is not None
        need = self._bank_wait(cfg.faults)
        due = (np.arange(len(full)) >= self._bank_check_at - self.n_steps - 1) \
            & (np.cumsum(full) >= need)
        return int(np.argmax(due)) + 1 if due.any() else len(full)

    def _step_block(self, Y: np.ndarray, full: np.ndarray, LL: np.ndarray, NIS: np.ndarray
                    ) -> None:
        """Step every filter over ``Y`` (k, ny) with ``full`` (k,), writing ``LL``, ``NIS``
        (k, padded m): the steady kernel or the exact recursion."""
        if self._steady:
            kf_steady_block(self._X, self._phi, self._H, Y, full, self._gains, LL, NIS)
        else:
            kf_block(self._X, self._P, self._phi, self._qd, self._H, self._r, Y, full,
                     self._P0, LL, NIS)
        if self._in_ramp:
            self._ramp(LL, full)

    # ------------------------------------------------------- resampling etc.
    def _floor_log(self) -> np.ndarray:
        """Roughening-std floor in log units, (d,).

        ``floor_reference == "nominal"`` (default, the issue's reading): ``floor_rel`` of
        the nominal value, converted at the cloud's geometric mean. ``"value"``: ``floor_rel``
        of the parameter itself (the paper's nominal values were the data-generating ones,
        so this equals its floor once converged); measured to give smaller sigma but to
        recover more slowly from a wrong start (docs/estimator.md).
        """
        cfg = self.config
        if cfg.floor_reference == "value":
            return np.full(len(cfg.names), cfg.floor_rel)
        w, _ = pt.normalise_log(self.logw)
        mean = np.exp(w @ self.z) if w.sum() > 0 else cfg.nominal_array
        return cfg.floor_rel * cfg.nominal_array / mean

    def _walk_var_log(self) -> np.ndarray | None:
        """Random-walk variance (d,) in log units for the updated samples since the last
        move: the parameters evolve while the vehicle runs, not while it stands."""
        cfg = self.config
        if not any(cfg.walk_rel_per_sqrt_s):
            return None
        rate = np.zeros(len(cfg.names))
        rate[:3] = np.square(cfg.walk_rel_per_sqrt_s)
        return rate * self.updated_since_move / cfg.fs_hz

    def _resample_move(self, w: np.ndarray, alarm: bool, fault: Detection | None = None
                       ) -> None:
        """Resample and move; an innovation-monitor ``alarm`` also re-draws part of the
        cloud and restarts every filter; a bank ``fault`` re-draws the changed parameter
        of every particle, weighted (:meth:`FaultBank.redraw`), and every particle takes
        the winning hypothesis filter's state (the vehicle's state does not jump with a
        parameter)."""
        cfg = self.config
        floor = self._floor_log()
        anc = pt.systematic(w, float(self.rng.random()))
        v0_anc = self._particle_null()[anc] if cfg.moves_drop_null else None
        znew = pt.liu_west_move(self.rng, self.z, w, anc, delta=cfg.delta,
                                steps=self.since_move, floor_log=floor,
                                walk_var_log=self._walk_var_log())
        logw_new = np.zeros(cfg.n_particles)
        if fault is not None:
            assert self._bank is not None
            znew[:, fault.parameter], logw_new = self._bank.redraw(fault, self.rng,
                                                                   cfg.n_particles)
            after_reseed(self.monitor_state)
        if alarm:
            self.n_detections += 1
            k = int(round(cfg.reseed_fraction * cfg.n_particles))
            pick = self.rng.permutation(cfg.n_particles)[:k]
            znew[pick] = pt.draw_log_uniform(self.rng, *cfg.box(cfg.reseed_lo, cfg.reseed_hi), k)
            after_reseed(self.monitor_state)
        lo, hi = cfg.box(cfg.support_lo, cfg.support_hi)
        self.z = np.clip(znew, np.log(lo), np.log(hi))
        if fault is not None:
            self._X = to_lanes(np.repeat(fault.state[None], cfg.n_particles, 0))
        else:
            X = from_lanes(self._X, cfg.n_particles, (NZ,))[anc]
            # optionally less the static-yaw component its new theta would turn into a
            # false transient (steady.without_null; RBPFConfig.moves_drop_null)
            self._X = to_lanes(X if v0_anc is None else without_null(X, v0_anc))
        self.logw = logw_new
        self.since_move = 0
        self.updated_since_move = 0
        self.n_resamples += 1
        p_anc: np.ndarray | None = None        # the ancestors' exact P (N, 256)
        if alarm:
            # The states were estimated under the old model: restart every filter from its
            # own prior (x = 0, P = P0(theta)). Keeping x with a widened P would be
            # inconsistent (small innovations against a large S favour small-P0 particles).
            self._X = np.zeros_like(self._X)
            self._P = self._own_prior()
            self._steady = False
            self._end_rejoin()
            self._warm_left = self._warm_steps()
            self._start_ramp()
            self._at_prior, self._prior_v = True, self._v_ref
        elif not self._steady:
            p_anc = from_lanes(self._P, cfg.n_particles, (NZ * NZ,))[anc]
            self._P = to_lanes(p_anc)
        # in the steady phase a moved particle's DARE starts from its ancestor's solution
        # (a jitter away); a fault's re-draw spans a range, so its particles start cold,
        # and the exact recursion after a lost frame then keeps the time rule alone
        if fault is not None:
            self._end_rejoin()
        warm = (self._steady or self._rejoin) and fault is None and not alarm
        was = self._target
        self._recompute(self._gains.take(anc) if warm else None)
        if self._rejoin:
            # on the way back from a lost frame a moved particle keeps its ancestor's
            # deviation from the steady P+ and takes its own theta's steady P+ under it, as
            # the steady phase gives it its own steady gains (the exact P would otherwise
            # carry the ancestor's theta into the slow mode for seconds, measured)
            assert was is not None and self._target is not None and p_anc is not None
            dev = p_anc - was.p_post[anc].reshape(cfg.n_particles, -1)
            self._P = to_lanes(dev + self._target.p_post.reshape(cfg.n_particles, -1))
        if self._bank is not None:
            if alarm:
                self._bank.stop()
            elif self._bank.active:
                self._bank.refresh(self.theta.mean(axis=0))

    def reset_parameter(self, index: int) -> None:
        """Baseline reset after a part is replaced: parameter ``index`` re-learns from its
        prior box while the others keep their particles; every filter restarts."""
        d = len(self.config.names)
        if not 0 <= int(index) < d:
            raise EstimatorError(f"expected a parameter index 0..{d - 1}, got {index}")
        z = self.z.copy()
        z[:, int(index)] = self._draw_prior()[:, int(index)]
        self.z = z
        self._start_filters()

    def restart_filters(self) -> None:
        """After a long gap in the data (or, in fast mode, a hold of
        :data:`PRIOR_SAMPLES`): every Kalman filter restarts from its own prior; the
        parameter particles and their weights are kept."""
        logw = self.logw
        self._start_filters()
        self.logw = logw

    def _reseed_all(self) -> None:
        """Every particle failed (e.g. all unstable): start again from the prior box."""
        self.n_reseeds += 1
        self.z = self._draw_prior()
        self._start_filters()

    # ------------------------------------------------------------ checkpoint
    def checkpoint(self) -> bytes:
        """The full filter state (incl. the Generator state) as bytes; see :meth:`restore`."""
        scalars = {k: getattr(self, k) for k in _SCALARS}
        if not self._p0_set:
            scalars["_v_ref"] = None
        meta = {"config": asdict(self.config), "rng": ckpt.generator_state(self.rng),
                "scalars": scalars}
        # Phi and Qd are functions of theta and v_ref (restore computes them again), and
        # fast mode's steady phase never reads P: 4-6 MB less at m = 1000, written to
        # flash every checkpoint_interval_s
        skip = {"_phi", "_qd"} | ({"_P"} if self._steady else set())
        arrays = {k: getattr(self, k) for k in _ARRAYS if hasattr(self, k) and k not in skip}
        if self._steady or self._rejoin:
            # the gains depend on the history (each move's DARE starts from its ancestor's)
            arrays.update({f"gains_{k}": getattr(self._gains, k) for k in _GAINS})
        if self._bank is not None:
            arrays.update(self._bank.arrays())
        return ckpt.pack(meta, arrays)

    @classmethod
    def restore(cls, data: bytes) -> RBPF:
        """A filter that continues exactly where :meth:`checkpoint` left off."""
        meta, arrays = ckpt.unpack(data)
        try:
            cfg = _config_from_dict(meta["config"])
            sc = meta["scalars"]
        except (KeyError, TypeError, ValueError) as err:
            raise EstimatorError(f"expected an RBPF checkpoint, got {err!r}") from err
        self = cls(cfg, np.random.default_rng(0))
        self.rng = ckpt.generator_from_state(meta["rng"])
        if sc["_v_ref"] is not None:
            self._set_speed(float(sc["_v_ref"]), restart=True)
        for k in _SCALARS:
            if sc.get(k) is not None:
                setattr(self, k, type(getattr(self, k))(sc[k]))
        if sc.get("_at_prior") is None:     # a checkpoint from before the field existed
            self._at_prior = False
        if sc.get("_last_data_step") is None:   # ... or before this one: no hold counted
            self._last_data_step = self.n_steps
        bank = {k: arrays.pop(k) for k in list(arrays) if k.startswith("bank_")}
        gains = {k[6:]: arrays.pop(k) for k in list(arrays) if k.startswith("gains_")}
        for k, v in arrays.items():
            setattr(self, k, v)
        if self._p0_set and self._left_out.any():
            self._set_output()
        if self._p0_set and "_phi" not in arrays:
            self._disc.compute(self.theta[:, :3], self._q(), self._phi, self._qd)
        if self._steady and set(gains) == set(_GAINS):
            self._gains = SteadyGains(**gains)
            self._P = self._gains.p_pred      # as _recompute_gains leaves it
        elif self._steady:
            self._enter_steady()      # a checkpoint from before the gains were kept
        if self._rejoin and set(gains) == set(_GAINS):
            self._gains = SteadyGains(**gains)
            self._target = self._rejoin_target(self._steady_post())
        elif self._rejoin:
            self._end_rejoin()
        if self._bank is not None:
            self._bank.load(bank)
        return self

    @property
    def left_out(self) -> np.ndarray:
        """The sensors the filters leave out now (bool (ny,), sensor-set order): dead
        ones (:mod:`gateway.estimator.sensormask`)."""
        return self._left_out.copy()

    def noise_check(self) -> NoiseCheck | None:
        """None: a plain filter makes no sensor-noise test (:mod:`.noisestart` does)."""
        return None

    @property
    def n_fault_detections(self) -> int:
        """Changes found by the fault bank (:mod:`gateway.estimator.faultbank`)."""
        return 0 if self._bank is None else self._bank.count

    def last_fault(self) -> tuple[float, str, float, float] | None:
        """The fault bank's latest detection: (data time, parameter name, located value
        relative to nominal, data time its CUSUM crossing was confirmed), or None."""
        last = None if self._bank is None else self._bank.last()
        if last is None:
            return None
        t_s, p, value, crossed = last
        return t_s, self.config.names[p], value / float(self.config.nominal_array[p]), crossed

    # --------------------------------------------------------------- outputs
    def _summary(self, t_s: float, updated: bool, w: np.ndarray | None = None) -> Estimate:
        if w is None:
            w = self._weights()
        mean, std, xs, xc, ess = _posterior(w, self.z, self._X)
        phys_w = self.coords.to_physical @ xs
        phys_c = self.coords.to_physical @ xc
        p = self.config.params
        v_sy = float(p.ksry_n_per_m * (phys_c[IDX["y_b"]] + p.c_m * phys_c[IDX["psi_b"]]
                                       - phys_c[IDX["y_sr"]]))
        v_say = float(p.lbw_m * phys_w[IDX["dpsi_b"]])
        return Estimate(t_s=float(t_s), mean=tuple(float(v) for v in mean),
                        std=tuple(float(v) for v in std),
                        ess=ess, v_sy_mps=v_sy, v_say_mps=v_say,
                        updated=updated, names=self.config.names, located=self._located(t_s),
                        left_out=tuple(s for s, out in zip(self.sensors, self._left_out,
                                                           strict=True) if out),
                        unresolved=self._unresolved)

    def _located(self, t_s: float) -> Located | None:
        """The bank's latest located change published before ``t_s`` (its detection, or
        a look of its refinement that moved the interval:
        :meth:`FaultBank.located_before`), on every estimate up to :data:`LOCATED_FOR_S`
        of data after it (a function of the state: the worker may drop estimates between
        outputs, and a restart repeats none); None otherwise. A detection's sample takes
        the per-sample path, so what was published before ``t_s`` is always about the
        bank's latest detection."""
        last = None if self._bank is None else self._bank.last()
        located = None if self._bank is None else self._bank.located_before(t_s)
        if last is None or located is None or not t_s - located[0] <= LOCATED_FOR_S:
            return None
        assert self._bank is not None
        rng = self._bank.last_range()
        assert rng is not None
        _, p, _, _ = last
        t_loc_s, value, *like = located
        nominal = float(self.config.nominal_array[p])
        return Located(t_s=t_loc_s, parameter=self.config.names[p], rel=value / nominal,
                       rel_lo=rng[0] / nominal, rel_hi=rng[1] / nominal,
                       like_lo=like[0] / nominal, like_hi=like[1] / nominal)


@numba.njit(cache=True)
def _posterior(w: np.ndarray, z: np.ndarray, x: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
    """Weighted mean/std of theta = exp(z) (d,), sum w x and sum w x / Csy (16,), ESS.

    ``w`` (N,) normalised, ``z`` (N, d), ``x`` lane layout (n_chunks, 16 * LANES). Serial
    (about 20 us for 1000 particles); summaries only, never fed back into the filter.
    """
    m, d = z.shape
    th = np.exp(z)
    mean = np.zeros(d)
    for p in range(m):
        for j in range(d):
            mean[j] += w[p] * th[p, j]
    sq = np.zeros(d)
    for p in range(m):
        for j in range(d):
            e = th[p, j] - mean[j]
            sq[j] += w[p] * e * e
    xs = np.zeros(NZ)
    xc = np.zeros(NZ)
    ww = 0.0
    for p in range(m):
        ch, lane = p // LANES, p % LANES
        wc = w[p] / th[p, 0]
        ww += w[p] * w[p]
        for i in range(NZ):
            v = x[ch, i * LANES + lane]
            xs[i] += w[p] * v
            xc[i] += wc * v
    return mean, np.sqrt(np.maximum(sq, 0.0)), xs, xc, 1.0 / ww


def block_prefix(samples: list[Sample], ny: int, v_ref: float, tol: float,
                 left_out: np.ndarray, steady: bool, data_last: bool
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The leading samples one compiled block may take, as arrays: ``Y`` (k, ny), the
    values with left-out sensors zeroed (zero rows for samples without data), and
    ``full`` (k,), whether each sample updates with every sensor in use.

    A sample ends the prefix when its values are not ``ny`` floats, its speed is not
    within ``tol`` of ``v_ref``, it updates with a left-out sensor's value (the
    per-sample path counts it back in) or with only some sensors (a lost frame), or it
    starts a hold: a sample without data in the ``steady`` phase, or right after one with
    data (the first sample: after the filter's last step, if ``data_last``), where the
    per-sample path leaves the steady gains, stops the fault bank and restarts its clock.
    One pass of array operations over the block (the per-sample loop it replaced cost
    about as much as the steady kernel's step, measured 2026-12-01).
    """
    n = len(samples)
    V = np.empty((n, ny))
    for j, smp in enumerate(samples):
        y = np.asarray(smp.values, dtype=float).reshape(-1)
        if y.shape != (ny,):
            n = j
            break
        V[j] = y
    V = V[:n]
    v = np.array([float(smp.speed_mps) for smp in samples[:n]])
    upd = np.array([bool(smp.update) for smp in samples[:n]], dtype=bool)
    fin = np.isfinite(V)
    every = upd & (fin | left_out).all(axis=1)
    stop = ~(np.abs(v - v_ref) <= tol) | (upd & (fin & left_out).any(axis=1))
    some = upd & fin.any(axis=1)
    stop |= some & ~every
    held = ~(every | some)
    after_data = np.concatenate(([data_last], every[:-1])) if n else every
    stop |= held & (steady | after_data)
    k = int(np.argmax(stop)) if stop.any() else n
    full = every[:k].copy()
    Y = np.where(full[:, None] & ~left_out, V[:k], 0.0)
    return Y, full


def config_of_checkpoint(data: bytes) -> RBPFConfig:
    """The configuration an RBPF checkpoint (:meth:`RBPF.checkpoint`) was made with, as
    :meth:`RBPF.restore` would rebuild it; EstimatorError if ``data`` is not one."""
    meta, _ = ckpt.unpack(data)
    try:
        return _config_from_dict(meta["config"])
    except (KeyError, TypeError, ValueError, AttributeError, ModelError) as err:
        raise EstimatorError(f"expected an RBPF checkpoint, got {err!r}") from err


def _config_from_dict(d: dict[str, Any]) -> RBPFConfig:
    d = dict(d)
    # a checkpoint from before the option existed moved whole states: it continues so
    d.setdefault("moves_drop_null", False)
    # ... and one from before the noise test said so counts as tested: an upgrade
    # resumes it under "measured", as before
    d.setdefault("noise_tested", True)
    d["nominal"] = Theta(**d["nominal"])
    d["params"] = VehicleParams(**d["params"])
    d["monitor"] = None if d["monitor"] is None else MonitorConfig(**d["monitor"])
    if d.get("faults") is not None:
        bank: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v
                                for k, v in d["faults"].items()}
        # a checkpoint from before the early stop (or the extension) summed the full
        # location phase, and no more
        bank.setdefault("locate_min_s", bank.get("locate_s", FaultBankConfig.locate_s))
        bank.setdefault("locate_max_s", bank.get("locate_s", FaultBankConfig.locate_s))
        # ... and before the look-back, located from the confirmation on, and redrew
        # over the range
        bank.setdefault("replay_s", 0.0)
        bank.setdefault("redraw_from", "range")
        # ... and before 2026-11-28 (fourth session), a replayed location started from the
        # same multiple of its steady covariance as one from the confirmation
        bank.setdefault("replay_cov_scale", bank.get("locate_cov_scale",
                                                     FaultBankConfig.locate_cov_scale))
        # ... and before 2026-11-28 (fifth session), had no refinement after a detection
        bank.setdefault("refine_s", 0.0)
        # ... and before 2026-11-29 (eighth session), watched again after a location that
        # found no change
        bank.setdefault("runner_up", False)
        # ... and before 2026-11-30 (fourteenth session), took the watch's CUSUMs' runner-up
        bank.setdefault("runner_by", "cusum")
        # ... and before 2026-11-30 (fifteenth session), located each crossing as named
        bank.setdefault("located_by", "crossing")
        d["faults"] = FaultBankConfig(**bank)
    for k, v in list(d.items()):
        if isinstance(v, list):
            d[k] = tuple(v)
    return RBPFConfig(**d)
