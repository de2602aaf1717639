"""What ``teamkf --help`` lists, read without importing a family module, SciPy or numpy.

:func:`family_listing` gives every registered family as plain data (the built-in ones from their
declarations, :data:`teamkf.estimators._builtin.DECLARED`; the plug-ins from their records) and
:func:`packaged_scenarios` the scenario files shipped with teamkf. A command that uses a family imports
it then (:func:`teamkf.families`).
"""

from __future__ import annotations

from typing import Any

from ..estimators.registry import family_listing

__all__ = ["family_listing", "packaged_scenarios"]


def packaged_scenarios() -> dict[str, Any]:
    """The example scenarios shipped with teamkf: name -> path (a Traversable), sorted by name.

    Examples
    --------
    >>> from teamkf.study.catalog import packaged_scenarios
    >>> {"platoon-4", "uav-10"} <= set(packaged_scenarios())
    True
    """
    from importlib.resources import files

    root = files("teamkf").joinpath("scenarios")
    try:
        entries = list(root.iterdir())
    except (FileNotFoundError, NotADirectoryError):  # pragma: no cover - broken install
        return {}
    found = {e.name[: -len(".toml")]: e for e in entries if e.name.endswith(".toml")}
    return {name: found[name] for name in sorted(found)}
