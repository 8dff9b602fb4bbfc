"""What every command shares: the ``--data`` context object and option parsing helpers."""
from __future__ import annotations

import contextlib
from pathlib import Path

import click


class Context:
    """The object of the ``facegeom`` group (``ctx.obj``): the ``--data`` bundle, loaded on demand."""

    def __init__(self, data):
        self.data = data

    def face_model(self):
        """The face model of the ``--data`` bundle (else $FACEGEOM_DATA or the default bundle)."""
        from facegeom.model import load_face_model

        return load_face_model(self.data)


def parse_params(items) -> dict:
    """``--param KEY=VALUE`` items as a dict of parsed values (``click.BadParameter`` on a missing ``=``)."""
    from facegeom.registry import parse_value

    out = {}
    for item in items:
        if "=" not in item:
            raise click.BadParameter(f"{item!r} must be key=value", param_hint="--param")
        k, v = item.split("=", 1)
        out[k.strip()] = parse_value(v)
    return out


#: where a command's takes come from when --takes is not given (option help)
TAKES_LOOKUP = ("the takes lookup: $FACEGEOM_TAKES, ../shared/data/arkit-takes in a checkout, then the public take "
                "`facegeom data fetch` downloads")


@contextlib.contextmanager
def other_take_sources(*alternatives: str):
    """Add the command's own ways round a missing take (``--take FILE``, ``--synthetic``) to its error."""
    from facegeom.errors import TakesNotFoundError

    try:
        yield
    except TakesNotFoundError as exc:
        more = "".join(f", or {a}" for a in alternatives)
        raise TakesNotFoundError(f"{exc}{more}") from None


def take_files(takes_path=None, take_path=None, alternatives=("--take FILE (one take)",)) -> list[Path]:
    """The takes a command plays: ``--take FILE``, else every ``.csv`` of the takes lookup (``--takes``, ...)."""
    if take_path:
        return [Path(take_path)]
    from facegeom.io import find_takes
    from facegeom.model import locate_takes

    with other_take_sources(*alternatives):
        where = locate_takes(takes_path)
    return [where] if where.is_file() else find_takes(where)
