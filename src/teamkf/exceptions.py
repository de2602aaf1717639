"""teamkf's exceptions.

Every error teamkf raises on purpose is a :class:`TeamkfError`; each subclass
also derives from the builtin exception a caller would naturally catch, so
``except ValueError`` keeps working.
"""

from __future__ import annotations

__all__ = [
    "TeamkfError",
    "ShapeError",
    "ArgumentError",
    "DivergenceError",
    "UnsupportedOperationError",
    "NotSymmetricError",
    "NotPositiveDefiniteError",
    "GraphError",
    "InformationStructureError",
    "DetectabilityError",
    "ConvergenceError",
    "ScenarioError",
    "OptionalDependencyError",
    "ResourceError",
]


class TeamkfError(Exception):
    """Base class of all errors raised by teamkf.

    Every error names what was wrong as a structured field, so that callers
    (the scenario reader, the CLI) can re-label it without parsing messages.

    Parameters
    ----------
    message : str
        ``"<argument>: <what is wrong; what was expected, what was found; the fix>"``.
    argument : str, optional
        The offending argument's path; taken from the message's head when not given.

    Attributes
    ----------
    argument : str or None
        The offending argument as the caller wrote it (``"R[2]"``, ``"horizon"``,
        ``"estimators[1]"``); None when the error is not about one argument.
    detail : str
        The message without the leading ``"argument: "``.

    Examples
    --------
    >>> from teamkf import TeamkfError
    >>> err = TeamkfError("horizon: expected a positive integer, found -1; give T >= 1")
    >>> err.argument, err.detail
    ('horizon', 'expected a positive integer, found -1; give T >= 1')
    """

    argument: str | None
    detail: str

    def __init__(self, message: str = "", *, argument: str | None = None) -> None:
        message = str(message)
        if argument is None:
            head, sep, rest = message.partition(": ")
            # messages are written "<argument>: <what is wrong>"; the head is an argument path
            # when it has no spaces (``R[2]``, ``cost.lambda``, ``designs['kcf']``)
            if sep and head and " " not in head and len(head) <= 80:
                argument, detail = head, rest
            else:
                detail = message
        else:
            prefix = f"{argument}: "
            detail = message[len(prefix) :] if message.startswith(prefix) else message
            if not message.startswith(prefix):
                message = prefix + message
        super().__init__(message)
        self.argument = argument
        self.detail = detail

    def rekeyed(self, key: str) -> "TeamkfError":
        """The same error for the argument path ``key`` (same type, same detail)."""
        err = type(self).__new__(type(self))
        TeamkfError.__init__(err, f"{key}: {self.detail}", argument=key)
        return err


class ShapeError(TeamkfError, ValueError):
    """An array has the wrong shape or the dimensions of two arguments disagree.

    Parameters
    ----------
    message : str
        ``"<argument>: <what is wrong; what was expected, what was found; the fix>"``.
    argument : str, optional
        The offending argument's path; taken from the message's head when not given.

    Examples
    --------
    >>> from teamkf import LinearGaussianSystem, ShapeError
    >>> try:
    ...     LinearGaussianSystem(A=[[0.9, 0.0]], Q=1.0, C=[[[1.0]]], R=[1.0], Sigma_x=1.0)
    ... except ShapeError as err:
    ...     print(type(err).__name__, err.argument)
    ShapeError A
    """


class ArgumentError(TeamkfError, ValueError):
    """An argument has a wrong value: out of range, not one of the allowed choices, the wrong type.

    It is a ``ValueError`` too, so ``except ValueError`` catches it.

    Parameters
    ----------
    message : str
        ``"<argument>: <what is wrong; what was expected, what was found; the fix>"``.
    argument : str, optional
        The offending argument's path; taken from the message's head when not given.

    Examples
    --------
    >>> import teamkf
    >>> try:
    ...     teamkf.get_family("kfc")
    ... except ValueError as err:
    ...     print(err.argument, "|", err.detail[:24])
    estimator | unknown estimator 'kfc';
    """


class DivergenceError(TeamkfError, FloatingPointError):
    """A computation left the floating-point range (an estimator or a closed loop diverges).

    It is a ``FloatingPointError`` too.

    Parameters
    ----------
    message : str
        ``"<argument>: <what is wrong; what was expected, what was found; the fix>"``.
    argument : str, optional
        The offending argument's path; taken from the message's head when not given.

    Examples
    --------
    >>> from teamkf import DivergenceError
    >>> err = DivergenceError("horizon: the cost passed 1e300 at step 412; use a shorter horizon")
    >>> isinstance(err, FloatingPointError), err.argument
    (True, 'horizon')
    """


class UnsupportedOperationError(TeamkfError, NotImplementedError):
    """A family (or a variant) does not provide an operation of the family contract.

    It is a ``NotImplementedError`` too.

    Parameters
    ----------
    family : str
        The family's name (and the error's ``argument``).
    operation : str
        The operation it lacks (``"graph_agents"``, ``"an analytic cost"``, ...).
    reason : str, optional
        Why, and what to do instead.

    Examples
    --------
    >>> from teamkf import LinearGaussianSystem, TeamCost, CommGraph, design_kcf, UnsupportedOperationError
    >>> kcf = design_kcf(LinearGaussianSystem.platoon(4), TeamCost.platoon(4, 10.0), CommGraph.line(4), 10, variant="stale")
    >>> try:
    ...     kcf.require_cost()
    ... except UnsupportedOperationError as err:
    ...     print(err.family, "|", err.operation)
    kcf | an analytic team cost
    """

    def __init__(self, family: str, operation: str, reason: str = "") -> None:
        why = f": {reason}" if reason else ""
        super().__init__(f"{family}: the {family!r} family does not support {operation}{why}", argument=family)
        self.family = family
        self.operation = operation


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


class ResourceError(ArgumentError):
    """A request would need more memory or time than the machine has; refused before anything is allocated.

    The message names the argument that sets the size, gives the estimate and what to change
    (:mod:`teamkf._budget`). An :class:`ArgumentError`, so ``except ValueError`` keeps working.
    """
