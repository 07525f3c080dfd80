"""Offline identification of the vehicle model from recorded runs (Kraft et al.).

One job per module:

- ``params``: the 25 model parameters by name, nominal values, the relative box and
  the optional free track offset;
- ``track``: the known track alignment (CSV, generators, lookup under each wheelset);
- ``simulate``: the deterministic forced response to that track;
- ``data``: the Dataset record and its checks; ``sources``: the reader registry by
  file ending (the source seam);
- ``canlog``: a CAN log through the gateway's front end into a Recording;
- ``synthetic``: "measured" data from a perturbed model, for tests and demos;
- ``misfit``: Kraft's time-domain least-squares misfit over learn sections;
- ``sync``: cross-correlation lag of measured against simulated signals;
- ``screening``: Morris screening with SALib and the choice of parameters;
- ``parallel`` / ``optimise``: misfit evaluation on all cores; DE, DA, NM, pattern search;
- ``prediction_error``: the no-track path, Kalman prediction-error maximum likelihood;
- ``linalg``: one BLAS thread for a fit, and the filter Riccati equation;
- ``pipeline``: the two Identifiers; ``report``: JSON and figures.

See docs/identification.md.
"""

from __future__ import annotations

from typing import Protocol, TypeVar

from gateway.identify.data import Dataset

R_co = TypeVar("R_co", covariant=True)


class Identifier(Protocol[R_co]):
    """The offline seam: fit a model to one recorded run."""

    def fit(self, dataset: Dataset) -> R_co:
        """Identify from ``dataset``; returns a frozen result record."""
        ...
