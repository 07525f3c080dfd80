"""Known perturbation: five parameters moved by 20-28 %, a known track, global vs local.

Data: the truth (Kx +25 %, f11 -25 %, lambda +28 %, Csay -22 %, mbd +20 %) simulated at
2 kHz on a random 3 mm RMS track, decimated to 200 Hz, paper sensor noise; two 15 s
learn sections at 42.5 m/s. These five are the Morris top five of the non-geometry
parameters (the fifth, mbd, only just ahead of f22). Measured finding
(docs/identification.md): this linear model's misfit is *not* multi-modal in the
+-30 % box; a local method can only stall in the flat, curved valley along f11 x lambda.
"""

import numpy as np
import pytest
import scipy.optimize

from gateway.identify.misfit import MisfitConfig, Section, TrackMisfit
from gateway.identify.optimise import Budget, run_method
from gateway.identify.parallel import Evaluator, Objective
from gateway.identify.params import ALL_NAMES, FreeSpace
from gateway.identify.screening import morris, select
from gateway.identify.synthetic import DEMO_PERTURBATION, demo_case

NAMES = tuple(DEMO_PERTURBATION)


@pytest.fixture(scope="module")
def case():
    return demo_case(seed=1, section_s=15.0)


@pytest.fixture(scope="module")
def objective(case):
    mf = TrackMisfit(case.dataset, case.track, [Section(*s) for s in case.sections],
                     MisfitConfig(), case.offset_m)
    return Objective(mf, FreeSpace.uniform(NAMES, 0.3))


def _errors(objective, case, u):
    got = objective.space.point(np.asarray(u)).as_dict()
    truth = case.truth.as_dict()
    return np.array([got[n] / truth[n] - 1.0 for n in NAMES])


def test_morris_picks_the_five_perturbed_parameters(objective):
    """The top four are stable across Morris seeds; the fifth (mbd) is close to f22."""
    every = Objective(objective.misfit, FreeSpace.uniform(ALL_NAMES, 0.3))
    with Evaluator(every) as ev:
        screening = morris(ev, trajectories=8)
    assert {"kx_n_per_m", "f11_n", "conicity", "csay_ns_per_m"} <= set(select(screening, top_k=5))
    assert set(NAMES) <= set(select(screening, top_k=6))


@pytest.fixture(scope="module")
def runs(objective):
    """Every optimiser once on the same data (about a minute on 2 cores)."""
    j0 = objective(np.zeros(len(NAMES)))
    budget = Budget(de_maxiter=40, de_popsize=8, da_maxfun=1500, local_maxfev=800)
    with Evaluator(objective) as ev:
        return {m: run_method(m, objective, ev, budget, j0) for m in ("de", "da", "nm", "ps")}


@pytest.mark.slow
def test_global_methods_recover_each_parameter_within_5_percent(objective, case, runs):
    j_truth = objective(objective.space.relative(case.truth))
    for res in (runs["de"], runs["da"]):
        err = _errors(objective, case, res.u)
        assert np.all(np.abs(err) < 0.05), (res.method, err)
        assert res.j_final <= j_truth * (1 + 1e-3)      # as good as the truth itself
        assert res.reduction_pct > 50.0


@pytest.mark.slow
def test_pattern_search_from_nominal_stalls_in_the_f11_lambda_valley(objective, case, runs):
    """Kraft's local method stops where J is flat but the parameters are far off.

    The stall point is not a second minimum: J rises along the straight line to the
    global answer (the valley is curved), yet L-BFGS-B from the stall point reaches
    the global misfit. Nelder-Mead from nominal reaches it too on these data.
    """
    de, ps = runs["de"], runs["ps"]
    assert ps.j_final >= de.j_final and ps.j_final < 1.03 * de.j_final
    err = np.abs(_errors(objective, case, ps.u))
    assert err[NAMES.index("f11_n")] > 0.10 and err[NAMES.index("conicity")] > 0.10, err
    a, b = np.array(ps.u), np.array(de.u)
    line = [objective(a + s * (b - a)) for s in np.linspace(0.0, 1.0, 9)]
    assert max(line) > ps.j_final > de.j_final, line
    polish = scipy.optimize.minimize(objective, a, method="L-BFGS-B",
                                     bounds=objective.space.bounds)
    assert polish.fun <= de.j_final * (1 + 1e-4)
    assert runs["nm"].j_final <= de.j_final * (1 + 1e-3)


def test_misfit_is_unimodal_along_each_parameter(objective, case):
    """1-D scans through the truth over the whole +-30 % box: one minimum each."""
    u_true = objective.space.relative(case.truth)
    for i in range(len(NAMES)):
        grid = np.linspace(-0.3, 0.3, 13)
        j = []
        for g in grid:
            u = u_true.copy()
            u[i] = g
            j.append(objective(u))
        inner_minima = [k for k in range(1, 12) if j[k] < j[k - 1] and j[k] < j[k + 1]]
        assert len(inner_minima) <= 1, (NAMES[i], j)
        assert abs(grid[int(np.argmin(j))] - u_true[i]) <= 0.05 + 1e-9, (NAMES[i], j)
