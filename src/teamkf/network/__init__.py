"""Communication graphs with integer delays and the information structures they induce."""

from .graph import CommGraph
from .information import InformationStructure

__all__ = ["CommGraph", "InformationStructure"]
