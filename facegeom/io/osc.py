"""OSC messages of the VMC protocol's blendshapes, written here (what VTuber apps such as VSeeFace read).

OSC 1.0 framing: a message is its address, its type tags (``,sf``: a string and a 32-bit float) and its
arguments, each padded with zeros to a multiple of 4 bytes, numbers big-endian; a bundle is ``#bundle``, an
8-byte time tag (1: immediately) and each element as a 32-bit length and its bytes. The VMC protocol sends a
frame's blendshapes as one ``/VMC/Ext/Blend/Val`` message per shape (name, value) followed by
``/VMC/Ext/Blend/Apply``, so the receiver applies them together.

The per-name prefix of each message is built once (:class:`VMCBlendEncoder`); a frame is then a join of byte
strings, a few microseconds for the 52 ARKit shapes.
"""
from __future__ import annotations

import struct
from collections.abc import Sequence

import numpy as np

__all__ = ["osc_string", "osc_message", "VMCBlendEncoder", "BLEND_VAL", "BLEND_APPLY"]

BLEND_VAL = "/VMC/Ext/Blend/Val"
BLEND_APPLY = "/VMC/Ext/Blend/Apply"
_BUNDLE = b"#bundle\x00" + struct.pack(">Q", 1)  # time tag 1: immediately


def osc_string(text: str) -> bytes:
    """An OSC string: UTF-8, a terminating zero, padded with zeros to a multiple of 4 bytes."""
    b = text.encode("utf-8") + b"\x00"
    return b + b"\x00" * (-len(b) % 4)


def osc_message(address: str, *args) -> bytes:
    """One OSC message of string and float arguments (``str`` -> ``s``, anything else -> ``f``, 32-bit)."""
    tags = "," + "".join("s" if isinstance(a, str) else "f" for a in args)
    out = [osc_string(address), osc_string(tags)]
    for a in args:
        out.append(osc_string(a) if isinstance(a, str) else struct.pack(">f", float(a)))
    return b"".join(out)


class VMCBlendEncoder:
    """A frame of blendshape values -> one OSC bundle: a ``/VMC/Ext/Blend/Val`` per name, then ``Apply``."""

    def __init__(self, names: Sequence[str]):
        self.names = tuple(names)
        head = osc_string(BLEND_VAL) + osc_string(",sf")
        # each element: its length (the value's 4 bytes included) and the message up to the value
        self._prefixes = []
        for n in self.names:
            body = head + osc_string(n)
            self._prefixes.append(struct.pack(">i", len(body) + 4) + body)
        apply = osc_message(BLEND_APPLY)
        self._apply = struct.pack(">i", len(apply)) + apply

    def encode(self, values) -> bytes:
        """The bundle for ``values`` (one per name, finite)."""
        v = np.asarray(values, dtype=">f4").reshape(-1)
        if v.size != len(self.names):
            raise ValueError(f"{len(self.names)} values expected, got {v.size}")
        raw = v.tobytes()
        parts = [_BUNDLE]
        for k, prefix in enumerate(self._prefixes):
            parts.append(prefix)
            parts.append(raw[4 * k:4 * k + 4])
        parts.append(self._apply)
        return b"".join(parts)
