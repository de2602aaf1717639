"""The documented command line is the parser's: every command and option of ``teamkf --help`` and
``teamkf COMMAND --help`` is in docs/scenario-and-cli.md's command list, and every ``--option`` that a
page shows on a ``teamkf COMMAND`` line exists for that command (so a renamed or hidden option fails here).
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path
from typing import Any

import pytest

from teamkf import cli
from teamkf.cli import build_parser
from tests.helpers import cli_commands

ROOT = Path(__file__).resolve().parents[2]
SPEC = ROOT / "docs" / "scenario-and-cli.md"
README = ROOT / "README.md"
PAGES = [
    README,
    ROOT / "examples" / "scenarios" / "README.md",
    *sorted((ROOT / "docs").glob("*.md")),
    *sorted((ROOT / "docs" / "guide").glob("*.md")),
]
#: the options every command takes (listed once, in the sentence under the command list)
COMMON = {"--debug", "--quiet", "--plugin", "--max-hours", "--help", "-h"}
OPTION = re.compile(r"(?<![\w-])(--[a-z][a-z0-9-]*)")


def _shown(parser: argparse.ArgumentParser) -> set[str]:
    """The option strings --help shows (hidden aliases such as the 0.2 name --no-progress are not)."""
    return {o for a in parser._actions if a.help != argparse.SUPPRESS for o in a.option_strings}


def _accepted(parser: argparse.ArgumentParser) -> set[str]:
    return {o for a in parser._actions for o in a.option_strings}


def _commands() -> dict[str, argparse.ArgumentParser]:
    return cli_commands()


def _command_of(first: str, second: str | None, commands: Any) -> str | None:
    """The command a ``teamkf FIRST [SECOND]`` line names (two words for a group's command), or None."""
    if second is not None and f"{first} {second}" in commands:
        return f"{first} {second}"
    return first if first in commands else None


def _command_lines(text: str) -> dict[str, str]:
    """``teamkf COMMAND ...`` lines of the spec's command list, with their indented continuation lines."""
    block = text.split("## Commands", 1)[1].split("```", 2)[1]
    out: dict[str, str] = {}
    current = None
    commands = _commands()
    for line in block.splitlines():
        m = re.match(r"teamkf (\w[\w-]*)(?: +([a-z][\w-]*))?", line)
        if m:
            current = _command_of(m.group(1), m.group(2), commands) or m.group(1)
            out[current] = out.get(current, "") + " " + line.split("  #")[0]
        elif line.startswith(" ") and current:
            out[current] += " " + line.split("  #")[0]
    return out


def test_every_command_is_in_the_spec_and_the_readme():
    lines = _command_lines(SPEC.read_text(encoding="utf-8"))
    commands = set(_commands())
    assert commands <= set(lines), f"docs/scenario-and-cli.md's command list lacks {sorted(commands - set(lines))}"
    assert set(lines) <= commands, f"docs/scenario-and-cli.md lists commands that do not exist: {sorted(set(lines) - commands)}"
    row = next(line for line in README.read_text(encoding="utf-8").splitlines() if line.startswith("| `teamkf.cli`"))
    missing = sorted(c for c in commands if not re.search(rf"\b{c}\b", row))
    assert not missing, f"the README's teamkf.cli row lacks the commands {missing}"
    doc = cli.__doc__ or ""
    assert all(re.search(rf"\b{c.split()[0]}\b", doc.split("\n\n")[0]) for c in commands), "cli.py's docstring names every command"


@pytest.mark.parametrize("command", sorted(_commands()))
def test_every_option_of_a_command_is_in_the_spec(command):
    parser = _commands()[command]
    line = _command_lines(SPEC.read_text(encoding="utf-8"))[command]
    documented = set(OPTION.findall(line))
    options = {o for o in _shown(parser) if o.startswith("--")} - COMMON
    assert options <= documented, f"teamkf {command}: options missing from docs/scenario-and-cli.md: {sorted(options - documented)}"
    assert documented <= _shown(parser), f"teamkf {command}: docs/scenario-and-cli.md shows options it lacks: {sorted(documented - _shown(parser))}"


def test_common_options_are_in_the_spec():
    text = SPEC.read_text(encoding="utf-8").split("## Commands", 1)[1]
    parser = build_parser()
    common = {o for o in _shown(parser) if o.startswith("--")} - {"--version"}
    for command in _commands().values():
        assert common <= _shown(command) | {"--help"}
    missing = sorted(o for o in common if f"`{o}" not in text)
    assert not missing, f"docs/scenario-and-cli.md does not describe the options every command takes: {missing}"
    assert "teamkf --version" in text


def _page_lines(page: Path) -> list[tuple[int, str, str]]:
    """(line number, command, text) of every ``teamkf COMMAND ...`` a page shows, continuations joined."""
    out: list[tuple[int, str, str]] = []
    commands = _commands()
    lines = page.read_text(encoding="utf-8").splitlines()
    k = 0
    while k < len(lines):
        line = lines[k]
        m = re.search(r"(?<![\w./-])teamkf (?:--[\w-]+(?: [^\s-]\S*)? )*([a-z][\w-]*)(?: +([a-z][\w-]*))?", line)
        command = _command_of(m.group(1), m.group(2), commands) if m else None
        if m and command is not None:
            text, j = line[m.start() :], k
            while (text.rstrip().endswith("\\") or (j + 1 < len(lines) and re.match(r"\s{8,}\[?--", lines[j + 1]))) and j + 1 < len(lines):
                j += 1
                text = text.rstrip().rstrip("\\") + " " + lines[j]
            for stop in ("`", "  #", " | ", ";"):  # the end of an inline command, a comment, a pipe
                text = text.split(stop)[0] if stop != "`" or "`" in line[: m.start()] else text
            out.append((k + 1, command, text))
            k = j
        k += 1
    return out


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_options_the_pages_show_exist(page):
    commands = _commands()
    glob = _accepted(build_parser())
    stale = []
    for number, command, text in _page_lines(page):
        shown = _shown(commands[command]) | glob - {"--no-progress"}
        for option in OPTION.findall(text):
            if option not in shown:
                stale.append(f"line {number}: teamkf {command} {option}")
    assert not stale, f"{page.name} shows options that teamkf does not have (or hides): {stale}"


def test_a_stale_option_fails(tmp_path, monkeypatch):
    """The check above finds a hidden or missing option: the 0.2 name --no-progress, or a typo."""
    page = tmp_path / "page.md"
    page.write_text("```\nteamkf filter SCENARIO --measurements F --out G\n                 [--no-progress]\nteamkf sweep S.toml --workrs 2\n```\n")
    found = [(c, OPTION.findall(t)) for _, c, t in _page_lines(page)]
    assert found == [("filter", ["--measurements", "--out", "--no-progress"]), ("sweep", ["--workrs"])]
    with pytest.raises(AssertionError, match="--no-progress"):
        test_options_the_pages_show_exist(page)
