"""Estimators: centralized Kalman filter, MTMSE (Theorems 1-3) and the per-agent MMSE baseline."""

from .base import Design
from .cikf import CIKFDesign, design_cikf
from .kalman import CentralizedDesign, design_centralized, kalman_covariances
from .kcf import KCFDesign, design_kcf
from .team import StaticTeamEstimate, TeamDesign, design_mmse, design_mtmse, static_team_estimate

__all__ = [
    "Design",
    "KCFDesign",
    "CIKFDesign",
    "design_cikf",
    "design_kcf",
    "CentralizedDesign",
    "TeamDesign",
    "StaticTeamEstimate",
    "design_centralized",
    "design_mtmse",
    "design_mmse",
    "static_team_estimate",
    "kalman_covariances",
]
