"""The README and the getting-started page as a new user reads them: files exist, commands and code run as written.

``test_readme_python_blocks_run`` (tests/test_examples_and_doctests.py) runs the README's Python blocks;
here the shell blocks: every ``teamkf ...`` line is run in a fresh folder that holds the README's
``platoon.toml`` and the repository's ``examples/``, as a reader who saved the file and pasted the
line would run it. The getting-started page (docs/guide/getting-started.md) is run the same way,
its Python blocks in order in one namespace, as a reader pasting them into one interpreter.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
GETTING_STARTED = ROOT / "docs" / "guide" / "getting-started.md"
#: the documents a reader follows from the README; each path they cite must exist
READER_DOCS = [
    README,
    ROOT / "examples" / "scenarios" / "README.md",
    *sorted((ROOT / "docs").glob("*.md")),
    *sorted((ROOT / "docs" / "guide").glob("*.md")),
]
CITED = re.compile(r"(?<![\w/.-])((?:examples|docs|src|tests|benchmarks)/[\w./*-]*[\w*])")
#: what a build writes (cited as where to look), not files of the repository
BUILT = ("docs/_build/",)


def _blocks(lang: str, doc: Path = README) -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", doc.read_text(encoding="utf-8"), re.S)


def _commands(doc: Path = README) -> list[str]:
    """The ``teamkf`` command lines of a page's shell blocks (continuations joined, comments dropped)."""
    out = []
    for block in _blocks("sh", doc):
        for line in block.replace("\\\n", " ").splitlines():
            line = line.split("  #")[0].strip()
            if line.startswith("teamkf "):
                out.append(line)
    return out


@pytest.mark.parametrize("doc", READER_DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_cited_file_exists(doc):
    text = doc.read_text(encoding="utf-8")
    missing = sorted({m for m in CITED.findall(text) if not m.startswith(BUILT) and not any(ROOT.glob(m))})
    assert not missing, f"{doc.relative_to(ROOT)} cites files that are not in the repository: {missing}"


def test_readme_says_how_to_reach_teamkf():
    setup = _blocks("sh")[0]
    assert "make demo" in setup and "source .venv/bin/activate" in setup, "the README must say how to reach teamkf after make demo"


@pytest.fixture
def reader_folder(tmp_path):
    """A folder with the README's platoon.toml and the repository's examples (as a reader would have)."""
    toml = [b for b in _blocks("toml") if b.lstrip().startswith("# platoon.toml")]
    assert len(toml) == 1, "the README's scenario-file quickstart (a ```toml block starting '# platoon.toml')"
    (tmp_path / "platoon.toml").write_text(toml[0], encoding="utf-8")
    (tmp_path / "examples").symlink_to(ROOT / "examples")
    return tmp_path


def _run(line: str, cwd: Path, *, demo_only: bool = True) -> subprocess.CompletedProcess:
    """Run a README line as ``teamkf`` would; with ``demo_only``, third-party packages that ``make demo`` does not
    install cannot be imported (as in the .venv that ``make demo`` creates)."""
    argv = shlex.split(line)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT / "src"), os.environ.get("PYTHONPATH", "")]), "MPLBACKEND": "Agg"}
    env["TEAMKF_PROGRESS"] = "0"
    prelude = ["-c", DEMO_ONLY, json.dumps(sorted(_blocked_modules()))] if demo_only else ["-m", "teamkf"]
    return subprocess.run([sys.executable, *prelude, *argv[1:]], cwd=cwd, env=env, capture_output=True, text=True, timeout=900)


# ---------------------------------------------------------------------------
# what `make demo` installs
# ---------------------------------------------------------------------------
#: run teamkf with the top-level modules of argv[1] (JSON) made unimportable
DEMO_ONLY = """
import importlib.abc, json, sys
blocked = set(json.loads(sys.argv.pop(1)))
class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in blocked:
            raise ModuleNotFoundError(f"No module named {name!r} (make demo does not install it)", name=name)
        return None
sys.meta_path.insert(0, Block())
from teamkf.cli import main
raise SystemExit(main(sys.argv[1:]))
"""


def _demo_extras() -> list[str]:
    """The extras that ``make demo`` installs (its stamp's ``pip install ... -e '.[EXTRAS]'``)."""
    make = (ROOT / "Makefile").read_text(encoding="utf-8")
    recipe = make.split("$(DEMO_STAMP):", 1)[1].split("\n\n", 1)[0]
    m = re.search(r"-e '\.\[([\w,-]+)\]'", recipe)
    assert m, "the Makefile's $(DEMO_STAMP) recipe installs -e '.[EXTRAS]'"
    return m.group(1).split(",")


def _demo_distributions() -> set[str]:
    """Every distribution a ``make demo`` install holds: teamkf's dependencies and its demo extras', recursively."""
    import tomllib
    from importlib import metadata

    from packaging.requirements import Requirement

    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    todo = list(project["dependencies"])
    extras = list(_demo_extras())
    while extras:
        for req in project["optional-dependencies"][extras.pop()]:
            r = Requirement(req)
            if r.name == "teamkf":
                extras += sorted(r.extras)
            else:
                todo.append(req)
    seen: set[str] = set()
    while todo:
        r = Requirement(todo.pop())
        name = r.name.lower().replace("_", "-")
        if name in seen or (r.marker is not None and not r.marker.evaluate({"extra": ""})):
            continue
        seen.add(name)
        try:
            deps = metadata.requires(r.name) or []
        except metadata.PackageNotFoundError:
            continue
        for d in deps:
            dr = Requirement(d)
            if dr.marker is None or any(dr.marker.evaluate({"extra": e}) for e in ("", *r.extras)):
                todo.append(f"{dr.name}[{','.join(dr.extras)}]" if dr.extras else dr.name)
    return seen


def _blocked_modules() -> set[str]:
    """Top-level modules of installed distributions that a ``make demo`` install would not have."""
    from importlib import metadata

    demo = _demo_distributions()
    out = set()
    for module, dists in metadata.packages_distributions().items():
        names = {d.lower().replace("_", "-") for d in dists}
        if module != "teamkf" and not names & (demo | {"teamkf"}):
            out.add(module)
    return out


def test_make_demo_installs_what_the_readme_filter_needs(reader_folder):
    """Old: `make demo` installed teamkf[plot] only, and the README's `teamkf filter` line stopped for pandas."""
    assert "pandas" in _blocked_modules() or "pandas" in _demo_distributions()
    line = next(c for c in _commands() if c.startswith("teamkf filter"))
    proc = _run(line, reader_folder)
    assert proc.returncode == 0, f"after make demo (extras {_demo_extras()}), {line!r} fails: {proc.stderr[-2000:]}"
    setup = _blocks("sh")[0]
    assert all(e in setup for e in _demo_extras()), "the README says which extras `make demo` installs"


def test_scenario_quickstart_is_the_four_vehicle_platoon(reader_folder):
    proc = _run("teamkf evaluate platoon.toml --json", reader_folder)
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    assert out["scenario"] == "platoon-4"
    assert list(out["estimators"]) == ["mtmse", "mmse", "centralized"]
    packaged = _run("teamkf evaluate platoon-4 --json", reader_folder)
    assert packaged.returncode == 0, packaged.stderr
    costs = {name: e["total_cost"] for name, e in out["estimators"].items()}
    assert costs == {name: e["total_cost"] for name, e in json.loads(packaged.stdout)["estimators"].items()}, (
        "the README's file is the packaged platoon-4"
    )


@pytest.mark.slow
@pytest.mark.parametrize("line", _commands())
def test_readme_command_runs(line, reader_folder):
    proc = _run(line, reader_folder)
    assert proc.returncode == 0, f"{line!r} failed:\n{proc.stdout[-2000:]}\n{proc.stderr[-4000:]}"
    assert proc.stdout.strip(), f"{line!r} printed nothing"


@pytest.mark.slow
@pytest.mark.parametrize("line", _commands(GETTING_STARTED))
def test_getting_started_command_runs(line, reader_folder):
    proc = _run(line, reader_folder)
    assert proc.returncode == 0, f"{line!r} failed:\n{proc.stdout[-2000:]}\n{proc.stderr[-4000:]}"
    assert proc.stdout.strip(), f"{line!r} printed nothing"


def test_getting_started_code_runs(reader_folder, monkeypatch, capsys):
    """Every Python block of the getting-started page, in order, in one namespace."""
    import matplotlib

    import teamkf

    matplotlib.use("Agg")
    blocks = _blocks("python", GETTING_STARTED)
    assert len(blocks) >= 4, "install, first design, first plot, recorded data, plug-in"
    monkeypatch.chdir(reader_folder)
    namespace: dict = {}
    try:
        for block in blocks:
            exec(compile(block, str(GETTING_STARTED), "exec"), namespace)
    finally:
        teamkf.unregister_family("mine")
    out = capsys.readouterr().out
    assert "J_T: centralized" in out and "mine" in out
    assert (reader_folder / "first-plot.png").stat().st_size > 10_000
