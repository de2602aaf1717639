"""Agent i of the drop-aware design (:mod:`teamkf.estimators.team_lossy`) as a slice (:mod:`teamkf.estimators._slices`).

``teamkf deploy`` designs the team once and ships agent i only what its step reads: its local Kalman gains
K_i(k), the items 𝓘_i(k) with their gains G_i(k) and fills H_i(k), and the delays ℓ_ji of the items reaching it.
The agent rebuilt from the slice runs :class:`~teamkf.estimators.team_lossy.LossyTeamAgent` on the same arrays,
so its estimates are those of the team design's agent bit for bit; its process never designs the team (over
T = 300 steps on six agents each design held about 0.6 GB before the windowed form, 0.14 GB with it).
"""

from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any

import numpy as np

from ._slices import SliceDesign


class _Own:
    """Per step, agent ``index``'s entry only, indexed as the team's ``x[k][index]``."""

    def __init__(self, index: int, value: Any):
        self.index, self.value = int(index), value

    def __getitem__(self, i: int) -> Any:
        if int(i) != self.index:
            raise IndexError(f"agent {self.index}'s slice holds nothing of agent {i}")
        return self.value


@dataclass(eq=False)
class LossySliceView(SliceDesign):
    """What :class:`~teamkf.estimators.team_lossy.LossyTeamAgent` reads of a design, for one agent."""

    coordinates: str = "measurements"
    memory: int | None = None
    K_local: Any = ()
    items: Any = ()
    gains: Any = ()
    fills: Any = ()
    arrivals: Any = None
    resend: int = 1
    G: Any = ()  # adaptive: per step, the agent's gains on its features
    D: int = 0
    lags: int = 0
    kept: str = "resend"

    @property
    def tolerates_losses(self) -> bool:
        return True


def slice_view(ctx: Any, i: int, arrays: dict[str, np.ndarray], meta: dict[str, Any], items: str, **fields: Any) -> LossySliceView:
    """The view of agent i's slice: its local gains ``K/k``, the rows ``<items>/k`` (pairs) and gains ``G/k`` of every step."""
    T = int(meta["horizon"])
    return LossySliceView(
        str(meta.get("estimator", "mtmse_lossy")),
        T,
        ctx.system,
        ctx.cost,
        ctx.graph,
        K_local=[_Own(i, arrays[f"K/{k}"]) for k in range(T)],
        items=[_Own(i, tuple((int(j), int(s)) for j, s in np.asarray(arrays[f"{items}/{k}"]).tolist())) for k in range(T)],
        gains=[_Own(i, arrays[f"G/{k}"]) for k in range(T)],
        **fields,
    )


def lossy_agent_from_slice(ctx: Any, i: int, arrays: dict[str, np.ndarray], meta: dict[str, Any]) -> tuple[Any, Any]:
    """``(view, agent)`` of agent i rebuilt from the arrays of :meth:`~teamkf.estimators.team_lossy.LossyTeamDesign.agent_slice` and the scenario's model (no design)."""
    from .team_lossy import LossyTeamAgent

    n = int(ctx.system.n_agents)
    ell = np.full((n, n), -1, dtype=np.int64)  # only column i (the delays of the items reaching agent i) is this agent's
    ell[:, i] = np.asarray(arrays["ell"], dtype=np.int64)
    view = slice_view(
        ctx,
        i,
        arrays,
        meta,
        "items",
        coordinates=str(meta["coordinates"]),
        memory=meta.get("memory"),
        fills=[_Own(i, arrays[f"F/{k}"]) for k in range(int(meta["horizon"]))],
        arrivals=SimpleNamespace(ell=ell),
        resend=int(meta.get("resend", 1)),
    )
    if meta.get("adaptive"):  # the re-sending agent plus its smoother (teamkf.estimators._lossy_adaptive)
        from ._lossy_adaptive import adaptive_agent_class

        view.G = [_Own(i, arrays[f"AG/{k}"]) for k in range(int(meta["horizon"]))]
        view.D, view.lags, view.kept = int(meta["D"]), int(meta["lags"]), "class"
        return view, adaptive_agent_class()(view, i)
    if view.resend > 1:  # packets of the sender's last r items (teamkf.estimators._lossy_resend)
        from ._lossy_resend import resend_agent_class

        return view, resend_agent_class()(view, i)
    return view, LossyTeamAgent(view, i)  # type: ignore[arg-type]
