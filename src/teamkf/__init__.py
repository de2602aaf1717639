"""teamkf — decentralized estimation and filtering for teams of agents.

Exact minimum team mean-squared error (MTMSE) estimation and filtering over
strongly connected communication graphs with integer delays (Afshari &
Mahajan 2021), with the centralized Kalman filter and per-agent MMSE
baselines.
"""

from importlib.metadata import PackageNotFoundError, version

from .estimators import (
    CentralizedDesign,
    CIKFDesign,
    Design,
    KCFDesign,
    StaticTeamEstimate,
    TeamDesign,
    design_centralized,
    design_cikf,
    design_kcf,
    design_mmse,
    design_mtmse,
    kalman_covariances,
    static_team_estimate,
)
from .exceptions import TeamkfError
from .models import LinearGaussianSystem, TeamCost
from .network import CommGraph, InformationStructure
from .simulation import run_online, sample

try:
    __version__ = version("teamkf")
except PackageNotFoundError:  # pragma: no cover - running from a source tree
    __version__ = "0.2.0"

__all__ = [
    "LinearGaussianSystem",
    "TeamCost",
    "CommGraph",
    "InformationStructure",
    "Design",
    "CentralizedDesign",
    "TeamDesign",
    "StaticTeamEstimate",
    "design_centralized",
    "design_kcf",
    "KCFDesign",
    "design_cikf",
    "CIKFDesign",
    "design_mtmse",
    "design_mmse",
    "static_team_estimate",
    "kalman_covariances",
    "sample",
    "run_online",
    "TeamkfError",
    "__version__",
]
