"""The documentation site: built with ``mkdocs build --strict`` and every page opened in headless Chromium.

The pictures are generated first (``docs/make_images.py`` into ``docs/images/``, as ``make docs`` does;
it redraws only what changed). The site is then built into a temporary folder and served on 127.0.0.1;
every HTML page is opened through playwright with the system's Chromium, and a page fails on

- an error in the browser console, or an uncaught script error;
- a failed request (a 4xx/5xx answer or a network failure), a request to any other host (fonts, scripts
  from a CDN: the site must work offline);
- an image that did not load (``naturalWidth`` 0);
- a link into the site to a file that is not there, or to an ``#anchor`` no element of its page has.

A self-check runs the same checks on a copy of the site with a broken page added, and expects each
problem to be reported: the checks can fail.
"""
from __future__ import annotations

import functools
import http.server
import os
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
    """Every HTML file of a built site, as paths relative to it (``index.html``, ``howto/drive/index.html``)."""
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*.html"))


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


def check_pages(chromium: str, folder: Path, pages: list[str], concurrency: int = 4) -> dict[str, list[str]]:
    """Open ``pages`` of the site in ``folder`` and return the problems found, by page (empty lists if none).

    Pages are opened ``concurrency`` at a time in one headless Chromium. Links are checked after every page
    has been read: a link's file must exist in ``folder`` and its ``#anchor`` must be an id of that page
    (the page must be one of ``pages`` when it has an anchor).
    """
    import asyncio

    from playwright.async_api import Error as PlaywrightError
    from playwright.async_api import async_playwright

    problems: dict[str, list[str]] = {p: [] for p in [*pages, OTHER]}
    ids: dict[str, set[str]] = {}
    links: dict[str, list[str]] = {}

    async def run(server: Server) -> None:
        async with async_playwright() as pw:
            browser = await pw.chromium.launch(executable_path=chromium, headless=True)
            context = await browser.new_context()
            opened: dict[object, str] = {}  # playwright page -> the site page it shows

            async def route(r):
                url = r.request.url
                if url.startswith((server.base, "data:", "blob:")):
                    await r.continue_()
                    return
                try:
                    where = opened.get(r.request.frame.page, OTHER)
                except PlaywrightError:  # a worker's request has no frame
                    where = OTHER
                problems[where].append(f"request to another host: {url}")
                await r.abort()

            await context.route("**/*", route)
            limit = asyncio.Semaphore(concurrency)

            async def check(rel: str) -> None:
                async with limit:
                    page = await context.new_page()
                    opened[page] = rel
                    report = problems[rel].append
                    page.on("console", lambda m: m.type == "error" and report(f"console error: {m.text}"))
                    page.on("pageerror", lambda e: report(f"script error: {e}"))
                    page.on("requestfailed", lambda r: r.url.startswith(server.base)
                            and report(f"request failed: {r.url} ({r.failure})"))
                    page.on("response", lambda r: r.status >= 400 and report(f"HTTP {r.status}: {r.url}"))
                    await page.goto(server.base + rel, wait_until="load")
                    await page.wait_for_load_state("networkidle")
                    found = await page.evaluate(_INSPECT)
                    await page.close()
                    ids[rel] = set(found["ids"])
                    links[rel] = found["links"]
                    for src in found["broken_images"]:
                        report(f"image did not load: {src}")

            await asyncio.gather(*(check(rel) for rel in pages))
            await context.close()
            await browser.close()

    with Server(folder) as server:
        asyncio.run(run(server))
        base_path = urlsplit(server.base).path
        for rel, hrefs in links.items():
            for href in sorted(set(hrefs)):
                if not href.startswith(server.base):
                    continue  # another site: not followed (the check runs offline)
                parts = urlsplit(href)
                target = unquote(parts.path[len(base_path):])
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
    return problems


def test_every_page_opens_without_errors(chromium, site):
    t = time.perf_counter()
    pages = html_pages(site)
    assert "index.html" in pages and len(pages) >= 10, pages
    problems = check_pages(chromium, site, pages)
    bad = {p: v for p, v in problems.items() if v}
    report = "\n".join(f"{p}:\n  " + "\n  ".join(v) for p, v in bad.items())
    assert not bad, f"{len(bad)} of {len(pages)} pages have problems:\n{report}"
    print(f"{len(pages)} pages checked in {time.perf_counter() - t:.1f} s")


def test_every_picture_is_generated_and_used(site):
    made = {p.name for p in (ROOT / "docs" / "images").glob("*.png")}
    wanted = {"driven-face.png", "retarget.png", "fitted-photo.png", "character.png", "transfer.png",
              "cleanup.png", "viewer.png"}
    assert wanted <= made, f"missing pictures: {sorted(wanted - made)}"
    assert all((site / "images" / name).is_file() for name in wanted)


def test_the_checks_find_broken_pages(chromium, site, tmp_path):
    """A copy of the site with a page holding one of each problem: every problem is reported."""
    copy = tmp_path / "site"
    shutil.copytree(site, copy)
    (copy / "broken").mkdir()
    (copy / "broken" / "index.html").write_text(
        """<!doctype html><html><head><meta charset="utf-8"><title>broken</title></head><body>
<p id="here">a page with one of each problem</p>
<img src="../images/no-such-picture.png" alt="missing">
<img src="http://example.invalid/picture.png" alt="elsewhere">
<a href="../no-such-page/">a missing page</a>
<a href="../index.html#no-such-anchor">a missing anchor</a>
<a href="#here">a good anchor</a>
<a href="../">the home page</a>
<script>console.error("an error in the console");</script>
</body></html>""", encoding="utf-8")
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
