"""Models: the observed process and the team cost."""

from .costs import TeamCost
from .population import PopulationModel, PopulationScenario, cdma_population
from .system import LinearGaussianSystem

__all__ = ["LinearGaussianSystem", "TeamCost", "PopulationModel", "PopulationScenario", "cdma_population"]
