"""Population scenario files (the bulk-filter paper) and their exact evaluation, as plain rows.

A ``[population]`` scenario (``scenario-and-cli.md``) describes N
interference-coupled scalar agents (:class:`~teamkf.models.population.PopulationModel`);
:func:`evaluate_population` gives what ``teamkf evaluate --json`` reports for it.
"""

from __future__ import annotations

import difflib
import math
from dataclasses import dataclass, field
from typing import Any, ClassVar, Mapping

from .._validation import positive_int
from ..exceptions import ScenarioError, TeamkfError
from ..models.population import PopulationModel, cdma_population
from .dotted import set_dotted
from .protocol import ScenarioBase

__all__ = ["PopulationScenario", "population_from_dict", "evaluate_population", "POPULATION_KEYS", "POPULATION_ESTIMATOR"]

#: the estimator name of a population scenario's rows (sweeps): the bulk filter, exact or memory-n
POPULATION_ESTIMATOR = "bulk"

#: keys of the ``[population]`` table (scenario-and-cli.md); ``r`` and ``a_f`` are teamkf additions
POPULATION_KEYS: tuple[str, ...] = (
    "n_agents",
    "a",
    "b",
    "c",
    "h",
    "f",
    "a_f",
    "sigma_w",
    "sigma_v",
    "sigma_0",
    "x0_mean",
    "memory",
    "r",
    "cdma",
)
_TOP_KEYS = ("name", "horizon", "description", "population")
_CDMA_KEYS = ("alpha", "beta", "h_prime")


# ---------------------------------------------------------------------------
# scenario files
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class PopulationScenario(ScenarioBase):
    """A validated ``[population]`` scenario (kind ``"population"``): name, horizon T and the model."""

    name: str
    horizon: int
    model: PopulationModel
    description: str = ""
    raw: Mapping[str, Any] = field(default_factory=dict, repr=False, compare=False)
    source: str = "<dict>"

    kind: ClassVar[str] = "population"
    simulates: ClassVar[bool] = False

    def updated(self, values: Mapping[str, Any]) -> "PopulationScenario":
        """A new population scenario with dotted keys replaced, e.g. ``{"population.memory": 3}``."""
        d: Mapping[str, Any] = self.raw
        for key, value in values.items():
            d = set_dotted(d, key, value)
        out = population_from_dict(d)
        return PopulationScenario(out.name, out.horizon, out.model, out.description, out.raw, self.source)

    #: the one estimator of a population scenario: ``("bulk",)`` (exact or memory-n, by ``population.memory``)
    estimators: tuple[str, ...] = field(default=(POPULATION_ESTIMATOR,), init=False)

    def describe_result(self, out: Mapping[str, Any]) -> str:
        """The text ``teamkf evaluate`` prints for :meth:`evaluate`'s result ``out`` (a few lines)."""
        m = self.model
        head = (
            f"scenario {self.name}: population of N = {m.n_agents:,} interference-coupled agents, horizon T = {self.horizon}, "
            f"{out['filter']} filter, feedback f = {m.f:g} (a_f = {out['a_f']:g})"
        )
        if out.get("diverged") and not math.isfinite(out["state_variance"]):
            return (
                f"{head}\n  diverged: the closed loop is unstable under this filter from step {out['diverged_at']} on "
                "(gains, variances and cost not finite)"
            )
        lines = [head, f"  final gains K_T (last 5, oldest first): [..., {', '.join(f'{v:.4g}' for v in out['gains'][-5:])}]"]
        iso = out.get("isolated_gains")
        if iso:
            lines.append(f"  isolated Kalman sequence (last 5):      [..., {', '.join(f'{v:.4g}' for v in iso[-5:])}]")
        lines.append(
            f"  stationarity index {out['stationarity_index']:.3g}; state variance Var x_T = {out['state_variance']:.6g}; "
            f"average LQ cost per agent {out['average_lq_cost']:.6g}"
        )
        if out.get("diverged"):
            lines.append(f"  diverged: the closed loop is unstable (Var x_k > 4.5e11 times the noise variance from step {out['diverged_at']} on)")
        return "\n".join(lines)

    def evaluate(self) -> dict[str, Any]:
        """:func:`evaluate_population` of the model over the horizon, with the scenario's name."""
        try:
            out = {"scenario": self.name, **evaluate_population(self.model, self.horizon)}
        except TeamkfError as exc:  # the filter's argument names -> the scenario's keys
            if exc.argument in ("memory", "n_agents"):
                raise exc.rekeyed(f"population.{exc.argument}") from exc
            raise
        return out


from .._validation import describe as _describe  # noqa: E402


def _fail(key: str, message: str) -> ScenarioError:
    err = ScenarioError(f"{key}: {message}")
    err.key = key  # type: ignore[attr-defined]
    return err


def _unknown(key: str, allowed: tuple[str, ...]) -> ScenarioError:
    leaf = key.rsplit(".", 1)[-1]
    close = difflib.get_close_matches(leaf, list(allowed), n=1, cutoff=0.6)
    hint = f"did you mean {close[0]!r}? " if close else ""
    return _fail(key, f"unknown key; {hint}expected one of: {', '.join(allowed)}")


def _number(tab: Mapping[str, Any], key: str, *, prefix: str = "population") -> float:
    v = tab[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise _fail(f"{prefix}.{key}", f"expected a number, found {_describe(v)}")
    if not math.isfinite(float(v)):
        raise _fail(f"{prefix}.{key}", f"expected a finite number, found {v!r}")
    return float(v)


def population_from_dict(d: Mapping[str, Any]) -> PopulationScenario:
    """Validate a population scenario (plain data from TOML or JSON).

    Top-level keys: ``name``, ``horizon`` (required, an integer >= 1),
    ``description`` and the ``[population]`` table. Its keys (contract of
    ``scenario-and-cli.md``): ``n_agents`` and ``a`` (required), ``f`` (default:
    the Riccati gain f*(a, r) of eq. 8), ``b``, ``c``, ``h``, ``sigma_w``,
    ``sigma_v``, ``sigma_0`` (default 1, the paper's setting), ``x0_mean``
    (default 0), ``memory`` (default 0, the exact filter); teamkf also reads
    ``r`` (LQ control weight, default 1), ``a_f`` (instead of ``f``:
    f = (a - a_f)/b) and a ``[population.cdma]`` table with ``alpha``,
    ``beta``, ``h_prime`` (instead of ``c`` and ``h``, eq. 64).

    Raises
    ------
    teamkf.exceptions.ScenarioError
        ``population.<key>: expected ..., found ...``.

    Examples
    --------
    >>> sc = population_from_dict({"name": "x", "horizon": 50,
    ...                            "population": {"n_agents": 10, "a": 2.5, "f": 2.0}})
    >>> sc.model.a_f, sc.horizon
    (0.5, 50)
    >>> population_from_dict({"horizon": 5, "population": {"n_agents": 0, "a": 1, "f": 0.5}})
    Traceback (most recent call last):
    ...
    teamkf.exceptions.ScenarioError: population.n_agents: expected an integer >= 1, found 0
    """
    if not isinstance(d, Mapping):
        raise ScenarioError(f"scenario: expected a table of keys, found {_describe(d)}")
    for k in d:
        if k not in _TOP_KEYS:
            raise _unknown(str(k), _TOP_KEYS)
    name = d.get("name", "population")
    if not isinstance(name, str) or not name.strip():
        raise _fail("name", f"expected a non-empty string, found {_describe(name)}")
    desc = d.get("description", "")
    if not isinstance(desc, str):
        raise _fail("description", f"expected a string, found {_describe(desc)}")
    if "horizon" not in d:
        raise _fail(
            "horizon", "missing required key; a population scenario needs a finite horizon T (the bulk filter grows with T), e.g. horizon = 1000"
        )
    h = d["horizon"]
    if isinstance(h, bool) or not isinstance(h, (int, float)) or (isinstance(h, float) and not h.is_integer()) or h < 1:
        raise _fail("horizon", f"expected an integer number of steps >= 1, found {_describe(h)}")
    horizon = int(h)
    if "population" not in d:
        raise _fail("population", "missing required key; add a [population] table with n_agents, a and f")
    tab = d["population"]
    if not isinstance(tab, Mapping):
        raise _fail("population", f"expected a table (n_agents = ..., a = ..., f = ...), found {_describe(tab)}")
    for k in tab:
        if k not in POPULATION_KEYS:
            raise _unknown(f"population.{k}", POPULATION_KEYS)
    for k in ("n_agents", "a"):
        if k not in tab:
            raise _fail(f"population.{k}", f"missing required key; {'the number of agents N' if k == 'n_agents' else 'the state gain a of eq. (1)'}")
    kw: dict[str, Any] = {}
    nv = tab["n_agents"]
    if isinstance(nv, bool) or not isinstance(nv, (int, float)) or (isinstance(nv, float) and not (math.isfinite(nv) and nv.is_integer())) or nv < 1:
        raise _fail(
            "population.n_agents",
            f"expected an integer >= 1, found {nv!r}"
            if isinstance(nv, (int, float)) and not isinstance(nv, bool)
            else f"expected an integer >= 1, found {_describe(nv)}",
        )
    kw["n_agents"] = int(nv)
    mv = tab.get("memory", 0)
    if isinstance(mv, bool) or not isinstance(mv, (int, float)) or (isinstance(mv, float) and not (math.isfinite(mv) and mv.is_integer())) or mv < 0:
        raise _fail(
            "population.memory", f"expected an integer >= 0 (0: exact growing-memory filter; n: keep the last n measurements), found {_describe(mv)}"
        )
    kw["memory"] = int(mv)
    for k in ("a", "b", "sigma_w", "sigma_v", "sigma_0", "x0_mean", "r"):
        if k in tab:
            kw[k] = _number(tab, k)
    if "cdma" in tab:
        if "c" in tab or "h" in tab:
            raise _fail("population.cdma", "give either c and h or a [population.cdma] table (alpha, beta, h_prime), not both")
        ct = tab["cdma"]
        if not isinstance(ct, Mapping):
            raise _fail("population.cdma", f"expected a table (alpha, beta, h_prime), found {_describe(ct)}")
        for k in ct:
            if k not in _CDMA_KEYS:
                raise _unknown(f"population.cdma.{k}", _CDMA_KEYS)
        for k in _CDMA_KEYS:
            if k not in ct:
                raise _fail(f"population.cdma.{k}", "missing required key; the CDMA mapping (eq. 64) needs alpha, beta and h_prime")
        vals = {k: _number(ct, k, prefix="population.cdma") for k in _CDMA_KEYS}
    else:
        vals = {}
        for k in ("c", "h"):
            if k in tab:
                kw[k] = _number(tab, k)
    if "f" in tab and "a_f" in tab:
        raise _fail("population.a_f", "give either f or a_f (= a - b f), not both")
    b = kw.get("b", 1.0)
    if "f" in tab:
        kw["f"] = _number(tab, "f")
    elif "a_f" in tab:
        if b <= 0:
            raise _fail("population.b", f"expected a number > 0, found {b!r}")
        kw["f"] = (kw["a"] - _number(tab, "a_f")) / b
    else:
        from ..estimators.bulk import riccati_feedback_gain

        if b <= 0:
            raise _fail("population.b", f"expected a number > 0, found {b!r}")
        kw["f"] = riccati_feedback_gain(kw["a"], kw.get("r", 1.0), b=b)
    try:
        if vals:
            model = cdma_population(kw.pop("n_agents"), kw.pop("a"), vals["alpha"], vals["beta"], vals["h_prime"], f=kw.pop("f"), **kw)
        else:
            model = PopulationModel(**kw)
    except TeamkfError as exc:
        msg = str(exc)
        head, _, rest = msg.partition(": ")
        key = f"population.cdma.{head}" if head in _CDMA_KEYS else f"population.{head}"
        raise _fail(key, rest) from None
    import copy

    return PopulationScenario(name=name, horizon=horizon, model=model, description=desc, raw=copy.deepcopy(dict(d)))


# ---------------------------------------------------------------------------
# evaluation (what `teamkf evaluate --json` reports for a population)
# ---------------------------------------------------------------------------
def evaluate_population(model: PopulationModel, horizon: int) -> dict[str, Any]:
    """Exact statistics of the closed loop over ``horizon`` steps, as plain JSON data.

    Nothing is simulated: the gains and the closed-loop covariances are exact
    for any N (the mean/deviation split of :mod:`teamkf.estimators.bulk`).

    Returns
    -------
    dict with
        ``kind`` ("population"), ``horizon``, ``n_agents``, ``memory``,
        ``filter`` ("exact" or "memory-n"), ``a_f``, ``r``;
        ``gains``: the final gain vector K_T, oldest measurement first (length T,
        or n for a memory-n filter);
        ``stationarity_index``: eq. (61), ||K_{T-1}(1:T-1) - K_T(2:T)||
        (for memory n: ||K_{T-1} - K_T||, both of length n);
        ``isolated_gains``: the naive Kalman sequence [.., K'_2, K'_1] of the same
        length (Proposition 1), or null where the isolated filter does not exist;
        ``isolated_kalman_gain``: K*(a) (eq. 6); ``discrepancy_index``: eq. (62);
        ``state_variance``: Var x_{T,i}; ``state_variance_trajectory``: Var x_{k,i},
        k = 0..T; ``estimation_error_variance``: Var(x_T - xhat_T);
        ``mean_state_variance``: Var m_T; ``cross_covariance``: Cov(x_{T,i}, x_{T,j}),
        i != j (null for N = 1);
        ``average_lq_cost``: (1/T) sum_{k<T} E[x_k**2 + r u_k**2] per agent (eq. 3 over
        the horizon); ``average_cost``: the same number (the contract's name for a
        long-run average); for a closed loop that diverges, ``diverged``: true and
        ``diverged_at``: the first step k with Var x_k > 4.5e11 (1e-4/eps) times the largest noise
        variance (for a memory-n filter the numbers from there on are NaN,
        :func:`~teamkf.estimators.bulk.finite_memory_filter`; the exact filter's stay exact).

    Raises
    ------
    teamkf.exceptions.DivergenceError
        The exact filter of an unstable closed loop loses its precision before T
        (:func:`~teamkf.estimators.bulk.exact_bulk_filter`; the message gives the
        last reliable horizon).

    Examples
    --------
    >>> out = evaluate_population(PopulationModel(n_agents=10**9, a=2.5, f=2.0), 200)
    >>> [round(k, 4) for k in out["gains"][-3:]]
    [0.0039, 0.0584, 0.865]
    >>> out["stationarity_index"] < 1e-12
    True
    """
    from ..estimators.bulk import bulk_filter, discrepancy_index, isolated_gains, isolated_kalman_gain

    T = positive_int(horizon, "horizon")
    filt = bulk_filter(model, T)
    K_T = filt.final_gains()
    cov = filt.covariances
    try:
        iso = isolated_gains(model, len(K_T))
        kstar: float | None = isolated_kalman_gain(model.a, c=model.c, sigma_w=model.sigma_w, sigma_v=model.sigma_v)
        disc: float | None = discrepancy_index(K_T, iso)
        iso_list: list[float] | None = [float(v) for v in iso]
    except TeamkfError:  # pragma: no cover - K* exists for every valid model (c > 0, sigma_v > 0)
        kstar, disc, iso_list = None, None, None
    cross = float(cov.cross_covariance[T]) if model.n_agents > 1 else None
    cost = cov.lq_cost(model.r, model.f)
    return {
        "kind": "population",
        "horizon": T,
        "n_agents": model.n_agents,
        "memory": model.memory,
        "filter": "exact" if model.memory == 0 else f"memory-{model.memory}",
        "a_f": model.a_f,
        "r": model.r,
        "gains": [float(v) for v in K_T],
        "stationarity_index": float(filt.stationarity_index()),
        "isolated_gains": iso_list,
        "isolated_kalman_gain": kstar,
        "discrepancy_index": disc,
        "state_variance": float(cov.state_variance[T]),
        "state_variance_trajectory": [float(v) for v in cov.state_variance],
        "estimation_error_variance": float(cov.error_variance[T]),
        "mean_state_variance": float(cov.mean_variance[T]),
        "cross_covariance": cross,
        "average_lq_cost": float(cost),
        "average_cost": float(cost),
        **_divergence(filt, model),
    }


def _divergence(filt: Any, model: PopulationModel) -> dict[str, Any]:
    """``{"diverged": True, "diverged_at": k}`` when the closed loop diverges, else ``{}``.

    A memory-n filter records the step itself (its numbers are NaN from there
    on); for the exact filter, whose numbers stay exact, k is the first step at
    which Var x_k exceeds ``DIVERGENCE_RATIO`` (1e-4/eps) times the largest noise
    variance, the same rule.
    """
    import numpy as np

    from ..estimators.bulk import DIVERGENCE_RATIO

    k = getattr(filt, "diverged_at", None)
    if k is None:
        sv = np.asarray(filt.covariances.state_variance)
        over = np.flatnonzero(~(sv <= DIVERGENCE_RATIO * max(model.q, model.r_v, model.p0)))
        k = int(over[0]) if over.size else None
    return {} if k is None else {"diverged": True, "diverged_at": int(k)}
