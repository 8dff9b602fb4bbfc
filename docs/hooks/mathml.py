"""mkdocs hook: the pages' LaTeX equations become MathML at build time (no JavaScript, no CDN).

Pages write ``$...$`` for inline math and ``$$...$$`` for display math (the two ``$$`` on their own
lines, or ``$$ ... $$`` on one line). Each equation is converted by ``latex2mathml`` and the browser
renders the MathML itself (MathML Core: Chromium, Firefox, Safari), so the site needs no math script.

How a page is processed:

1. ``on_page_markdown``: fenced code blocks and inline code spans are left untouched; every equation
   elsewhere is converted and replaced by a placeholder word (letters and digits only), so Markdown
   never sees the LaTeX (``|`` in a table cell, ``_`` or ``*`` cannot be taken for Markdown);
2. ``on_page_content``: the placeholders in the page's HTML are replaced by the MathML.

Rules (each broken rule fails the build, naming the page and the equation):

- an inline ``$`` opens only before a non-space character and closes only after one, not before a digit
  (so "costs $5 or $10" and a shell prompt ``$ facegeom ...`` stay text); ``\\$`` is a literal dollar;
- an equation must convert: balanced braces and environments, no unknown command (latex2mathml
  would print it as text), well-formed MathML;
- no math in headings (the heading's anchor and the table of contents are plain text);
- a ``$$`` that opens must close.

Rewritten before conversion (latex2mathml lacks them): ``aligned`` -> ``split`` (the same right/left aligned
rows), ``\\operatorname*`` -> ``\\operatorname``, ``\\arg`` -> ``\\operatorname{arg}``.
"""
from __future__ import annotations

import re
import xml.etree.ElementTree as ET

from latex2mathml.converter import convert
from mkdocs.exceptions import PluginError

_FENCE = re.compile(r"^(\s*)(`{3,}|~{3,})")
_DISPLAY = re.compile(r"^(\s*(?:>\s*)*)\$\$(.*)$")
_HEADING = re.compile(r"^\s{0,3}#{1,6}\s")
_UNKNOWN = re.compile(r"^\\[A-Za-z]+")
_ENV = re.compile(r"\\(begin|end)\{([^}]*)\}")
_BLANK = re.compile(r"\n[ \t]*\n")
_TOKEN_ELEMENTS = {"mi", "mn", "mo", "ms", "mtext"}
# LaTeX that latex2mathml lacks or gets wrong, rewritten to what it renders the same way
_REWRITES = [
    (re.compile(r"\\begin\{aligned\}"), r"\\begin{split}"),
    (re.compile(r"\\end\{aligned\}"), r"\\end{split}"),
    (re.compile(r"\\operatorname\*"), r"\\operatorname"),
    (re.compile(r"\\arg(?![A-Za-z])"), r"\\operatorname{arg}"),
]
_TOKEN = "fgmath{}q"  # letters and digits: Markdown leaves it alone; the end letter keeps 1 from matching 12
_TOKENS = re.compile(r"fgmath(\d+)q")

# the page being converted -> its equations' MathML, by placeholder number
_MATH: dict[str, list[str]] = {}


class MathError(PluginError):
    """An equation of a page that cannot be converted (the page and the equation in the message)."""


def _brace_error(latex: str) -> str | None:
    """Why the braces or environments of ``latex`` do not balance, or None."""
    depth = 0
    i = 0
    while i < len(latex):
        c = latex[i]
        if c == "\\":
            i += 2
            continue
        if c == "{":
            depth += 1
        elif c == "}":
            depth -= 1
            if depth < 0:
                return "a '}' closes nothing"
        i += 1
    if depth:
        return f"{depth} '{{' never closed"
    stack = []
    for kind, name in _ENV.findall(latex):
        if kind == "begin":
            stack.append(name)
        elif not stack or stack.pop() != name:
            return f"\\end{{{name}}} does not match a \\begin"
    if stack:
        return f"\\begin{{{stack[-1]}}} never ended"
    return None


def to_mathml(latex: str, display: bool) -> str:
    """Convert one equation to MathML.

    Raises
    ------
    ValueError
        The equation does not convert (the reason in the message).
    """
    source = latex.strip()
    if not source:
        raise ValueError("empty equation")
    problem = _brace_error(source)
    if problem:
        raise ValueError(problem)
    for pattern, replacement in _REWRITES:
        source = pattern.sub(replacement, source)
    try:
        out = convert(source, display="block" if display else "inline")
    except Exception as exc:  # noqa: BLE001 - latex2mathml raises many kinds; each one is the page's error
        raise ValueError(f"latex2mathml: {type(exc).__name__}: {exc}") from None
    try:
        tree = ET.fromstring(out)
    except ET.ParseError as exc:
        raise ValueError(f"latex2mathml wrote malformed MathML ({exc}); an unsupported construct?") from None
    for el in tree.iter():
        m = _UNKNOWN.match(el.text or "")
        if m:
            raise ValueError(f"unknown command {m.group(0)}")
        if el.tag.rpartition("}")[2] in _TOKEN_ELEMENTS and len(el):
            raise ValueError("latex2mathml nested elements in a token element (an unsupported construct such as "
                             "\\mathop{...}; use \\operatorname{...})")
    return out


class _Page:
    """The equations of one page, converted as they are found."""

    def __init__(self, name: str):
        self.name = name
        self.math: list[str] = []

    def equation(self, latex: str, display: bool, line: int) -> str:
        try:
            mathml = to_mathml(latex, display)
        except ValueError as exc:
            d = "$$" if display else "$"
            raise MathError(f"{self.name}, line {line}: the equation {d}{latex.strip()}{d} does not convert "
                            f"to MathML: {exc}") from None
        self.math.append(mathml)
        return _TOKEN.format(len(self.math) - 1)

    def inline(self, text: str, first_line: int) -> str:
        """``text`` (no fenced code) with its code spans kept and its equations replaced by placeholders."""
        out = []
        i, n = 0, len(text)
        while i < n:
            c = text[i]
            if c == "`":
                run = len(re.match(r"`+", text[i:]).group(0))
                close = re.compile(r"(?<!`)" + "`" * run + r"(?!`)")
                m = close.search(text, i + run)
                end = m.end() if m else i + run
                out.append(text[i:end])
                i = end
                continue
            if c == "\\" and i + 1 < n:
                out.append("&#36;" if text[i + 1] == "$" else text[i:i + 2])
                i += 2
                continue
            if c == "$":
                line = first_line + text.count("\n", 0, i)
                if text.startswith("$$", i):  # display math inside a line
                    end = text.find("$$", i + 2)
                    if end < 0:
                        raise MathError(f"{self.name}, line {line}: '$$' opens an equation that never closes")
                    out.append(self.equation(text[i + 2:end], True, line))
                    i = end + 2
                    continue
                end = self._inline_end(text, i)
                if end is None:
                    out.append(c)
                    i += 1
                    continue
                out.append(self.equation(text[i + 1:end], False, line))
                i = end + 1
                continue
            out.append(c)
            i += 1
        return "".join(out)

    @staticmethod
    def _inline_end(text: str, start: int) -> int | None:
        """Where the inline equation opened at ``start`` closes, or None when this ``$`` opens nothing."""
        if start + 1 >= len(text) or text[start + 1].isspace() or text[start + 1] == "$":
            return None
        j = start + 1
        while j < len(text):
            c = text[j]
            if c == "\\":
                j += 2
                continue
            if c == "\n" and _BLANK.match(text, j):
                return None  # the paragraph ends first
            if c == "`":
                return None  # an equation never contains a code span: this '$' is text
            if c == "$":
                after = text[j + 1] if j + 1 < len(text) else ""
                if not text[j - 1].isspace() and not after.isdigit():
                    return j
            j += 1
        return None


def convert_markdown(markdown: str, name: str) -> tuple[str, list[str]]:
    """A page's Markdown with every equation replaced by a placeholder -> ``(markdown, mathml per placeholder)``.

    Raises
    ------
    MathError
        An equation does not convert, is in a heading, or a ``$$`` never closes.
    """
    page = _Page(name)
    lines = markdown.split("\n")
    out: list[str] = []
    text: list[str] = []  # pending prose lines, converted together (code spans may cross lines)
    text_start = 1

    def flush():
        nonlocal text
        if text:
            out.append(page.inline("\n".join(text), text_start))
            text = []

    i = 0
    while i < len(lines):
        line = lines[i]
        fence = _FENCE.match(line)
        if fence:
            flush()
            mark = fence.group(2)
            out.append(line)
            i += 1
            while i < len(lines):
                out.append(lines[i])
                close = lines[i].strip()
                i += 1
                if close.startswith(mark[0] * len(mark)) and not close.strip(mark[0]):
                    break
            continue
        display = _DISPLAY.match(line)
        if display:
            flush()
            prefix, rest = display.group(1), display.group(2)
            start = i + 1
            if rest.rstrip().endswith("$$") and rest.strip() != "":
                body = rest.rstrip()[:-2]
                i += 1
            else:
                body_lines = [rest]
                i += 1
                while True:
                    if i >= len(lines):
                        raise MathError(f"{name}, line {start}: '$$' opens an equation that never closes")
                    cur = lines[i].removeprefix(prefix)
                    i += 1
                    if cur.rstrip().endswith("$$"):
                        body_lines.append(cur.rstrip()[:-2])
                        break
                    body_lines.append(cur)
                body = "\n".join(body_lines)
            out.append(prefix + page.equation(body, True, start))
            continue
        if _HEADING.match(line):
            converted = page.inline(line, i + 1)
            if converted != line.replace("\\$", "&#36;"):
                raise MathError(f"{name}, line {i + 1}: math in a heading ({line.strip()!r}); headings are plain "
                                "text (their anchors and the table of contents): move the equation to the text")
        if not text:
            text_start = i + 1
        text.append(line)
        i += 1
    flush()
    return "\n".join(out), page.math


def on_page_markdown(markdown, page, config, files):
    """Replace each equation of the page by a placeholder; keep its MathML for :func:`on_page_content`."""
    new, math = convert_markdown(markdown, page.file.src_uri)
    _MATH[page.file.src_uri] = math
    return new


def on_page_content(html_text, page, config, files):
    """Put each equation's MathML where its placeholder ended up in the page's HTML."""
    math = _MATH.pop(page.file.src_uri, [])
    if not math:
        return html_text
    used = set()

    def put(m):
        k = int(m.group(1))
        if k >= len(math):
            return m.group(0)
        used.add(k)
        return math[k]

    out = _TOKENS.sub(put, html_text)
    lost = sorted(set(range(len(math))) - used)
    if lost:
        raise MathError(f"{page.file.src_uri}: {len(lost)} equation(s) lost by the Markdown conversion "
                        f"(first: placeholder {lost[0]}); is an equation inside raw HTML or an attribute?")
    return out

