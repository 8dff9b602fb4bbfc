"""Progress of a long command: a bar on a terminal, a plain line every few seconds anywhere else.

tqdm draws its bar only on a terminal (``disable=None``); a command whose output goes to a pipe, a log or a
CI job would then be silent for as long as it runs. :class:`Ticker` keeps the bar on a terminal and, off one,
writes ``desc: done/total units`` to stderr at the first report and then at most every :data:`EVERY_S` seconds.
"""
from __future__ import annotations

import sys
import time

import click

__all__ = ["EVERY_S", "Ticker"]

EVERY_S = 5.0
"""Seconds between plain progress lines when stderr is not a terminal."""


class Ticker:
    """A progress callable ``(done, total)``: a tqdm bar on a terminal, else a line at most every ``every`` s.

    ``total`` may be None or 0 (unknown); :meth:`close` ends the bar (call it in a ``finally``).
    """

    def __init__(self, desc: str, unit: str, every: float = EVERY_S, stream=None):
        self.desc, self.unit, self.every = desc, unit, float(every)
        self.stream = sys.stderr if stream is None else stream
        self.bar = None
        self.last = None  # the first report is written at once
        isatty = getattr(self.stream, "isatty", None)
        if callable(isatty) and isatty():
            from tqdm import tqdm

            self.bar = tqdm(total=None, unit=unit, desc=desc, leave=False, dynamic_ncols=True, file=self.stream)

    def __call__(self, done: int, total=None) -> None:
        if self.bar is not None:
            if total and self.bar.total != total:
                self.bar.total = total
            self.bar.update(done - self.bar.n)
            return
        now = time.perf_counter()
        if self.last is None or now - self.last >= self.every:
            self.last = now
            of = f"/{total}" if total else ""
            click.echo(f"{self.desc}: {done}{of} {self.unit}s", err=True)

    def close(self) -> None:
        """Close the bar (nothing to do off a terminal)."""
        if self.bar is not None:
            self.bar.close()
