"""The 0.1 paths are gone in 0.3 (ImportError), and every name they offered is importable from its new home.

CHANGELOG.md ("Unreleased (0.3)") lists the same table for users.
"""

import importlib

import numpy as np
import pytest

#: module removed in 0.3 -> (new home, the names users imported from the old path)
MOVED_MODULES = {
    "teamkf.scenario": (
        "teamkf.study.scenario",
        ("Scenario", "load_scenario", "scenario_from_dict", "set_dotted", "packaged_scenarios", "load_packaged"),
    ),
    "teamkf.simulation.sweep": (
        "teamkf.study.sweep",
        ("SweepSpec", "SweepPoint", "load_sweep", "sweep_from_dict", "run_sweep", "run_point", "point_id"),
    ),
    "teamkf.simulation.results": ("teamkf.study.results", ("SweepResult", "CostCurves", "SweepError", "load_results", "MANIFEST_NAME")),
    "teamkf.simulation.evaluate": ("teamkf.study.evaluate", ("evaluate_point", "is_analytic", "DEFAULT_MC_RUNS")),
    "teamkf.models.random_field": ("teamkf.study.random_field", ("random_field", "random_field_instance", "RandomFieldInstance")),
    "teamkf.estimators.consensus": ("teamkf.estimators.kcf", ("KCFDesign", "KCFAgent", "design_kcf", "kcf_schedules")),
}

#: (old module, name) that is gone from the old module -> its new home (the old module itself stays, with its own names)
MOVED_NAMES = {
    ("teamkf.models.population", "PopulationScenario"): "teamkf.study.population",
    ("teamkf.models.population", "population_from_dict"): "teamkf.study.population",
    ("teamkf.models.population", "evaluate_population"): "teamkf.study.population",
    ("teamkf.models.population", "POPULATION_KEYS"): "teamkf.study.population",
    ("teamkf.network.shedding", "evaluate_structures"): "teamkf.experiments.shedding",
}


@pytest.mark.parametrize("old", sorted(MOVED_MODULES))
def test_old_module_paths_are_gone(old):
    with pytest.raises(ModuleNotFoundError, match=old.replace(".", r"\.")):
        importlib.import_module(old)


@pytest.mark.parametrize("old", sorted(MOVED_MODULES))
def test_moved_module_names_import_from_their_new_home(old):
    new, names = MOVED_MODULES[old]
    mod = importlib.import_module(new)
    for name in names:
        assert hasattr(mod, name), f"{new}.{name}"
        assert name in mod.__all__, f"{name} is public in {new}"


@pytest.mark.parametrize("old, name", sorted(MOVED_NAMES))
def test_moved_names_are_gone_from_the_old_module_and_live_in_the_new(old, name):
    with pytest.raises(ImportError):
        exec(f"from {old} import {name}", {})
    new = importlib.import_module(MOVED_NAMES[old, name])
    assert hasattr(new, name), f"{new.__name__}.{name}"


def test_the_old_modules_keep_their_own_names():
    """models.population and network.shedding are real modules (the bulk model, hop structures), not aliases."""
    from teamkf.models.population import PopulationModel, cdma_population
    from teamkf.network.shedding import HopWindows, hop_structures, pareto_front

    assert callable(cdma_population) and callable(hop_structures) and callable(pareto_front)
    assert PopulationModel.__module__ == "teamkf.models.population" and HopWindows.__module__ == "teamkf.network.shedding"


def test_registry_replaces_the_estimator_tuples():
    """AVAILABLE_ESTIMATORS / ANALYTIC (0.1) are teamkf.families() and its analytic_cost field."""
    import teamkf

    fams = teamkf.families()
    assert {"mtmse", "mmse", "centralized", "kcf", "cikf"} <= set(fams)
    assert {n for n, f in fams.items() if f.analytic_cost} >= {"mtmse", "mmse", "centralized"}


def test_the_0_1_argument_orders_raise_and_name_the_fix():
    from teamkf import ArgumentError, CommGraph, LinearGaussianSystem, TeamCost, design_centralized, design_cikf

    system, cost = LinearGaussianSystem.platoon(3), TeamCost.mse(3, 3)
    with pytest.raises(ArgumentError, match=r"graph_or_structure: .*found the integer 5.*design_centralized\(system, cost, horizon=5\)"):
        design_centralized(system, cost, 5)
    graph = CommGraph.line(3, delay=1)
    with pytest.raises(ArgumentError, match=r"cost: expected a TeamCost or None.*design_cikf\(system, cost, graph, horizon\)"):
        design_cikf(system, graph, 4)  # type: ignore[arg-type]
    # the documented order gives the design
    a = design_centralized(system, cost, horizon=5)
    b = design_centralized(system, cost, None, 5)
    np.testing.assert_array_equal(a.stage_costs, b.stage_costs)
    assert design_cikf(system, None, graph, 4).stage_costs.shape == (4,)
