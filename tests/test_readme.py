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


def _run(line: str, cwd: Path) -> subprocess.CompletedProcess:
    argv = shlex.split(line)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT / "src"), os.environ.get("PYTHONPATH", "")]), "MPLBACKEND": "Agg"}
    env["TEAMKF_PROGRESS"] = "0"
    return subprocess.run([sys.executable, "-m", "teamkf", *argv[1:]], cwd=cwd, env=env, capture_output=True, text=True, timeout=900)


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
