"""The documentation site: every experiment and example has a gallery page, and the built HTML holds what it should.

The build test runs ``sphinx-build -E -W --keep-going`` (the command of ``make docs``) into
``docs/_build/html``; sphinx-gallery re-runs only the scripts that changed, so after ``make docs``
it takes about a minute. ``make test`` builds the site only here (once). The browser test then opens
every page reached from index.html in Debian's chromium (tests/_site_browser.py), a few minutes.
They are skipped, with the reason, when the ``docs`` extra (sphinx and its extensions, playwright)
or chromium is not installed.
"""

from __future__ import annotations

import ast
import html
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

import teamkf
from teamkf import experiments

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
OUT = DOCS / "_build" / "html"
GALLERY = DOCS / "gallery"
EXAMPLES = sorted((ROOT / "examples").glob("*.py"))

#: one pytest-xdist worker should run this module (`--dist loadgroup`); the site's lock holds where that is not honoured
pytestmark = pytest.mark.xdist_group("docs-site")


def gallery_script(name: str) -> Path:
    """The gallery page of ``teamkf reproduce NAME``: ``docs/gallery/plot_<name with _>.py``."""
    return GALLERY / f"plot_{name.replace('-', '_')}.py"


# --- no build needed -------------------------------------------------------------------------------
@pytest.mark.parametrize("name", experiments.names())
def test_every_experiment_has_a_gallery_page(name):
    path = gallery_script(name)
    assert path.is_file(), f"experiment {name!r} has no gallery page: add {path.relative_to(ROOT)} (copy another plot_*.py)"
    tree = ast.parse(path.read_text(encoding="utf-8"))
    calls = [
        n
        for n in ast.walk(tree)
        if isinstance(n, ast.Call) and isinstance(n.func, ast.Attribute) and n.func.attr == "run" and n.args and isinstance(n.args[0], ast.Constant)
    ]
    assert [c.args[0].value for c in calls] == [name], f"{path.name} must run experiments.run({name!r}, ...) once"
    quick = [k for c in calls for k in c.keywords if k.arg == "quick"]
    assert quick and isinstance(quick[0].value, ast.Constant) and quick[0].value.value is True, f"{path.name}: run it with quick=True"
    doc = ast.get_docstring(tree) or ""
    title = doc.strip().splitlines()[:2]
    assert len(title) == 2 and set(title[1]) == {"="} and len(title[1]) == len(title[0]), f"{path.name}: the docstring starts with a reST title"


def test_no_gallery_page_without_an_experiment():
    names = {gallery_script(n).name for n in experiments.names()}
    orphans = sorted(p.name for p in GALLERY.glob("plot_*.py") if p.name not in names)
    assert not orphans, f"gallery pages of no registered experiment: {orphans}"


# --- the built site ----------------------------------------------------------------------------------
def _require_sphinx() -> None:
    for mod in ("sphinx", "sphinx_gallery", "numpydoc", "myst_parser", "pydata_sphinx_theme", "matplotlib"):
        pytest.importorskip(mod, reason=f"the docs build needs {mod}: pip install 'teamkf[docs]'")


def _build_site() -> None:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT / "src"), os.environ.get("PYTHONPATH", "")]), "MPLBACKEND": "Agg"}
    env["TEAMKF_PROGRESS"] = "0"
    cmd = [sys.executable, "-m", "sphinx", "-E", "-b", "html", "-W", "--keep-going", "-q", str(DOCS), str(OUT)]
    proc = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, f"make docs failed ({' '.join(cmd)}):\n{proc.stdout[-4000:]}\n{proc.stderr[-8000:]}"
    # numpydoc reports a docstring section it cannot parse as a Python warning, not a Sphinx one
    bad = [line for line in proc.stderr.splitlines() if "Unknown section" in line or "Potentially wrong underline" in line]
    assert not bad, "docstrings numpydoc cannot parse:\n" + "\n".join(bad)


@pytest.fixture(scope="session")
def site() -> Path:
    """The site, built once per test run: pytest-xdist workers take a file lock, and the first one builds it.

    Two builds at once in the same folder fail (each removes the other's generated API stubs), and the xdist
    group of this module is not honoured by every pytest/xdist pair, so the lock is what keeps it to one.
    """
    _require_sphinx()
    import fcntl

    OUT.parent.mkdir(parents=True, exist_ok=True)
    run = os.environ.get("PYTEST_XDIST_TESTRUNUID")  # the same in every worker of one run; absent without xdist
    done = OUT.parent / ".built-for-run"
    with open(OUT.parent / ".build-lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            if run is None or not done.is_file() or done.read_text() != run:
                done.unlink(missing_ok=True)
                _build_site()
                if run is not None:
                    done.write_text(run)
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)
    return OUT


def _page(site: Path, rel: str) -> str:
    path = site / rel
    assert path.is_file(), f"{rel} was not built"
    return path.read_text(encoding="utf-8")


def _text(fragment: str) -> str:
    return html.unescape(re.sub(r"<[^>]+>", "", fragment)).replace("¶", "").replace("#", "").strip()


def _headings(page: str) -> list[str]:
    return [_text(m) for m in re.findall(r"<h[1-4][^>]*>(.*?)</h[1-4]>", page, flags=re.S)]


def _images(site: Path, rel: str, page: str) -> list[Path]:
    """The files of the page's <img> tags (local sources only), checked to exist."""
    srcs = re.findall(r'<img[^>]*\ssrc="([^"]+)"', page)
    files = [(site / rel).parent / s for s in srcs if not s.startswith(("http:", "https:", "data:"))]
    missing = [str(f) for f in files if not f.is_file()]
    assert not missing, f"{rel}: <img> without its file: {missing}"
    return files


@pytest.mark.slow
def test_api_page_of_design_mtmse(site):
    rel = "api/generated/teamkf.design_mtmse.html"
    page = _page(site, rel)
    heads = _headings(page)
    assert heads[0] == "teamkf.design_mtmse"
    assert 'id="teamkf.design_mtmse"' in page  # the autodoc signature
    for section in ("Parameters", "Examples"):
        assert re.search(rf">\s*{section}\s*<", page), f"{rel}: no {section} section"
    assert "Gallery pages using design_mtmse" in heads
    assert _images(site, rel, page), f"{rel}: no gallery thumbnail"


@pytest.mark.slow
def test_user_guide_estimator_table(site):
    rel = "guide/estimators.html"
    page = _page(site, rel)
    heads = _headings(page)
    assert heads[0] == "Choosing an estimator" and "Decision table" in heads
    table = re.search(r'<section id="estimator-table">.*?<table.*?</table>', page, flags=re.S)
    assert table, f"{rel}: no table under 'Decision table'"
    header = [_text(h) for h in re.findall(r"<th[^>]*>(.*?)</th>", table.group(0), flags=re.S)]
    assert header == ["family", "function", "exact or approximate", "handles delays", "scale (measured, see Performance and scale)", "cost"]
    rows = [_text(r.split("</td>")[0]) for r in re.findall(r"<tr[^>]*>\s*<td[^>]*>(.*?)</tr>", table.group(0), flags=re.S)]
    for family in ("centralized", "MTMSE", "per-agent MMSE", "Kalman-consensus", "consensus+innovations", "bulk population", "LQG"):
        assert any(family in r for r in rows), f"{rel}: no row for {family}"
    registered = re.search(r'<section id="the-registered-families">.*?<table.*?</table>', page, flags=re.S)
    assert registered, f"{rel}: no table of the registered families"
    names = [_text(r.split("</td>")[0]) for r in re.findall(r"<tr[^>]*>\s*<td[^>]*>(.*?)</tr>", registered.group(0), flags=re.S)]
    # what a fresh interpreter registers (this process may hold families that tests registered)
    fresh = subprocess.run(
        [sys.executable, "-c", "import teamkf; print(' '.join(teamkf.families()))"],
        env={**os.environ, "PYTHONPATH": str(ROOT / "src")},
        capture_output=True,
        text=True,
        check=True,
    ).stdout.split()
    assert names == fresh, "the registered-families table is generated from teamkf.families()"
    assert _images(site, rel, page), f"{rel}: the comparison figure is missing"


@pytest.mark.slow
def test_gallery_page_of_fig1(site):
    rel = "auto_gallery/plot_fig1.html"
    page = _page(site, rel)
    heads = _headings(page)
    assert heads[0] == "Fig. 1: MTMSE vs MMSE, two agents"
    imgs = [p for p in _images(site, rel, page) if "sphx_glr_plot_fig1" in p.name]
    assert imgs and imgs[0].stat().st_size > 5000, f"{rel}: the experiment's figure is not shown"
    assert 'class="teamkf-table"' in page  # the result table (ExperimentResult._repr_html_)
    for col in experiments.run("fig1", None, quick=True).columns:
        assert f"<th>{html.escape(col)}</th>" in page


@pytest.mark.slow
def test_every_gallery_page_shows_its_figure_and_table(site):
    for name in experiments.names():
        rel = f"auto_gallery/{gallery_script(name).stem}.html"
        page = _page(site, rel)
        assert 'class="teamkf-table"' in page, f"{rel}: no result table"
        assert any(p.name.startswith("sphx_glr_plot_") for p in _images(site, rel, page)), f"{rel}: no figure"
    for ex in EXAMPLES:
        rel = f"auto_examples/{ex.stem}.html"
        page = _page(site, rel)
        assert "sphx-glr-script-out" in page, f"{rel}: the example's output is not shown"


@pytest.mark.slow
def test_every_public_name_is_in_the_api_reference(site):
    page = _page(site, "api/index.html")
    names = [n for n in teamkf.__all__]
    assert names, "teamkf.__all__ is empty"
    missing = [n for n in names if f'id="teamkf.{n}"' not in page and f'href="generated/teamkf.{n}.html' not in page]
    assert not missing, f"public names missing from the API reference: {missing}"
    for n in names:
        if callable(getattr(teamkf, n)):
            assert (site / "api" / "generated" / f"teamkf.{n}.html").is_file(), f"no API page for teamkf.{n}"


# --- the site as a reader sees it: headless Chromium, 1280 x 800, no network --------------------------
@pytest.fixture(scope="module")
def browser_report(site):
    from tests import _site_browser

    pytest.importorskip("playwright", reason="the browser test needs playwright: pip install 'teamkf[docs]'")
    if not _site_browser.CHROMIUM.is_file():
        pytest.skip(f"the browser test needs Debian's chromium at {_site_browser.CHROMIUM}: apt-get install chromium")
    return _site_browser.check_site(site)


@pytest.mark.slow
def test_site_in_a_browser_offline(browser_report):
    """Every page reached from index.html: no request leaves the site, maths typeset, nothing cut off, no process words."""
    report = browser_report
    assert len(report.pages) > 100, f"only {len(report.pages)} pages reached from index.html"
    assert report.typeset > 100, f"only {report.typeset} formulas typeset on the whole site"
    problems = report.lines()
    assert not problems, f"{len(problems)} problems on {len(report.problems)} of {len(report.pages)} pages:\n" + "\n".join(problems[:80])


def test_site_checker_finds_what_it_looks_for(tmp_path):
    """The checker itself: a page with a remote script, raw TeX, a too-wide image and a process word is caught."""
    from tests import _site_browser

    pytest.importorskip("playwright", reason="the browser test needs playwright: pip install 'teamkf[docs]'")
    if not _site_browser.CHROMIUM.is_file():
        pytest.skip(f"the browser test needs Debian's chromium at {_site_browser.CHROMIUM}: apt-get install chromium")
    (tmp_path / "index.html").write_text(
        '<html><body><article><a href="good.html">good</a>'
        '<span class="math">\\(n = 4\\)</span><p>as decided in session 3 (issue 13)</p>'
        '<img src="wide.svg" width="2000" height="10"><script src="http://example.invalid/x.js"></script>'
        "</article></body></html>"
    )
    (tmp_path / "wide.svg").write_text('<svg xmlns="http://www.w3.org/2000/svg" width="2000" height="10"></svg>')
    (tmp_path / "good.html").write_text(
        '<html><body><article><p>fine</p><div style="overflow-x:auto"><pre style="width:3000px">x</pre></div></article></body></html>'
    )
    report = _site_browser.check_site(tmp_path)
    assert report.pages == ["good.html", "index.html"]
    assert "good.html" not in report.problems, report.problems
    found = "\n".join(report.problems["index.html"])
    for what in (
        "MathJax did not load",
        "request leaves the site: http://example.invalid/x.js",
        "cut off: <img>",
        "a work session",
        "an issue number",
    ):
        assert what in found, f"the checker missed {what!r}:\n{found}"
