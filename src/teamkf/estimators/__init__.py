"""Estimator families and the contract they share.

Every family module declares a :class:`~teamkf.estimators.registry.Family`
record; :func:`families` lists them (teamkf's own, those of installed
packages through the ``teamkf.families`` entry points, and a user's
:func:`register_family`). Every design is a :class:`Design`.
"""

from typing import TYPE_CHECKING

from .._lazy import attach

#: public name -> its module (imported on first use; the registry imports the built-in families when first asked)
_LAZY = {
    "Design": ".base",
    "design_ci": ".ci",
    "CIKFDesign": ".cikf",
    "design_cikf": ".cikf",
    "design_diffusion": ".diffusion",
    "design_hcmci": ".hcmci",
    "design_icf": ".icf",
    "CentralizedDesign": ".kalman",
    "design_centralized": ".kalman",
    "kalman_covariances": ".kalman",
    "KCFDesign": ".kcf",
    "design_kcf": ".kcf",
    "LinearTeamDesign": ".linear_team",
    "design_local": ".local",
    "Family": ".registry",
    "Option": ".registry",
    "families": ".registry",
    "get_family": ".registry",
    "register_family": ".registry",
    "unregister_family": ".registry",
    "StaticTeamEstimate": ".static_team",
    "TeamDesign": ".team",
    "design_mmse": ".team",
    "design_mtmse": ".team",
    "static_team_estimate": ".static_team",
}
__getattr__, __dir__ = attach(__name__, _LAZY)

if TYPE_CHECKING:
    from .base import Design

    # baselines: linear filters with data-independent gains on the exact engine of .linear_team
    from .ci import design_ci
    from .cikf import CIKFDesign, design_cikf
    from .diffusion import design_diffusion
    from .hcmci import design_hcmci
    from .icf import design_icf
    from .kalman import CentralizedDesign, design_centralized, kalman_covariances
    from .kcf import KCFDesign, design_kcf
    from .linear_team import LinearTeamDesign
    from .local import design_local
    from .registry import Family, Option, families, get_family, register_family, unregister_family
    from .team import StaticTeamEstimate, TeamDesign, design_mmse, design_mtmse, static_team_estimate

__all__ = [
    "Design",
    "Family",
    "Option",
    "families",
    "get_family",
    "register_family",
    "unregister_family",
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
    "LinearTeamDesign",
    "design_local",
    "design_diffusion",
    "design_ci",
    "design_icf",
    "design_hcmci",
]
