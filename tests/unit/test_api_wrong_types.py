"""Wrong types and impossible sizes given to the public Python API (reliability round 4).

Each call must raise one of teamkf's exceptions naming the argument, never an
``AttributeError``, ``TypeError``, ``OverflowError`` or ``MemoryError`` from deep inside.
Every row failed with such a builtin exception before round 4.
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np
import pytest

import teamkf as T
from teamkf.exceptions import ResourceError, TeamkfError
from teamkf.study.scenario import load_packaged

SYS = T.LinearGaussianSystem.platoon(3)
COST = T.TeamCost.platoon(3, lam=10.0)
GRAPH = T.CommGraph.line(3, delay=1)
DESIGNS = {name: f(SYS, COST, GRAPH, horizon=5) for name, f in (("mtmse", T.design_mtmse), ("kcf", T.design_kcf), ("local", T.design_local))}
DESIGNS["centralized"] = T.design_centralized(SYS, COST, horizon=5)

WRONG: list[Any] = ["abc", None, 1.5, [1, 2], {"a": 1}, object(), True, np.zeros((2, 2))]

CALLS: dict[str, tuple[str, Callable[[Any], Any]]] = {
    "kalman_covariances(system)": ("system", lambda v: T.kalman_covariances(v, 5)),
    "own_window(n_agents)": ("n_agents", lambda v: T.InformationStructure.own_window(v, common_lag=3)),
    "static_team_estimate(dims)": ("dims", lambda v: T.static_team_estimate(np.eye(3), v, T.TeamCost.common_target(1, 1, 1.0))),
    "Scenario.updated(values)": ("values", lambda v: load_packaged("platoon-4").updated(v)),
    **{f"{name}.errors(paths)": ("paths", (lambda d: lambda v: d.errors(v))(d)) for name, d in DESIGNS.items()},
}


@pytest.mark.parametrize("value", WRONG, ids=lambda v: type(v).__name__)
@pytest.mark.parametrize("call", list(CALLS), ids=str)
def test_a_wrong_type_is_a_teamkf_error_naming_the_argument(call: str, value: Any) -> None:
    argument, f = CALLS[call]
    if call.startswith("static_team_estimate") and isinstance(value, list):
        value = ["a", 1, 1]  # a list of the wrong things (a valid length-2 list is a shape error, also teamkf's)
    with pytest.raises(TeamkfError) as info:
        f(value)
    if call.startswith("Scenario.updated") and isinstance(value, dict):
        return  # a mapping is the right type: its unknown key 'a' is named instead
    assert argument in str(info.value) or argument.split(".")[0] in str(info.value), str(info.value)


@pytest.mark.parametrize(
    "call",
    [
        lambda: T.LinearGaussianSystem.platoon(10**30),
        lambda: T.InformationStructure.own_window(10**30, common_lag=3),
        lambda: T.design_cikf(SYS, COST, GRAPH, horizon=10**30),
    ],
    ids=["platoon-1e30", "own_window-1e30", "cikf-horizon-1e30"],
)
def test_an_impossible_size_is_refused_before_anything_is_allocated(call: Callable[[], Any]) -> None:
    with pytest.raises(ResourceError):
        call()


@pytest.mark.parametrize("family", sorted(T.families()), ids=str)
def test_a_delay_far_beyond_the_horizon_costs_nothing(family: str, tmp_path: Any, capsys: Any) -> None:
    """A graph delay of 1e9 at T = 6 (nothing ever arrives): every family designs it at once or refuses it in one line.

    Before round 4, the payload bookkeeping of the consensus designs looped over every step back to k - 1e9 and
    the drop-aware design over every shift in [-1e9, 1e9]: both hung.
    """
    import signal

    from teamkf.cli import main

    sc = tmp_path / "far.toml"
    sc.write_text(
        f'name = "far"\nhorizon = 6\nestimators = ["{family}"]\n[system]\nA = [[0.9, 0.1], [0.0, 0.8]]\nQ = 1.0\nSigma_x = 1.0\n'
        "[[agents]]\nC = [[1.0, 0.0]]\nR = 0.5\n[[agents]]\nC = [[0.0, 1.0]]\nR = 0.5\n"
        '[graph]\nkind = "line"\ndelay = 1000000000\n[cost]\nkind = "average"\nlambda = 1.0\n'
    )

    def hung(*_: Any) -> None:
        raise TimeoutError(f"{family}: still designing after 60 s")

    old = signal.signal(signal.SIGALRM, hung)
    signal.alarm(60)
    try:
        rc = main(["evaluate", str(sc)])
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)
    err = capsys.readouterr().err
    assert rc in (0, 2), err
    if rc == 2:
        assert len(err.splitlines()) == 1 and err.startswith("teamkf: error:"), err
