"""Morris screening: the ranking agrees with the influence the truth model itself shows.

The known answer is computed without SALib: move one parameter at a time to its
+-30 % bounds and measure directly how much the simulated, band-limited responses
change. Parameters that change them a lot must rank above those that barely do.
"""

import numpy as np
import pytest

from gateway.errors import InputError
from gateway.identify.misfit import MisfitConfig, Section, TrackMisfit
from gateway.identify.parallel import Evaluator, Objective
from gateway.identify.params import ALL_NAMES, SHORT_NAMES, FreeSpace, ParamPoint
from gateway.identify.screening import GEOMETRY, morris, select
from gateway.identify.synthetic import demo_case


@pytest.fixture(scope="module")
def misfit():
    case = demo_case(seed=2, section_s=8.0)
    return TrackMisfit(case.dataset, case.track, [Section(*s) for s in case.sections],
                       MisfitConfig(), case.offset_m)


@pytest.fixture(scope="module")
def screening(misfit):
    with Evaluator(Objective(misfit, FreeSpace.uniform(ALL_NAMES, 0.3))) as ev:
        return morris(ev, trajectories=8)


def _one_at_a_time_influence(misfit):
    """Largest relative change of any signal's energy-normalised response, per parameter."""
    nominal = ParamPoint.nominal()
    ref = [misfit.section_response(nominal, k) for k in range(len(misfit.sections))]
    energy = sum(np.sum(r**2, axis=0) for r in ref)
    out = {}
    for name in ALL_NAMES:
        worst = 0.0
        for factor in (0.7, 1.3):
            p = nominal.scaled({name: factor})
            diff = sum(np.sum((misfit.section_response(p, k) - ref[k]) ** 2, axis=0)
                       for k in range(len(ref)))
            worst = max(worst, float(np.max(diff / energy)))
        out[name] = worst
    return out


def test_influential_parameters_rank_above_the_others(misfit, screening):
    influence = _one_at_a_time_influence(misfit)
    strong = [n for n in ALL_NAMES if influence[n] >= 0.05]
    weak = [n for n in ALL_NAMES if influence[n] < 1e-3]
    assert len(strong) >= 8 and len(weak) >= 5, (strong, weak)
    score = dict(zip(screening.names, screening.score(), strict=True))
    lowest_strong = min(score[n] for n in strong)
    highest_weak = max(score[n] for n in weak)
    assert lowest_strong > 3 * highest_weak, (
        {SHORT_NAMES[n]: round(score[n], 3) for n in strong},
        {SHORT_NAMES[n]: round(score[n], 3) for n in weak})
    # the ranking puts every strong parameter ahead of every weak one
    rank = screening.ranking()
    assert max(rank.index(n) for n in strong) < min(rank.index(n) for n in weak)


def test_table_and_shapes(screening):
    n_sig, n_par = len(screening.signals), len(ALL_NAMES)
    assert screening.mu_star.shape == screening.sigma.shape == (n_sig, n_par)
    assert screening.n_evals == 8 * (n_par + 1)
    assert len(screening.table()) == n_sig * n_par
    assert np.all(screening.mu_star >= 0) and np.all(np.isfinite(screening.sigma))


def test_selection_rules(screening):
    top = select(screening, top_k=4)
    assert len(top) == 4 and not set(top) & set(GEOMETRY)
    above = select(screening, fraction=0.5)
    assert above[0] == top[0] and set(above) <= set(select(screening, top_k=len(ALL_NAMES)))
    assert select(screening, top_k=2, candidates=("ksy_n_per_m", "mb_kg"))[0] in (
        "ksy_n_per_m", "mb_kg")
    with pytest.raises(InputError, match="expected top_k or fraction"):
        select(screening)
