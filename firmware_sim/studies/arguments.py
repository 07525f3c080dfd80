"""Command-line arguments the studies share: fault cases, the kernel delta, filter options,
the truth's track input.

:func:`fault_case` and :func:`kernel_delta_arg` are argparse types; :func:`add_filter_options`
adds the options of a :class:`firmware_sim.studies.filtering.FilterOptions` record to a
parser and :func:`filter_options` reads them back as one, with a bad value refused as a
one-line usage error; :func:`add_track_input` adds ``--track-input``.
"""

from __future__ import annotations

import argparse

from firmware_sim.studies.filtering import FilterOptions, kernel_delta_problem
from firmware_sim.truth import TRACK_INPUTS
from gateway.errors import InputError
from gateway.estimator.faultbank import LOCATED_BY, REDRAWS, RUNNERS
from gateway.model.vehicle import PARAM_NAMES


def fault_case(text: str) -> tuple[int, float]:
    """An argparse type: ``PARAMETER:FACTOR`` (a parameter name or its prefix) as
    (parameter index, factor)."""
    name, _, factor = text.partition(":")
    matches = [i for i, p in enumerate(PARAM_NAMES) if p.startswith(name)]
    try:
        value = float(factor)
    except ValueError:
        value = float("nan")
    if len(matches) != 1 or not value > 0:
        raise argparse.ArgumentTypeError(f"expected PARAMETER:FACTOR with PARAMETER one of "
                                         f"{PARAM_NAMES} (a prefix will do) and FACTOR > 0, "
                                         f"got {text!r}")
    return matches[0], value


def kernel_delta_arg(text: str) -> float:
    """An argparse type: a value of the service's ``[estimator] kernel_delta`` (its
    configuration domain)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number for the kernel delta, got "
                                         f"{text!r}") from None
    problem = kernel_delta_problem(value)
    if problem is not None:
        raise argparse.ArgumentTypeError(f"kernel delta: {problem}")
    return value


def add_track_input(ap: argparse.ArgumentParser) -> None:
    """``--track-input``: how the truth's track velocities enter
    (:data:`firmware_sim.truth.TRACK_INPUTS`; default the filter's white input)."""
    ap.add_argument("--track-input", choices=TRACK_INPUTS, default="white",
                    help="how the truth's track velocities enter: continuous white noise "
                         "(the filter's model, default) or held over each sample (the "
                         "paper's literal eqs. (6)-(7))")


def add_filter_options(ap: argparse.ArgumentParser) -> None:
    """The filter's options (:class:`FilterOptions`; default: the service's own)."""
    ap.add_argument("--particles", type=int, default=1000)
    ap.add_argument("--mode", choices=("fast", "exact"), default="fast")
    ap.add_argument("--sensor-noise", choices=("measured", "model"), default="measured",
                    help="the filter's sensor noise: tested against the data (the service's "
                         "default) or the model's")
    ap.add_argument("--kernel-delta", type=kernel_delta_arg, default=None,
                    help="the service's [estimator] kernel_delta (default: the service's)")
    ap.add_argument("--moves-drop-null", action=argparse.BooleanOptionalAction,
                    default=None, help="the filter's moves_drop_null option (default: the "
                    "filter's own)")
    ap.add_argument("--fast-warmup-s", type=float, default=None,
                    help="fast mode's exact warm-up after every filter start and hold, s "
                         "(default: the filter's own, 0.5; 2 before 2026-11-30's sixteenth "
                         "session; the filter's configuration checks it)")
    ap.add_argument("--gain-fit", action=argparse.BooleanOptionalAction, default=None,
                    help="fast mode's gains fitted over the cloud at a move (default: the "
                         "filter's own, on since 2026-12-01; --no-gain-fit solves every "
                         "particle's, as before)")
    ap.add_argument("--redraw-from", choices=REDRAWS, default=None,
                    help="how a detection redraws its parameter (default: the bank's own; "
                         "range: log-uniformly over the redraw range, as before "
                         "2026-11-27)")
    ap.add_argument("--locate-min-s", type=float, default=None,
                    help="the fault bank's shortest location phase, s (default: the bank's "
                         "own, its full location phase; below it: the early stop)")
    ap.add_argument("--locate-max-s", type=float, default=None,
                    help="the fault bank's longest location phase, s (default: the bank's "
                         "own; its locate_s: no extension of an inconclusive location)")
    ap.add_argument("--replay-s", type=float, default=None,
                    help="the fault bank's look-back, s (default: the bank's own; 0: the "
                         "location starts at the confirmation)")
    ap.add_argument("--replay-cov-scale", type=float, default=None,
                    help="the multiple of its steady covariance a replayed location starts "
                         "from (default: the bank's own)")
    ap.add_argument("--refine-s", type=float, default=None,
                    help="how long the location grid sums on after a detection, s (0: "
                         "not at all; default: the bank's own)")
    ap.add_argument("--runner-up", action=argparse.BooleanOptionalAction, default=None,
                    help="where a location finds no change, locate the runner-up damper "
                         "next from the same look-back (default: the bank's own, on)")
    ap.add_argument("--runner-by", choices=RUNNERS, default=None,
                    help="how the runner-up is chosen: by each damper's change-time "
                         "search over the look-back, or by the watch's CUSUMs (the bank "
                         "before 2026-11-30; default: the bank's own, replay)")
    ap.add_argument("--located-by", choices=LOCATED_BY, default=None,
                    help="what a confirmed crossing locates: the parameter and side the "
                         "look-back's change-time search favours, or the crossing's own "
                         "(the bank before 2026-11-30's fifteenth session; default: the "
                         "bank's own, search)")


def filter_options(ap: argparse.ArgumentParser, args: argparse.Namespace) -> FilterOptions:
    """The options :func:`add_filter_options` added, as a record; a bad value exits with
    ``ap``'s one-line usage error."""
    try:
        return FilterOptions(
            particles=args.particles, mode=args.mode, sensor_noise=args.sensor_noise,
            kernel_delta=args.kernel_delta, moves_drop_null=args.moves_drop_null,
            fast_warmup_s=args.fast_warmup_s, gain_fit=args.gain_fit,
            redraw_from=args.redraw_from,
            locate_min_s=args.locate_min_s, locate_max_s=args.locate_max_s,
            replay_s=args.replay_s,
            replay_cov_scale=args.replay_cov_scale, refine_s=args.refine_s,
            runner_up=args.runner_up, runner_by=args.runner_by,
            located_by=args.located_by)
    except InputError as exc:
        ap.error(str(exc))
