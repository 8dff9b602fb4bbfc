"""Exceptions for user mistakes.

Every error that a user can cause (a bad file, a bad argument, missing data)
is an :class:`InputError` (a ``ValueError``). The CLI prints its message on one
line and exits with status 2; no traceback.
"""
from __future__ import annotations


class FacegeomError(Exception):
    """Base class of all facegeom errors."""


class InputError(FacegeomError, ValueError):
    """Bad input: a malformed file, an invalid array or argument.

    Parameters
    ----------
    message : str
        What is wrong.
    path : str or os.PathLike, optional
        The file the problem is in; it is named first in the message.
    """

    def __init__(self, message: str, path=None):
        self.path = None if path is None else _one_line(str(path))
        self.reason = _one_line(str(message))
        super().__init__(f"{self.path}: {self.reason}" if self.path else self.reason)


# every character str.splitlines() breaks a line at, written as an escape: a message quoting a file's text (a CSV
# header cell "a\nb", a file name) stays the one line the command line promises
_LINE_BREAKS = {c: ascii(chr(c))[1:-1] for c in (0x0A, 0x0B, 0x0C, 0x0D, 0x1C, 0x1D, 0x1E, 0x85, 0x2028, 0x2029)}


def _one_line(text: str) -> str:
    return text.translate(_LINE_BREAKS)


class DataNotFoundError(InputError):
    """The face-model data bundle was found nowhere."""


class TakesNotFoundError(DataNotFoundError):
    """No ARKit take was found where takes are looked for (a command may offer other sources: say so)."""


class DownloadError(DataNotFoundError):
    """The face-model files could not be downloaded: no network, a server error, or a file failing its hash."""


class SolveError(FacegeomError, ValueError):
    """A system cannot be solved as posed (e.g. a component with no label)."""
