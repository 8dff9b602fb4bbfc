"""One report writer for every benchmark: CSV tables, a Markdown summary, a PNG plot, the machine note.

A benchmark named ``drive`` writing into ``out`` produces ``out/drive.csv``
(or ``out/drive-<part>.csv`` for several tables), ``out/drive-summary.md``
(the Markdown table, a blank line, the note) and ``out/drive.png``. Every file
is written atomically (a temporary file renamed into place): an exception
while writing leaves no partial file and the previous one untouched. Without
an output folder the report only echoes the table and the note.
"""
from __future__ import annotations

import csv
import json
import os
import platform
from pathlib import Path
from typing import Callable

from facegeom.errors import InputError
from facegeom.io import atomic_path

__all__ = ["Report", "write_csv", "write_json", "format_table", "machine_note"]


def write_csv(path: str | os.PathLike, rows: list[dict]) -> Path:
    """Write ``rows`` as a CSV with a header (the keys of the first row), atomically.

    Parameters
    ----------
    path : path-like
        The CSV file; its folder must exist.
    rows : list of dict
        One dict per row, all with the keys of the first.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    InputError
        No row to write.
    """
    path = Path(path)
    if not rows:
        raise InputError("nothing to write", path)
    with atomic_path(path) as tmp:
        with open(tmp, "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)
    return path


def write_json(path: str | os.PathLike, data: dict) -> Path:
    """Write ``data`` as indented JSON (and a final newline), atomically.

    Parameters
    ----------
    path : path-like
        The JSON file; its folder must exist.
    data : dict
        JSON-serialisable numbers and lists.

    Returns
    -------
    Path
        ``path``.
    """
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(data, indent=2) + "\n")
    return path


def format_table(header: list[str], rows: list[list]) -> str:
    """A GitHub-markdown table; floats with 3 significant digits (no decimals from 1000 up).

    Parameters
    ----------
    header : list of str
        Column titles.
    rows : list of list
        One list of cells per row, as many as ``header``.

    Returns
    -------
    str
        The table, lines joined by newlines (no trailing newline).
    """
    def fmt(x):
        if isinstance(x, float):
            return f"{x:.3g}" if abs(x) < 1000 else f"{x:.0f}"
        return str(x)
    cells = [[fmt(c) for c in r] for r in rows]
    widths = [max(len(h), *(len(r[i]) for r in cells)) for i, h in enumerate(header)]
    line = lambda r: "| " + " | ".join(c.ljust(w) for c, w in zip(r, widths)) + " |"  # noqa: E731
    return "\n".join([line(header), "|" + "|".join("-" * (w + 2) for w in widths) + "|", *map(line, cells)])


def machine_note() -> str:
    """``'<machine>, <n> cores, Python <version>'``: where the numbers were measured."""
    return f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"


class Report:
    """The files of one benchmark run, written atomically into one folder.

    Parameters
    ----------
    out : path-like or None
        Output folder (created if missing); ``None`` writes nothing, the
        summary is only echoed.
    name : str
        The benchmark's name: the stem of every file.
    echo : callable(str)
        Prints the summary and the list of files written.
    """

    def __init__(self, out: str | os.PathLike | None, name: str, echo: Callable[[str], None] = print):
        self.out = None if out is None else Path(out)
        self.name = name
        self.echo = echo
        self.written: list[Path] = []
        if self.out is not None:
            self.out.mkdir(parents=True, exist_ok=True)

    def _path(self, filename: str) -> Path:
        return self.out / filename

    def csv(self, rows: list[dict], part: str | None = None) -> Path | None:
        """Write ``<name>.csv`` (or ``<name>-<part>.csv``) from ``rows`` (see :func:`write_csv`).

        Returns
        -------
        Path or None
            The file written; ``None`` without an output folder.
        """
        if self.out is None:
            return None
        path = write_csv(self._path(f"{self.name}-{part}.csv" if part else f"{self.name}.csv"), rows)
        self.written.append(path)
        return path

    def summary(self, table: str, note: str) -> Path | None:
        """Echo ``table`` and ``note``, and write them to ``<name>-summary.md``.

        Parameters
        ----------
        table : str
            The Markdown table(s), as from :func:`format_table`.
        note : str
            One line on the protocol and the machine (:func:`machine_note`).

        Returns
        -------
        Path or None
            The file written; ``None`` without an output folder.
        """
        self.echo(table)
        self.echo(note)
        if self.out is None:
            return None
        path = self._path(f"{self.name}-summary.md")
        with atomic_path(path) as tmp:
            tmp.write_text(table + "\n\n" + note + "\n")
        self.written.append(path)
        return path

    def plot(self, draw: Callable[[], object], dpi: int = 110) -> Path | None:
        """Save the matplotlib figure that ``draw()`` returns as ``<name>.png`` and close it.

        Parameters
        ----------
        draw : callable() -> matplotlib.figure.Figure
            Builds the figure (called only when there is an output folder).
        dpi : int
            Resolution of the PNG.

        Returns
        -------
        Path or None
            The file written; ``None`` without an output folder.
        """
        if self.out is None:
            return None
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig = draw()
        path = self._path(f"{self.name}.png")
        try:
            with atomic_path(path) as tmp:
                fig.savefig(tmp, dpi=dpi, format="png")
        finally:
            plt.close(fig)
        self.written.append(path)
        return path

    def done(self) -> list[Path]:
        """Echo ``wrote <file>, <file>, ...`` (nothing when no file was written); returns the files."""
        if self.written:
            self.echo("wrote " + ", ".join(str(p) for p in self.written))
        return list(self.written)
