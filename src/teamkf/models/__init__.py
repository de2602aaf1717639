"""Models: the observed process and the team cost."""

from .costs import TeamCost
from .population import PopulationModel, cdma_population
from .system import LinearGaussianSystem

__all__ = ["LinearGaussianSystem", "TeamCost", "PopulationModel", "cdma_population"]
