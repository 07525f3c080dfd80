"""The start of a run that checks the model's sensor noise against the data.

:class:`NoiseCheckedStart` is an :class:`gateway.records.Estimator` around an
:class:`gateway.estimator.rbpf.RBPF`. From the first sample with data (an update with
a sensor's value: a gateway that boots at standstill waits for the train to move),
for ``window_s`` it runs the filter as configured, keeps the samples, and the filter's
checkpoint from before them. Then it measures each sensor's white-noise variance
in the band above the vehicle's dynamics (:mod:`gateway.estimator.noisefloor`) and tests
it against the variance the filter assumed:

- where every sensor agrees (the usual case), it goes on with the same filter: the run is
  the plain filter's, bit for bit;
- where a sensor's measured variance differs by more than ``Z_REJECT`` standard errors
  (and more than ``MIN_LOG_RATIO``), it restores that checkpoint with the measured
  variances for those sensors and replays the kept samples (and any filter restart or
  parameter reset among them) through it. Estimates from then on are the new filter's.
  The replay costs about 5 s of filtering once (1-2.5 s at m = 1000 in fast mode).

Estimates made before the test are ``provisional``: the alert policy does not judge
them (with the sensors 2 x noisier than the model, the untested filter's λ reached
+55 % within those seconds and raised an ADVISORY), unless a first look after
``INTERIM_S`` found every sensor's variance within ``TRUST_FACTOR`` of the model's.

The test's standard error is the measurement's own plus ``MODEL_REL`` of the model's
signal subtracted in the band (that signal depends on θ, the speed and the track).
A measured variance below 1/``PLAUSIBLE`` or above ``PLAUSIBLE`` times the model's
(e.g. a low-pass filter in front, a dead sensor) changes nothing and is reported.

After the test the checkpoint is the filter's own (its configuration carries the
variances), so a restart keeps them. Before it, the checkpoint holds the kept samples
too. No I/O, no clock.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable
from dataclasses import replace

import numpy as np

from gateway.errors import EstimatorError
from gateway.estimator import checkpoint as ckpt
from gateway.estimator.noisefloor import (
    BandVariance,
    band_variance,
    complete_samples,
    model_band_variance,
    segment_starts,
)
from gateway.estimator.rbpf import RBPF, RBPFConfig, config_of_checkpoint
from gateway.records import Estimate, NoiseCheck, Sample

MAGIC = b"RAILGW-NOISE-START-1\n"
WINDOW_S = 5.0
"""Data kept and measured before the test (3-4 % standard error per sensor at 1 kHz)."""
Z_REJECT = 4.0
"""Standard errors by which a measured variance must differ to replace the model's."""
MIN_LOG_RATIO = math.log(1.1)
"""...and at least this (10 % in variance, 5 % in std)."""
MODEL_REL = 0.25
"""Relative uncertainty of the model's own signal in the band, subtracted."""
PLAUSIBLE = 100.0
"""A measured/model variance ratio outside [1/PLAUSIBLE, PLAUSIBLE] changes nothing."""
MIN_TEST_SEGMENTS = 16
"""Complete segments (of 0.256 s, half overlapping) the test needs: about 2 s of
usable data; with fewer it waits for the next window."""
INTERIM_S = 2.0
"""A first look after this much data: where no sensor's band variance is off by more
than ``TRUST_FACTOR``, estimates stop being provisional (the test itself still comes at
the window's end)."""
TRUST_FACTOR = 1.5
"""A variance this far off (1.22 x in std) moves λ by about 8 % in seconds, far from
the alert thresholds (λ +60 %, dampers -25 %); 4 x (2 x in std) moved it +55 %."""
GIVE_UP_WINDOWS = 4
"""With too few complete segments after this many windows, keep the model's."""
_RESTART, _RESET = -1, -2


def decide(model_var: np.ndarray, band: np.ndarray, signal: np.ndarray,
           se_rel: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The variances to use (ny,), which were replaced (ny,) bool, and the test's
    relative standard errors (ny,), from the model's ``model_var``, the band's
    ``band`` and the model's ``signal`` in it, and the band's ``se_rel``."""
    noise = band - signal
    with np.errstate(divide="ignore", invalid="ignore"):
        se = np.sqrt(se_rel**2 + (MODEL_REL * signal / np.maximum(noise, 1e-300))**2)
        ratio = noise / model_var
    plausible = (ratio > 1.0 / PLAUSIBLE) & (ratio < PLAUSIBLE)
    log_r = np.log(np.where(plausible, ratio, 1.0))
    replace_ = plausible & (np.abs(log_r) > np.maximum(MIN_LOG_RATIO, Z_REJECT * se))
    return np.where(replace_, noise, model_var), replace_, se


def _usable(sample: Sample) -> bool:
    """A sample the filter learns from: an update with a sensor's value. (Until
    2026-11-27 every sensor's: with a sensor dead from boot the test never began, and
    every estimate stayed provisional, so no alert was ever judged. Now the test measures
    the sensors in use, a dead one left out (:meth:`NoiseCheckedStart._values`), and
    without complete data it gives up after ``GIVE_UP_WINDOWS`` windows, saying why.)"""
    return bool(sample.update) and bool(np.any(np.isfinite(sample.values)))


def _with_noise(blob: bytes, noise_var: tuple[float, ...]) -> bytes:
    """An RBPF checkpoint with the configuration's sensor-noise variances replaced (for a
    filter that has used no data yet, the state a filter with them would have: R enters
    only through the updates and the gains, which a restore recomputes: kept steady gains
    are dropped, since they were solved with the old variances)."""
    meta, arrays = ckpt.unpack(blob)
    meta["config"]["noise_var"] = list(noise_var)
    return ckpt.pack(meta, {k: v for k, v in arrays.items() if not k.startswith("gains_")})


class NoiseCheckedStart:
    """An RBPF whose first ``window_s`` tests its sensor noise against the data."""

    def __init__(self, config: RBPFConfig, window_s: float = WINDOW_S) -> None:
        if not window_s > 0:
            raise EstimatorError(f"expected a positive noise window, got {window_s} s")
        self.window = max(1, int(round(window_s * config.fs_hz)))
        self.interim = max(1, min(self.window, int(round(INTERIM_S * config.fs_hz))))
        self._trusted = False                # the first look found nothing gross
        self._base = config
        self.inner = RBPF(config)
        self.result: NoiseCheck | None = None
        self._start: bytes | None = None     # the filter's checkpoint at the window's start
        self._kept: list[Sample] = []        # the samples since
        self._events: list[tuple[int, int]] = []       # (position in _kept, control)

    # ------------------------------------------------------------ the test
    @property
    def config(self) -> RBPFConfig:
        return self.inner.config

    @property
    def testing(self) -> bool:
        """True until the noise test has been made."""
        return self.result is None

    def _values(self) -> np.ndarray:
        """The kept samples' values (T, ny), a sensor the filter leaves out (dead:
        :mod:`gateway.estimator.sensormask`) as 0.0: the test measures the sensors in
        use, and a dead one no longer makes every sample incomplete."""
        v = np.stack([s.values for s in self._kept])
        v[:, self.inner.left_out] = 0.0
        return v

    def _band(self) -> BandVariance | None:
        """The band's variance of the kept samples; NaN for a sensor left out."""
        band = band_variance(self._values(), self.inner.config.fs_hz,
                             np.array([s.update for s in self._kept]))
        if band is not None:
            out = self.inner.left_out
            band.variance[out], band.se_rel[out] = np.nan, np.nan
        return band

    def _signal(self, est: Estimate) -> np.ndarray:
        """The model's own signal in the band (ny,) at ``est``'s θ and the kept samples'
        median speed (zeros when either is unknown)."""
        cfg = self.inner.config
        theta = np.array(est.mean[:3])
        speeds = np.array([s.speed_mps for s in self._kept])
        moving = speeds[np.isfinite(speeds) & (speeds > 0)]
        if len(moving) == 0 or not np.all(np.isfinite(theta) & (theta > 0)):
            return np.zeros(self.inner.ny)
        return model_band_variance(cfg.params, theta, float(np.median(moving)),
                                   self.inner.sensors, cfg.ar_paper, cfg.fs_hz)

    def _too_few(self) -> str:
        """Why the test could not be made, with the figures a fitter can act on: the
        complete segments found, and the share of kept samples without every sensor's
        value (a late, suspect or missing node) or not updates (gated)."""
        kept = self._kept
        ok = complete_samples(self._values(),
                              np.array([s.update for s in kept]))
        found = len(segment_starts(ok, self.inner.config.fs_hz))
        return (f"too few complete segments of data: {found} of {MIN_TEST_SEGMENTS} "
                f"needed, {100.0 * (1.0 - ok.mean()):.1f} % of the last {len(kept)} "
                f"samples lacked a sensor's value or were gated")

    def _looks_right(self, est: Estimate) -> bool:
        """The first look: every sensor's band variance within ``TRUST_FACTOR`` of the
        model's (no test, nothing replaced)."""
        band = self._band()
        if band is None:
            return False
        ratio = (band.variance - self._signal(est)) / self.inner.config.noise_variances
        ratio = ratio[~self.inner.left_out]
        return bool(np.all((ratio > 1.0 / TRUST_FACTOR) & (ratio < TRUST_FACTOR)))

    def _test(self, est: Estimate) -> Estimate:
        """Test the kept samples (``est``: the filter's estimate after them); the
        estimate after them from the filter that goes on."""
        cfg = self.inner.config
        kept = self._kept
        band = self._band()
        model = tuple(float(x) for x in cfg.noise_variances)
        sensors = self.inner.sensors
        if band is None or band.segments < MIN_TEST_SEGMENTS:
            if len(kept) < GIVE_UP_WINDOWS * self.window:
                return est
            nan = (math.nan,) * len(model)
            return self._finish(NoiseCheck(sensors, model, nan, nan, nan, model,
                                           (False,) * len(model), kept[-1].t_s,
                                           self._too_few()), est)
        signal = self._signal(est)
        used, replaced, se = decide(np.array(model), band.variance, signal, band.se_rel)
        out = [name for name, o in zip(sensors, self.inner.left_out, strict=True) if o]
        note = f"not measured: {', '.join(out)} (no values: left out)" if out else ""
        return self._finish(NoiseCheck(
            sensors, model, tuple(float(x) for x in band.variance - signal),
            tuple(float(x) for x in signal), tuple(float(x) for x in se),
            tuple(float(x) for x in used), tuple(bool(x) for x in replaced),
            kept[-1].t_s, note), est)

    def _finish(self, result: NoiseCheck, est: Estimate) -> Estimate:
        """End the test; where it replaced a variance, the filter again with the new
        ones over the kept samples and controls, and its estimate after them."""
        self.result = result
        if any(result.replaced):
            assert self._start is not None
            fresh = RBPF.restore(_with_noise(self._start, result.used_var))
            done = 0
            for at, control in self._events + [(len(self._kept), 0)]:
                if at > done:
                    est = fresh.run(self._kept[done:at], output_every=at - done)[-1]
                    done = at
                if control == _RESTART:
                    fresh.restart_filters()
                elif control <= _RESET:
                    fresh.reset_parameter(_RESET - control)
            self.inner = fresh
        # the filter from here on is a tested one (its checkpoints say so)
        self.inner.config = replace(self.inner.config, noise_tested=True)
        self._start, self._kept, self._events = None, [], []
        return est

    def _feed(self, chunk: list[Sample]) -> Estimate:
        """Run ``chunk`` through the filter, keeping what the test needs and testing at
        each window's end; the estimate after it (the new filter's after a replacement)."""
        est: Estimate | None = None
        i = 0
        while i < len(chunk):
            if self.result is not None:
                return self.inner.run(chunk[i:], output_every=len(chunk) - i)[-1]
            if self._start is None:          # the window starts at the first data
                u = next((j for j in range(i, len(chunk)) if _usable(chunk[j])), len(chunk))
                if u > i:
                    est = self.inner.run(chunk[i:u], output_every=u - i)[-1]
                    i = u
                    continue
                self._start = self.inner.checkpoint()
            n = min(len(chunk) - i, self.window - len(self._kept) % self.window)
            if len(self._kept) < self.interim:
                n = min(n, self.interim - len(self._kept))
            est = self.inner.run(chunk[i:i + n], output_every=n)[-1]
            self._kept.extend(chunk[i:i + n])
            i += n
            if len(self._kept) == self.interim:
                self._trusted = self._looks_right(est)
            if len(self._kept) % self.window == 0:
                est = self._test(est)
        assert est is not None
        if self.result is not None or self._trusted:
            return est
        return replace(est, provisional=True)

    # ------------------------------------------------------------ Estimator
    def reset(self, rng: np.random.Generator) -> None:
        self.inner = RBPF(self._base, rng)
        self.result, self._start, self._kept, self._events = None, None, [], []
        self._trusted = False

    def step(self, sample: Sample) -> Estimate:
        if self.result is not None:
            return self.inner.step(sample)
        return self._feed([sample])

    def advance(self, sample: Sample) -> None:
        if self.result is not None:
            self.inner.advance(sample)
        else:
            self._feed([sample])

    def run(self, samples: Iterable[Sample], output_every: int | None = None
            ) -> list[Estimate]:
        every = self.inner.config.output_every if output_every is None else int(output_every)
        if every < 1:
            raise EstimatorError(f"expected output_every >= 1, got {every}")
        source = iter(samples)
        out: list[Estimate] = []
        k = 0
        pending: Estimate | None = None       # the estimate after the last sample so far
        while self.result is None:
            chunk = list(itertools.islice(source, every - k % every))
            if not chunk:
                break
            pending = self._feed(chunk)
            k += len(chunk)
            if k % every == 0:
                out.append(pending)
                pending = None
        if self.result is not None and pending is None:
            out.extend(self.inner.run(source, output_every=every))
        elif pending is not None:
            out.append(pending)
        return out

    def checkpoint(self) -> bytes:
        if self.result is not None:
            return self.inner.checkpoint()
        kept = self._kept
        ny = self.inner.ny
        arrays = {
            "t_s": np.array([s.t_s for s in kept]),
            "values": np.stack([s.values for s in kept]) if kept else np.zeros((0, ny)),
            "speed_mps": np.array([s.speed_mps for s in kept]),
            "update": np.array([s.update for s in kept], dtype=bool),
            "events": np.array(self._events, dtype=np.int64).reshape(-1, 2),
            "inner": np.frombuffer(self.inner.checkpoint(), dtype=np.uint8),
        }
        if self._start is not None:
            arrays["start"] = np.frombuffer(self._start, dtype=np.uint8)
        return ckpt.pack({"window": self.window, "interim": self.interim,
                          "trusted": self._trusted}, arrays, magic=MAGIC)

    @staticmethod
    def config_of(blob: bytes) -> tuple[RBPFConfig, bool]:
        """The filter configuration a checkpoint :meth:`restore` accepts was made with,
        and whether it is still in its noise test (True) or a plain filter's (False);
        EstimatorError if ``blob`` is neither."""
        if not blob.startswith(MAGIC):
            return config_of_checkpoint(blob), False
        _, arrays = ckpt.unpack(blob, magic=MAGIC)
        if "inner" not in arrays:
            raise EstimatorError("expected a noise-test checkpoint with its filter, got "
                                 f"the arrays {sorted(arrays)}")
        return config_of_checkpoint(arrays["inner"].tobytes()), True

    @classmethod
    def restore(cls, blob: bytes) -> NoiseCheckedStart | RBPF:
        """The estimator ``blob`` came from: this class during the test, the plain
        filter after it (its configuration carries the variances)."""
        if not blob.startswith(MAGIC):
            return RBPF.restore(blob)
        meta, arrays = ckpt.unpack(blob, magic=MAGIC)
        try:
            inner = RBPF.restore(arrays["inner"].tobytes())
            self = cls.__new__(cls)
            self.window = int(meta["window"])
            self.interim = int(meta["interim"])
            self._trusted = bool(meta["trusted"])
            self._base = inner.config
            self.inner = inner
            self.result = None
            self._start = arrays["start"].tobytes() if "start" in arrays else None
            self._kept = [Sample(float(t), v, float(sp), bool(u)) for t, v, sp, u in zip(
                arrays["t_s"], arrays["values"], arrays["speed_mps"], arrays["update"],
                strict=True)]
            self._events = [(int(a), int(b)) for a, b in arrays["events"]]
        except (KeyError, TypeError, ValueError) as err:
            raise EstimatorError(f"expected a noise-test checkpoint, got {err!r}") from err
        return self

    def restart_filters(self) -> None:
        self.inner.restart_filters()
        if self._start is not None:
            self._events.append((len(self._kept), _RESTART))

    def reset_parameter(self, index: int) -> None:
        self.inner.reset_parameter(index)
        if self._start is not None:
            self._events.append((len(self._kept), _RESET - index))

    # ------------------------------------------------------------ the filter's counters
    @property
    def n_resamples(self) -> int:
        return self.inner.n_resamples

    @property
    def n_detections(self) -> int:
        return self.inner.n_detections

    @property
    def n_reseeds(self) -> int:
        return self.inner.n_reseeds

    @property
    def n_fault_detections(self) -> int:
        return self.inner.n_fault_detections

    def noise_check(self) -> NoiseCheck | None:
        return self.result

    def last_fault(self) -> tuple[float, str, float, float] | None:
        return self.inner.last_fault()
