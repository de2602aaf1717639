"""Open the built documentation site as a reader does: headless Chromium, 1280 x 800, no network.

:func:`check_site` serves ``docs/_build/html`` on 127.0.0.1, follows every link from ``index.html``
to the site's own pages, opens each one in Chromium (Debian's ``chromium``, driven by playwright)
with every request to another host blocked, and returns what it found wrong, page by page:

* a request for anything that is not on the site (a font, a script, an image from another host);
* maths not typeset: a ``.math`` element without MathJax's output, or a MathJax error;
* something cut off or scrolling sideways: the page wider than the window, or an element (an image,
  a table, a code block, a formula) reaching past the window's right edge without a box of its own
  that scrolls;
* a word about how the project is made rather than what the package does (a session, an issue
  number, a workspace path).
"""

from __future__ import annotations

import functools
import http.server
import re
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from html.parser import HTMLParser
from pathlib import Path
from urllib.parse import urldefrag, urljoin, urlparse

CHROMIUM = Path("/usr/bin/chromium")
VIEWPORT = {"width": 1280, "height": 800}

#: words about how the project is made, not about the package (each with why it is one)
PROCESS_WORDS = {
    r"\bsessions?\b": "a work session",
    r"\bissues? #?\d+": "an issue number",
    r"(?<![\w.])shared/": "a workspace path",
    r"/work/": "a workspace path",
    r"\bworktree\b": "a workspace word",
}

# Runs in the page: the problems a reader sees, as strings.
PAGE_CHECKS_JS = r"""
async () => {
  const out = [];
  const maths = Array.from(document.querySelectorAll('.math'));
  if (maths.length) {
    if (!window.MathJax || !window.MathJax.startup) {
      out.push('maths: MathJax did not load (' + maths.length + ' formulas shown as raw TeX)');
    } else {
      await window.MathJax.startup.promise;
      const raw = maths.filter(m => !m.querySelector('mjx-container'));
      if (raw.length) out.push('maths: ' + raw.length + ' formulas not typeset, e.g. ' + raw[0].textContent.slice(0, 60));
      const errs = document.querySelectorAll('mjx-merror');
      if (errs.length) out.push('maths: ' + errs.length + ' MathJax errors, e.g. ' + errs[0].textContent.slice(0, 60));
    }
  }
  const W = document.documentElement.clientWidth;
  if (document.documentElement.scrollWidth > W + 1) {
    out.push('the page scrolls sideways: ' + document.documentElement.scrollWidth + ' px wide in a ' + W + ' px window');
  }
  const scrolls = (el) => {
    for (let a = el.parentElement; a && a !== document.body; a = a.parentElement) {
      const s = getComputedStyle(a).overflowX;
      if (s === 'auto' || s === 'scroll') return true;
    }
    return false;
  };
  const visible = (el) => el.getClientRects().length > 0 && getComputedStyle(el).visibility !== 'hidden';
  const sel = 'article img, article table, article pre, article mjx-container, article dl, article p';
  for (const el of document.querySelectorAll(sel)) {
    if (!visible(el)) continue;
    const r = el.getBoundingClientRect();
    if (r.right > W + 1 && !scrolls(el)) {
      out.push('cut off: <' + el.tagName.toLowerCase() + '> reaches ' + Math.round(r.right) + ' px: ' + (el.textContent || el.getAttribute('src') || '').trim().slice(0, 60));
    }
  }
  for (const img of document.querySelectorAll('article img')) {
    if (visible(img) && img.complete && img.naturalWidth === 0) out.push('image not shown: ' + img.getAttribute('src'));
  }
  return out;
}
"""


class _Links(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.hrefs: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        if tag == "a":
            href = dict(attrs).get("href")
            if href:
                self.hrefs.append(href)


def pages_from_index(root: Path) -> list[str]:
    """Every page of the site reached from ``index.html`` by its links (paths relative to ``root``)."""
    seen = {"index.html"}
    todo = ["index.html"]
    while todo:
        rel = todo.pop()
        parser = _Links()
        parser.feed((root / rel).read_text(encoding="utf-8"))
        for href in parser.hrefs:
            url = urlparse(urldefrag(urljoin("http://site/" + rel, href)).url)
            if url.netloc != "site" or not url.path.endswith(".html"):
                continue
            target = url.path.lstrip("/")
            if target not in seen and (root / target).is_file():
                seen.add(target)
                todo.append(target)
    return sorted(seen)


def process_words(text: str) -> list[str]:
    """The words of ``text`` about how the project is made (see :data:`PROCESS_WORDS`)."""
    found = []
    for pattern, what in PROCESS_WORDS.items():
        for m in re.finditer(pattern, text, flags=re.I):
            ctx = text[max(0, m.start() - 40) : m.end() + 40].replace("\n", " ")
            found.append(f"{what}: ...{ctx}...")
    return found


@contextmanager
def serve(root: Path) -> Iterator[str]:
    """Serve ``root`` on 127.0.0.1 (a free port); yield the base URL."""
    handler = functools.partial(_QuietHandler, directory=str(root))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}/"
    finally:
        server.shutdown()
        server.server_close()


class _QuietHandler(http.server.SimpleHTTPRequestHandler):
    def log_message(self, format: str, *args: object) -> None:  # noqa: A002 - the base class's name
        pass


@dataclass
class SiteReport:
    """What :func:`check_site` found: the pages opened and the problems of each."""

    pages: list[str]
    problems: dict[str, list[str]] = field(default_factory=dict)
    typeset: int = 0  # formulas MathJax typeset, over the whole site

    def lines(self) -> list[str]:
        return [f"{page}: {p}" for page, ps in self.problems.items() for p in ps]


def check_site(root: Path, pages: list[str] | None = None) -> SiteReport:
    """Open every page (default: every page reached from index.html) and collect its problems."""
    from playwright.sync_api import sync_playwright

    pages = pages_from_index(root) if pages is None else pages
    report = SiteReport(pages=pages)
    with serve(root) as base, sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=str(CHROMIUM), args=["--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage"])
        context = browser.new_context(viewport=VIEWPORT, service_workers="block")
        outside: list[str] = []

        def route(r):  # every request: the site's own, or blocked and recorded
            if r.request.url.startswith(base) or r.request.url.startswith(("data:", "blob:", "about:")):
                r.continue_()
            else:
                outside.append(r.request.url)
                r.abort()

        context.route("**/*", route)
        page = context.new_page()
        for rel in pages:
            outside.clear()
            problems: list[str] = []
            page.goto(base + rel, wait_until="load")
            problems += page.evaluate(PAGE_CHECKS_JS)
            problems += [f"a request leaves the site: {u}" for u in sorted(set(outside))]
            problems += process_words(page.inner_text("body"))
            report.typeset += page.evaluate("() => document.querySelectorAll('.math mjx-container').length")
            if problems:
                report.problems[rel] = problems
        browser.close()
    return report
