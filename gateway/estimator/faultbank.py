"""Abrupt-fault detector: a bank of fault-hypothesis Kalman filters and a CUSUM per hypothesis.

Over 400 lines: the watch, confirm, locate and refine phases share one state vector
and one set of filters; splitting them would pass that state around. What the location
replays is kept by :mod:`gateway.estimator.lookback`; the redraw's densities are
:mod:`gateway.estimator.particles`.

The particle cloud learns a parameter change only as fast as its roughening lets it
crawl, and the innovation monitor (:mod:`gateway.estimator.monitor`) tests the cloud's
average NIS, which a drifting cloud keeps quiet. The data hold far more (issue 15: about
1,000 nats/s for Csy 40 -> 10 kNs/m). This bank reads them directly, in four phases:

- *Watch.* Beside the cloud run ``1 + 3 * len(factors)`` steady-gain Kalman filters
  (:mod:`gateway.estimator.steady`): a *reference* at the cloud's posterior mean
  ``theta_ref`` and one *hypothesis* per parameter p and factor f, ``theta_ref`` with its
  p-th value times f. Each full sample adds every hypothesis's log-likelihood ratio to
  the reference to a one-sided CUSUM (Page; Lindley's recursion)::

      g_j <- max(0, g_j + ll_j - ll_ref)          crossing when g_j > h_nats

  For a correct model ``exp(-h)`` bounds the chance that a CUSUM ever crosses (Wald).
- *Confirm.* ``confirm_s`` after a crossing the largest CUSUM, if still over ``h``,
  names the parameter and the side (drop or rise).
- *Locate.* The hypotheses become a grid over that parameter on that side
  (:meth:`FaultBank.locate_grid`). For a damper (since 2026-11-27, ``replay_s``), every
  filter starts from the reference's state at the likeliest change time (the
  generalised likelihood ratio's, up to ``replay_s`` back, :meth:`FaultBank._glr_start`)
  and replays the samples since (:mod:`gateway.estimator.lookback`): the evidence that
  made the CUSUM cross counts, and the phase's ``locate_s`` runs from the change time,
  so a change that took longer than ``locate_s`` to cross is decided at the
  confirmation. The conicity does not replay (:data:`CONICITY`). Without a replay every
  filter restarts from the leading hypothesis's state less its unobservable static-yaw
  component (a conicity change would otherwise turn that arbitrary component into a
  transient the data never had, and the grid read it as a larger rise). Either state
  was estimated under another value, and this model's slow closed-loop mode (about
  8 s) would carry its error through the whole phase under steady gains, biasing the
  grid towards the value it came from. So each grid filter
  runs the exact Kalman recursion (:func:`gateway.estimator.kalman.kf_block`) from a
  covariance ``locate_cov_scale`` (100) times its own steady covariance, which lets it
  correct that error within the phase; a replayed start, whose state was estimated
  under the right value up to the change's sample (since 2026-11-29; before, up to the
  look-back's snapshot spacing), uses
  ``replay_cov_scale`` (10): the wider start spent the change's first evidence on
  converging (since 2026-11-28: at 20 m/s the first alerts' median 0.8 s earlier). Their
  log-likelihood ratios to the reference are summed for ``locate_s``, and the best grid
  value, if it beats the reference by ``h / 2``, is the :class:`Detection`; if it does
  not beat the reference at all, that parameter did not change: since 2026-11-29
  (``runner_up``) another damper is located next, at once, replaying from the look-back
  before the confirmation (:meth:`FaultBank._runner_up`): since 2026-11-30
  (``runner_by``) the damper and side whose change-time search over that look-back sums
  the most (:meth:`FaultBank._best_runner`), if that crosses ``h``; after a conicity
  location, the conicity on its other side where its search sums more than every
  damper's (since the nineteenth session) or where no damper's crosses ``h`` (since the
  eighteenth), from the reference's state then; otherwise every filter
  restarts from the reference's state and the bank watches again. (Since 2026-11-30's
  fifteenth session, ``located_by``, the confirmation itself asks that search which
  parameter and side to locate: among the dampers for a crossing on a damper, among
  every parameter for one on the conicity; since the seventeenth, a damper it picks
  over the crossing's parameter keeps a runner-up too, and each location starts at the
  change time its search found, without searching again.) In between, the sum goes on,
  up to ``locate_max_s``, until one of the two holds (Wald: a later look costs no
  more false detections). Optionally (``locate_min_s`` below ``locate_s``; off by
  default) the sum stops early, after at least ``locate_min_s``, at
  the first sample where the best value also leads every grid value outside its redraw
  range (three grid steps or more away) by ``h / 2``: for a correct model ``exp(-h /
  2)`` bounds the chance that a value that far from the truth ever leads it by that much
  (Wald), so the redraw range then holds the truth. The estimator then redraws that
  parameter of every particle (:meth:`FaultBank.redraw`) and gives every particle the
  best filter's state. Since 2026-11-27 (``redraw_from = "likelihood"``) the new values
  follow the grid's summed likelihood, so the evidence since the change carries into the
  cloud instead of being gathered again from a flat start over the redraw range
  (:data:`DEFENSIVE_SHARE` of them still spread over that range).
- *Refine* (since 2026-11-28, ``refine_s``). The grid sums on after the detection, and
  every :data:`REFINE_EVERY` samples its likelihood interval is looked at again; where
  it or the best value moved, that is the latest located change
  (:meth:`FaultBank.located_before`), which the alert policy acts on like the
  detection's: an interval that straddled a threshold at the detection raises once the
  data have narrowed it past. Then the bank watches again about the best value.

Life cycle: the bank is idle until the cloud has ``start_after_s`` of updated data
since its filters started and every parameter's posterior std is within
``max_rel_std`` of its mean; it starts from the cloud's posterior mean state. After a
start or a detection it holds its CUSUMs at 0 for ``hold_s``. ``theta_ref`` follows
the cloud at every resample-move (:meth:`FaultBank.refresh`); every state that passes to
a filter at another theta there, or at a start, loses its static-yaw component first,
because a moved reference turns it into a false CUSUM rise. The estimator stops the bank
at a sample without every sensor, and after one without data (a hold: a curve, a
dropout) waits ``after_hold_s`` of data before it starts it again: steady gains score
the data after a hold too sharply (a false Csy drop after a 3 s hold, measured). Samples
without data that reach :meth:`FaultBank.scan` are predicted.

State is five arrays (:meth:`FaultBank.arrays`, the location grid's covariances among
them), so checkpoints stay bit-exact; the gains are recomputed from them and the speed
on restore. No I/O. Measured in
docs/estimator.md "Change detection".
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from gateway.errors import EstimatorError
from gateway.estimator.batch_expm import DiscreteBatch
from gateway.estimator.kalman import from_lanes, kf_block, n_chunks, to_lanes
from gateway.estimator.lanecode import LANES
from gateway.estimator.lookback import SNAP_EVERY, Lookback
from gateway.estimator.particles import draw_log_cells, draw_log_uniform, log_cell_density
from gateway.estimator.steady import (
    NullVectors,
    SteadyGains,
    kf_steady_block,
    steady_gains,
    steady_posterior,
    without_null,
)
from gateway.model.coordinates import NZ

N_THETA = 3
"""Parameters the bank tests (Csy, Csay, lambda); Ar, when estimated, is not."""
CONICITY = 2
"""Index of the conicity in theta. Its location does not replay: a conicity change
turns the vehicle's static yawed set-up, unobservable before it (model notes section 2),
into a transient the model cannot predict, and the first second after a rise then
favours larger values (lambda x 1.6, fresh seeds: located at 1.07-1.46 x the truth
with the replay, 0.92-1.12 x without; docs/estimator.md "The location replays the
change"). A damper change leaves that set-up where it was."""
REDRAW_STEPS = 3
"""Location grid steps either side of the located value over which the detected
parameter is redrawn (:meth:`FaultBank.redraw_range`)."""
DEFENSIVE_SHARE = 0.1
"""Share of a likelihood redraw's particles spread log-uniformly over the redraw range
(:meth:`FaultBank.redraw`), weighted so that the cloud still follows the likelihood: a
defensive mixture (Hesterberg 1995), which keeps particles near the truth if the grid's
profile likelihood is off (another parameter, the model)."""
LIKELY_NATS = 8.0
"""How far (nats) a grid value's summed log-likelihood ratio may trail the located
value's and still count as likely (:meth:`FaultBank.likely_range`): (4 sigma)^2 / 2, the
alert policy's standard for a sure estimate (``PolicyConfig.sure_sigmas`` = 4), so that
an alert the location raises at once asks of the location what a sure alert asks of the
estimates. h / 2 = 12.5 nats was measured too (docs/estimator.md "Located alerts follow
the likelihood interval")."""
REDRAWS = ("likelihood", "range")
"""How a detection redraws its parameter (:attr:`FaultBankConfig.redraw_from`)."""
RUNNERS = ("replay", "cusum")
"""How a location's runner-up is chosen (:attr:`FaultBankConfig.runner_by`)."""
LOCATED_BY = ("search", "crossing")
"""What a confirmed crossing locates (:attr:`FaultBankConfig.located_by`)."""


@dataclass(frozen=True)
class FaultBankConfig:
    """The bank's hypotheses and decision rule (module docstring).

    ``factors``: hypothesis values relative to the reference, each != 1; ``h_nats``:
    CUSUM threshold in nats; ``start_after_s``: updated data (s) since a filter start
    before the bank may start; ``after_hold_s``: updated data (s) after a hold (samples
    without data: a curve) before it may start again (1 s: the first alert of a fault
    during a curve at worst 5.4 s instead of 7.4 s after it, and no false detection in 100
    healthy minutes with 200 holds, measured; docs/estimator.md "Samples without every
    sensor"); ``max_rel_std``: largest posterior std / mean of any
    parameter at which it starts; ``hold_s``: data time (s) its CUSUMs stay at 0 after a
    start or a detection; ``confirm_s``: data time (s) from a crossing to the decision,
    which takes the largest CUSUM then (parameter and side); ``locate_s``: data time (s)
    over which the location grid's log-likelihoods are summed before a decision;
    ``locate_max_s``: at most (an inconclusive sum, the best value ahead of the
    reference by less than ``h / 2``, goes on until the lead passes ``h / 2`` or
    vanishes; ``locate_max_s == locate_s``: never); ``locate_min_s``: at least (the
    early stop, module docstring; ``locate_min_s >= locate_s``: off, the default: the
    early stop's locations were biased, docs/estimator.md);
    ``locate_cov_scale``: the location grid's exact filters start from this multiple of
    their steady covariance (module docstring; measured in docs/estimator.md, "A fair
    location"); ``replay_cov_scale``: the same multiple where they replay from the
    likeliest change time, from a state estimated under the right value up to the
    change's sample (docs/estimator.md, "The replayed location starts from 10 x its
    steady covariance", "The replay starts at the change's sample"); ``replay_s``: the
    longest look-back (s) over which the location grid replays from the likeliest change
    time (:mod:`gateway.estimator.lookback`; 0: the grid starts at the confirmation, as
    before 2026-11-27); ``redraw_from``: how the detected parameter is redrawn
    (:meth:`FaultBank.redraw`; "range": log-uniformly over the redraw range, as before
    2026-11-27); ``refine_s``: data time (s) the location grid sums on after a
    detection, its interval looked at every :data:`REFINE_EVERY` samples (module
    docstring; 0: the bank watches again at once, as before 2026-11-28's fifth session;
    it counts towards ``hold_s``, so the bank is back to watching ``max(hold_s,
    refine_s)`` after a detection; docs/estimator.md "The location refines its interval
    after a detection"); ``runner_up``: where a location finds no change, locate the
    runner-up damper next, from the same look-back (:meth:`FaultBank._runner_up`), or,
    after a conicity location with no damper to follow, the conicity on its other side
    (:meth:`FaultBank._located`; False: watch again, as before 2026-11-29's eighth
    session); ``runner_by``: how the
    runner-up is chosen (``"replay"``, since 2026-11-30: the damper and side whose
    location grid's change-time search over the look-back sums the most, if that
    crosses ``h_nats`` (:meth:`FaultBank._best_runner`); ``"cusum"``: the watch's best
    hypothesis on another damper at the confirmation, if its CUSUM was positive, as
    before); ``located_by``: what a confirmed crossing locates (``"search"``, since
    2026-11-30's fifteenth session: the parameter and side whose change-time search over
    the look-back sums the most, if that crosses ``h_nats``, among the dampers' drops and
    rises for a crossing on a damper, among every parameter's for one on the conicity
    (:meth:`FaultBank._best_search`); ``"crossing"``: the crossing's parameter and side,
    as before).
    """

    factors: tuple[float, ...] = (0.25, 0.4, 0.6, 1.6, 2.5)
    h_nats: float = 25.0
    start_after_s: float = 3.0
    after_hold_s: float = 1.0
    max_rel_std: float = 0.1
    hold_s: float = 1.0
    confirm_s: float = 0.25
    locate_s: float = 1.0
    locate_min_s: float = 1.0
    locate_max_s: float = 3.0
    locate_cov_scale: float = 100.0
    replay_cov_scale: float = 10.0
    replay_s: float = 2.0
    redraw_from: str = "likelihood"
    refine_s: float = 1.0
    runner_up: bool = True
    runner_by: str = "replay"
    located_by: str = "search"

    def __post_init__(self) -> None:
        if self.redraw_from not in REDRAWS:
            raise EstimatorError(f"expected redraw_from from {REDRAWS}, "
                                 f"got {self.redraw_from!r}")
        if self.runner_by not in RUNNERS:
            raise EstimatorError(f"expected runner_by from {RUNNERS}, "
                                 f"got {self.runner_by!r}")
        if self.located_by not in LOCATED_BY:
            raise EstimatorError(f"expected located_by from {LOCATED_BY}, "
                                 f"got {self.located_by!r}")
        f = np.asarray(self.factors, dtype=float)
        if f.ndim != 1 or len(f) == 0 or np.any(~(f > 0)) or np.any(f == 1.0) \
                or len(set(self.factors)) != len(f):
            raise EstimatorError(f"expected distinct positive hypothesis factors other than "
                                 f"1, got {self.factors}")
        if not self.h_nats > 0:
            raise EstimatorError(f"expected a positive CUSUM threshold in nats, "
                                 f"got {self.h_nats}")
        if not self.locate_max_s >= self.locate_s:
            raise EstimatorError(f"expected locate_max_s >= locate_s ({self.locate_s} s), "
                                 f"got {self.locate_max_s}")
        for name in ("locate_cov_scale", "replay_cov_scale"):
            if not getattr(self, name) >= 1.0:
                raise EstimatorError(f"expected {name} >= 1 (a multiple of the steady "
                                     f"covariance), got {getattr(self, name)}")
        for name in ("start_after_s", "after_hold_s", "max_rel_std", "hold_s", "confirm_s",
                     "locate_s", "locate_min_s", "replay_s", "refine_s"):
            if not getattr(self, name) >= 0:
                raise EstimatorError(f"expected {name} >= 0, got {getattr(self, name)}")


@dataclass(frozen=True)
class Detection:
    """A located change: parameter index, the best factor of the location grid and that
    grid's ratio between neighbours, the reference value, the data time of the decision
    and of the confirmed CUSUM crossing (``confirm_s`` after it), the best filter's
    state (16,) at the decision, and the grid's factors (J,) with their log-likelihood
    ratios to the reference (J,) summed over the location, nats."""

    parameter: int
    factor: float
    t_s: float
    reference: float
    state: np.ndarray
    confirmed_s: float
    step: float
    grid: np.ndarray
    llr: np.ndarray


_NO_RESET = np.zeros((NZ, NZ))
"""The covariance a failed location filter restarts from: its summed log-likelihood
ratio is -inf from then on, so no value is needed."""

# layout of the bank's scalar vector
_ACTIVE, _HOLD, _LAST_T, _LAST_P, _LAST_F, _COUNT, _PEND, _MODE, _LOC_P, _LOC_SIDE, _LEFT, \
    _CONF_T, _LAST_V, _LIKE_LO, _LIKE_HI, _REFINE, _REF_T, _REF_V, _PREV_T, _PREV_V, \
    _PREV_LO, _PREV_HI, _RUNNER, _RUNNER_AT = range(24)
_VEC_BEFORE_LIKE = 13
"""Length of the scalar vector in checkpoints from before the likelihood interval."""
_VEC_BEFORE_RUNNER = 22
"""Length of the scalar vector in checkpoints from before the runner-up's location."""
_VEC_LEN = 24
"""Length of the scalar vector; shorter ones are extended: before the refinement (15),
not refining, the last detection's own interval published; before the runner-up (22),
no runner-up pending."""
REFINE_EVERY = 5 * SNAP_EVERY
"""Samples between the refinement's looks at its likelihood interval (250 ms at 1 kHz)."""
GLR_BACK = 60
"""How far before the CUSUM's change time (samples) :meth:`FaultBank._glr_start` looks: the
CUSUM of filters that run through the change names it 20 samples late (measured, Csy x
0.25 at 42.5 m/s)."""
GLR_STEP = 4
"""Samples between the change times :meth:`FaultBank._glr_start` tries first, before each
sample within one such step of the best."""

_WATCH, _LOCATE = 0.0, 1.0

Searched = dict[tuple[int, float], int]
"""The change time (a count) a change-time search found for each grid it ran: keyed by
(parameter, side: -1.0 a drop, 1.0 a rise) (:meth:`FaultBank._best_search`)."""


class FaultBank:
    """The hypothesis filters, their CUSUMs and their life cycle (module docstring)."""

    def __init__(self, config: FaultBankConfig, n_params: int, fs_hz: float,
                 ar_paper: float) -> None:
        self.config = config
        self.fs_hz = float(fs_hz)
        self.ar_paper = float(ar_paper)
        self.factors = np.asarray(config.factors, dtype=float)
        self.n_hyp = N_THETA * len(self.factors)
        self.m = 1 + self.n_hyp
        self._nch = n_chunks(self.m)
        self.n_params = int(n_params)
        self.ref = np.ones(self.n_params)          # theta_ref (d,), SI (and Ar)
        self.g = np.zeros(self.n_hyp)              # CUSUMs, nats
        self.x = np.zeros((self._nch, NZ * LANES))  # filter states, lane layout
        self.P = np.zeros((self._nch, NZ * NZ * LANES))  # covariances while locating
        self.vec = np.zeros(_VEC_LEN)              # active, hold left, last detection
        self.vec[_PREV_T] = np.nan                 # no earlier published interval
        self._gains: SteadyGains | None = None
        self._phi = np.empty((self._nch, NZ * NZ * LANES))
        self._qd = np.empty_like(self._phi)
        self._taken = 0
        self._part = 0
        self._model: tuple[DiscreteBatch, NullVectors, np.ndarray, np.ndarray, float] | None \
            = None
        self.lookback = Lookback(0, 1, self.n_params)  # sized by set_model
        self._memo: tuple[bytes, tuple[tuple[np.ndarray, ...], Lookback],
                          Detection | None] | None = None   # the last location (_locate)
        # _best_search: its key, its answer, and each searched grid's change time (a count)
        self._runner_memo: tuple[object, tuple[int, float], Searched] | None = None

    # ----------------------------------------------------------------- state
    @property
    def active(self) -> bool:
        return bool(self.vec[_ACTIVE])

    @property
    def locating(self) -> bool:
        """In the location phase (a confirmed crossing, the grid summing)."""
        return self.active and self.vec[_MODE] == _LOCATE

    @property
    def refining(self) -> bool:
        """After a detection, the location grid still sums (``refine_s``)."""
        return self.locating and self.vec[_REFINE] > 0

    @property
    def busy(self) -> bool:
        """A crossing is being confirmed or a change located: the innovation monitor's
        alarm (which restarts every filter) waits for this bank's answer (not for a
        refinement: the change is decided)."""
        return self.active and ((self.vec[_MODE] == _LOCATE and not self.refining)
                                or self.vec[_PEND] > 0)

    @property
    def count(self) -> int:
        """Detections since the estimator was made."""
        return int(self.vec[_COUNT])

    def arrays(self) -> dict[str, np.ndarray]:
        """The state to checkpoint (the gains are a function of it and the speed)."""
        return {"bank_ref": self.ref, "bank_g": self.g, "bank_x": self.x, "bank_vec": self.vec,
                "bank_P": self.P, **self.lookback.arrays()}

    def load(self, arrays: dict[str, np.ndarray]) -> None:
        """Restore :meth:`arrays` output (after :meth:`set_model`): the gains are solved
        again from it, bit-identical. A checkpoint from before the exact location phase
        has no ``bank_P``: if it was locating, the grid's covariances start again there.
        One from before the likelihood interval gives its last detection the redraw range
        as its interval (the alert rule it ran with)."""
        arrays = self._upgraded(arrays)
        for key, attr in (("bank_ref", "ref"), ("bank_g", "g"), ("bank_x", "x"),
                          ("bank_vec", "vec"), ("bank_P", "P")):
            if key in arrays:
                if arrays[key].shape != getattr(self, attr).shape:
                    raise EstimatorError(f"expected {key} of shape {getattr(self, attr).shape}"
                                         f", got {arrays[key].shape}")
                setattr(self, attr, np.array(arrays[key], dtype=float))
        self.lookback.load(arrays)
        if self.active and self._model is not None:
            v0 = self._solve()
            if self.locating and "bank_P" not in arrays:
                self.P = self._start_cov(v0)

    def _upgraded(self, arrays: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """``arrays`` with a scalar vector from an older checkpoint extended: one from
        before the likelihood interval gets its last detection's redraw range as that
        interval (zeros without a detection), and one from before the refinement is not
        refining."""
        vec = arrays.get("bank_vec")
        if vec is None or vec.ndim != 1 or len(vec) >= _VEC_LEN:
            return arrays
        ext = np.zeros_like(self.vec)
        ext[:len(vec)] = vec
        if len(vec) < _VEC_BEFORE_RUNNER:
            if len(vec) == _VEC_BEFORE_LIKE and vec[_COUNT] > 0:
                ext[_LIKE_LO], ext[_LIKE_HI] = self._range_of(vec)
            ext[_REF_T], ext[_REF_V], ext[_PREV_T] = ext[_LAST_T], ext[_LAST_V], np.nan
        return {**arrays, "bank_vec": ext}

    def snapshot(self) -> tuple[tuple[np.ndarray, ...], Lookback]:
        """A copy of the whole state, gains and look-back included, for :meth:`rewind`
        (the estimator scans ahead to find where a detection falls, then steps again up
        to there)."""
        assert self._gains is not None
        gains = self._gains
        return (tuple(a.copy() for a in (self.ref, self.g, self.x, self.P, self.vec,
                                         self._phi, self._qd, gains.p_pred, gains.g,
                                         gains.s, gains.c0, gains.iters)),
                self.lookback.copy())

    def rewind(self, snap: tuple[tuple[np.ndarray, ...], Lookback]) -> None:
        """Back to a :meth:`snapshot`."""
        arrays, lookback = snap
        self.ref, self.g, self.x, self.P, self.vec, self._phi, self._qd = (
            a.copy() for a in arrays[:7])
        self._gains = SteadyGains(*(a.copy() for a in arrays[7:]))
        self.lookback = lookback.copy()

    def stop(self) -> None:
        """Idle until :meth:`start` (a filter restart, a sensor outage, a reseed)."""
        self.vec[_ACTIVE] = 0.0
        self.vec[_PEND] = 0.0
        self.vec[_MODE] = _WATCH
        self.vec[_REFINE] = 0.0
        self.g[:] = 0.0

    def start(self, theta_ref: np.ndarray, state: np.ndarray) -> None:
        """Start at the cloud's posterior mean ``theta_ref`` (d,) with every filter in the
        posterior mean ``state`` (16,) less its static-yaw component under ``theta_ref``
        (the filters run at other thetas); the CUSUMs hold for ``hold_s``."""
        self.vec[_ACTIVE] = 1.0
        self.vec[_MODE] = _WATCH
        self.vec[_REFINE] = 0.0
        self.ref = np.array(theta_ref, dtype=float).reshape(self.n_params)
        x = self._without_null(np.asarray(state, dtype=float)[None], self.ref[None])
        self.x[:] = to_lanes(np.repeat(x, self.m, 0))
        self._hold()
        self._solve()
        self.lookback.reset(x[0], self.ref)

    def _hold(self, held_s: float = 0.0) -> None:
        """The CUSUMs at 0, and held there for ``hold_s`` less ``held_s``."""
        self.g[:] = 0.0
        self.vec[_PEND] = 0.0
        self.vec[_HOLD] = round(max(0.0, self.config.hold_s - held_s) * self.fs_hz)

    def hypotheses(self) -> np.ndarray:
        """theta of every filter (m, d): the reference, then parameter-major hypotheses
        (watching) or the location grid of one parameter (locating)."""
        th = np.repeat(self.ref[None], self.m, 0)
        if self.vec[_MODE] == _LOCATE:
            th[1:, int(self.vec[_LOC_P])] *= self.locate_grid()
            return th
        for p in range(N_THETA):
            th[1 + p * len(self.factors):1 + (p + 1) * len(self.factors), p] *= self.factors
        return th

    def set_model(self, disc: DiscreteBatch, null: NullVectors, H: np.ndarray, r: np.ndarray,
                  q_unit: float) -> None:
        """The model at the current speed: the discretisation, null vectors, output
        matrix (ny, 16), measurement variances (ny,) and track intensity per unit Ar."""
        self._model = (disc, null, H, r, float(q_unit))
        self._gains = SteadyGains.empty(self._nch, len(r))
        window = round(self.config.replay_s * self.fs_hz)
        # a runner-up replays from the first confirmation's look-back, after a location
        extra = self._locate_samples(self.config.locate_max_s) if self.config.runner_up else 0
        if self.lookback.window != window or self.lookback.y.shape[1] != len(r) \
                or self.lookback.cap != Lookback.capacity(window, extra):
            self.lookback = Lookback(window, len(r), self.n_params, extra)
        if self.active:
            self._solve()
            # the look-back's samples were filtered under the last model
            self.lookback.restart(self._ref_state(), self.ref)

    def refresh(self, theta_ref: np.ndarray) -> None:
        """Follow the cloud: the reference (and every hypothesis) moves to ``theta_ref``;
        states and CUSUMs are kept. Ignored while locating (the grid is relative to the
        reference at the crossing)."""
        if self.vec[_MODE] == _LOCATE:
            return
        moving = self.active and self._model is not None
        if moving:
            # each filter's theta moves with the reference: its state loses the component
            # along its old theta's static-yaw null vector, which the new theta would turn
            # into a transient the data never had (a false CUSUM rise)
            self.x = to_lanes(self._without_null(from_lanes(self.x, self.m, (NZ,)),
                                                 self.hypotheses()))
        self.ref = np.array(theta_ref, dtype=float).reshape(self.n_params)
        if moving:
            self._solve()

    def _without_null(self, x: np.ndarray, theta: np.ndarray) -> np.ndarray:
        """States ``x`` (k, 16) less their component along the static-yaw null vectors
        of the thetas ``theta`` (k, d) they were estimated under, at the current speed
        (:func:`gateway.estimator.steady.without_null`): every hand-over to a filter at
        another theta goes through here."""
        assert self._model is not None
        return without_null(x, self._model[1](theta[:, :N_THETA]))

    def _solve(self) -> np.ndarray:
        """Every filter's discretisation and steady gains at its theta; returns their
        static-yaw null vectors (m, 16)."""
        assert self._model is not None and self._gains is not None
        disc, null, H, r, q_unit = self._model
        th = self.hypotheses()
        ar = th[:, 3] if self.n_params > N_THETA else np.full(self.m, self.ar_paper)
        disc.compute(th[:, :N_THETA], q_unit * ar, self._phi, self._qd)
        v0 = null(th[:, :N_THETA])
        steady_gains(self._phi, self._qd, to_lanes(v0), H, r, self._gains)
        return v0

    # ------------------------------------------------------------------ step
    def scan(self, Y: np.ndarray, full: np.ndarray, t0_s: float, dt_s: float
             ) -> Detection | None:
        """Step the bank over ``Y`` (k, ny) with ``full`` (k,) (False: predict only) and
        stop after the sample that completes a detection; returns it (or None: all k
        taken). Sample j has data time ``t0_s + j * dt_s``; :attr:`taken` tells how many
        samples were consumed.
        """
        k = len(Y)
        self._taken = 0
        det = None
        while det is None and self._taken < k and self.active:
            j0 = self._taken
            det = self._scan_part(Y[j0:], full[j0:], t0_s + j0 * dt_s, dt_s)
            self._taken = j0 + self._part
        self._taken = k if det is None else self._taken
        return det

    def _scan_part(self, Y: np.ndarray, full: np.ndarray, t0_s: float, dt_s: float
                   ) -> Detection | None:
        """Up to the next change of phase: a confirmed crossing starts the location
        phase (returns None, having consumed ``_part`` samples); the end of the location
        phase returns the detection."""
        assert self._gains is not None and self._model is not None
        if self.vec[_MODE] == _LOCATE:
            return self._locate_part(Y, full, t0_s, dt_s)
        k = len(Y)
        x0 = self.x.copy()
        LL, snaps = self._watch(Y, full)
        d = self._ratios(LL, full)                                        # (k, J)
        self._part = k
        hold = int(self.vec[_HOLD])
        held = min(hold, k)
        d[:held] = 0.0
        self.vec[_HOLD] = hold - held
        g_path = _cusum_path(self.g, d)                                   # (k, J)
        at = self._decision(g_path)
        if at is None:
            self.g = g_path[-1].copy()
            self._keep(Y, full, snaps)
            return None
        self.x = x0
        self._watch(Y[:at + 1], full[:at + 1])
        self._keep(Y[:at + 1], full[:at + 1], snaps)
        self._part = at + 1
        return self._locate(int(np.argmax(g_path[at])), t0_s + at * dt_s)

    def _watch(self, Y: np.ndarray, full: np.ndarray
               ) -> tuple[np.ndarray, list[tuple[int, np.ndarray]]]:
        """Every filter stepped over ``Y`` (k, ny) with the steady gains, in place: the
        log-likelihoods (k, lanes) and the reference state (16,) at each sample count
        that is a multiple of :data:`gateway.estimator.lookback.SNAP_EVERY` (count,
        state), for :meth:`_keep`."""
        lb = self.lookback
        if not lb.on:
            return self._step(Y, full), []
        LL = np.empty((len(Y), self._nch * LANES))
        snaps: list[tuple[int, np.ndarray]] = []
        c, j = lb.count, 0
        while j < len(Y):
            n = min(len(Y) - j, lb.until_snapshot(c + j))
            LL[j:j + n] = self._step(Y[j:j + n], full[j:j + n])
            j += n
            if (c + j) % SNAP_EVERY == 0:
                snaps.append((c + j, self._ref_state()))
        return LL, snaps

    def _keep(self, Y: np.ndarray, full: np.ndarray, snaps: list[tuple[int, np.ndarray]]
              ) -> None:
        """The look-back takes the watched samples ``Y`` (k, ny) with ``full`` (k,) and
        the snapshots of :meth:`_watch` up to them."""
        lb = self.lookback
        for n, x in snaps:
            if n <= lb.count + len(Y):
                lb.snapshot(n, x, self.ref)
        lb.commit(Y, full)

    def _ref_state(self) -> np.ndarray:
        """The reference filter's state (16,), as it is (its static-yaw component is
        dropped when a replay starts from it)."""
        return self.x.reshape(self._nch, NZ, LANES)[0, :, 0].copy()

    def _locate_part(self, Y: np.ndarray, full: np.ndarray, t0_s: float, dt_s: float
                     ) -> Detection | None:
        """The location phase over up to the samples it has left: the exact recursion
        (module docstring), the log-likelihood ratios summed; the detection (or None)
        at its end."""
        if self.vec[_REFINE] > 0:
            self._refine_part(Y, full)
            return None
        left = int(self.vec[_LEFT])
        n = min(len(Y), left)
        Y, full = Y[:n], full[:n]
        x0, P0 = self.x.copy(), self.P.copy()
        LL = self._step(Y, full)
        d = self._grid_ratios(LL, full)                                   # (n, J)
        self._part = n
        j = self._located_row(d, left)
        if j is None:
            self.g = _running(self.g, d)[-1]
            self.vec[_LEFT] = left - n
            self.lookback.commit(Y, full)
            return None
        if j < n - 1:                          # the early stop: the states up to it only
            self.x, self.P = x0, P0
            self._step(Y[:j + 1], full[:j + 1])
            self._part = j + 1
        self.g = _running(self.g, d[:j + 1])[-1]
        # the look-back keeps the located samples: a runner-up's replay needs them
        self.lookback.commit(Y[:j + 1], full[:j + 1])
        return self._located(t0_s + j * dt_s)

    def _step(self, Y: np.ndarray, full: np.ndarray) -> np.ndarray:
        """Every filter stepped over ``Y`` (k, ny) in place: the steady gains while
        watching, the exact recursion while locating; the log-likelihoods (k, lanes)."""
        assert self._gains is not None and self._model is not None
        LL = np.empty((len(Y), self._nch * LANES))
        if self.vec[_MODE] == _LOCATE:
            kf_block(self.x, self.P, self._phi, self._qd, self._model[2], self._model[3],
                     np.ascontiguousarray(Y), np.ascontiguousarray(full), _NO_RESET, LL,
                     np.empty_like(LL))
        else:
            kf_steady_block(self.x, self._phi, self._model[2], Y, full, self._gains, LL,
                            np.empty_like(LL))
        return LL

    def _state_of(self, filt: int) -> np.ndarray:
        """Filter ``filt``'s state (16,) less its component along the static-yaw null
        vector of its own theta: the state is taken over by filters at other thetas
        (:func:`gateway.estimator.steady.without_null`)."""
        x = self.x.reshape(self._nch, NZ, LANES)[filt // LANES, :, filt % LANES]
        return self._without_null(x[None], self.hypotheses()[filt:filt + 1])[0]

    def _locate(self, best: int, t_s: float, runner_at: int | None = None,
                searched: Searched | None = None) -> Detection | None:
        """:meth:`_locate_now`, or where the bank is in the very state it was in at the
        last call with the same arguments, that call's outcome again.

        The estimator scans the bank ahead over a block and rewinds it where the particles
        stop earlier (a resample), so the same location ran two to four times, each with
        its change-time search and replay (a 100-680 ms stall each, measured 2026-11-29).
        The key is a digest of every array the location reads; the outcome is a
        :meth:`snapshot`, which :meth:`rewind` restores bit for bit. The CUSUMs enter the
        key only through the runner-up they pick: the vectorised CUSUM's last bits depend
        on how the samples came in blocks (:func:`_cusum_path`), and the location
        restarts them."""
        key = self._memo_key(best, t_s, runner_at)
        if self._memo is not None and self._memo[0] == key:
            _, after, det = self._memo
            self.rewind(after)
            return det
        det = self._locate_now(best, t_s, runner_at, searched)
        self._memo = (key, self.snapshot(), det)
        return det

    def _memo_key(self, best: int, t_s: float, runner_at: int | None) -> bytes:
        """A digest of the arguments and of every array :meth:`_locate_now` reads: the
        bank's state and look-back, the discretisation and the measurement model."""
        assert self._model is not None
        runner = self._runner_up(best // len(self.factors)) if runner_at is None else None
        h = hashlib.sha1(repr((best, t_s, runner_at, runner)).encode())
        vec = self.vec.copy()
        vec[_LEFT] = 0.0             # set before it is read (a decided location's is stale)
        for name, a in sorted({**self.arrays(), "bank_vec": vec}.items()):
            if name != "bank_g":
                h.update(np.ascontiguousarray(a).tobytes())
        for a in (self._phi, self._qd, self._model[2], self._model[3]):
            h.update(np.ascontiguousarray(a).tobytes())
        h.update(repr(self._model[4]).encode())
        return h.digest()

    def _locate_now(self, best: int, t_s: float, runner_at: int | None = None,
                    searched: Searched | None = None) -> Detection | None:
        """A confirmed crossing by hypothesis ``best`` at data time ``t_s``: the
        hypotheses become a grid over the changed parameter on the crossing's side of
        the reference (:meth:`locate_grid`), and their log-likelihood ratios are summed
        (:meth:`_located_row`). With a look-back (``replay_s``; not for the conicity,
        :data:`CONICITY`), every grid filter starts from the reference's state at the
        snapshot :meth:`_glr_start` picks and replays the samples since; the detection
        (or None) if that sum already decides. Without one (or before the look-back has
        a snapshot), every filter starts from ``best``'s state here.

        From the watch (``located_by = "search"``), which parameter and side to locate
        is first asked of the look-back's change-time search (:meth:`_best_search`), as
        the runner-up's is: among the dampers' drops and rises for a crossing on a
        damper, among every parameter's for one on the conicity. Where one crosses
        ``h``, a damper is located from the look-back as a runner-up would be (with no
        runner-up after it), the conicity on the search's side; else the crossing's own.
        The crossing's CUSUMs name the change poorly in its first quarter second, their
        filters having run at wrong values before it: seeds 4902 and 6501 (Csy x 0.25, 3
        sensors) crossed on lambda at 35.0 and 28.7 nats where the searches summed 45.0
        and 53.5 for the Csy drop (35.7 and 19.0 for the conicity), and the conicity's
        location, which does not replay, summed up to ``locate_max_s`` undecided before
        the runner-up was asked; seed 6611 (5 sensors) crossed on a Csy *rise* at 117
        nats where the searches summed 1248 for its drop, 124 for its rise.

        From the watch (``runner_at`` None) a runner-up is kept pending
        (:meth:`_runner_up`: with ``runner_by = "replay"`` chosen by :meth:`_best_runner`
        when needed, with ``"cusum"`` the largest CUSUM on another damper): where this
        location finds no change, that damper is located next, at once, from the
        look-back's snapshots before this confirmation (``runner_at``, the look-back's
        count then). So does a damper the search picks over the crossing's parameter:
        where its location finds no change, the runner-up among the other dampers is
        searched again from the same look-back, now with the samples since, and located
        (seed 6908, Csy x 0.25, 5 sensors: the search summed 116 nats for a Csay drop a
        quarter second after the step, whose location found nothing; watching again
        from scratch put the Csy detection 2.3 s after the step, at 0.4 x its value,
        from a look-back that had lost the change). Every confirmation thus has at
        most two locations: the first, and one runner-up (for a conicity location, the
        conicity's other side where no damper's search crosses ``h``,
        :meth:`_located`).

        ``searched``: the change times a runner-up's search found at this count
        (:meth:`_best_search`); the location of one of those grids starts there without
        searching again, as a first location does after its own search."""
        p, fi = divmod(best, len(self.factors))
        pending = runner_at is None
        searched = searched or {}              # change times found at this count
        if pending and self.config.located_by == "search" \
                and self.lookback.starts(self.lookback.count):
            params = tuple(range(N_THETA)) if p == CONICITY \
                else tuple(q for q in range(N_THETA) if q != CONICITY)
            (found, _), searched = self._best_search(params, self.lookback.count)
            found -= 1
            side = np.sign(self.factors[found % len(self.factors)] - 1.0) if found >= 0 else 0
            if found >= 0 and found // len(self.factors) != p:
                # another damper: located from the look-back as a runner-up is (a
                # runner-up stays pending for it)
                best, runner_at = found, self.lookback.count
                p, fi = divmod(best, len(self.factors))
            elif side and side != np.sign(self.factors[fi] - 1.0):
                # the other side: its hypothesis whose CUSUM leads lends its state
                on_side = [i for i, f in enumerate(self.factors) if np.sign(f - 1.0) == side]
                fi = max(on_side, key=lambda i: self.g[p * len(self.factors) + i])
                best = p * len(self.factors) + fi
        self.vec[_RUNNER] = self._runner_up(p) if self.config.runner_up and pending else 0.0
        self.vec[_RUNNER_AT] = self.lookback.count if pending else 0.0
        # under its watch theta (a runner-up replays; the conicity's other side, located
        # after its first side, starts from the reference's state: the grid's filters
        # fit only their own values)
        state = self._state_of(0 if self.locating else 1 + best)
        starts = self.lookback.starts(runner_at) if p != CONICITY else []
        self.vec[_MODE], self.vec[_LOC_P] = _LOCATE, p
        self.vec[_LOC_SIDE] = -1.0 if self.factors[fi] < 1.0 else 1.0
        self.vec[_LEFT] = self._locate_samples(self.config.locate_max_s)
        self.vec[_CONF_T] = t_s
        v0 = self._solve()                     # the grid's gains and null vectors
        if starts:
            n0, xs, ref0 = self._glr_start(
                starts, searched.get((int(p), float(self.vec[_LOC_SIDE]))))
            state = self._without_null(xs[None], ref0[None])[0]
        self.x[:] = to_lanes(np.repeat(state[None], self.m, 0))
        self.g[:] = 0.0
        self.P = self._start_cov(v0, self.config.replay_cov_scale if starts else None)
        if not starts:
            return None
        Y, full = self.lookback.samples(n0)
        if len(Y) == 0:
            return None
        LL = self._step(Y, full)
        self.g = self._grid_ratios(LL, full).sum(axis=0)
        self.vec[_LEFT] = max(1, int(self.vec[_LEFT]) - len(Y))
        return self._located(t_s) if self._settled(len(Y), self.g.max()) else None

    def _runner_up(self, p: int) -> float:
        """Whether a runner-up is pending after this location of parameter ``p``: with
        ``runner_by = "replay"`` 1 where another damper exists (:meth:`_best_runner`
        picks it when it is needed); with ``"cusum"`` the watch's best hypothesis (1 + its
        index) on a damper other than ``p``, if its CUSUM is positive; 0 for none.

        A crossing says that something changed (``exp(-h)`` bounds the chance of one in a
        correct model), not always what: in the first quarter second after a large damper
        step the conicity's CUSUM can lead (seed 4902, 3 sensors, Csy x 0.25: lambda x 1.6
        at 25.8 nats, Csy x 0.25 at 10.7). Its location then finds no change, and
        watching again from scratch, with the look-back restarted after the change, put
        the damper's detection 2.7-5.3 s after it, located at 0.4 x its value. The
        runner-up's location replays from the look-back's change time, as a first
        location would, and needs the same lead over the reference."""
        nf = len(self.factors)
        others = [j for j in range(self.n_hyp) if j // nf not in (p, CONICITY)]
        if not others:
            return 0.0
        if self.config.runner_by == "replay":
            return 1.0
        j = max(others, key=lambda i: self.g[i])
        return float(j + 1) if self.g[j] > 0.0 else 0.0

    def _best_runner(self, p: int, at: int, side: float
                     ) -> tuple[tuple[int, float], Searched]:
        """The runner-up of a location of parameter ``p`` on ``side`` that found no change:
        of every other damper's drop and rise (and, after a conicity location, the
        conicity's other side), the one whose location grid, run with steady gains from
        its likeliest change time in the look-back before count ``at`` (:meth:`_glr_best`),
        sums the largest log-likelihood ratio to the reference (:meth:`_best_search`).
        Returns (1 + a
        hypothesis of that parameter on that side, the sum), or (0, h) where no sum is over
        the watch's threshold ``h`` (the runner-up must cross it on its own, as the watch's
        CUSUM would: a location of lambda x 0.7 that found no change handed a Csay rise at
        10.5 nats to its location, which put it at 1.4 x nominal, seed 6573, 3 sensors);
        with each searched grid's change time, as :meth:`_best_search` gives them.

        The watch's CUSUMs name a runner-up poorly: their filters ran at the hypotheses'
        thetas before the change, and their states, estimated under those wrong values,
        can hide the change's first evidence (seed 6501's failed lateral damper, replayed
        with 3 sensors: a quarter second after the step every Csy drop's CUSUM was at 0,
        the conicity's at 28.7, the best other one a Csay rise at 2.2; the conicity's
        location then summed 3 s undecided, and the Csay rise's found nothing, where the
        Csy drop's search summed 7341 nats at its end). The change-time search starts
        every grid filter from the reference's state before the change, as the location
        itself will (the generalised likelihood ratio over the damper, the side and the
        change time).

        The conicity's other side competes with the dampers since the nineteenth session:
        a conicity drop whose first transient read as a rise (the rise's location found
        nothing) handed the runner-up to a Csay rise whose search crossed ``h`` though the
        drop's summed more (seed 7091, 3 sensors, lambda x 0.5: 45.6 against 92.3 nats);
        the Csay rise was located at 1.7 x, a wrong detection, and the drop found 2.7 s
        later."""
        if p == CONICITY:
            return self._best_search(tuple(range(N_THETA)), at, skip=(CONICITY, side))
        return self._best_search(tuple(q for q in range(N_THETA) if q not in (p, CONICITY)),
                                 at)

    def _best_search(self, params: tuple[int, ...], at: int,
                     skip: tuple[int, float] | None = None
                     ) -> tuple[tuple[int, float], Searched]:
        """Of the drop and rise of each parameter in ``params``, the one whose location
        grid's change-time search over the look-back before count ``at`` (not empty: the
        callers check) sums the largest log-likelihood ratio to the reference: (1 + a
        hypothesis of that parameter on that side, the sum), or (0, h) where no sum is
        over the watch's threshold ``h``; and the change time (a count) the search found
        for each parameter and side, where a location of one of them from the same
        look-back at the same count starts without searching again (:meth:`_glr_start`).
        The bank's state is as it was. ``skip``: a parameter and side left out (a
        location that found nothing). Computed once per state, ``params`` and ``skip``
        (the estimator rescans). Every grid tries the change times near each searched
        grid's Page start, its own and the others' (one change, however named; since
        2026-11-30's twentieth session, :meth:`_glr_best`)."""
        key = (self._memo_key(-1, 0.0, at), params, skip)
        if self._runner_memo is not None and self._runner_memo[0] == key:
            return self._runner_memo[1], self._runner_memo[2]
        starts = self.lookback.starts(at)
        x0, vec0 = self.x.copy(), self.vec.copy()
        best = (0, self.config.h_nats)
        counts: Searched = {}
        grids = [(q, side) for q in params for side in (-1.0, 1.0) if (q, side) != skip]
        Y, full = self.lookback.samples(starts[0][0])
        pages: list[int] = []
        for q, side in grids:                   # one change: every grid's Page start
            self.vec[_MODE], self.vec[_LOC_P], self.vec[_LOC_SIDE] = _LOCATE, q, side
            self._solve()
            pages.append(self._page_start(starts, Y, full))
        for q, side in grids:
            self.vec[_MODE], self.vec[_LOC_P], self.vec[_LOC_SIDE] = _LOCATE, q, side
            self._solve()
            counts[(q, side)], total = self._glr_best(starts, pages)
            if total > best[1]:
                best = (1 + self._outermost(q, side), total)
        self.x, self.vec = x0, vec0
        self._solve()
        self._runner_memo = (key, best, counts)
        return best, counts

    def _outermost(self, p: int, side: float) -> int:
        """The watch's hypothesis of parameter ``p`` furthest out on ``side`` (< 0 a drop,
        > 0 a rise): what a location of that parameter and side is named by."""
        fi = int(np.argmin(self.factors) if side < 0 else np.argmax(self.factors))
        return p * len(self.factors) + fi

    def _ratios(self, LL: np.ndarray, full: np.ndarray) -> np.ndarray:
        """Each hypothesis's log-likelihood ratio to the reference (k, J) from the
        filters' log-likelihoods ``LL`` (k, lanes); 0 where ``full`` (k,) is False."""
        return np.where(full[:, None], LL[:, 1:self.m] - LL[:, :1], 0.0)

    def _grid_ratios(self, LL: np.ndarray, full: np.ndarray) -> np.ndarray:
        """:meth:`_ratios` while locating: a failed filter (or reference) loses."""
        d = self._ratios(LL, full)
        d[~np.isfinite(d)] = -np.inf
        return d

    def _settled(self, n: np.ndarray | int, lead: np.ndarray | float) -> np.ndarray:
        """Whether a location with ``n`` samples summed and its best value ``lead``
        nats ahead of the reference is decided without the early stop: ``locate_s``
        summed, and the best value ahead by ``h / 2`` (a change) or not ahead at all
        (none). Elementwise."""
        return np.logical_and(
            np.asarray(n) >= self._locate_samples(self.config.locate_s),
            np.logical_or(np.asarray(lead) > self.config.h_nats / 2.0,
                          np.logical_not(np.asarray(lead) > 0.0)))

    def _glr_start(self, starts: list[tuple[int, np.ndarray, np.ndarray]],
                   change_at: int | None = None) -> tuple[int, np.ndarray, np.ndarray]:
        """The generalised likelihood ratio's change time (Willsky and Jones 1976) and the
        reference's state there: (count, reference state (16,), its theta). ``starts``
        are the look-back's snapshots (count, reference state, its theta; oldest
        first). From each candidate start the location grid, run with steady gains from
        the reference's state there (:meth:`_ref_at`), sums a log-likelihood ratio of
        each grid value to the reference (:meth:`_glr_sum`); the start whose largest sum
        is largest wins. Samples before a change count against every grid value, and a
        start after it inherits a state estimated under the old value.

        The candidates are the snapshots, :data:`SNAP_EVERY` samples apart, and the
        samples up to :data:`GLR_BACK` before the change time that Page's CUSUM of the
        grid gives (:meth:`_page_start`), every :data:`GLR_STEP`-th and then each sample
        within a step of the best. Near a large change the sum falls by thousands of
        nats within a few samples either side (measured: Csy x 0.25 at 42.5 m/s, 5
        sensors, 3566 nats from the change's sample, 835 four samples later, -124 at
        24), so on snapshots alone a change between two of them was located at 1.3-1.8
        x its value, and one on a snapshot at 1.2 x. Called in the location phase's
        mode, with the grid's steady gains solved, before its filters start.
        ``change_at``: the change time a search at this count (:meth:`_best_search`: the
        confirmation's, or a runner-up's) found for this grid from the same ``starts``,
        which this search would find again (None: search)."""
        assert self._gains is not None and self._model is not None
        n_first = starts[0][0]
        Y, full = self.lookback.samples(n_first)
        if len(Y) == 0:                       # nothing to replay: the newest snapshot
            n, xs, ref0 = starts[-1]
            return n, self._without_null(xs[None], ref0[None])[0], ref0
        best = self._glr_best(starts)[0] if change_at is None else change_at
        x, ref0 = self._ref_at(starts, best, Y, full)
        return best, x[0], ref0

    def _glr_best(self, starts: list[tuple[int, np.ndarray, np.ndarray]],
                  pages: Sequence[int] = ()) -> tuple[int, float]:
        """The change-time search of :meth:`_glr_start`: the likeliest change time (a
        count) and the location grid's largest summed log-likelihood ratio from it to the
        end of the look-back (-inf: nothing to replay). ``pages``: the Page starts of
        every grid a search compares (:meth:`_best_search`), each tried as this grid's own
        is (none: this grid's alone).

        The change is one, whichever grid names it, and a grid's own Page start can miss
        it: seed 6611 (Csy x 0.25 at 8.025 s, 5 sensors, filter seed 1), searched 252
        samples after the step, the Csy drop's Page CUSUM restarted 227 samples after the
        step, its sum from the step's sample was 1128 nats but 294 and 235 five samples
        either side and at most 36 elsewhere it looked, so the search summed 10.5 for
        it, and a Csay drop (276 nats from a Page start 4 samples before the step) was
        located at 0.92 x, a wrong detection, the Csy drop detected 3 s after the step
        (on 4 of 8 filter seeds of that record: 1, 2, 3, 7)."""
        assert self._gains is not None and self._model is not None
        n_first = starts[0][0]
        Y, full = self.lookback.samples(n_first)
        if len(Y) == 0:
            return starts[-1][0], -np.inf
        end = n_first + len(Y)
        sums: dict[int, float] = {}

        def best_of(cands: Iterable[int]) -> int:
            for c in cands:
                if n_first <= c < end and c not in sums:
                    x, _ = self._ref_at(starts, c, Y, full)
                    sums[c] = self._glr_sum(x, Y[c - n_first:], full[c - n_first:])
            return max(sums, key=lambda c: (sums[c], -c))

        pages = pages or (self._page_start(starts, Y, full),)
        best_of([n for n, _, _ in starts])
        coarse = best_of(c for page in sorted(set(pages))
                         for c in range(page - GLR_BACK, page + GLR_STEP, GLR_STEP))
        best = best_of(range(coarse - GLR_STEP + 1, coarse + GLR_STEP))
        return best, sums[best]

    def _page_start(self, starts: list[tuple[int, np.ndarray, np.ndarray]], Y: np.ndarray,
                    full: np.ndarray) -> int:
        """The change time to the sample (a count): every grid filter runs with steady
        gains from the oldest snapshot's reference state over the look-back ``Y`` (k, ny),
        ``full`` (k,), Page's CUSUM of each against the reference follows, and the grid
        value whose CUSUM ends highest names the count after its last zero (the CUSUM's
        own estimate of when its run began)."""
        assert self._gains is not None and self._model is not None
        n_first = starts[0][0]
        if len(Y) == 0:
            return n_first
        x, _ = self._ref_at(starts, n_first, Y, full)
        d = self._grid_ratios(self._steady_from(x, Y, full), full)
        d[~np.isfinite(d)] = -1e300
        g = _cusum_path(np.zeros(d.shape[1]), d)
        zero = np.flatnonzero(g[:, int(np.argmax(g[-1]))] <= 0.0)
        return n_first + (int(zero[-1]) + 1 if len(zero) else 0)

    def _ref_at(self, starts: list[tuple[int, np.ndarray, np.ndarray]], c: int,
                Y: np.ndarray, full: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The reference's state (1, 16) at count ``c`` less its static-yaw component,
        and its theta: the newest snapshot at or before ``c``, stepped on to ``c`` by the
        reference filter with steady gains, as the watch did. ``Y``, ``full``: the
        look-back's samples from ``starts[0]``'s count."""
        assert self._gains is not None and self._model is not None
        n, xs, ref0 = max((s for s in starts if s[0] <= c), key=lambda s: s[0])
        x = self._without_null(xs[None], ref0[None])
        if c > n:
            k0 = starts[0][0]
            self._steady_from(x, Y[n - k0:c - k0], full[n - k0:c - k0])
            x = self._without_null(self.x.reshape(self._nch, NZ, LANES)[0, :, 0][None],
                                   ref0[None])
        return x, ref0

    def _glr_sum(self, x: np.ndarray, Y: np.ndarray, full: np.ndarray) -> float:
        """The location grid's largest summed log-likelihood ratio to the reference over
        ``Y`` (k, ny) with ``full`` (k,), every filter started from the state ``x``
        (1, 16) with steady gains; -inf for no samples."""
        assert self._gains is not None and self._model is not None
        if len(Y) == 0:
            return -np.inf
        return float(np.max(self._ratios(self._steady_from(x, Y, full), full).sum(axis=0)))

    def _steady_from(self, x: np.ndarray, Y: np.ndarray, full: np.ndarray) -> np.ndarray:
        """Every filter started from the state ``x`` (1, 16) and stepped with steady gains
        over ``Y`` (k, ny), ``full`` (k,), in place: the log-likelihoods (k, lanes)."""
        assert self._gains is not None and self._model is not None
        self.x[:] = to_lanes(np.repeat(x, self.m, 0))
        LL = np.empty((len(Y), self._nch * LANES))
        kf_steady_block(self.x, self._phi, self._model[2], Y, full, self._gains, LL,
                        np.empty_like(LL))
        return LL

    def _start_cov(self, v0: np.ndarray | None = None, scale: float | None = None
                   ) -> np.ndarray:
        """The location grid's starting covariances (lane layout): ``scale`` (None:
        ``locate_cov_scale``) times each filter's steady updated covariance at its own
        theta (module docstring), from the gains and null vectors ``v0`` (m, 16) of
        :meth:`_solve` (None: solved here)."""
        assert self._gains is not None and self._model is not None
        _, null, H, r, _ = self._model
        if v0 is None:
            v0 = null(self.hypotheses()[:, :N_THETA])
        scale = self.config.locate_cov_scale if scale is None else scale
        P = steady_posterior(self._gains, v0, H, r, self.m) * scale
        return to_lanes(P.reshape(self.m, NZ * NZ))

    def locate_grid(self, side: float | None = None) -> np.ndarray:
        """The location phase's factors (J,): log-spaced from half the smallest factor
        to 0.9 (a drop, ``side`` < 0), or from 1/0.9 to twice the largest (a rise);
        ``side`` defaults to that of the current location phase."""
        if (self.vec[_LOC_SIDE] if side is None else side) < 0:
            lo, hi = float(self.factors.min()) / 2.0, 0.9
        else:
            lo, hi = 1.0 / 0.9, 2.0 * float(self.factors.max())
        return np.geomspace(lo, hi, self.n_hyp)

    def _located_row(self, d: np.ndarray, left: int) -> int | None:
        """The sample of this block, with log-likelihood ratios ``d`` (k, J), that ends
        the location phase, or None (``left`` samples were left before this block). The
        first sample where, with ``n`` samples summed:

        - ``n >= locate_min_s`` (the early stop): the best value beats the reference by
          ``h / 2`` and every grid value three or more steps away by ``h / 2``;
        - ``n >= locate_s``: the best value beats the reference by ``h / 2`` (a
          detection) or does not beat it at all (no change);
        - ``n`` reaches ``locate_max_s``.

        Between ``locate_s`` and ``locate_max_s`` the sum goes on only while the best
        value is ahead by less than ``h / 2``: for a correct model ``exp(-h / 2)`` bounds
        the chance that a wrong value ever leads the truth by that much (Wald), so a
        later look costs no more false detections than the first."""
        k, half = min(left, len(d)), self.config.h_nats / 2.0
        done = self._locate_samples(self.config.locate_max_s) - left
        n_min = round(self.config.locate_min_s * self.fs_hz)
        n_loc = self._locate_samples(self.config.locate_s)
        first = max(0, min(n_min, n_loc) - done - 1)
        if first < k:                         # a stop can fire in this block
            rows = _running(self.g, d[:k])[first:]
            n = done + first + 1 + np.arange(len(rows))
            best = np.argmax(rows, axis=1)
            lead = rows[np.arange(len(rows)), best]
            idx = np.arange(rows.shape[1])
            far = np.abs(idx[None] - best[:, None]) >= REDRAW_STEPS
            runner = np.where(far, rows, -np.inf).max(axis=1)
            early = (n >= n_min) & (lead > half) & (lead - runner >= half)
            settled = self._settled(n, lead)
            stop = np.nonzero(early | settled)[0]
            if len(stop):
                return first + int(stop[0])
        return left - 1 if left <= k else None

    def _locate_samples(self, seconds: float) -> int:
        """Samples in ``seconds`` of location phase (at least one)."""
        return max(1, round(seconds * self.fs_hz))

    def _located(self, t_s: float) -> Detection | None:
        """The location phase's answer: the best grid value, if it beats the reference
        by ``h_nats / 2`` over ``locate_s``; else no change on that side, and the pending
        runner-up is located next (:meth:`_locate_now`), or the bank watches again.

        A conicity location's runner-up is, of the dampers and the conicity's other side,
        the one whose change-time search sums the most over ``h`` (:meth:`_best_runner`;
        since the nineteenth session, before it the dampers only); where none crosses
        ``h``, the conicity on its other side all the same. That side starts from the
        reference's state here (the conicity does not replay, :data:`CONICITY`). A
        conicity drop's first transient can favour a rise: on the seventeenth session's
        fresh seeds both the crossing and the search named lambda x 0.7 a rise (seed
        6952, 5 sensors: 500 and 374 nats), the rise's location found nothing, and the
        drop was found only after watching again, +4.1-4.4 s median after the step, 2 of
        8 never with 3 sensors (seeds 6950, 6951); with the other side located next,
        seeds 6950-6952 (3 sensors) were found at +2.25 s, each likelihood interval
        holding the truth."""
        grid = self.locate_grid()
        best = int(np.argmax(self.g))
        p = int(self.vec[_LOC_P])
        if not self.g[best] > self.config.h_nats / 2.0:
            runner, at = int(self.vec[_RUNNER]) - 1, int(self.vec[_RUNNER_AT])
            searched: Searched = {}
            if runner >= 0 and self.config.runner_by == "replay" and self.lookback.starts(at):
                (runner, _), searched = self._best_runner(p, at, float(self.vec[_LOC_SIDE]))
                runner -= 1
            pending = self.vec[_RUNNER] > 0    # a first location: a runner-up may follow
            self.vec[_RUNNER] = 0.0
            if runner >= 0 and self.lookback.starts(at):
                # the change was not where the crossing pointed: the runner-up next
                return self._locate(runner, t_s, runner_at=at, searched=searched)
            if pending and p == CONICITY:
                # no search crossed h (the other side's either): that side, from here
                return self._locate(self._outermost(p, -self.vec[_LOC_SIDE]), t_s,
                                    runner_at=self.lookback.count)
            # no change: every filter restarts from the reference's state (consistent
            # with theta_ref), as at a start; the grid's states fit only their own values
            self._watch_again(self._state_of(0))
            return None
        det = Detection(parameter=p, factor=float(grid[best]), t_s=t_s,
                        reference=float(self.ref[p]), state=self._state_of(1 + best),
                        confirmed_s=float(self.vec[_CONF_T]),
                        step=float(grid[1] / grid[0]), grid=grid, llr=self.g.copy())
        self.vec[_LAST_T], self.vec[_LAST_P], self.vec[_LAST_F] = t_s, p, det.factor
        self.vec[_LAST_V] = det.factor * det.reference
        self.vec[_COUNT] += 1
        self._publish(t_s, self.vec[_LAST_V], self.likely_range(det))
        if self.config.refine_s > 0:
            self.vec[_REFINE] = self._locate_samples(self.config.refine_s)
            return det
        # the bank restarts around the located value; the estimator refreshes theta_ref
        self._watch_again(det.state)
        return det

    def _watch_again(self, state: np.ndarray, held_s: float = 0.0) -> None:
        """Back to watching, every filter in ``state`` (16,), the CUSUMs held for what
        is left of ``hold_s`` after ``held_s`` (s) since the detection."""
        self.vec[_MODE] = _WATCH
        self.vec[_REFINE] = 0.0
        self.x[:] = to_lanes(np.repeat(state[None], self.m, 0))
        self._hold(held_s)
        self._solve()
        self.lookback.restart(state, self.ref)

    def _refine_part(self, Y: np.ndarray, full: np.ndarray) -> None:
        """The refinement over up to the samples it has left: the location grid sums on
        (the exact recursion), and every :data:`REFINE_EVERY` samples its likelihood
        interval is published again where it changed (:meth:`_refined`); at its end the
        bank watches again about the best value."""
        left = int(self.vec[_REFINE])
        n = min(len(Y), left)
        rows = _running(self.g, self._grid_ratios(self._step(Y[:n], full[:n]), full[:n]))
        done = self._locate_samples(self.config.refine_s) - left
        for i in np.flatnonzero((done + 1 + np.arange(n)) % REFINE_EVERY == 0):
            # the look's data time from the detection's, by its sample count: the same
            # bits whether the samples came one by one or in a block
            self._refined(rows[i], float(self.vec[_LAST_T]) + (done + 1 + i) / self.fs_hz)
        if n:
            self.g = rows[-1].copy()
        self.vec[_REFINE] = left - n
        self._part = n
        if left - n <= 0:
            best = int(np.argmax(self.g))
            state = self._state_of(1 + best)
            p = int(self.vec[_LOC_P])
            if np.isfinite(self.g[best]):
                self.ref[p] *= self.locate_grid()[best]
            # the hold after a detection lets the redrawn cloud settle: the refinement's
            # time counts towards it, so the watch is off no longer than without one
            self._watch_again(state, held_s=self.config.refine_s)

    def _refined(self, llr: np.ndarray, t_s: float) -> None:
        """A look at the refinement's sums ``llr`` (J,) at data time ``t_s``: where the
        likelihood interval or the best value moved, they are the latest located change
        (:meth:`located_before`; the alert policy acts on each once)."""
        if not np.isfinite(llr.max()):
            return
        grid, p = self.locate_grid(), int(self.vec[_LOC_P])
        lo, hi = self._likely(grid, float(self.ref[p]), llr)
        value = float(grid[int(np.argmax(llr))] * self.ref[p])
        if (lo, hi, value) != (self.vec[_LIKE_LO], self.vec[_LIKE_HI], self.vec[_REF_V]):
            self._publish(t_s, value, (lo, hi))

    def _publish(self, t_s: float, value: float, like: tuple[float, float]) -> None:
        """The latest located change is ``value`` with interval ``like`` from data time
        ``t_s``; the one before it stays readable (:meth:`located_before`)."""
        v = self.vec
        v[_PREV_T], v[_PREV_V], v[_PREV_LO], v[_PREV_HI] = (v[_REF_T], v[_REF_V],
                                                           v[_LIKE_LO], v[_LIKE_HI])
        v[_REF_T], v[_REF_V] = t_s, value
        v[_LIKE_LO], v[_LIKE_HI] = like

    def _decision(self, g_path: np.ndarray) -> int | None:
        """The row of ``g_path`` (k, J) at which a detection is decided, or None.

        A crossing of ``h_nats`` is confirmed ``confirm_s`` later if some CUSUM is then
        still above it (the first samples after a change can favour a hypothesis on
        another parameter); the decision may fall in a later call (``_PEND``).
        """
        k, h = len(g_path), self.config.h_nats
        pend, start = int(self.vec[_PEND]), 0
        confirm = int(round(self.config.confirm_s * self.fs_hz))
        while start < k:
            if pend == 0:
                over = np.nonzero((g_path[start:] > h).any(axis=1))[0]
                if len(over) == 0:
                    break
                decide = start + int(over[0]) + confirm
            else:
                decide = start + pend - 1
            pend = 0
            if decide >= k:
                pend = decide - k + 1
                break
            if g_path[decide].max() > h:
                self.vec[_PEND] = 0
                return decide
            start = decide + 1
        self.vec[_PEND] = pend
        return None

    @property
    def taken(self) -> int:
        """Samples consumed by the last :meth:`scan`."""
        return self._taken

    def redraw(self, det: Detection, rng: np.random.Generator, n: int
               ) -> tuple[np.ndarray, np.ndarray]:
        """New log values (n,) of the detected parameter and their log weights (n,).

        ``redraw_from = "range"``: log-uniform over :meth:`redraw_range`, equal weights.
        ``"likelihood"``: the grid's summed likelihood as a density in log theta, constant
        over each grid value's cell (half a step either side; the end cells reach
        :data:`REDRAW_STEPS` steps beyond the grid, as the redraw range may), drawn for all
        but :data:`DEFENSIVE_SHARE` of the particles, the rest log-uniform over the redraw
        range; each weighted by that density over the mixture's, so the weighted cloud
        follows the likelihood."""
        lo, hi = self.redraw_range(det)
        if self.config.redraw_from == "range":
            return (draw_log_uniform(rng, np.array([lo]), np.array([hi]), n)[:, 0],
                    np.zeros(n))
        half = 0.5 * np.log(det.step)
        mid = np.log(det.grid * det.reference)
        edges = np.concatenate(([mid[0] - REDRAW_STEPS * 2 * half], mid[:-1] + half,
                                [mid[-1] + REDRAW_STEPS * 2 * half]))
        n_wide = int(round(DEFENSIVE_SHARE * n))
        z = np.concatenate((draw_log_cells(rng, edges, det.llr, n - n_wide),
                            draw_log_uniform(rng, np.array([lo]), np.array([hi]),
                                             n_wide)[:, 0]))
        p = log_cell_density(z, edges, det.llr)
        wide = np.where((z >= np.log(lo)) & (z <= np.log(hi)),
                        -np.log(np.log(hi / lo)), -np.inf)
        q = np.logaddexp(np.log1p(-DEFENSIVE_SHARE) + p, np.log(DEFENSIVE_SHARE) + wide)
        return z, p - q

    @staticmethod
    def redraw_range(det: Detection) -> tuple[float, float]:
        """The values (lo, hi) over which the detected parameter is redrawn: three grid
        steps either side of the located value."""
        return _around(det.factor * det.reference, det.step)

    def last_range(self) -> tuple[float, float] | None:
        """The range (lo, hi) the latest detection redrew its parameter over
        (:meth:`redraw_range`), in the parameter's unit, or None."""
        if self.count == 0:
            return None
        return self._range_of(self.vec)

    def _range_of(self, vec: np.ndarray) -> tuple[float, float]:
        """The redraw range of the last detection in the scalar vector ``vec``."""
        grid = self.locate_grid(side=-1.0 if vec[_LAST_F] < 1.0 else 1.0)
        return _around(float(vec[_LAST_V]), float(grid[1] / grid[0]))

    def likely_range(self, det: Detection) -> tuple[float, float]:
        """The values (lo, hi) the location cannot tell from its best one: those whose
        summed log-likelihood ratio is within :data:`LIKELY_NATS` of the best grid
        value's. Each end lies between the last grid value inside and the first outside
        (where the sum is known to trail by that much or more), where the slower-falling
        of the last value's two secants, extended, reaches that level
        (:func:`_likely_edge`): where the sum is concave there, or convex, every value
        beyond trails by more, and for a sum Gaussian in log theta the end is near the
        true one instead of up to a grid step (15 %) beyond it. Past the grid's
        old-value end the interval ends at the old value (which the location beat by
        ``h / 2``, more than :data:`LIKELY_NATS`); past its far end nothing was summed,
        so 0 or infinity. For a likelihood Gaussian in log theta a value outside is
        4 sigma or more from the best, and the alert policy raises at once only on a
        threshold this whole interval is past (docs/alerts.md, "Located changes")."""
        return self._likely(det.grid, det.reference, det.llr)

    @staticmethod
    def _likely(grid: np.ndarray, reference: float, llr: np.ndarray) -> tuple[float, float]:
        """:meth:`likely_range` of a grid of factors ``grid`` (J,), ascending, about
        ``reference`` with summed log-likelihood ratios ``llr`` (J,)."""
        values = grid * reference
        level = llr.max() - LIKELY_NATS
        inside = np.nonzero(llr >= level)[0]
        i0, i1 = int(inside[0]), int(inside[-1])
        drop = grid[-1] < 1.0
        below = reference if not drop else 0.0
        above = reference if drop else np.inf
        return (_likely_edge(values, llr, level, i0, -1) if i0 > 0 else below,
                _likely_edge(values, llr, level, i1, +1) if i1 + 1 < len(values) else above)

    def last_likely(self) -> tuple[float, float] | None:
        """The latest detection's :meth:`likely_range`, in the parameter's unit, or
        None."""
        if self.count == 0:
            return None
        return float(self.vec[_LIKE_LO]), float(self.vec[_LIKE_HI])

    def located_before(self, t_s: float) -> tuple[float, float, float, float] | None:
        """(data time, value, likely lo, likely hi; in the parameter's unit) of the latest
        located change published before data time ``t_s``: the detection's, or a look of
        its refinement that moved its interval; None before any. The one before the
        latest counts where the latest came at ``t_s`` or later: an estimate is
        summarised before the bank takes its own sample, and a block's last sample may
        be a look."""
        v = self.vec
        if self.count == 0:
            return None
        before = t_s - 0.5 / self.fs_hz          # half a sample: robust to rounding
        if v[_REF_T] < before:
            return float(v[_REF_T]), float(v[_REF_V]), float(v[_LIKE_LO]), float(v[_LIKE_HI])
        if v[_PREV_T] < before:
            return float(v[_PREV_T]), float(v[_PREV_V]), float(v[_PREV_LO]), float(v[_PREV_HI])
        return None

    def last(self) -> tuple[float, int, float, float] | None:
        """(data time, parameter index, located value, time the crossing was confirmed)
        of the latest detection, or None."""
        if self.count == 0:
            return None
        return (float(self.vec[_LAST_T]), int(self.vec[_LAST_P]), float(self.vec[_LAST_V]),
                float(self.vec[_CONF_T]))


def _around(value: float, step: float) -> tuple[float, float]:
    """(lo, hi): :data:`REDRAW_STEPS` grid steps of ratio ``step`` either side of ``value``."""
    return value / step**REDRAW_STEPS, value * step**REDRAW_STEPS


def _running(g0: np.ndarray, d: np.ndarray) -> np.ndarray:
    """The sums ``g0 + d_1 + ... + d_t`` (k, J) for every row of ``d`` (k, J), added one
    sample at a time, so that the location's sums, which the likelihood redraw reads, are
    the same bits whichever blocks the samples came in."""
    return np.cumsum(np.concatenate((g0[None], d)), axis=0)[1:]


def _cusum_path(g0: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Page's CUSUM ``g_t = max(0, g_{t-1} + d_t)`` for every column at once: with
    ``T_t = g0 + sum d``, ``g_t = T_t - min(0, min_{s<=t} T_s)`` (Lindley). (k, J)."""
    T = g0[None] + np.cumsum(d, axis=0)
    return T - np.minimum(np.minimum.accumulate(T, axis=0), 0.0)


def _likely_edge(values: np.ndarray, llr: np.ndarray, level: float, i: int, out: int
                 ) -> float:
    """Where the likelihood interval ends beyond the grid value ``values[i]`` (inside:
    ``llr[i] >= level``), going ``out`` (+1 up, -1 down) towards ``values[i + out]``
    (outside: ``llr[i + out] < level``). Of the two secants at ``values[i]`` (from its
    inner neighbour ``values[i - out]``, and to ``values[i + out]``; linear in log
    theta), the one that falls more slowly, extended from ``values[i]``, reaches
    ``level`` at the end. Where the sum is concave over the three values that is the
    inner secant, which bounds the sum beyond it from above; where it is convex between
    the last two, the outer one (the chord), which bounds it there: either way the sum
    is at or below ``level`` past the end. Without an inner neighbour, or where the sum
    does not fall from it, the end is ``values[i + out]``."""
    j, k = i + out, i - out
    if not 0 <= k < len(values) or not llr[k] > llr[i]:
        return float(values[j])
    u_i, u_k, u_j = np.log(values[i]), np.log(values[k]), np.log(values[j])
    fall_per_log = min((llr[k] - llr[i]) / abs(u_i - u_k), (llr[i] - llr[j]) / abs(u_j - u_i))
    reach = (llr[i] - level) / fall_per_log
    if reach >= abs(u_j - u_i):
        return float(values[j])
    return float(np.exp(u_i + out * reach))
