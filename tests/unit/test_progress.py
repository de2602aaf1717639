"""teamkf._progress: a bar on a terminal, silent when not a TTY, under quiet, with progress=False or TEAMKF_PROGRESS=0."""

import io

import pytest

from teamkf import _progress as P

pytest.importorskip("tqdm")


class FakeTTY(io.StringIO):
    def isatty(self):
        return True


@pytest.fixture(autouse=True)
def _env(monkeypatch):
    monkeypatch.delenv("TEAMKF_PROGRESS", raising=False)
    old = P.set_quiet(False)
    yield
    P.set_quiet(old)


def test_bar_on_a_terminal():
    tty = FakeTTY()
    items = list(range(5))
    wrapped = P.progress(items, desc="work", stream=tty, delay=0)
    assert wrapped is not items
    assert list(wrapped) == items  # same items, in order
    out = tty.getvalue()
    assert "work:" in out and "/5 " in out  # the bar (cleared at the end: leave=False)


@pytest.mark.parametrize("how", ["not-a-tty", "enabled-false", "env", "quiet", "quiet-context"])
def test_silent(how, monkeypatch):
    items = list(range(3))
    stream = io.StringIO() if how == "not-a-tty" else FakeTTY()
    kwargs = {"stream": stream, "delay": 0}
    if how == "enabled-false":
        kwargs["enabled"] = False
    if how == "env":
        monkeypatch.setenv("TEAMKF_PROGRESS", "0")
    if how == "quiet":
        P.set_quiet(True)
    if how == "quiet-context":
        with P.quiet():
            assert P.progress(items, **kwargs) is items
        assert P.progress(items, **kwargs) is not items  # restored after the block
        return
    assert P.progress(items, **kwargs) is items
    assert stream.getvalue() == ""


def test_delay_keeps_short_loops_silent():
    tty = FakeTTY()
    assert list(P.progress(range(3), stream=tty, delay=60)) == [0, 1, 2]
    assert tty.getvalue().strip() == ""
