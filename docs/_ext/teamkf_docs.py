"""Sphinx helpers for the teamkf site.

* :func:`write_api_pages` writes ``api/public.rst`` from ``teamkf.__all__`` and one page per
  subpackage from its ``__all__`` (or, for a package without one, from its submodules' ``__all__``),
  so the API reference never holds a hand-kept list of names.
* :func:`experiment_png_scraper` is a sphinx-gallery image scraper: the reproductions save their
  figures as PNG files (``ExperimentResult.figures``); the scraper copies each new one into the
  gallery, so the page shows the figure exactly as ``teamkf reproduce`` writes it.
"""

from __future__ import annotations

import importlib
import pkgutil
import shutil
from pathlib import Path
from typing import Any

SUBPACKAGES = ("models", "network", "estimators", "simulation", "study", "control", "experiments", "plotting", "exceptions")


def autosummary_sources() -> list[str]:
    """The generated pages whose autosummary tables get stub pages (paths relative to docs/)."""
    return ["api/public.rst", *(f"api/teamkf.{sub}.rst" for sub in SUBPACKAGES)]


def _public_names(mod: Any) -> list[str]:
    names = getattr(mod, "__all__", None)
    if names is None:
        return []
    return [n for n in names if not n.startswith("_") or (n.startswith("__") and n.endswith("__"))]  # __version__ is public


def _is_documentable(obj: Any) -> bool:
    """Classes, functions and other callables get a page; constants are listed as data."""
    return callable(obj)


def _heading(text: str, ch: str = "=") -> str:
    return f"{text}\n{ch * len(text)}\n"


#: The API index by what users do: (heading, one line, names of teamkf.__all__ or "sub.name" of a
#: subpackage). A public name in no group is listed under "Everything else", so none is ever missing.
API_GROUPS: tuple[tuple[str, str, tuple[str, ...]], ...] = (
    (
        "Describe the team",
        "The process, the agents' measurements, the team cost, who talks to whom with which delay.",
        ("LinearGaussianSystem", "TeamCost", "CommGraph", "InformationStructure"),
    ),
    (
        "Design an estimator",
        "One function per family, each returning a design with its gains and (where there is one) its exact cost.",
        (
            "design_mtmse",
            "design_mmse",
            "design_centralized",
            "design_kcf",
            "design_cikf",
            "design_local",
            "design_diffusion",
            "design_ci",
            "design_icf",
            "design_hcmci",
            "static_team_estimate",
            "kalman_covariances",
        ),
    ),
    (
        "The designs",
        "What the design functions return: one contract (:class:`Design`) for every family.",
        ("Design", "TeamDesign", "CentralizedDesign", "LinearTeamDesign", "KCFDesign", "CIKFDesign", "StaticTeamEstimate"),
    ),
    (
        "Simulate and run the agents",
        "Sample paths, and online agents that use only what the structure or the graph delivers.",
        ("sample", "run_online", "run_graph"),
    ),
    (
        "Evaluate",
        "Monte Carlo costs with confidence intervals on the same sampled paths, and scenario rows.",
        ("monte_carlo", "MonteCarloResult", "evaluate_point"),
    ),
    (
        "Scenario files and data",
        "Scenario files (TOML or JSON) as objects; recorded measurement logs are in :mod:`teamkf.study`.",
        ("Scenario", "load_scenario", "scenario_from_dict"),
    ),
    (
        "Extend: your own family",
        "The registry every command, scenario file and Monte Carlo reads; add a family with one call.",
        ("families", "get_family", "register_family", "unregister_family", "Family", "Option"),
    ),
    (
        "Errors",
        "Every error teamkf raises on purpose; each names the argument, what was expected and found, and the fix.",
        ("TeamkfError", "ArgumentError", "ShapeError", "DivergenceError", "UnsupportedOperationError"),
    ),
)


def write_api_pages(api_dir: Path) -> list[str]:
    """Write the generated API pages under ``api_dir``; return the subpackage page names."""
    import teamkf

    api_dir.mkdir(parents=True, exist_ok=True)
    # autosummary writes the stubs again from the tables below; old ones (a name that moved or went
    # away) would be orphan pages, so they go first
    for stub in (api_dir / "generated").glob("*.rst"):
        stub.unlink()
    top = [n for n in _public_names(teamkf)]
    callables = [n for n in top if _is_documentable(getattr(teamkf, n))]
    data = [n for n in top if n not in callables]
    lines = [
        ".. This file is generated from teamkf.__all__ by docs/_ext/teamkf_docs.py; do not edit.",
        "",
        ".. currentmodule:: teamkf",
        "",
    ]
    grouped: set[str] = set()
    for heading, blurb, names in API_GROUPS:
        names = tuple(n for n in names if n in callables)  # a name that left teamkf.__all__ is dropped
        grouped.update(names)
        if names:
            lines += [_heading(heading, "-"), blurb, "", ".. autosummary::", "   :toctree: generated", "   :nosignatures:", ""]
            lines += [*[f"   {n}" for n in names], ""]
    plotting = importlib.import_module("teamkf.plotting")
    lines += [
        _heading("Plot", "-"),
        "Figures of designs, sweeps, graphs and information structures (matplotlib, the ``[plot]`` extra); "
        "most objects also have a ``.plot()`` method. See :mod:`teamkf.plotting`.",
        "",
        ".. autosummary::",
        "   :nosignatures:",
        "",
        *[f"   ~plotting.{n}" for n in _public_names(plotting) if _is_documentable(getattr(plotting, n))],
        "",
    ]
    rest = [n for n in callables if n not in grouped]
    if rest:
        lines += [_heading("Everything else", "-"), ".. autosummary::", "   :toctree: generated", "   :nosignatures:", "", *[f"   {n}" for n in rest], ""]
    if data:
        lines += [_heading("Version and constants", "-")]
    for n in data:
        lines += [f".. data:: {n}", "", f"   ``{getattr(teamkf, n)!r}``", ""]
    _write(api_dir / "public.rst", "\n".join(lines))

    pages = []
    for sub in SUBPACKAGES:
        modname = f"teamkf.{sub}"
        mod = importlib.import_module(modname)
        pages.append(modname)
        _write(api_dir / f"{modname}.rst", _subpackage_page(mod, set(top)))
    return pages


def _submodules(mod: Any) -> list[str]:
    """Public submodules, without the deprecated aliases (a module that replaced itself in sys.modules)."""
    out: list[str] = []
    if not hasattr(mod, "__path__"):  # a module, not a package (teamkf.exceptions)
        return out
    for m in pkgutil.iter_modules(mod.__path__):
        if m.name.startswith("_") or m.name == "__main__":
            continue
        full = f"{mod.__name__}.{m.name}"
        if importlib.import_module(full).__name__ == full:
            out.append(full)
    return sorted(out)


def _subpackage_page(mod: Any, top: set[str]) -> str:
    """The page of one subpackage: its own ``__all__``, then each submodule with its further public names."""
    import teamkf

    name = mod.__name__
    out = [
        f".. This page is generated from {name}.__all__ by docs/_ext/teamkf_docs.py; do not edit.",
        "",
        _heading(f"``{name}``"),
        f".. automodule:: {name}",
        "   :no-members:",
        "",
        ".. currentmodule:: teamkf",
        "",
    ]
    own = _public_names(mod)
    shown: set[int] = set()  # ids of the objects that already have a page or an entry

    def at_top(n: str, m: Any) -> bool:
        return n in top and getattr(teamkf, n, None) is getattr(m, n, None)

    def table(modname: str, names: list[str], m: Any) -> list[str]:
        lines: list[str] = []
        tops = [n for n in names if at_top(n, m)]
        rest = [n for n in names if n not in tops]
        fns = [n for n in rest if _is_documentable(getattr(m, n))]
        consts = [n for n in rest if n not in fns]
        if tops:
            lines += [
                "Also exported by :mod:`teamkf` (documented there):",
                "",
                ".. autosummary::",
                "   :nosignatures:",
                "",
                *[f"   {n}" for n in tops],
                "",
            ]
        if fns:
            lines += [".. autosummary::", "   :toctree: generated", "   :nosignatures:", "", *[f"   ~{_rel(modname)}.{n}" for n in fns], ""]
        if consts:
            lines += ["Constants: " + ", ".join(f"``{n}``" for n in consts), ""]
        for n in names:
            shown.add(id(getattr(m, n)))
        return lines

    out += table(name, own, mod)
    subs = _submodules(mod)
    if subs:
        out += [_heading("Modules", "-")]
    for sm in subs:
        m = importlib.import_module(sm)
        extra = []
        for n in _public_names(m):
            obj = getattr(m, n, None)
            if id(obj) in shown or at_top(n, m):
                continue
            home = getattr(obj, "__module__", sm) if _is_documentable(obj) else sm
            private_home = any(part.startswith("_") for part in home.split("."))  # teamkf.estimators._kalman_common has no page
            if home != sm and not home.startswith(sm + ".") and not private_home:  # re-exported from another module: documented at home
                continue  # (a package's own submodules, e.g. teamkf.estimators.cikf.design, document through the package)
            extra.append(n)
        out += [
            _heading(f"``{sm}``", "~"),
            ".. autosummary::",
            "   :toctree: generated",
            "   :template: autosummary/module-doc.rst",
            "",
            f"   {_rel(sm)}",
            "",
        ]
        out += table(sm, extra, m)
    return "\n".join(out)


def _rel(modname: str) -> str:
    """A name relative to ``teamkf`` (the pages' current module)."""
    return modname.split(".", 1)[1]


def _write(path: Path, text: str) -> None:
    """Write only when the text changed, so Sphinx's incremental build stays incremental."""
    if not path.exists() or path.read_text() != text:
        path.write_text(text)


# --------------------------------------------------------------------------------------------------
# sphinx-gallery: scrape the PNG files an ExperimentResult lists
# --------------------------------------------------------------------------------------------------


def experiment_png_scraper(block: Any, block_vars: dict[str, Any], gallery_conf: dict[str, Any]) -> str:
    """Copy the PNGs of every ExperimentResult in the example's globals that were not shown yet."""
    from sphinx_gallery.scrapers import figure_rst

    from teamkf.experiments import ExperimentResult

    shown = block_vars.setdefault("_teamkf_png_shown", set())
    image_names = []
    iterator = block_vars["image_path_iterator"]
    for value in list(block_vars["example_globals"].values()):
        if not isinstance(value, ExperimentResult):
            continue
        for png in value.figures:
            if png in shown or not Path(png).is_file():
                continue
            shown.add(png)
            target = next(iterator)
            shutil.copyfile(png, target)
            image_names.append(target)
    return figure_rst(image_names, gallery_conf["src_dir"])


# --------------------------------------------------------------------------------------------------
# the examples gallery: the repository's examples/*.py, each under a title taken from its docstring
# --------------------------------------------------------------------------------------------------
EXAMPLES_README = """Examples
========

The scripts of the repository's ``examples/`` folder, executed when the site is built (the test
suite runs them too). Run one with ``python examples/NAME.py``.
"""


def sync_examples(src: Path, dst: Path) -> list[str]:
    """Copy ``src/*.py`` into ``dst`` with the first docstring line made a reST title; return the names.

    sphinx-gallery needs a title at the top of each script's docstring; the repository's examples
    start with a one-line summary instead. The copy changes only that line, so the page shows the
    script as it is in the repository.
    """
    import ast

    dst.mkdir(parents=True, exist_ok=True)
    _write(dst / "README.rst", EXAMPLES_README)
    names = []
    for path in sorted(src.glob("*.py")):
        text = path.read_text(encoding="utf-8")
        tree = ast.parse(text)
        doc = ast.get_docstring(tree, clean=False)
        first = tree.body[0] if tree.body else None
        if doc is None or first is None:
            raise RuntimeError(f"{path}: an example needs a module docstring (its first line is the gallery title)")
        summary, _, rest = doc.strip().partition("\n")
        title = summary.strip().rstrip(".")
        new_doc = f'"""\n{title}\n{"=" * len(title)}\n\n{rest.strip()}\n"""\n'
        lines = text.splitlines(keepends=True)
        body = "".join(lines[first.end_lineno :])  # type: ignore[attr-defined]
        _write(dst / path.name, new_doc + body)
        names.append(path.stem)
    for old in dst.glob("*.py"):
        if old.stem not in names:
            old.unlink()
    return names


# --------------------------------------------------------------------------------------------------
# the registered estimator families, as a table for the user guide
# --------------------------------------------------------------------------------------------------
def write_family_table(path: Path) -> list[str]:
    """Write the registry (``teamkf.families()``) as a Markdown table; return the family names."""
    import teamkf

    def cell(text: Any) -> str:
        return str(text).replace("|", "\\|").replace("\n", " ")

    uses = {"structure": "system, cost, information structure (or graph)", "graph": "system, cost, graph", "none": "system, cost"}
    lines = [
        "<!-- generated from teamkf.families() by docs/_ext/teamkf_docs.py; do not edit -->",
        "",
        "| name | what | design function takes | horizons | analytic cost | options (default) |",
        "|---|---|---|---|---|---|",
    ]
    fams = teamkf.families()
    for name, fam in fams.items():
        fn = getattr(fam.design, "__name__", "")
        mod = getattr(fam.design, "__module__", "")
        ref = f"{{func}}`{fn} <teamkf.{fn}>`" if getattr(teamkf, fn, None) is fam.design else f"`{mod}.{fn}`"
        takes = uses.get(fam.uses, fam.uses) + ("; every edge delay 1" if fam.unit_delays else "")
        horizons = ", ".join(sorted(fam.horizons))
        opts = "; ".join(f"`{o.name}` ({o.default!r}): {o.doc}" for o in fam.options) or "none"
        lines.append(
            f"| `{name}` | {cell(fam.title)} ({ref}) | {cell(takes)} | {horizons} | {'yes' if fam.analytic_cost else 'no (Monte Carlo)'} | {cell(opts)} |"
        )
    _write(path, "\n".join(lines) + "\n")
    return list(fams)


#: abbreviations after which an API summary's first sentence goes on ("(eqs. 2-3)", "(Fig. 5)")
ABBREVIATIONS = ("eq.", "eqs.", "Eq.", "Eqs.", "Fig.", "Figs.", "Sec.", "cf.")


def setup(app: Any) -> dict[str, Any]:
    from sphinx.ext import autosummary

    # autosummary cuts a summary at the first period unless it ends a known abbreviation; the
    # docstrings cite the papers' equations and figures, so add those (read at call time)
    autosummary.WELL_KNOWN_ABBREVIATIONS = tuple(dict.fromkeys((*autosummary.WELL_KNOWN_ABBREVIATIONS, *ABBREVIATIONS)))
    write_api_pages(Path(app.srcdir) / "api")
    write_family_table(Path(app.srcdir) / "guide" / "_families.md")
    sync_examples(Path(app.srcdir).parent / "examples", Path(app.srcdir) / "_examples")
    return {"parallel_read_safe": True, "parallel_write_safe": True}
