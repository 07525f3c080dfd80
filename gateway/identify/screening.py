"""Morris screening (Kraft Sec. 4.1) of all model parameters, per response signal, with SALib.

Each parameter moves over ``nominal * (1 + u)``, ``u`` in ``[-tolerance, +tolerance]``;
the response of signal i is its own misfit against the measurement, bounded as
``J_i / (1 + J_i)``: that equals J_i for a usable fit but saturates at 1 where the model
fails outright (a few corners of a +-30 % box of all 25 parameters are unstable at
speed and give J_i of 100 or more, which would otherwise swamp every other effect).
SALib returns mu* (overall effect) and sigma (interaction / non-linearity) per
parameter and signal, in units of that response per unit of the normalised range.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from SALib.analyze import morris as morris_analyze
from SALib.sample import morris as morris_sample

from gateway.errors import InputError
from gateway.identify.parallel import Evaluator
from gateway.identify.params import SHORT_NAMES

GEOMETRY: tuple[str, ...] = ("a_m", "b_m", "c_m", "d_m", "e_m", "l_m", "lbw_m", "r0_m")
"""Dimensions known from drawings: screened, but not identified by default."""


@dataclass(frozen=True)
class MorrisResult:
    """mu*, sigma and the mu* 95 % half-width, each (n_signals, n_params)."""

    names: tuple[str, ...]
    signals: tuple[str, ...]
    mu_star: np.ndarray
    sigma: np.ndarray
    mu_star_conf: np.ndarray
    n_evals: int
    trajectories: int
    tolerance: float

    def score(self) -> np.ndarray:
        """One ranking score per parameter (n_params,): mu* / max mu* per signal, summed.

        Each signal counts equally, whatever the size of its misfit.
        """
        peak = np.max(self.mu_star, axis=1, keepdims=True)
        return np.sum(self.mu_star / np.where(peak > 0, peak, 1.0), axis=0)

    def ranking(self) -> tuple[str, ...]:
        """Parameter names, most influential first."""
        return tuple(self.names[i] for i in np.argsort(-self.score(), kind="stable"))

    def table(self) -> list[dict[str, object]]:
        """Rows for the JSON report: one per parameter and signal."""
        rows: list[dict[str, object]] = []
        for j, name in enumerate(self.names):
            for i, sig in enumerate(self.signals):
                rows.append({"parameter": name, "symbol": SHORT_NAMES[name], "signal": sig,
                             "mu_star": float(self.mu_star[i, j]),
                             "sigma": float(self.sigma[i, j]),
                             "mu_star_conf": float(self.mu_star_conf[i, j])})
        return rows


def morris(evaluator: Evaluator, trajectories: int, levels: int = 4,
           seed: int = 0) -> MorrisResult:
    """Screen the evaluator's free parameters (all of them, normally) per signal.

    Cost: ``trajectories * (k + 1)`` misfit evaluations, spread over the workers.
    """
    space = evaluator.objective.space
    if trajectories < 2:
        raise InputError(f"expected at least 2 Morris trajectories, got {trajectories}")
    tol = float(np.max(space.tolerance))
    problem = {"num_vars": len(space.names), "names": list(space.names),
               "bounds": [list(b) for b in space.bounds]}
    X = morris_sample.sample(problem, N=trajectories, num_levels=levels, seed=seed)
    J = np.array(evaluator.signals(list(X)))          # (n_runs, n_signals)
    Y = J / (1.0 + J)
    signals = tuple(evaluator.objective.misfit.dataset.sensors)  # type: ignore[attr-defined]
    mu, sd, conf = [], [], []
    for i in range(Y.shape[1]):
        res = morris_analyze.analyze(problem, X, Y[:, i], num_levels=levels, seed=seed,
                                     print_to_console=False)
        mu.append(np.asarray(res["mu_star"], dtype=float))
        sd.append(np.asarray(res["sigma"], dtype=float))
        conf.append(np.asarray(res["mu_star_conf"], dtype=float))
    return MorrisResult(names=tuple(space.names), signals=signals, mu_star=np.array(mu),
                        sigma=np.array(sd), mu_star_conf=np.array(conf), n_evals=len(X),
                        trajectories=trajectories, tolerance=tol)


def select(result: MorrisResult, top_k: int | None = None, fraction: float | None = None,
           candidates: tuple[str, ...] | None = None) -> tuple[str, ...]:
    """Parameters to identify: the ``top_k`` best-ranked candidates, or every candidate whose
    score is at least ``fraction`` of the best candidate's. Candidates default to all
    screened parameters except the geometry."""
    cand = candidates if candidates is not None else tuple(
        n for n in result.names if n not in GEOMETRY)
    ranked = [n for n in result.ranking() if n in cand]
    if not ranked:
        raise InputError(f"expected candidates among the screened parameters, got {cand}")
    score = dict(zip(result.names, result.score().tolist(), strict=True))
    if top_k is not None:
        if top_k < 1:
            raise InputError(f"expected top_k >= 1, got {top_k}")
        return tuple(ranked[:top_k])
    if fraction is not None:
        best = score[ranked[0]]
        return tuple(n for n in ranked if score[n] >= fraction * best)
    raise InputError("expected top_k or fraction to select parameters, got neither")
