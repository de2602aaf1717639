"""Start-up on demand: ``teamkf --help``, ``--version`` and ``teamkf COMMAND --help`` import only what they print.

Structural, not timed (``benchmarks/bench_startup.py`` measures the seconds): each case runs in a fresh
interpreter, as the console script does, and reads ``sys.modules`` afterwards. The built-in families are
listed from their declarations (``teamkf.estimators._builtin.DECLARED``); the tests check those against the
records the family modules register, and that the help text is the same before and after the families load.
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

import teamkf
from teamkf.cli import build_parser
from teamkf.estimators import _builtin
from teamkf.estimators.registry import family_listing
from teamkf.exceptions import TeamkfError

ROOT = Path(__file__).resolve().parents[2]
PLUGIN = ROOT / "examples" / "custom_family.py"
MARK = "---modules---"

#: third-party packages that no help or version output needs
HEAVY = ("numpy", "scipy", "matplotlib", "dask", "distributed", "networkx", "pandas", "pyarrow", "tqdm", "zenoh")
#: the teamkf modules that --help may import (the CLI, the registry and its declarations, the scenario listing)
ALLOWED = {
    "teamkf",
    "teamkf.__main__",
    "teamkf._budget",  # the --max-hours argument type (math and os only)
    "teamkf._lazy",
    "teamkf._version",
    "teamkf.cli",
    "teamkf.exceptions",
    "teamkf.estimators",
    "teamkf.estimators._builtin",
    "teamkf.estimators.registry",
    "teamkf.study",
    "teamkf.study.catalog",
    "teamkf.study.deploy_args",
    "teamkf.study.textout",  # the CLI's tables and JSON (numpy on first use)
    "teamkf.study.recording_args",
    "teamkf.study.roster_cmd",  # the parser of teamkf roster new (its work imports the roster when it runs)
}


def _env(**extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != "TEAMKF_PLUGINS"}
    return {**env, **extra}


def _run_main(argv: list[str], env: dict[str, str] | None = None, prelude: str = "") -> tuple[str, list[str]]:
    """Run ``python -m teamkf ARGV`` in a fresh interpreter (through runpy, as ``-m`` does); its stdout and modules."""
    code = (
        "import runpy, sys, json\n"
        f"{prelude}"
        f"sys.argv = ['teamkf', *{argv!r}]\n"
        "try:\n    runpy.run_module('teamkf', run_name='__main__', alter_sys=True)\nexcept SystemExit as exc:\n    assert exc.code in (0, None), exc.code\n"
        f"print({MARK!r})\n"
        "print(json.dumps(sorted(sys.modules)))\n"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env or _env(), cwd=ROOT)
    assert res.returncode == 0, res.stderr
    out, _, mods = res.stdout.rpartition(MARK + "\n")
    return out, json.loads(mods)


def _commands() -> list[str]:
    sub = next(a for a in build_parser()._actions if a.dest == "command")
    return sorted(sub.choices)  # type: ignore[arg-type]


def _check_light(modules: list[str], what: str) -> None:
    heavy = sorted(m for m in modules if m.split(".")[0] in HEAVY)
    assert not heavy, f"{what} imports {heavy[:8]}"
    ours = sorted(m for m in modules if (m == "teamkf" or m.startswith("teamkf.")) and m not in ALLOWED)
    assert not ours, f"{what} imports {ours} (a family module, the study layer's workflows or an engine)"


@pytest.mark.parametrize("argv", [["--help"], ["--version"], ["-h"]])
def test_help_and_version_import_no_family_and_no_heavy_library(argv: list[str]) -> None:
    out, modules = _run_main(argv)
    _check_light(modules, f"teamkf {' '.join(argv)}")
    if argv == ["--version"]:
        assert out.strip() == f"teamkf {teamkf.__version__}"
    else:  # every built-in family and packaged scenario is still listed
        for d in _builtin.DECLARED:
            assert f"  {d.name:12s} {d.title}" in out, d.name
        assert "platoon-4" in out and "interference" in out


@pytest.mark.parametrize("command", _commands())
def test_command_help_imports_no_family_and_no_heavy_library(command: str) -> None:
    out, modules = _run_main([command, "--help"])
    assert out.startswith(f"usage: teamkf {command}"), out[:200]
    _check_light(modules, f"teamkf {command} --help")


def test_a_command_still_imports_what_it_uses() -> None:
    """The guard above is not vacuous: a command that lists the records (``teamkf families``) loads every family module."""
    out, modules = _run_main(["families"])
    assert "mtmse" in out
    assert {f"teamkf.estimators.{d.module}" for d in _builtin.DECLARED} <= set(modules)
    assert "numpy" in modules


def test_help_text_is_the_same_from_declarations_and_from_records() -> None:
    """``--help`` printed before any family module is imported equals ``--help`` printed from the loaded records."""
    code = (
        "import sys, io, contextlib, json\n"
        "from teamkf.cli import main\n"
        "def helptext():\n"
        "    buf = io.StringIO()\n"
        "    with contextlib.redirect_stdout(buf):\n"
        "        assert main(['--help']) == 0\n"
        "    return buf.getvalue()\n"
        "before = helptext()\n"
        "assert 'teamkf.estimators.kcf' not in sys.modules\n"
        "import teamkf\n"
        "from teamkf.estimators.registry import family_listing\n"
        "listed = [list(v) for v in family_listing().values()]\n"
        "records = teamkf.families()\n"
        "assert 'teamkf.estimators.kcf' in sys.modules\n"
        "print(json.dumps({'same': helptext() == before, 'listed': listed, 'loaded': [list(v) for v in family_listing().values()]}))\n"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=_env(), cwd=ROOT)
    assert res.returncode == 0, res.stderr
    got = json.loads(res.stdout)
    assert got["same"]
    assert got["listed"] == got["loaded"]
    assert got["listed"] == json.loads(json.dumps([list(d) for d in _builtin.DECLARED]))


def test_declarations_match_the_registered_records() -> None:
    """Brute force: every built-in record, field by field, against its declaration; in the order families() lists them."""
    fams = teamkf.families()
    builtin = [name for name in fams if _builtin.declared(name) is not None]
    assert builtin == [d.name for d in _builtin.DECLARED]
    for d in _builtin.DECLARED:
        fam = fams[d.name]
        assert _builtin.declaration_of(fam) == d
        assert (fam.title, fam.analytic_cost, fam.capabilities, fam.example) == (d.title, d.analytic_cost, d.capabilities, d.example)
        assert fam.design.__module__ == f"teamkf.estimators.{d.module}"
    assert _builtin.MODULES == tuple(dict.fromkeys(d.module.split(".")[0] for d in _builtin.DECLARED))
    assert list(family_listing()) == list(fams)


@pytest.mark.parametrize(
    "change, field",
    [
        ({"title": "another title"}, "title"),
        ({"analytic_cost": False}, "analytic_cost"),
        ({"example": "x()"}, "example"),
        ({"steady_form": False}, "capabilities"),
    ],
)
def test_a_record_that_drifts_from_its_declaration_is_refused(change: dict[str, Any], field: str) -> None:
    fam = teamkf.get_family("mtmse")
    _builtin.check_declared(fam)  # the real record passes
    with pytest.raises(TeamkfError, match=f"'mtmse': its record's {field} is .* but teamkf.estimators._builtin.DECLARED says"):
        _builtin.check_declared(dataclasses.replace(fam, **change))


def test_an_undeclared_builtin_is_refused() -> None:
    fam = dataclasses.replace(teamkf.get_family("kcf"), name="kcf_two")
    with pytest.raises(TeamkfError, match="'kcf_two' .* is not declared in teamkf.estimators._builtin.DECLARED"):
        _builtin.check_declared(fam)


def test_help_lists_plugins_from_the_flag_the_variable_and_entry_points() -> None:
    out, _ = _run_main(["--plugin", str(PLUGIN), "--help"])
    assert "  avg_kf       local Kalman filters, averaged with delay-compensated neighbour estimates" in out
    assert "(examples/custom_family.py) [Monte Carlo cost]" in out
    out_env, _ = _run_main(["--help"], env=_env(TEAMKF_PLUGINS=str(PLUGIN)))
    assert out_env == out
    # an installed package's entry point, in a fresh process where no family module is loaded yet
    prelude = (
        "import importlib.metadata as md, teamkf\n"
        "class EP:\n"
        "    name, value = 'ep_fam', 'somepkg:FAMILY'\n"
        "    def load(self):\n"
        "        return lambda: teamkf.Family(name='ep_fam', design=lambda *a, **k: None, title='a family from an entry point', uses='graph')\n"
        "md.entry_points = lambda group=None: [EP()] if group == 'teamkf.families' else []\n"
    )
    out_ep, _ = _run_main(["--help"], prelude=prelude)
    assert "  ep_fam       a family from an entry point [analytic cost]" in out_ep
    names = [line.split()[0] for line in out_ep.splitlines() if line.startswith("  ") and not line.startswith("   ") and line.split()]
    assert names[: len(_builtin.DECLARED) + 1] == [d.name for d in _builtin.DECLARED] + ["ep_fam"]
