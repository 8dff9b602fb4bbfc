"""What every command shares: the ``--data`` context object and option parsing helpers."""
from __future__ import annotations

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
