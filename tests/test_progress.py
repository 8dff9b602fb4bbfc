"""Progress of long commands: a bar on a terminal, a plain line every few seconds in a pipe or a log."""
from __future__ import annotations

import io

from facegeom.cli import progress as prog


class _Clock:
    def __init__(self):
        self.t = 100.0

    def __call__(self):
        return self.t


def test_off_a_terminal_a_line_at_once_then_every_few_seconds(monkeypatch, capsys):
    clock = _Clock()
    monkeypatch.setattr(prog.time, "perf_counter", clock)
    t = prog.Ticker("track", "frame", every=5.0, stream=io.StringIO())  # not a terminal
    assert t.bar is None
    t(1, 120)
    clock.t += 4.9
    t(60, 120)  # within 5 s of the last line: quiet
    clock.t += 0.2
    t(70, None)  # total unknown
    t.close()
    assert capsys.readouterr().err.splitlines() == ["track: 1/120 frames", "track: 70 frames"]


def test_on_a_terminal_a_bar_and_no_lines(monkeypatch, capsys):
    class Tty(io.StringIO):
        def isatty(self):
            return True

    stream = Tty()
    t = prog.Ticker("track", "frame", stream=stream)
    assert t.bar is not None
    t(3, 10)
    assert t.bar.n == 3 and t.bar.total == 10
    t.close()
    assert capsys.readouterr().err == "" and "track" in stream.getvalue()
