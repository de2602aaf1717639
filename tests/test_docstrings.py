"""Every callable in ``teamkf.__all__`` has a complete numpydoc docstring whose examples run.

numpydoc's own validator (``numpydoc.validate``) checks each one for the sections a reader needs:
a one-line summary, every parameter documented with a description and no parameter that does not
exist, a Returns section where the function returns a value, and an Examples section. The
examples are then run as doctests, exactly as written (``make test`` runs this file).
"""

from __future__ import annotations

import doctest
import inspect
import warnings

import pytest

import teamkf

numpydoc_validate = pytest.importorskip("numpydoc.validate", reason="the docstring checks need numpydoc: pip install 'teamkf[docs]'")

#: numpydoc's checks that must pass (see numpydoc.validate.ERROR_MSGS for the texts)
REQUIRED = {
    "GL08": "no docstring",
    "SS01": "no summary",
    "PR01": "a parameter not documented",
    "PR02": "a documented parameter that does not exist",
    "PR07": "a parameter without a description",
    "RT01": "no Returns section",
    "EX01": "no Examples section",
}

PUBLIC = [n for n in teamkf.__all__ if callable(getattr(teamkf, n))]


def _returns_nothing(obj: object) -> bool:
    """A function annotated ``-> None`` needs no Returns section."""
    if inspect.isclass(obj):
        return True
    try:
        ann = inspect.signature(obj).return_annotation  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return False
    return ann in (None, "None")


def test_the_public_api_has_callables():
    assert len(PUBLIC) >= 30, PUBLIC


@pytest.mark.parametrize("name", PUBLIC)
def test_numpydoc_validation(name):
    obj = getattr(teamkf, name)
    with warnings.catch_warnings(record=True) as caught:  # numpydoc warns about a section it cannot parse
        warnings.simplefilter("always")
        result = numpydoc_validate.validate(f"teamkf.{name}")
    garbled = [str(w.message) for w in caught if "section" in str(w.message).lower() or "underline" in str(w.message).lower()]
    assert not garbled, f"teamkf.{name}: numpydoc cannot parse the docstring: {garbled}"
    errors = [(code, msg) for code, msg in result["errors"] if code in REQUIRED]
    if _returns_nothing(obj):
        errors = [(c, m) for c, m in errors if c != "RT01"]
    assert not errors, f"teamkf.{name} ({result['file']}:{result['file_line']}):\n" + "\n".join(f"  {c} {REQUIRED[c]}: {m}" for c, m in errors)


@pytest.mark.parametrize("name", PUBLIC)
def test_docstring_examples_run(name):
    obj = getattr(teamkf, name)
    finder = doctest.DocTestFinder(recurse=False)
    tests = [t for t in finder.find(obj, f"teamkf.{name}", globs={}) if t.examples]
    assert tests, f"teamkf.{name}: no example to run"
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    for t in tests:
        runner.run(t)
    assert runner.failures == 0, f"teamkf.{name}: {runner.failures} docstring examples failed (run it: python -m pytest {__file__} -k {name} -s)"
