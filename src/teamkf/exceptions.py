"""teamkf's exceptions.

Every error teamkf raises on purpose is a :class:`TeamkfError`; each subclass
also derives from the builtin exception a caller would naturally catch, so
``except ValueError`` keeps working.
"""

from __future__ import annotations

__all__ = [
    "TeamkfError",
    "ShapeError",
    "NotSymmetricError",
    "NotPositiveDefiniteError",
    "GraphError",
    "InformationStructureError",
    "DetectabilityError",
    "ConvergenceError",
    "ScenarioError",
    "OptionalDependencyError",
]


class TeamkfError(Exception):
    """Base class of all errors raised by teamkf."""


class ShapeError(TeamkfError, ValueError):
    """An array has the wrong shape or the dimensions of two arguments disagree."""


class NotSymmetricError(TeamkfError, ValueError):
    """A matrix that must be symmetric is not."""


class NotPositiveDefiniteError(TeamkfError, ValueError):
    """A matrix that must be positive (semi-)definite is not."""


class GraphError(TeamkfError, ValueError):
    """A communication graph is malformed (bad delay, not strongly connected, ...)."""


class InformationStructureError(TeamkfError, ValueError):
    """An information structure is malformed or not realizable on a graph."""


class DetectabilityError(TeamkfError, ValueError):
    """A steady-state design needs (A, C) detectable and (A, Q^1/2) stabilizable."""


class ConvergenceError(TeamkfError, RuntimeError):
    """An iterative solver did not reach its tolerance."""


class ScenarioError(TeamkfError, ValueError):
    """A scenario or sweep file is invalid; the message names the key."""


class OptionalDependencyError(TeamkfError, ImportError):
    """An optional dependency is missing; the message gives the install command."""
