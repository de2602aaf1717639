"""teamkf — decentralized estimation and filtering for teams of agents.

Agents observe parts of a linear-Gaussian process, talk over a directed
communication graph with integer delays, and estimate for the team. teamkf
designs, runs and evaluates four families from three papers, plus baselines:

===============  =====================================================================
``mtmse``        minimum team MSE filter, exact for any strongly connected delay graph
                 (Afshari & Mahajan, IEEE TSP 2021, Theorems 1-3): :func:`design_mtmse`
``mmse``         per-agent MMSE, blind to the team coupling (eq. 46): :func:`design_mmse`
``centralized``  the centralized Kalman filter, the lower bound: :func:`design_centralized`
``kcf``          Kalman-consensus filter (Olfati-Saber 2007): :func:`design_kcf`
``cikf``         Consensus+Innovations KF with optimized gains (Das & Moura 2016): :func:`design_cikf`
baselines        ``local``, ``diffusion``, ``ci``, ``icf``, ``hcmci`` (and ``kcf``): ideal and delay-compensated
                 honest variants with exact costs (docs/baselines.md, ``teamkf reproduce leaderboard``)
bulk filter      interference-coupled populations (Abedinpour Fallah et al. 2017):
                 :mod:`teamkf.estimators.bulk`, ``[population]`` scenarios
LQG              decentralized LQG through MTMSE (Appendix D): :mod:`teamkf.control.lqg`
===============  =====================================================================

Every design function is ``design_X(system, cost, graph_or_structure, horizon=None, **options)``
and returns a :class:`Design` (gains, analytic cost, ``errors``, ``graph_agents``,
``filter``, ``arrays``, ``summary``). :func:`families` lists every registered
family; :func:`register_family` adds your own.

Examples
--------
>>> from teamkf import LinearGaussianSystem, TeamCost, CommGraph, design_mtmse, design_centralized
>>> system, cost = LinearGaussianSystem.platoon(4), TeamCost.platoon(4, lam=100.0)
>>> mtmse = design_mtmse(system, cost, CommGraph.line(4, delay=1), horizon=50)
>>> design_centralized(system, cost, horizon=50).total_cost <= mtmse.total_cost
True
"""

from typing import TYPE_CHECKING

from ._lazy import attach
from ._version import __version__

#: public name -> the module it comes from (imported on first use: `import teamkf` stays fast)
_LAZY = {
    "CentralizedDesign": ".estimators",
    "CIKFDesign": ".estimators",
    "Design": ".estimators",
    "Family": ".estimators",
    "KCFDesign": ".estimators",
    "LinearTeamDesign": ".estimators",
    "Option": ".estimators",
    "StaticTeamEstimate": ".estimators",
    "TeamDesign": ".estimators",
    "design_centralized": ".estimators",
    "design_ci": ".estimators",
    "design_cikf": ".estimators",
    "design_diffusion": ".estimators",
    "design_hcmci": ".estimators",
    "design_icf": ".estimators",
    "design_kcf": ".estimators",
    "design_local": ".estimators",
    "design_mmse": ".estimators",
    "design_mtmse": ".estimators",
    "families": ".estimators",
    "load_plugin": ".estimators.registry",
    "loaded_plugins": ".estimators.registry",
    "get_family": ".estimators",
    "kalman_covariances": ".estimators",
    "register_family": ".estimators",
    "static_team_estimate": ".estimators",
    "unregister_family": ".estimators",
    "ArgumentError": ".exceptions",
    "DivergenceError": ".exceptions",
    "ShapeError": ".exceptions",
    "TeamkfError": ".exceptions",
    "UnsupportedOperationError": ".exceptions",
    "LinearGaussianSystem": ".models",
    "TeamCost": ".models",
    "CommGraph": ".network",
    "InformationStructure": ".network",
    "run_online": ".simulation",
    "sample": ".simulation",
    "MonteCarloResult": ".simulation.monte_carlo",
    "monte_carlo": ".simulation.monte_carlo",
    "run_graph": ".simulation.runtime",
    "evaluate_point": ".study.evaluate",
    "Scenario": ".study.scenario",
    "load_scenario": ".study.scenario",
    "scenario_from_dict": ".study.scenario",
}
__getattr__, __dir__ = attach(__name__, _LAZY)

if TYPE_CHECKING:  # the names for type checkers and IDEs
    from .estimators import (  # baselines
        CentralizedDesign,
        CIKFDesign,
        Design,
        Family,
        KCFDesign,
        LinearTeamDesign,
        Option,
        StaticTeamEstimate,
        TeamDesign,
        design_centralized,
        design_ci,
        design_cikf,
        design_diffusion,
        design_hcmci,
        design_icf,
        design_kcf,
        design_local,
        design_mmse,
        design_mtmse,
        families,
        get_family,
        kalman_covariances,
        register_family,
        static_team_estimate,
        unregister_family,
    )
    from .estimators.registry import load_plugin, loaded_plugins
    from .exceptions import ArgumentError, DivergenceError, ShapeError, TeamkfError, UnsupportedOperationError
    from .models import LinearGaussianSystem, TeamCost
    from .network import CommGraph, InformationStructure
    from .simulation import run_online, sample
    from .simulation.monte_carlo import MonteCarloResult, monte_carlo
    from .simulation.runtime import run_graph
    from .study.evaluate import evaluate_point
    from .study.scenario import Scenario, load_scenario, scenario_from_dict


__all__ = [
    "LinearGaussianSystem",
    "TeamCost",
    "CommGraph",
    "InformationStructure",
    "Design",
    "Family",
    "Option",
    "families",
    "get_family",
    "register_family",
    "unregister_family",
    "load_plugin",
    "loaded_plugins",
    "CentralizedDesign",
    "TeamDesign",
    "KCFDesign",
    "CIKFDesign",
    "StaticTeamEstimate",
    "design_centralized",
    "design_mtmse",
    "design_mmse",
    "design_kcf",
    "design_cikf",
    "static_team_estimate",
    "kalman_covariances",
    "LinearTeamDesign",
    "design_local",
    "design_diffusion",
    "design_ci",
    "design_icf",
    "design_hcmci",
    "sample",
    "run_online",
    "run_graph",
    "monte_carlo",
    "MonteCarloResult",
    "Scenario",
    "load_scenario",
    "scenario_from_dict",
    "evaluate_point",
    "TeamkfError",
    "ShapeError",
    "ArgumentError",
    "DivergenceError",
    "UnsupportedOperationError",
    "__version__",
]
