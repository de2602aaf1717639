"""The lossy runtime's all-runs-at-once steps give the run-by-run estimates bit for bit.

KCF, diffusion, local, CI, ICF, HCMCI (``agent_step_runs``, :mod:`teamkf.estimators._runs`) and the
drop-aware team filter's agents (:func:`teamkf.simulation.lossy._run_lossy_team`) against the agents'
own one-run step (:func:`teamkf.simulation.lossy._run_grouped`) on the same link events: drops,
jitter, an outage and a failed agent.
"""

from __future__ import annotations

import numpy as np
import pytest

from teamkf.estimators import design_ci, design_diffusion, design_hcmci, design_icf, design_kcf, design_local
from teamkf.estimators.team_lossy import design_mtmse_lossy
from teamkf.simulation import lossy
from teamkf.simulation.links import LinkModel, link_streams
from teamkf.simulation.monte_carlo import runtime_estimates
from teamkf.simulation.sampling import sample_paths
from teamkf.study.scenario import load_packaged

T, R = 10, 12
DESIGNS = {
    "kcf": lambda sc: design_kcf(sc.system, sc.cost, sc.graph, T),
    "diffusion": lambda sc: design_diffusion(sc.system, sc.cost, sc.graph, T),
    "local": lambda sc: design_local(sc.system, sc.cost, sc.graph, T),
    "ci": lambda sc: design_ci(sc.system, sc.cost, sc.graph, T),
    "icf": lambda sc: design_icf(sc.system, sc.cost, sc.graph, T),
    "icf-heard": lambda sc: design_icf(sc.system, sc.cost, sc.graph, T, count="heard"),
    "hcmci": lambda sc: design_hcmci(sc.system, sc.cost, sc.graph, T),
    "hcmci-heard": lambda sc: design_hcmci(sc.system, sc.cost, sc.graph, T, count="heard"),
}
LINKS = [
    LinkModel(p_drop=0.3, jitter=2),
    LinkModel(p_drop=1.0),
    LinkModel(p_drop={(0, 1): 0.5}, jitter=1, outages=[(1, 2, 2, 5)], failures={3: 4}),
]


def _both(monkeypatch: pytest.MonkeyPatch, design: object, sc: object, links: LinkModel, switch: str) -> tuple[np.ndarray, np.ndarray]:
    y = sample_paths(sc.system, T, R, rng=11).y  # type: ignore[attr-defined]
    out = []
    for stacked in (True, False):
        with monkeypatch.context() as m:
            if not stacked:
                m.setattr(lossy, switch, lambda *a: False)
            lossy._LAST.clear()
            lossy._DRAWS.clear()
            out.append(runtime_estimates(design, y, sc.graph, links=links, streams=link_streams(3, R)))  # type: ignore[attr-defined]
    return out[0], out[1]


@pytest.mark.parametrize("links", LINKS, ids=["drops+jitter", "all lost", "outage+failure"])
@pytest.mark.parametrize("name", sorted(DESIGNS))
def test_stacked_tolerant_steps_match_run_by_run(monkeypatch: pytest.MonkeyPatch, name: str, links: LinkModel) -> None:
    sc = load_packaged("uav-4").updated({"horizon": T})
    d = DESIGNS[name](sc)
    calls = []
    real = lossy._run_stacked
    monkeypatch.setattr(lossy, "_run_stacked", lambda *a: calls.append(1) or real(*a))
    new, old = _both(monkeypatch, d, sc, links, "_stackable")
    assert calls, "the stacked path was not taken"
    assert np.array_equal(new, old)


def test_non_published_combination_falls_back(monkeypatch: pytest.MonkeyPatch) -> None:
    sc = load_packaged("platoon-4").updated({"horizon": T})
    d = design_diffusion(sc.system, sc.cost, sc.graph, T, combination="ci")
    calls = []
    monkeypatch.setattr(lossy, "_run_stacked", lambda *a: calls.append(1))
    runtime_estimates(d, sample_paths(sc.system, T, 3, rng=1).y, sc.graph, links=LinkModel(p_drop=0.2), streams=link_streams(3, 3))
    assert not calls


@pytest.mark.parametrize("links", LINKS, ids=["drops+jitter", "all lost", "outage+failure"])
def test_lossy_team_all_runs_match_run_by_run(monkeypatch: pytest.MonkeyPatch, links: LinkModel) -> None:
    sc = load_packaged("platoon-4").updated({"horizon": T})
    d = design_mtmse_lossy(sc.system, sc.cost, sc.graph, T, p_drop=0.3, jitter=1)
    calls = []
    real = lossy._run_lossy_team
    monkeypatch.setattr(lossy, "_run_lossy_team", lambda *a: calls.append(1) or real(*a))
    new, old = _both(monkeypatch, d, sc, links, "_is_lossy_team")
    assert calls, "the all-runs path was not taken"
    assert np.array_equal(new, old)


@pytest.mark.parametrize("links", LINKS, ids=["drops+jitter", "all lost", "outage+failure"])
def test_cikf_all_runs_match_run_by_run(monkeypatch: pytest.MonkeyPatch, links: LinkModel) -> None:
    sc = load_packaged("platoon-4").updated({"horizon": T})
    d = sc.design("cikf")
    calls = []
    real = lossy._run_cikf
    monkeypatch.setattr(lossy, "_run_cikf", lambda *a: calls.append(1) or real(*a))
    new, old = _both(monkeypatch, d, sc, links, "_is_cikf")
    assert calls, "the all-runs path was not taken"
    assert np.array_equal(new, old)
