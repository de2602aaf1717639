"""The small walls: a closed pipe ends silently, progress bars on a (pseudo-)terminal, a sweep grid that a
scenario file would refuse, and a family that sends nothing labelled as such.

The progress tests run the command in a child process whose stderr is the slave side of a pseudo-terminal
(``os.openpty``), as a user's terminal would be, with the bars' delay lowered from 2 s so that each test
takes about a second; and the same job with stderr on a pipe, where nothing may be drawn.
"""

from __future__ import annotations

import importlib.util
import os
import select
import shutil
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from teamkf.exceptions import ScenarioError
from teamkf.study.scenario import load_packaged, scenario_from_dict, set_dotted
from teamkf.study.sweep import load_sweep

ROOT = Path(__file__).resolve().parents[2]
HAS_TQDM = importlib.util.find_spec("tqdm") is not None
needs_tqdm = pytest.mark.skipif(not HAS_TQDM, reason="progress bars need tqdm (the dask extra)")
needs_pty = pytest.mark.skipif(not hasattr(os, "openpty") or sys.platform == "win32", reason="needs a POSIX pseudo-terminal")


def _env(**extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in ("TEAMKF_PROGRESS", "COLUMNS", "LINES")}
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT / "src"), env.get("PYTHONPATH", "")])
    env["MPLBACKEND"] = "Agg"
    return {**env, **extra}


# ---------------------------------------------------------------------------
# a closed pipe
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("argv", [["families"], ["reproduce", "--list"], ["--help"]])
def test_output_into_a_closed_pipe_is_silent(argv):
    """``teamkf ... | head`` after head has left: no 'Broken pipe' error, no traceback; status 1 (CPython's advice)."""
    r, w = os.pipe()
    os.close(r)  # the reader is gone: every write gets EPIPE
    try:
        proc = subprocess.run([sys.executable, "-m", "teamkf", *argv], stdout=w, stderr=subprocess.PIPE, text=True, env=_env(), timeout=120)
    finally:
        os.close(w)
    assert proc.stderr == "", proc.stderr
    assert proc.returncode in ((0, 1) if argv == ["--help"] else (1,))  # argparse itself ignores a failed help write


@pytest.mark.skipif(shutil.which("head") is None or shutil.which("bash") is None, reason="needs bash and head")
@pytest.mark.parametrize("lines", [1, 0])
def test_piping_into_head_is_silent(lines):
    """``| head -n 0`` leaves before teamkf writes (always EPIPE); ``| head -1`` may or may not have left by then."""
    cmd = f"{sys.executable} -m teamkf families | head -n {lines}; exit ${{PIPESTATUS[0]}}"
    proc = subprocess.run(["bash", "-c", cmd], capture_output=True, text=True, env=_env(), timeout=120)
    assert proc.stdout.split()[:2] == (["family", "cost"] if lines else [])
    assert proc.stderr == "", proc.stderr  # old: "teamkf: error: Broken pipe", status 2
    assert proc.returncode in ((0, 1) if lines else (1,))


# ---------------------------------------------------------------------------
# progress bars
# ---------------------------------------------------------------------------
#: a child that lowers the bars' delay, optionally shrinks the robustness grid, and runs ``teamkf ARGV``
CHILD = textwrap.dedent(
    """
    import sys
    import teamkf._progress as P
    P.DELAY = float(sys.argv[1])
    if sys.argv[2] == "small-robustness":
        import teamkf.experiments.robustness as R
        R.SCENARIOS, R.P_QUICK, R.J_QUICK = ("platoon-4",), (0.0, 0.5), (0,)
    from teamkf.cli import main
    raise SystemExit(main(sys.argv[3:]))
    """
)
SLOW = textwrap.dedent(
    """
    import sys, time
    import teamkf._progress as P
    P.DELAY = 0.3
    with P.bar(2, desc="slow work", unit="block") as b:  # one update, after the delay: only a redraw shows it
        time.sleep(1.2)
        b.update()
    """
)


def _on_pty(argv: list[str], *, cwd: Path, timeout: float = 120) -> tuple[int, str]:
    """Run ``argv`` with stderr on a fresh pseudo-terminal that nobody sized (0 x 0, as ``pty.fork`` gives); stderr's text."""
    master, slave = os.openpty()
    proc = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=slave, cwd=cwd, env=_env(), close_fds=True)
    os.close(slave)
    buf, end = b"", time.monotonic() + timeout
    try:
        while time.monotonic() < end:
            ready, _, _ = select.select([master], [], [], 0.2)
            if ready:
                try:
                    data = os.read(master, 65536)
                except OSError:  # the child closed its side (Linux: EIO)
                    data = b""
                if not data:
                    break
                buf += data
            elif proc.poll() is not None:
                break
        rc = proc.wait(timeout=max(1.0, end - time.monotonic()))
    finally:
        os.close(master)
        if proc.poll() is None:  # pragma: no cover - timed out
            proc.kill()
    return rc, buf.decode("utf-8", "replace")


def _bars(text: str, desc: str) -> list[str]:
    """The drawn states of the tqdm bar labelled ``desc`` (``desc: 50%|#### | 1/2 [...]``)."""
    return [part for part in text.replace("\n", "\r").split("\r") if part.startswith(f"{desc}:") and "|" in part]


@needs_tqdm
@needs_pty
def test_bar_is_drawn_on_an_unsized_terminal_when_updates_are_rare(tmp_path):
    """Old: tqdm drew nothing on a 0 x 0 terminal, and nothing until an update came after the delay."""
    rc, text = _on_pty([sys.executable, "-c", SLOW], cwd=tmp_path)
    assert rc == 0, text
    drawn = _bars(text, "slow work")
    assert drawn, f"no bar drawn on a pseudo-terminal: {text!r}"
    assert any("0/2" in d for d in drawn), "the bar is drawn once the delay is over, before the first update"


@needs_tqdm
@needs_pty
@pytest.mark.parametrize(
    "argv, desc",
    [
        (["evaluate", "platoon-4", "--monte-carlo", "1000", "--seed", "1"], "Monte Carlo"),
        (["reproduce", "robustness", "--quick"], "robustness"),
    ],
    ids=["monte-carlo", "reproduce-robustness"],
)
def test_cli_jobs_draw_a_bar_on_a_terminal_and_nothing_elsewhere(argv, desc, tmp_path):
    child = [sys.executable, "-c", CHILD, "0.05", "small-robustness", *argv]
    rc, text = _on_pty(child, cwd=tmp_path)
    assert rc == 0, text
    assert _bars(text, desc), f"teamkf {' '.join(argv)}: no '{desc}' bar on a terminal: {text[-2000:]!r}"
    proc = subprocess.run(child, cwd=tmp_path, env=_env(), capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "%|" not in proc.stderr and "\r" not in proc.stderr, f"a bar was drawn off a terminal: {proc.stderr[-1000:]!r}"


@needs_tqdm
@needs_pty
@pytest.mark.skipif(importlib.util.find_spec("pyarrow") is None, reason="sweeps need the dask extra")
def test_sweep_draws_a_bar_on_a_terminal(tmp_path):
    (tmp_path / "s.toml").write_text('scenario = "platoon-4"\nruns = 0\n[grid]\n"horizon" = [4, 5, 6]\n')
    rc, text = _on_pty([sys.executable, "-c", CHILD, "0.0", "-", "sweep", "s.toml", "--scheduler", "serial", "--out", "r"], cwd=tmp_path)
    assert rc == 0, text
    assert _bars(text, "sweep s"), text[-2000:]


def test_quiet_and_environment_silence_bars(monkeypatch):
    import io

    from teamkf import _progress as P

    class Tty(io.StringIO):
        def isatty(self) -> bool:
            return True

    assert P.progress_enabled(None, Tty()) == HAS_TQDM
    assert not P.progress_enabled(None, io.StringIO())  # not a terminal
    monkeypatch.setenv("TEAMKF_PROGRESS", "0")
    assert not P.progress_enabled(None, Tty())


# ---------------------------------------------------------------------------
# sweep grid = scenario file
# ---------------------------------------------------------------------------
EDGES = [[0, 1, 1], [1, 0, 3], [1, 2, 1], [2, 1, 1], [2, 3, 1], [3, 2, 1]]


def test_graph_delay_on_edges_with_different_delays_is_refused():
    raw = dict(load_packaged("platoon-4").raw)
    raw["graph"] = {"edges": EDGES}
    with pytest.raises(ScenarioError, match="graph.delay") as file_error:
        scenario_from_dict({**raw, "graph": {"edges": EDGES, "delay": 2}})  # what a file with both says
    assert "graph.delay" in str(file_error.value)
    with pytest.raises(ScenarioError, match=r"graph.delay: the graph has explicit edges with different delays \(1, 3\).*set graph.edges"):
        set_dotted(raw, "graph.delay", 2)  # old: every edge's delay silently replaced (the 3 gone)
    assert scenario_from_dict(set_dotted(raw, "graph.edges", [[a, b, 2] for a, b, _ in EDGES])).graph.delay(1, 0) == 2
    uniform = set_dotted(load_packaged("platoon-4").raw, "graph.delay", 2)  # one common delay (the packaged platoon): set
    assert {e[2] for e in uniform["graph"]["edges"]} == {2}


def test_sweep_refuses_a_grid_key_that_a_scenario_file_refuses(tmp_path):
    (tmp_path / "edges.toml").write_text(
        'name = "edges"\nhorizon = 6\nestimators = ["mtmse"]\n[system]\nA = [[0.9, 0], [0.5, 0.9]]\nQ = 1.0\nSigma_x = 1.0\n'
        '[[agents]]\nC = [[1, 0]]\nR = 0.1\n[[agents]]\nC = [[0, 1]]\nR = 0.1\n[graph]\nedges = [[0, 1, 1], [1, 0, 3]]\n[cost]\nkind = "mse"\n'
    )
    (tmp_path / "s.toml").write_text('scenario = "edges.toml"\nruns = 0\n[grid]\n"graph.delay" = [1, 2]\n')
    with pytest.raises(ScenarioError, match=r'grid\["graph.delay"\] = 1: graph.delay: the graph has explicit edges with different delays'):
        load_sweep(tmp_path / "s.toml")  # refused when read, before any point runs
    from teamkf.cli import main

    assert main(["sweep", str(tmp_path / "s.toml"), "--scheduler", "serial", "--out", str(tmp_path / "r")]) == 2
    assert not (tmp_path / "r").exists()


# ---------------------------------------------------------------------------
# a family that sends nothing
# ---------------------------------------------------------------------------
def test_local_is_not_labelled_with_an_exchange_variant():
    """Old: 'local [honest]', though local's agents send nothing."""
    from teamkf import families
    from teamkf.experiments.leaderboard import _label
    from teamkf.study.evaluation import evaluate

    sc = load_packaged("platoon-4").updated({"horizon": 6, "estimators": ["local", "kcf"]})
    labels = [r["label"] for r in evaluate(sc).rows]
    assert labels == ["local", "kcf [honest]"]
    assert families()["local"].design(sc.system, sc.cost, sc.graph, 6).label == "local"
    row = {"estimator": "local", "variant": "honest", "form": "published defaults", "diverging": False}
    assert _label(row) == "local"
    assert _label({**row, "estimator": "kcf"}) == "kcf honest"
