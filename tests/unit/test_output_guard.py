"""One guard for every file written (issue "Reliability, round 4", point 1).

Every command and every output option, pointed at each input of the command (the same path, another
spelling, a symbolic link to it, a hard link to it) and at the command's other outputs, must be refused
before any work: exit status 2, one line ``teamkf: error: <flag>: ...``, every input unchanged byte for
byte (and its modification time), nothing new in the folder. The commands and their options come from
:func:`teamkf.cli.build_parser`; :data:`OPTIONS` classifies each option that takes a value, so a new
option that it does not know (an output the guard was not told about) fails
:func:`test_every_option_that_takes_a_value_is_classified`.
"""

from __future__ import annotations

import argparse
import itertools
import os
from pathlib import Path
from typing import Any

import pytest

from teamkf.cli import main
from teamkf.study.outputs import check_output, open_stream, write_atomic
from tests.helpers import cli_commands

SCENARIO = """name = "guard"
horizon = 4
estimators = ["mtmse"]
[system]
A = [[0.9, 0.1], [0.0, 0.8]]
Q = 1.0
Sigma_x = 1.0
[[agents]]
C = [[1.0, 0.0]]
R = 0.5
[[agents]]
C = [[0.0, 1.0]]
R = 0.5
[graph]
kind = "line"
[cost]
kind = "average"
lambda = 1.0
"""
ROSTER = 'run_id = 1\nprefix = "teamkf/1"\n\n[[agents]]\nid = 0\nendpoint = "tcp/127.0.0.1:17447"\n\n[[agents]]\nid = 1\nendpoint = "tcp/127.0.0.1:17448"\n'

#: the input files: option -> (file name, content)
INPUTS: dict[str, tuple[str, str]] = {
    "scenario": ("scenario.toml", SCENARIO),
    "sweep": ("sweep.toml", 'scenario = "scenario.toml"\n[grid]\n"cost.lambda" = [1.0]\n'),
    "--measurements": ("log.csv", "step,agent,y0\n" + "".join(f"{k},{i},{0.1 * (2 * k + i):.1f}\n" for k in range(4) for i in range(2))),
    "--truth": ("truth.csv", "step,x0,x1\n" + "".join(f"{k},0.5,-0.5\n" for k in range(4))),
    "--drops": ("drops.json", '{"format": "teamkf-drops"}\n'),
    "--roster": ("roster.toml", ROSTER),
    "--plugin": ("plugin_guard.py", "# a plug-in that registers nothing\n"),
    "--map": ("map.toml", 'period = 1.0\n[[topics]]\ntopic = "/a"\nagent = 0\nfields = ["x"]\n'),
    "--design": ("slices.npz", "not read: the outputs are refused first"),
    "input": ("table.csv", "step,agent,y0\n0,0,1.0\n"),
    "reports": ("report0.json", "{}\n"),
    "--tls-root-ca": ("ca.pem", "-----BEGIN CERTIFICATE-----\n"),
    "--tls-certificate": ("cert.pem", "-----BEGIN CERTIFICATE-----\n"),
    "--tls-private-key": ("key.pem", "-----BEGIN PRIVATE KEY-----\n"),
}

IN, OTHER = "input", "other"


def out(ext: str) -> tuple[str, str]:
    """An output file option whose fresh valid value ends in ``ext``."""
    return ("file", ext)


DIR = ("dir", "")

#: every option that takes a value, per command: an input, an output (file or folder), or something else
OPTIONS: dict[str, dict[str, Any]] = {
    "evaluate": {
        "scenario": IN,
        "--monte-carlo": OTHER,
        "--seed": OTHER,
        "--scheduler": OTHER,
        "--plot": out(".png"),
        "--p-drop": OTHER,
        "--jitter": OTHER,
    },
    "design": {"scenario": IN, "--out": out(".npz")},
    "demo": {"--out": DIR},
    "reproduce": {"name": OTHER, "--out": DIR, "--scheduler": OTHER},
    "sweep": {"sweep": IN, "--scheduler": OTHER, "--out": DIR, "--workers": OTHER},
    "filter": {
        "scenario": IN,
        "--measurements": IN,
        "--truth": IN,
        "--out": out(".csv"),
        "--estimators": OTHER,
        "--chunk-rows": OTHER,
        "--drops": IN,
        "--map": IN,
    },
    "measurements convert": {"input": IN, "--map": IN, "--out": out(".csv")},
    "families": {},
    "deploy": {
        "scenario": IN,
        "--measurements": IN,
        "--out": out(".csv"),
        "--estimator": OTHER,
        "--deadline": OTHER,
        "--join-timeout": OTHER,
        "--p-drop": OTHER,
        "--seed": OTHER,
        "--record": out(".json"),
        "--transport": OTHER,
        "--kill": OTHER,
        "--timeout": OTHER,
        "--map": IN,
        "--rate": OTHER,
    },
    "agent": {
        "scenario": IN,
        "--id": OTHER,
        "--roster": IN,
        "--measurements": IN,
        "--out": out(".npz"),
        "--report": out(".json"),
        "--stream": out(".f8"),
        "--steps": OTHER,
        "--estimator": OTHER,
        "--deadline": OTHER,
        "--join-timeout": OTHER,
        "--p-drop": OTHER,
        "--seed": OTHER,
        "--kill-at": OTHER,
        "--map": IN,
        "--rate": OTHER,
        "--design": IN,
    },
    "record": {"action": OTHER, "reports": IN, "--out": out(".json"), "--died": OTHER},
    "roster new": {
        "--endpoints": OTHER,
        "--out": out(".toml"),
        "--key-out": out(".key"),
        "--prefix": OTHER,
        "--run-id": OTHER,
        "--tls-root-ca": IN,
        "--tls-certificate": IN,
        "--tls-private-key": IN,
    },
}
#: options of every command (teamkf.cli.build_parser's add())
COMMON = {"--plugin": IN, "--max-hours": OTHER}
#: inputs that a command reads through another input: the scenario a sweep file names
REFERENCED: dict[str, dict[str, str]] = {"sweep": {"scenario (of the sweep file)": "scenario"}}
#: the values a command needs besides its inputs and outputs
REQUIRED: dict[str, list[str]] = {"reproduce": ["table1"], "agent": ["--id", "0"], "roster new": ["--endpoints", "tcp/127.0.0.1:17447"]}
#: the values a command needs before its positional inputs (``record merge REPORT...``)
FIRST: dict[str, list[str]] = {"record": ["merge"]}


def _commands() -> dict[str, argparse.ArgumentParser]:
    return cli_commands()


def _value_options(p: argparse.ArgumentParser) -> list[tuple[str, argparse.Action]]:
    """(key, action) of each option of ``p`` that takes a value: the long option string, or the positional's dest."""
    found = []
    for a in p._actions:
        if a.nargs == 0 or isinstance(a, (argparse._HelpAction, argparse._VersionAction)):
            continue
        longs = [s for s in a.option_strings if s.startswith("--")]
        found.append((longs[0] if longs else a.dest, a))
    return found


def _spec(command: str) -> dict[str, Any]:
    return {**COMMON, **OPTIONS[command]}


def _cases() -> list[tuple[str, str, str, str]]:
    """(command, output option, input option, spelling) for every command, output option and input of the command."""
    cases = []
    for command, p in _commands().items():
        spec = _spec(command) if command in OPTIONS else {}
        keys = [k for k, _ in _value_options(p)]
        outs = [k for k in keys if isinstance(spec.get(k), tuple)]
        ins = [k for k in keys if spec.get(k) == IN] + list(REFERENCED.get(command, {}))
        cases += [(command, o, i, s) for o in outs for i in ins for s in ("same", "relative", "symlink", "hardlink")]
    return cases


def _cross_cases() -> list[tuple[str, str, str]]:
    """(command, output option, another output option of the same command): two outputs in one file."""
    cases = []
    for command, p in _commands().items():
        spec = _spec(command) if command in OPTIONS else {}
        outs = [k for k, _ in _value_options(p) if isinstance(spec.get(k), tuple) and spec[k][0] == "file"]
        cases += [(command, a, b) for a, b in itertools.permutations(outs, 2)]
    return cases


def test_every_option_that_takes_a_value_is_classified() -> None:
    """A new option (an output the guard does not check, or an input it does not protect) must be added to OPTIONS."""
    commands = _commands()
    assert set(commands) == set(OPTIONS), f"commands changed: classify the options of {set(commands) ^ set(OPTIONS)} in OPTIONS"
    for command, p in commands.items():
        spec = _spec(command)
        for key, _ in _value_options(p):
            assert key in spec, f"teamkf {command} {key}: a new option; classify it in OPTIONS (an input, an output, or other)"
    assert len(_cases()) >= 100  # every command x output x input x spelling


def _setup(tmp: Path, command: str) -> dict[str, Path]:
    """The input files of ``command`` in ``tmp``, a unique plug-in name (a plug-in module is loaded once per process)."""
    files = {}
    spec = _spec(command)
    for key, (name, text) in INPUTS.items():
        if spec.get(key) != IN:
            continue
        if key == "--plugin":
            name = f"plugin_guard_{tmp.name.replace('-', '_')}.py"
        path = tmp / name
        path.write_text(text, encoding="utf-8")
        files[key] = path
    for key, what in REFERENCED.get(command, {}).items():
        name, text = INPUTS[what]
        (tmp / name).write_text(text, encoding="utf-8")
        files[key] = tmp / name
    (tmp / "sub").mkdir()
    return files


def _argv(command: str, files: dict[str, Path], outputs: dict[str, str]) -> list[str]:
    argv = [a for k, f in files.items() if k == "--plugin" for a in ("--plugin", str(f))]
    argv += command.split() + FIRST.get(command, [])
    argv += [str(f) for k, f in files.items() if not k.startswith("-") and " " not in k]
    argv += REQUIRED.get(command, [])
    argv += [a for k, f in files.items() if k.startswith("-") and k != "--plugin" for a in (k, str(f))]
    for k, v in outputs.items():
        argv += [k, v]
    return argv


def _fresh(command: str, option: str) -> str:
    kind, ext = _spec(command)[option]
    return f"fresh-{option.strip('-')}{ext}" if kind == "file" else f"fresh-{option.strip('-')}-dir"


def _snapshot(tmp: Path) -> dict[str, tuple[bytes, int] | str]:
    state: dict[str, tuple[bytes, int] | str] = {}
    for p in sorted(tmp.rglob("*")):
        rel = str(p.relative_to(tmp))
        if p.is_symlink():
            state[rel] = "-> " + os.readlink(p)
        elif p.is_dir():
            state[rel] = "dir"
        else:
            state[rel] = (p.read_bytes(), p.stat().st_mtime_ns)
    return state


def _refused(capsys: Any, argv: list[str], flags: tuple[str, ...], tmp: Path) -> None:
    before = _snapshot(tmp)
    rc = main(argv)
    cap = capsys.readouterr()
    lines = cap.err.splitlines()
    assert rc == 2, (argv, rc, cap.out[-300:], cap.err[-500:])
    assert len(lines) == 1 and lines[0].startswith("teamkf: error: "), (argv, cap.err)
    assert any(lines[0].startswith(f"teamkf: error: {f}: ") for f in flags), (argv, lines[0])
    assert cap.out == "", (argv, cap.out)
    assert _snapshot(tmp) == before, argv  # every input byte for byte, same mtime; nothing written or created


@pytest.mark.parametrize(("command", "option", "input_option", "spelling"), _cases(), ids=lambda v: str(v))
def test_no_output_option_writes_over_an_input(
    tmp_path: Path, monkeypatch: Any, capsys: Any, command: str, option: str, input_option: str, spelling: str
) -> None:
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("TEAMKF_PLUGINS", raising=False)
    files = _setup(tmp_path, command)
    target = files[input_option]
    ext = _spec(command)[option][1] or ".x"
    if spelling == "same":
        value = str(target)  # as the input was given
    elif spelling == "relative":
        value = f"sub/../{target.name}"
    elif spelling == "symlink":
        value = f"link{ext}"
        (tmp_path / value).symlink_to(target.name)
    else:
        value = f"hard{ext}"
        os.link(target, tmp_path / value)
    outputs = {o: _fresh(command, o) for o, kind in OPTIONS[command].items() if isinstance(kind, tuple) and kind[0] == "file"}
    outputs[option] = value
    _refused(capsys, _argv(command, files, outputs), (option,), tmp_path)


@pytest.mark.parametrize(("command", "option", "other"), _cross_cases(), ids=lambda v: str(v))
@pytest.mark.parametrize("spelling", ["same", "relative"])
def test_two_outputs_never_share_a_file(tmp_path: Path, monkeypatch: Any, capsys: Any, command: str, option: str, other: str, spelling: str) -> None:
    monkeypatch.chdir(tmp_path)
    files = _setup(tmp_path, command)
    ext = _spec(command)[other][1]
    fmt = {".csv", ".parquet", ".npz"} if option == "--out" else set()
    name = f"both{ext if not fmt or ext in fmt else _spec(command)[option][1]}"
    outputs = {o: _fresh(command, o) for o, kind in OPTIONS[command].items() if isinstance(kind, tuple) and kind[0] == "file"}
    outputs[other] = name
    outputs[option] = name if spelling == "same" else f"sub/../{name}"
    _refused(capsys, _argv(command, files, outputs), (option, other), tmp_path)


def test_the_cost_file_of_filter_is_guarded_too(tmp_path: Path, monkeypatch: Any, capsys: Any) -> None:
    """``filter --truth`` also writes FILE-cost.csv: it must not be an input either."""
    monkeypatch.chdir(tmp_path)
    files = _setup(tmp_path, "filter")
    files.pop("--drops")
    os.link(files["--measurements"], tmp_path / "est-cost.csv")
    _refused(capsys, _argv("filter", files, {"--out": "est.csv"}), ("--out (its cost file)",), tmp_path)


def test_a_named_cache_folder_is_never_made_with_its_parents(tmp_path: Path, monkeypatch: Any, capsys: Any) -> None:
    from teamkf.experiments import leaderboard

    monkeypatch.setenv("TEAMKF_CACHE_DIR", str(tmp_path / "typo" / "cache"))
    rc = main(["reproduce", "leaderboard", "--quick"])
    err = capsys.readouterr().err
    assert rc == 2 and err.startswith("teamkf: error: TEAMKF_CACHE_DIR: ") and "does not exist" in err
    assert not (tmp_path / "typo").exists()
    monkeypatch.setenv("TEAMKF_CACHE_DIR", str(tmp_path / "cache"))
    first = leaderboard._cached("k", lambda: {"rows": [1]})
    assert {k: first[k] for k in ("rows", "network seconds", "cached")} == {"rows": [1], "network seconds": pytest.approx(0, abs=5), "cached": False}
    assert leaderboard._cached("k", lambda: {"rows": [2]})["rows"] == [1]  # the folder itself was made, the entry read back
    assert sorted(p.name for p in (tmp_path / "cache").iterdir()) == ["k.json"]


# ---------------------------------------------------------------------------
# the pieces: write_atomic and the stream
# ---------------------------------------------------------------------------
def test_write_atomic_replaces_a_link_never_the_file_it_points_to(tmp_path: Path) -> None:
    data = tmp_path / "data.csv"
    data.write_text("keep")
    (tmp_path / "link.csv").symlink_to(data)
    os.link(data, tmp_path / "hard.csv")
    write_atomic(tmp_path / "link.csv", lambda fh: fh.write("new"), text=True)
    write_atomic(tmp_path / "hard.csv", lambda fh: fh.write("new"), text=True)
    assert data.read_text() == "keep"
    assert not (tmp_path / "link.csv").is_symlink() and (tmp_path / "link.csv").read_text() == "new"
    assert (tmp_path / "hard.csv").read_text() == "new" and data.stat().st_nlink == 1


def test_write_atomic_leaves_no_file_when_interrupted(tmp_path: Path) -> None:
    def boom(fh: Any) -> None:
        fh.write(b"partial")
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        write_atomic(tmp_path / "new.npz", boom)
    assert list(tmp_path.iterdir()) == []  # no target, no temporary file


def test_open_stream_refuses_links_and_inputs_without_truncating(tmp_path: Path) -> None:
    from teamkf.exceptions import ArgumentError

    data = tmp_path / "log.csv"
    data.write_bytes(b"step,agent,y0\n")
    (tmp_path / "link.f8").symlink_to(data)
    os.link(data, tmp_path / "hard.f8")
    with pytest.raises(ArgumentError, match="--stream: .*symbolic link"):
        open_stream(tmp_path / "link.f8", "--stream", inputs=[data])
    with pytest.raises(ArgumentError, match="--stream: .*is also an input"):
        open_stream(tmp_path / "hard.f8", "--stream", inputs=[data])
    assert data.read_bytes() == b"step,agent,y0\n"
    (tmp_path / "old.f8").write_bytes(b"x" * 16)
    with open_stream(tmp_path / "old.f8", "--stream", inputs=[data]) as fh:
        fh.write(b"12345678")
    assert (tmp_path / "old.f8").read_bytes() == b"12345678"  # emptied, then appended to


def test_check_output_names_the_other_output(tmp_path: Path) -> None:
    from teamkf.exceptions import ArgumentError

    with pytest.raises(ArgumentError, match="--record: .* is also the --out of this command"):
        check_output(tmp_path / "sub" / ".." / "x.csv", "--record", outputs=[(tmp_path / "x.csv", "--out")])
