"""The one interface every kind of scenario answers.

A scenario is a validated file (or dict): a team of agents with a system, a
graph and a cost (:class:`~teamkf.study.scenario.Scenario`, kind ``"team"``;
with a ``[control]`` table it also carries a decentralized LQG problem), or an
interference-coupled population
(:class:`~teamkf.study.population.PopulationScenario`, kind ``"population"``).
Commands, sweeps and the evaluation ask a scenario what it is and what it can
do through :class:`ScenarioBase`; nothing in the package probes a scenario
with ``hasattr``. A later kind subclasses :class:`ScenarioBase` and answers
the same members.

=========================  ==================================================================
``kind``                   ``"team"`` or ``"population"``
``name``, ``horizon``      the scenario's name and T (None: steady state)
``estimators``             the registry names it evaluates
``simulates``              True when its estimators run as agents (Monte Carlo, filter, sweeps with runs)
``has_lossy_links``        True when a ``[network]`` table makes links drop, jitter or fail
``family(name)``           the registry record of one of its estimators
``designs(names)``         name -> design (team scenarios)
``updated(values)``        a new scenario of the same kind with dotted keys replaced (sweeps)
``monte_carlo_options()``  keywords for ``monte_carlo`` (unreliable links)
``control``                the ``[control]`` LQG problem, or None
=========================  ==================================================================
"""

from __future__ import annotations

import abc
from typing import Any, ClassVar, Mapping, Sequence

from .. import _validation as V
from ..exceptions import ArgumentError

__all__ = ["ScenarioBase", "scenario_kind", "KINDS"]

#: the scenario kinds this version knows
KINDS = ("team", "population")


class ScenarioBase(abc.ABC):
    """What every scenario kind answers (module docstring)."""

    #: ``"team"`` or ``"population"``
    kind: ClassVar[str]
    #: True when the scenario's estimators run as online agents (Monte Carlo, ``teamkf filter``)
    simulates: ClassVar[bool] = True

    name: str
    horizon: int | None
    #: the registry names of the estimators the scenario evaluates
    estimators: tuple[str, ...]
    #: the scenario as read (plain data); :meth:`updated` starts from it
    raw: Mapping[str, Any]

    @property
    def has_lossy_links(self) -> bool:
        """True when links drop, jitter or fail (a ``[network]`` table); False for reliable links."""
        return False

    @property
    def control(self) -> Any:
        """The decentralized LQG problem of a ``[control]`` table, or None."""
        return None

    def family(self, name: str) -> Any:
        """The registry record (:class:`~teamkf.estimators.registry.Family`) of estimator ``name``."""
        from ..estimators.registry import get_family

        return get_family(name)

    def designs(self, estimators: Sequence[str] | None = None, horizon: Any = "scenario") -> dict[str, Any]:
        """Design the scenario's estimators: name -> design."""
        raise ArgumentError(
            f"scenario: a {self.kind} scenario has no estimator designs (it is evaluated by its own exact statistics); "
            "use teamkf.study.evaluation.evaluate(scenario)",
            argument="scenario",
        )

    def monte_carlo_options(self) -> dict[str, Any]:
        """Keywords for :func:`~teamkf.simulation.monte_carlo.monte_carlo` (empty: reliable links)."""
        return {}

    @abc.abstractmethod
    def updated(self, values: Mapping[str, Any]) -> "ScenarioBase":
        """A new scenario of the same kind with dotted keys replaced, e.g. ``{"horizon": 50}``."""

    def require_simulation(self, what: str, argument: str) -> None:
        """Refuse ``what`` (one line naming ``argument``) when the scenario's estimators do not run as agents."""
        if not self.simulates:
            raise ArgumentError(
                f"{argument}: {what} needs a scenario whose agents run (a team with [system], [[agents]] and a graph), "
                f"found a {self.kind} scenario, which is evaluated exactly",
                argument=argument,
            )


def scenario_kind(scenario: Any, argument: str = "scenario") -> str:
    """The kind of ``scenario``; an :class:`~teamkf.exceptions.ArgumentError` naming ``argument`` for anything else."""
    if not isinstance(scenario, ScenarioBase):
        raise ArgumentError(
            f"{argument}: expected a scenario (teamkf.study.load_scenario(path), load_packaged(name) or scenario_from_dict(data)), "
            f"found {V.describe(scenario)}",
            argument=argument,
        )
    return scenario.kind
