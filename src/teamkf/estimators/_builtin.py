"""teamkf's own families declared as data: what ``teamkf --help`` lists without importing a family module.

Each built-in family is declared here by its name, the module that defines it, its title, its cost kind,
its capabilities and its example, in the order ``teamkf.families()`` lists them. Listing them (``teamkf
--help``) reads this table only; :func:`load` imports the modules, each of which registers its
:class:`~teamkf.estimators.registry.Family` record, and the registry checks that record against its
declaration here (:func:`check_declared`), so the table and the modules cannot drift apart.
"""

from __future__ import annotations

from importlib import import_module
from typing import Any, NamedTuple

__all__ = ["Declared", "DECLARED", "MODULES", "declared", "declaration_of", "check_declared", "load"]


class Declared(NamedTuple):
    """A built-in family as plain data: the fields of its registry record that listings show.

    Attributes
    ----------
    name : str
        The registry name (``estimators = [...]`` in a scenario file).
    module : str
        The defining module, relative to :mod:`teamkf.estimators` (``"cikf.design"``).
    title : str
        One line: what the family is, with its reference (:attr:`Family.title`).
    analytic_cost : bool
        The designs carry the exact team cost (:attr:`Family.analytic_cost`).
    capabilities : tuple of str
        :attr:`Family.capabilities`, in the order of ``Family.CAPABILITIES``.
    example : str
        A short Python example (:attr:`Family.example`).
    """

    name: str
    module: str
    title: str
    analytic_cost: bool
    capabilities: tuple[str, ...]
    example: str


_ALL = ("analytic_cost", "lossy_links", "missing_data", "steady_form")

#: every built-in family, in the order ``teamkf.families()`` lists them
DECLARED: tuple[Declared, ...] = (
    Declared(
        "centralized",
        "kalman",
        "centralized Kalman filter: every agent holds every measurement at once (the lower bound, not a network)",
        True,
        _ALL,
        "design_centralized(system, cost, horizon=100)",
    ),
    Declared(
        "mtmse",
        "team",
        "minimum team MSE filter (Afshari & Mahajan 2021, Thms 2-3): the exact team optimum for the information structure",
        True,
        _ALL,
        "design_mtmse(system, cost, graph, horizon=100)",
    ),
    Declared(
        "mmse",
        "team",
        "per-agent MMSE (eq. 46): each agent's best estimate for itself, blind to the team coupling (cost eq. 47)",
        True,
        _ALL,
        "design_mmse(system, cost, graph, horizon=100)",
    ),
    Declared(
        "kcf",
        "kcf",
        "Kalman-consensus filter (Olfati-Saber 2007): local information fusion plus a consensus step on the priors",
        True,
        ("analytic_cost", "lossy_links"),
        "design_kcf(system, cost, graph, horizon=100, epsilon=0.1, variant='honest')",
    ),
    Declared(
        "cikf",
        "cikf.design",
        "Consensus+Innovations Kalman filter with optimized gains (Das & Moura 2016, Algorithms 1-2, Theorem 4)",
        True,
        ("analytic_cost", "lossy_links"),
        "design_cikf(system, cost, graph, horizon=32)",
    ),
    Declared(
        "local",
        "local",
        "Local Kalman filters on own measurements only (no communication): the floor",
        True,
        ("analytic_cost", "lossy_links"),
        "design_local(system, cost, graph, horizon=100)",
    ),
    Declared(
        "diffusion",
        "diffusion",
        "ATC diffusion Kalman filter, information form (Cattivelli & Sayed 2010), honest = delay-compensated",
        True,
        ("analytic_cost", "lossy_links"),
        "design_diffusion(system, cost, graph, horizon=100, weights='metropolis', variant='honest')",
    ),
    Declared(
        "ci",
        "ci",
        "Local Kalman filters fused by covariance intersection, trace-minimizing weights (Julier & Uhlmann 1997)",
        True,
        ("analytic_cost", "lossy_links"),
        "design_ci(system, cost, graph, horizon=100, variant='honest')",
    ),
    Declared(
        "icf",
        "icf",
        "Information-weighted consensus filter (Kamal, Farrell & Roy-Chowdhury 2013), honest = one delay-compensated exchange per step",
        True,
        ("analytic_cost", "lossy_links"),
        "design_icf(system, cost, graph, horizon=100, iterations=5, variant='ideal')",
    ),
    Declared(
        "hcmci",
        "hcmci",
        "Hybrid consensus on measurements and information (Battistelli et al. 2015), honest = one delay-compensated exchange per step",
        True,
        ("analytic_cost", "lossy_links"),
        "design_hcmci(system, cost, graph, horizon=100, iterations=5, variant='ideal')",
    ),
    Declared(
        "mtmse_lossy",
        "team_lossy",
        "drop-aware team filter: minimum expected team MSE for links that drop packets with a known probability (exact cost, certified bound)",
        True,
        ("analytic_cost", "lossy_links"),
        "design_mtmse_lossy(system, cost, graph, horizon=50, p_drop=0.2)",
    ),
)

#: the top-level modules of the built-in families (relative to teamkf.estimators), in the order they are listed
MODULES: tuple[str, ...] = tuple(dict.fromkeys(d.module.split(".")[0] for d in DECLARED))

_BY_NAME = {d.name: d for d in DECLARED}


def declared(name: str) -> Declared | None:
    """The declaration of the built-in family ``name``, or None when no built-in family has that name."""
    return _BY_NAME.get(name)


def declaration_of(family: Any) -> Declared:
    """The :class:`Declared` fields of a registered :class:`~teamkf.estimators.registry.Family` record (any family)."""
    module = getattr(family.design, "__module__", "") or ""
    module = module[len(__package__) + 1 :] if module.startswith(f"{__package__}.") else module
    return Declared(family.name, module, family.title, family.analytic_cost, tuple(family.capabilities), family.example)


def check_declared(family: Any) -> None:
    """Raise :class:`~teamkf.exceptions.TeamkfError` when a built-in family's record differs from its declaration here.

    Called by the registry for every record a built-in module registers, so an edit of a family's title,
    cost kind, capabilities or example that forgets this table fails at import, naming the field.
    """
    from ..exceptions import TeamkfError

    d = _BY_NAME.get(family.name)
    found = declaration_of(family)
    if d is None:
        raise TeamkfError(
            f"built-in family {family.name!r} (module {found.module}) is not declared in {__name__}.DECLARED; add its declaration there"
        )
    for field, want, got in zip(Declared._fields, d, found):
        if want != got:
            raise TeamkfError(
                f"built-in family {family.name!r}: its record's {field} is {got!r} but {__name__}.DECLARED says {want!r}; "
                "update the declaration (teamkf --help lists the families from it)"
            )


#: modules that extend a family module (imported after it; each registers its part with the family module)
#: mtmse_lossy's keyed=1 (gains keyed on the current arrivals), fill="held" (the class of the rule), resend=r (re-sent items)
EXTENSIONS: tuple[str, ...] = ("_lossy_keyed", "_lossy_rulefill", "_lossy_resend", "_lossy_adaptive", "_lossy_summary")


def load() -> None:
    """Import every built-in family module, then their extensions; each registers itself (see :mod:`.registry`)."""
    for name in (*MODULES, *EXTENSIONS):
        import_module(f"{__package__}.{name}")
