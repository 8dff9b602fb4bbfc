"""The documentation site: built with ``mkdocs build --strict`` and every page opened in headless Chromium.

The pictures are generated first (``docs/make_images.py`` into ``docs/images/``, as ``make docs`` does;
it redraws only what changed). The site is then built into a temporary folder and checked both ways a
reader opens it: served on 127.0.0.1 (HTTP), and from disk (``file://``, ``site/index.html`` opened
directly). Every HTML page is opened through playwright with the system's Chromium, one browser per way,
and a page fails on

- an error in the browser console, or an uncaught script error;
- a failed request (a 4xx/5xx answer, a network failure, a file not found), a request to any other host
  (fonts, scripts from a CDN: the site must work offline);
- an image that did not load (``naturalWidth`` 0);
- a link into the site to a file that is not there, or to an ``#anchor`` no element of its page has;
  from disk also a link to a folder (the browser shows a directory listing there, not the page).

Each way, the search is used too: a word of the docs typed into Material's search box must list results
(from disk this needs Material's offline plugin and docs/hooks/offline.py). From disk, a sample of the
navigation's links is followed and each must show its page (a title and a heading, not a listing); and the
built HTML is read without a browser: every ``href``/``src`` into the site (links, navigation, images,
styles, scripts) must name a file, relative to its page.

Self-checks run the same checks on a copy of the site with a broken page added, and expect each problem
to be reported: the checks can fail.
"""
from __future__ import annotations

import functools
import html.parser
import http.server
import os
import posixpath
import re
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Self
from urllib.parse import unquote, urlsplit

import pytest

ROOT = Path(__file__).resolve().parents[1]
CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


def chromium_path() -> str | None:
    """The system's Chromium: ``$FACEGEOM_CHROMIUM``, else the first of :data:`CHROMIUM_NAMES` on the PATH."""
    given = os.environ.get("FACEGEOM_CHROMIUM")
    if given:
        return given if Path(given).is_file() else None
    return next((p for p in map(shutil.which, CHROMIUM_NAMES) if p), None)


@pytest.fixture(scope="module")
def chromium() -> str:
    """The Chromium executable, with playwright to drive it; skips (saying which) when either is missing."""
    pytest.importorskip("playwright.async_api", reason="playwright is not installed (the test extra has it: "
                        "pip install -e '.[test]')")
    exe = chromium_path()
    if exe is None:
        pytest.skip("no Chromium found (apt-get install chromium, or set $FACEGEOM_CHROMIUM to its executable)")
    return exe


@pytest.fixture(scope="module")
def site(face_model, tmp_path_factory) -> Path:
    """The pictures generated, then the site built with ``mkdocs build --strict`` into a temporary folder."""
    env = {**os.environ, "MPLBACKEND": "Agg", "NO_MKDOCS_2_WARNING": "1"}
    images = subprocess.run([sys.executable, str(ROOT / "docs" / "make_images.py"), "--out",
                             str(ROOT / "docs" / "images")], cwd=ROOT, env=env, capture_output=True, text=True,
                            check=False)
    assert images.returncode == 0, f"docs/make_images.py failed:\n{images.stdout}{images.stderr}"
    out = tmp_path_factory.mktemp("docs") / "site"
    build = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--config-file",
                            str(ROOT / "mkdocs.yml"), "--site-dir", str(out)], cwd=ROOT, env=env,
                           capture_output=True, text=True, check=False)
    assert build.returncode == 0, f"mkdocs build --strict failed:\n{build.stdout}{build.stderr}"
    return out


class Server:
    """``folder`` served over HTTP on 127.0.0.1 at a free port, in a thread."""

    def __init__(self, folder: Path):
        handler = functools.partial(_QuietHandler, directory=str(folder))
        self.httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
        self.base = f"http://127.0.0.1:{self.httpd.server_address[1]}/"
        self.thread = threading.Thread(target=self.httpd.serve_forever, daemon=True)

    def __enter__(self) -> Self:
        self.thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()
        self.thread.join(timeout=5)


class _QuietHandler(http.server.SimpleHTTPRequestHandler):
    def log_message(self, format, *args):  # the base class's signature
        pass


def html_pages(folder: Path) -> list[str]:
    """Every HTML file of a built site, as paths relative to it (``index.html``, ``howto/drive.html``)."""
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*.html"))


# the page a web server shows for a missing address: its links are absolute (/assets/...), as it may be
# shown at any depth, and from disk it is never reached, so it is checked over HTTP only
NOT_FOUND_PAGE = "404.html"
SEARCH_WORD = "retarget"  # a word the docs use: searching for it must list pages


# the attribute of each element that refers to a file: links, styles, scripts, images, frames
_REF_ATTRS = {"a": "href", "link": "href", "img": "src", "script": "src", "source": "src", "iframe": "src"}


class _Refs(html.parser.HTMLParser):
    """The ``href`` and ``src`` values (:data:`_REF_ATTRS`) of a page."""

    def __init__(self):
        super().__init__()
        self.refs: list[str] = []

    def handle_starttag(self, tag, attrs):
        name = _REF_ATTRS.get(tag)
        value = dict(attrs).get(name) if name else None
        if value is not None:
            self.refs.append(value)


def static_link_problems(folder: Path, pages: list[str]) -> dict[str, list[str]]:
    """Read the built HTML of ``pages``: every reference into the site must name a file, relative to its page.

    A reference is each ``<a href>``, ``<link href>``, ``<img src>``, ``<script src>``, ``<source src>`` and
    ``<iframe src>``; other sites (``http(s)://``, ``mailto:``, ``data:``) and links to an anchor of the
    same page are left out. Opened from disk, a reference to a folder shows a directory listing, and an
    absolute path (``/assets/...``) names a file from the disk's root: both are problems, as are a file
    that is not there and a path that leaves the site.
    """
    problems: dict[str, list[str]] = {}
    for rel in pages:
        parser = _Refs()
        parser.feed((folder / rel).read_text(encoding="utf-8"))
        found = problems.setdefault(rel, [])
        for ref in sorted(set(parser.refs)):
            parts = urlsplit(ref)
            if parts.scheme or parts.netloc or not parts.path:
                continue  # another site, mailto:, data:, or an anchor of this page
            path = unquote(parts.path)
            if path.startswith("/"):
                found.append(f"absolute path {ref!r}: from disk it names a file from the disk's root")
                continue
            target = posixpath.normpath(posixpath.join(posixpath.dirname(rel), path))
            if target == ".." or target.startswith("../"):
                found.append(f"{ref!r} leaves the site")
            elif path.endswith("/") or (folder / target).is_dir():
                found.append(f"link to a folder: {ref!r} (from disk the browser lists the folder {target}/)")
            elif not (folder / target).is_file():
                found.append(f"{ref!r}: no file {target}")
    return problems


# JavaScript run in each page once it has loaded: lazy images are loaded too, then the page's ids, the
# images that did not load and the links are read
_INSPECT = """async () => {
  const imgs = Array.from(document.images);
  for (const img of imgs) { img.loading = "eager"; }
  await Promise.all(imgs.map(img => img.decode().catch(() => null)));
  return {
    ids: Array.from(document.querySelectorAll("[id]"), e => e.id)
      .concat(Array.from(document.querySelectorAll("a[name]"), e => e.name)),
    broken_images: imgs.filter(i => !i.complete || i.naturalWidth === 0).map(i => i.currentSrc || i.src),
    links: Array.from(document.querySelectorAll("a[href]"), a => a.href),
  };
}"""


OTHER = "(a worker or a request no page made)"  # where requests that no page made are reported
SEARCH = "(search)"  # where the search check reports
NAV = "(navigation followed)"  # where following the navigation reports

# JavaScript polled once a word is typed into the search box: true when results are listed (Material lists
# each result as an .md-search-result__item and writes "N matching documents" above them)
_FOUND = """() => document.querySelectorAll(".md-search-result__item").length > 0
  && /[0-9]+ matching documents?/.test(
    (document.querySelector(".md-search-result__meta") || {}).textContent || "")"""

# JavaScript run in a page reached through the navigation: what it shows
_SHOWN = """() => ({
  title: document.title,
  heading: (document.querySelector(".md-content h1") || {}).textContent || "",
})"""


def check_pages(chromium: str, folder: Path, pages: list[str], concurrency: int = 4, *, from_disk: bool = False,
                search: str | None = None, follow_nav: int = 0) -> dict[str, list[str]]:
    """Open ``pages`` of the site in ``folder`` and return the problems found, by page (empty lists if none).

    The site is served over HTTP, or opened from disk (``file://`` URLs) with ``from_disk``. Pages are opened
    in one headless Chromium by ``concurrency`` tabs, each going from page to page. Links are checked after every page has been read: a
    link's file must exist in ``folder`` (from disk a link must name a file, not a folder) and its
    ``#anchor`` must be an id of that page (the page must be one of ``pages`` when it has an anchor).

    With ``search``, that word is typed into the search box of ``index.html`` and results must be listed
    (their links are checked like the pages' links), reported under :data:`SEARCH`. With ``follow_nav``,
    about that many links of ``index.html``'s navigation, spread over it, are followed in one tab and each
    must show a page (a title naming the site and a heading), reported under :data:`NAV`.
    """
    import asyncio

    from playwright.async_api import Error as PlaywrightError
    from playwright.async_api import TimeoutError as PlaywrightTimeout
    from playwright.async_api import async_playwright

    problems: dict[str, list[str]] = {p: [] for p in [*pages, OTHER, SEARCH, NAV]}
    ids: dict[str, set[str]] = {}
    links: dict[str, list[str]] = {}

    async def run(base: str) -> None:
        async with async_playwright() as pw:
            browser = await pw.chromium.launch(executable_path=chromium, headless=True)
            context = await browser.new_context()
            opened: dict[object, str] = {}  # playwright page -> the site page it shows

            async def route(r):  # a request to any other place than the site (the route's pattern)
                url = r.request.url
                try:
                    where = opened.get(r.request.frame.page, OTHER)
                except PlaywrightError:  # a worker's request has no frame
                    where = OTHER
                problems[where].append(f"request to another host: {url}")
                await r.abort()

            # only requests to other places come to Python (one round trip each), the site's own go on
            await context.route(re.compile(f"^(?!{re.escape(base)}|data:|blob:)"), route)

            async def new_tab():
                """A tab and where its problems go: ``at["where"]`` (a page, or SEARCH, NAV). With
                ``at["moves_on"]`` the tab leaves pages before they finish loading, so requests aborted by
                that are not problems (those pages are checked on their own)."""
                page = await context.new_page()
                at = {"where": OTHER, "moves_on": False}

                def report(message: str) -> None:
                    problems[at["where"]].append(message)

                page.on("console", lambda m: m.type == "error" and report(f"console error: {m.text}"))
                page.on("pageerror", lambda e: report(f"script error: {e}"))
                page.on("requestfailed", lambda r: r.url.startswith(base)
                        and not (at["moves_on"] and "ERR_ABORTED" in (r.failure or ""))
                        and report(f"request failed: {r.url} ({r.failure})"))
                page.on("response", lambda r: r.status >= 400 and report(f"HTTP {r.status}: {r.url}"))
                return page, at

            async def check(page, rel: str) -> None:
                await page.goto(base + rel, wait_until="load")
                await page.wait_for_load_state("networkidle")
                found = await page.evaluate(_INSPECT)
                ids[rel] = set(found["ids"])
                links[rel] = found["links"]
                for src in found["broken_images"]:
                    problems[rel].append(f"image did not load: {src}")

            async def check_search(page, word: str) -> None:
                await page.goto(base + "index.html", wait_until="load")
                box = page.locator("input.md-search__input")
                if not await box.is_visible():
                    problems[SEARCH].append("the search box is hidden (Material hides it when its search "
                                            "worker cannot start)")
                    return
                # Material reads the box on a key's release (keyup), so a key is pressed after the word is in;
                # the query waits for the search worker to have built its index
                await box.fill(word)
                await box.press("End")
                try:
                    await page.wait_for_function(_FOUND, timeout=15_000)
                except PlaywrightTimeout:
                    meta = await page.locator(".md-search-result__meta").all_inner_texts()
                    problems[SEARCH].append(f"searching for {word!r} listed no results in 15 s "
                                            f"(the search box says {' '.join(meta).strip()!r})")
                    return
                links[SEARCH] = await page.eval_on_selector_all(
                    ".md-search-result__item a[href]", "as => as.map(a => a.href)")

            async def follow(page, count: int) -> None:
                await page.goto(base + "index.html", wait_until="load")
                hrefs = await page.eval_on_selector_all(
                    ".md-nav--primary a.md-nav__link[href]",
                    "as => [...new Set(as.map(a => a.href.split('#')[0]))]")
                if len(hrefs) < count:
                    problems[NAV].append(f"only {len(hrefs)} links in the navigation: {hrefs}")
                for href in hrefs[::max(1, len(hrefs) // max(count, 1))][:count]:
                    await page.goto(href, wait_until="load")
                    shown = await page.evaluate(_SHOWN)
                    if (shown["title"].startswith("Index of") or not shown["title"].endswith("facegeom")
                            or not shown["heading"].strip()):
                        problems[NAV].append(f"{href} does not show a page: title {shown['title']!r}, "
                                             f"heading {shown['heading']!r}")

            # the jobs, done by `concurrency` tabs that each take the next job when done: the search and the
            # navigation first (they wait the most), then the pages
            jobs: list[tuple[str, object]] = []
            if search:
                jobs.append((SEARCH, lambda page: check_search(page, search)))
            if follow_nav:
                jobs.append((NAV, lambda page: follow(page, follow_nav)))
            jobs += [(rel, functools.partial(check, rel=rel)) for rel in pages]

            async def tab() -> None:
                page, at = await new_tab()
                while jobs:
                    where, job = jobs.pop(0)
                    at.update(where=where, moves_on=where == NAV)
                    opened[page] = where
                    await job(page)
                    at["moves_on"] = True  # leaving the page, before the next job's problems go elsewhere
                    await page.goto("about:blank")
                await page.close()

            await asyncio.gather(*(tab() for _ in range(min(concurrency, len(jobs)))))
            await context.close()
            await browser.close()

    def check_links(base: str) -> None:
        base_path = urlsplit(base).path
        for rel, hrefs in links.items():
            for href in sorted(set(hrefs)):
                if not href.startswith(base):
                    if from_disk and href.startswith("file:"):
                        problems[rel].append(f"link outside the site: {href}")
                    continue  # another site: not followed (the check runs offline)
                parts = urlsplit(href)
                target = unquote(parts.path[len(base_path):])
                if from_disk and (target == "" or target.endswith("/") or (folder / target).is_dir()):
                    problems[rel].append(f"link to a folder: {href} (from disk the browser lists the folder)")
                    continue
                if target == "" or target.endswith("/"):
                    target += "index.html"
                if not (folder / target).is_file():
                    problems[rel].append(f"broken link: {href} (no file {target})")
                elif parts.fragment:
                    anchor = unquote(parts.fragment)
                    if target not in ids:
                        problems[rel].append(f"link to an anchor of a page that was not checked: {href}")
                    elif anchor not in ids[target]:
                        problems[rel].append(f"broken anchor: {href} (no id {anchor!r} in {target})")

    if from_disk:
        base = folder.resolve().as_uri() + "/"
        asyncio.run(run(base))
        check_links(base)
    else:
        with Server(folder) as server:
            asyncio.run(run(server.base))
            check_links(server.base)
    return problems


def _report(problems: dict[str, list[str]], most: int = 8) -> str:
    """The problems as text: each page or check with its first ``most`` problems."""
    bad = {p: v for p, v in problems.items() if v}
    return f"{len(bad)} pages or checks have problems:\n" + "\n".join(
        f"{p}:\n  " + "\n  ".join(v[:most] + ([f"... and {len(v) - most} more"] if len(v) > most else []))
        for p, v in bad.items())


def test_every_page_opens_without_errors(chromium, site):
    """Over HTTP: every page opens without a problem, and the search lists results."""
    t = time.perf_counter()
    pages = html_pages(site)
    assert "index.html" in pages and NOT_FOUND_PAGE in pages and len(pages) >= 10, pages
    problems = check_pages(chromium, site, pages, search=SEARCH_WORD)
    assert not any(problems.values()), _report(problems)
    print(f"{len(pages)} pages checked over HTTP in {time.perf_counter() - t:.1f} s")


def test_every_link_names_a_file(site):
    """From disk every link must name a file: the built HTML read without a browser."""
    pages = [p for p in html_pages(site) if p != NOT_FOUND_PAGE]
    problems = static_link_problems(site, pages)
    assert not any(problems.values()), _report(problems)


def test_every_page_opens_from_disk(chromium, site):
    """From disk (file://): every page opens without a problem, the navigation leads to pages, search works."""
    t = time.perf_counter()
    pages = [p for p in html_pages(site) if p != NOT_FOUND_PAGE]
    problems = check_pages(chromium, site, pages, from_disk=True, search=SEARCH_WORD, follow_nav=6)
    assert not any(problems.values()), _report(problems)
    print(f"{len(pages)} pages checked from disk in {time.perf_counter() - t:.1f} s")


def test_every_picture_is_generated_and_used(site):
    made = {p.name for p in (ROOT / "docs" / "images").glob("*.png")}
    wanted = {"driven-face.png", "retarget.png", "fitted-photo.png", "character.png", "transfer.png",
              "cleanup.png", "viewer.png"}
    assert wanted <= made, f"missing pictures: {sorted(wanted - made)}"
    assert all((site / "images" / name).is_file() for name in wanted)


# a page holding one of each problem, for the self-checks (it is put at broken/index.html of a copy of the site)
_BROKEN_PAGE = """<!doctype html><html><head><meta charset="utf-8"><title>broken</title></head><body>
<p id="here">a page with one of each problem</p>
<img src="../images/no-such-picture.png" alt="missing">
<img src="http://example.invalid/picture.png" alt="elsewhere">
<a href="../no-such-page/">a missing page</a>
<a href="../index.html#no-such-anchor">a missing anchor</a>
<a href="#here">a good anchor</a>
<a href="../">the home page</a>
<a href="/index.html">the home page by an absolute path</a>
<script>console.error("an error in the console");</script>
</body></html>"""


def _broken_copy(site: Path, tmp_path: Path) -> Path:
    copy = tmp_path / "site"
    shutil.copytree(site, copy)
    (copy / "broken").mkdir()
    (copy / "broken" / "index.html").write_text(_BROKEN_PAGE, encoding="utf-8")
    return copy


def test_the_checks_find_broken_pages(chromium, site, tmp_path):
    """Over HTTP, a copy of the site with a page holding one of each problem: every problem is reported."""
    copy = _broken_copy(site, tmp_path)
    problems = check_pages(chromium, copy, ["broken/index.html", "index.html"])
    found = "\n".join(problems["broken/index.html"])
    assert "no-such-picture.png" in found and "HTTP 404" in found, found
    assert "image did not load" in found, found
    assert "request to another host: http://example.invalid/picture.png" in found, found
    assert "broken link" in found and "no-such-page" in found, found
    assert "broken anchor" in found and "no-such-anchor" in found, found
    assert "console error: an error in the console" in found, found
    links = [x for x in problems["broken/index.html"] if x.startswith("broken link")]
    assert len(links) == 1 and "#here" not in found, found  # the good links are not reported
    assert problems["index.html"] == [] and problems[OTHER] == [], problems


def test_the_disk_checks_find_broken_pages(chromium, site, tmp_path):
    """From disk, a copy of the site with the broken page, navigation links to folders, no search shim."""
    copy = _broken_copy(site, tmp_path)
    index = copy / "index.html"
    index.write_text(re.sub(r'href="((?:howto|methods|benchmarks|api)/)[^"#/]*\.html"', r'href="\1"',
                            index.read_text(encoding="utf-8")), encoding="utf-8")
    (copy / "assets" / "javascripts" / "iframe-worker-shim.js").unlink()
    static = static_link_problems(copy, ["broken/index.html", "index.html"])
    found = "\n".join(static["broken/index.html"])
    assert "'../': no file" not in found and "link to a folder: '../'" in found, found
    assert "absolute path '/index.html'" in found and "no file images/no-such-picture.png" in found, found
    assert "#here" not in found and "example.invalid" not in found, found  # not into the site: left out
    assert "link to a folder: 'howto/'" in "\n".join(static["index.html"]), static["index.html"]

    problems = check_pages(chromium, copy, ["broken/index.html", "index.html"], from_disk=True,
                           search=SEARCH_WORD, follow_nav=2)
    found = "\n".join(problems["broken/index.html"])
    assert "request failed" in found and "no-such-picture.png" in found, found
    assert "request to another host: http://example.invalid/picture.png" in found, found
    assert "link to a folder" in found and "link outside the site: file:///index.html" in found, found
    assert "broken anchor" in found and "console error: an error in the console" in found, found
    index_found = "\n".join(problems["index.html"])
    assert "link to a folder" in index_found and "iframe-worker-shim.js" in index_found, index_found
    assert "Index of" in "\n".join(problems[NAV]), problems[NAV]
    assert "the search box is hidden" in "\n".join(problems[SEARCH]), problems[SEARCH]


def _math_hook():
    import importlib.util

    spec = importlib.util.spec_from_file_location("facegeom_docs_mathml", ROOT / "docs" / "hooks" / "mathml.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_math_hook_converts_equations_and_leaves_code_alone():
    hook = _math_hook()
    text = "\n".join([
        "Inline $w_i \\ge 0$, code `$x$`, ``a `$y$` b``, costs $5 or $10, a prompt: $ facegeom drive, \\$3.",
        "",
        "| a | b |", "|---|---|", "| $\\|w\\|_1$ | $a|b$ |",
        "",
        "$$", "\\min_{\\mathbf w} \\sum_i w_i", "$$",
        "",
        "```bash", "echo $HOME $x$", "```",
        "",
        "- item", "",
        "    $$ \\begin{aligned} a &= b \\\\ c &= d \\end{aligned} $$",
    ])
    out, math = hook.convert_markdown(text, "page.md")
    assert len(math) == 5, math
    assert "`$x$`" in out and "``a `$y$` b``" in out and "echo $HOME $x$" in out
    assert "costs $5 or $10" in out and "$ facegeom drive" in out and "&#36;3" in out
    assert "| fgmath1q | fgmath2q |" in out and "    fgmath4q" in out
    assert all(m.startswith("<math") for m in math) and 'display="block"' in math[3]


@pytest.mark.parametrize("text, why", [
    ("$\\foo{x}$", "unknown command \\foo"),
    ("$x^{2$", "never closed"),
    ("a\n\n$$\nx = 1\n", "never closes"),
    ("## The $x$ heading", "math in a heading"),
    ("$\\begin{pmatrix} a \\end{bmatrix}$", "does not match"),
])
def test_math_hook_names_the_page_and_the_equation_it_cannot_convert(text, why):
    hook = _math_hook()
    with pytest.raises(hook.MathError, match="page.md, line") as info:
        hook.convert_markdown(text, "page.md")
    assert why in str(info.value)


def test_a_bad_equation_fails_the_build(tmp_path):
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "index.md").write_text("# Home\n\nFine: $x^2$.\n\nBroken: $\\nosuchcommand{y}$.\n")
    (tmp_path / "mkdocs.yml").write_text(f"site_name: t\nhooks:\n  - {ROOT / 'docs' / 'hooks' / 'mathml.py'}\n")
    build = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict"], cwd=tmp_path, capture_output=True,
                           text=True, check=False, env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
    assert build.returncode != 0
    assert "index.md, line 5" in build.stderr and "\\nosuchcommand{y}" in build.stderr, build.stderr
