"""The 0.1 module paths keep working for one release (aliases of the moved modules)."""

import importlib

import pytest


@pytest.mark.parametrize(
    "old, new",
    [
        ("teamkf.scenario", "teamkf.study.scenario"),
        ("teamkf.simulation.sweep", "teamkf.study.sweep"),
        ("teamkf.simulation.results", "teamkf.study.results"),
        ("teamkf.simulation.evaluate", "teamkf.study.evaluate"),
        ("teamkf.models.random_field", "teamkf.study.random_field"),
        ("teamkf.estimators.consensus", "teamkf.estimators.kcf"),
    ],
)
def test_old_module_paths_are_aliases(old, new):
    assert importlib.import_module(old) is importlib.import_module(new)


def test_old_names_still_resolve():
    from teamkf.estimators.riccati import is_detectable
    from teamkf.models.population import evaluate_population, population_from_dict
    from teamkf.network.shedding import evaluate_structures
    from teamkf.study.evaluate import ANALYTIC
    from teamkf.study.scenario import AVAILABLE_ESTIMATORS

    assert callable(is_detectable) and callable(evaluate_population) and callable(population_from_dict) and callable(evaluate_structures)
    import teamkf

    assert set(AVAILABLE_ESTIMATORS) == set(teamkf.families())
    assert set(ANALYTIC) == {name for name, fam in teamkf.families().items() if fam.analytic_cost}


def test_old_argument_orders_warn_and_work():
    import numpy as np

    from teamkf import CommGraph, LinearGaussianSystem, TeamCost, design_centralized, design_cikf

    system, cost = LinearGaussianSystem.platoon(3), TeamCost.mse(3, 3)
    with pytest.warns(DeprecationWarning, match="horizon=T"):
        old = design_centralized(system, cost, 5)
    np.testing.assert_array_equal(old.stage_costs, design_centralized(system, cost, horizon=5).stage_costs)
    graph = CommGraph.line(3, delay=1)
    with pytest.warns(DeprecationWarning, match="design_cikf\\(system, cost, graph, horizon\\)"):
        old = design_cikf(system, graph, 4)
    np.testing.assert_array_equal(old.stage_costs, design_cikf(system, None, graph, 4).stage_costs)
