"""Live Link Face network packets (what the iPhone app streams over UDP), read and written.

The app sends one datagram per frame (version 6 of its layout, all numbers big-endian)::

    uint8    version                      6
    int32    length, then UTF-8 bytes     the device's id
    int32    length, then UTF-8 bytes     the subject's name
    int32    frame number                 the frame time: frame number, sub-frame,
    float32  sub-frame                    and the rate as a fraction
    int32    rate numerator               (60 / 1 for the app's 60 fps)
    int32    rate denominator
    uint8    count                        61
    float32  x count                      52 ARKit weights in Unreal's order
                                          (:data:`PACKET_NAMES`), then head yaw,
                                          pitch, roll and each eye's yaw, pitch,
                                          roll (radians)

A datagram is hostile until parsed: :func:`parse_packet` checks every length
against what the datagram holds and every value for being finite, and raises
:class:`PacketError` (one line saying what is wrong) for anything else, so a
receiver counts and drops it. :func:`encode_packet` writes the same layout (what
Unreal's Live Link source reads).

Recordings: ``.gesichter`` files (think-biq/LLV's tape of packets, gzip) hold
real packets; :func:`read_recording` returns them, refusing a damaged file in
one line naming it.
"""
from __future__ import annotations

import gzip
import math
import os
import struct
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facegeom.errors import FacegeomError, InputError

__all__ = ["PACKET_VERSION", "PACKET_NAMES", "PACKET_VALUES", "MAX_PACKET", "MAX_NAME", "MAX_VALUE", "PacketError",
           "LiveLinkPacket", "parse_packet", "encode_packet", "read_recording", "write_recording"]

PACKET_VERSION = 6
#: The 61 values of a packet, in order: Unreal's ARKit blendshape order (``EARFaceBlendShape``; the app's CSV
#: takes swap the left / right pairs of the jaw and the mouth), then the head's and the eyes' rotations.
PACKET_NAMES: tuple[str, ...] = (
    "EyeBlinkLeft", "EyeLookDownLeft", "EyeLookInLeft", "EyeLookOutLeft", "EyeLookUpLeft", "EyeSquintLeft",
    "EyeWideLeft", "EyeBlinkRight", "EyeLookDownRight", "EyeLookInRight", "EyeLookOutRight", "EyeLookUpRight",
    "EyeSquintRight", "EyeWideRight", "JawForward", "JawLeft", "JawRight", "JawOpen", "MouthClose", "MouthFunnel",
    "MouthPucker", "MouthLeft", "MouthRight", "MouthSmileLeft", "MouthSmileRight", "MouthFrownLeft",
    "MouthFrownRight", "MouthDimpleLeft", "MouthDimpleRight", "MouthStretchLeft", "MouthStretchRight",
    "MouthRollLower", "MouthRollUpper", "MouthShrugLower", "MouthShrugUpper", "MouthPressLeft", "MouthPressRight",
    "MouthLowerDownLeft", "MouthLowerDownRight", "MouthUpperUpLeft", "MouthUpperUpRight", "BrowDownLeft",
    "BrowDownRight", "BrowInnerUp", "BrowOuterUpLeft", "BrowOuterUpRight", "CheekPuff", "CheekSquintLeft",
    "CheekSquintRight", "NoseSneerLeft", "NoseSneerRight", "TongueOut",
    "HeadYaw", "HeadPitch", "HeadRoll", "LeftEyeYaw", "LeftEyePitch", "LeftEyeRoll", "RightEyeYaw",
    "RightEyePitch", "RightEyeRoll",
)
PACKET_VALUES = len(PACKET_NAMES)  # 61
MAX_NAME = 256  # bytes of a device id or subject name (the app's are a UUID and a short name)
MAX_PACKET = 1 + 4 + MAX_NAME + 4 + MAX_NAME + 16 + 1 + 4 * PACKET_VALUES  # 790 bytes
#: No weight or rotation (radians) of a face reaches this; a larger value is a damaged or forged packet.
MAX_VALUE = 100.0
_HEAD = struct.Struct(">ifii")  # frame number, sub-frame, rate numerator, rate denominator
_VALUES_BYTES = 4 * PACKET_VALUES
_RECORDING_VERSION = PACKET_VERSION  # the tape carries the packets' version
MAX_RECORDING_BYTES = 256 << 20  # a recording's packets, decompressed (an hour at 60 fps is ~80 MB)


class PacketError(FacegeomError):
    """A datagram that is not a Live Link Face packet: what is wrong, in one line."""


@dataclass(frozen=True)
class LiveLinkPacket:
    """One frame of a Live Link Face stream.

    ``values`` (61,) float64: the 52 weights then the 9 rotations, in :data:`PACKET_NAMES` order.
    """

    device_id: str
    subject: str
    frame: int
    sub_frame: float
    rate: tuple[int, int]
    values: np.ndarray

    @property
    def weights(self) -> np.ndarray:
        """The 52 ARKit weights, in :data:`PACKET_NAMES` order."""
        return self.values[:52]

    @property
    def rotations(self) -> np.ndarray:
        """Head yaw, pitch, roll, left eye yaw, pitch, roll, right eye yaw, pitch, roll (radians)."""
        return self.values[52:]

    @property
    def fps(self) -> float | None:
        """The stream's frame rate, or None if the packet's rate is not one."""
        num, den = self.rate
        return num / den if num > 0 and den > 0 else None

    @property
    def time_s(self) -> float | None:
        """The frame's time in seconds (frame number plus sub-frame over the rate), or None without a rate."""
        fps = self.fps
        return (self.frame + self.sub_frame) / fps if fps else None


def _text(data: bytes, at: int, what: str) -> tuple[str, int]:
    if at + 4 > len(data):
        raise PacketError(f"ends inside the {what}'s length ({len(data)} bytes)")
    (n,) = struct.unpack_from(">i", data, at)
    at += 4
    if n < 0 or n > MAX_NAME:
        raise PacketError(f"the {what} is {n} bytes long (0 to {MAX_NAME})")
    if at + n > len(data):
        raise PacketError(f"the {what} ({n} bytes) runs past the packet's end ({len(data)} bytes)")
    return data[at:at + n].decode("utf-8", errors="replace"), at + n


def parse_packet(data: bytes) -> LiveLinkPacket:
    """A Live Link Face datagram -> :class:`LiveLinkPacket`.

    Raises
    ------
    PacketError
        Not one: another version, a length past the data, a count that is not 61, bytes left over, a value
        that is not finite or beyond :data:`MAX_VALUE`, a frame rate that is not one.
    """
    data = bytes(data)
    if len(data) > MAX_PACKET:
        raise PacketError(f"{len(data)} bytes: longer than any packet ({MAX_PACKET})")
    if not data:
        raise PacketError("empty")
    if data[0] != PACKET_VERSION:
        raise PacketError(f"version {data[0]}, not {PACKET_VERSION} (the Live Link Face app's)")
    device, at = _text(data, 1, "device id")
    subject, at = _text(data, at, "subject name")
    if at + _HEAD.size + 1 > len(data):
        raise PacketError(f"ends inside the frame time ({len(data)} bytes)")
    frame, sub, num, den = _HEAD.unpack_from(data, at)
    at += _HEAD.size
    count = data[at]
    at += 1
    if count != PACKET_VALUES:
        raise PacketError(f"{count} values, not {PACKET_VALUES}")
    if at + _VALUES_BYTES != len(data):
        raise PacketError(f"{len(data) - at} bytes of values, not {_VALUES_BYTES}")
    values = np.frombuffer(data, dtype=">f4", count=PACKET_VALUES, offset=at).astype(np.float64)
    if not np.isfinite(values).all():
        bad = int(np.flatnonzero(~np.isfinite(values))[0])
        raise PacketError(f"{PACKET_NAMES[bad]} is not a number ({values[bad]})")
    if np.abs(values).max() > MAX_VALUE:
        bad = int(np.argmax(np.abs(values)))
        raise PacketError(f"{PACKET_NAMES[bad]} is {values[bad]:.3g}, beyond any face's (|v| <= {MAX_VALUE:g})")
    if not math.isfinite(sub) or abs(sub) > 1e6 or num < 0 or den < 0:
        raise PacketError(f"the frame time is not one (sub-frame {sub}, rate {num}/{den})")
    values.setflags(write=False)
    return LiveLinkPacket(device, subject, int(frame), float(sub), (int(num), int(den)), values)


def encode_packet(values, device_id: str = "facegeom", subject: str = "facegeom", frame: int = 0,
                  sub_frame: float = 0.0, rate: tuple[int, int] = (60, 1)) -> bytes:
    """The datagram of one frame: ``values`` (61,) in :data:`PACKET_NAMES` order (or (52,) weights, the
    rotations then 0). Raises :class:`PacketError` for values a packet cannot carry."""
    v = np.asarray(values, dtype=np.float64).reshape(-1)
    if v.size == 52:
        v = np.concatenate([v, np.zeros(PACKET_VALUES - 52)])
    if v.size != PACKET_VALUES:
        raise PacketError(f"a packet carries {PACKET_VALUES} values (or 52 weights), not {v.size}")
    if not np.isfinite(v).all():
        raise PacketError("a value is not finite")
    dev, sub = device_id.encode("utf-8"), subject.encode("utf-8")
    if len(dev) > MAX_NAME or len(sub) > MAX_NAME:
        raise PacketError(f"the device id and the subject name are at most {MAX_NAME} bytes")
    return b"".join([
        bytes([PACKET_VERSION]), struct.pack(">i", len(dev)), dev, struct.pack(">i", len(sub)), sub,
        _HEAD.pack(int(frame), float(sub_frame), int(rate[0]), int(rate[1])), bytes([PACKET_VALUES]),
        v.astype(">f4").tobytes(),
    ])


def read_recording(path: str | os.PathLike) -> list[bytes]:
    """The packets of a ``.gesichter`` recording (gzip: a version byte, a uint32 count, then each packet as a
    uint32 length and its bytes), in order. The packets are returned as recorded, unparsed.

    Raises
    ------
    InputError
        Missing, not gzip, damaged or cut short, a count or a length past the data, larger than
        :data:`MAX_RECORDING_BYTES` decompressed; one line naming the file.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("no such file" if not path.exists() else "not a file", path)
    try:
        with gzip.open(path, "rb") as fh:
            data = fh.read(MAX_RECORDING_BYTES + 1)
    except (OSError, EOFError, zlib.error) as exc:
        raise InputError(f"not a readable recording (gzip): {exc}", path) from None
    if len(data) > MAX_RECORDING_BYTES:
        raise InputError(f"more than {MAX_RECORDING_BYTES >> 20} MB of packets decompressed: refused", path)
    if len(data) < 5:
        raise InputError(f"too short for a recording's header ({len(data)} bytes)", path)
    if data[0] != _RECORDING_VERSION:
        raise InputError(f"recording version {data[0]}, not {_RECORDING_VERSION}", path)
    (count,) = struct.unpack_from(">I", data, 1)
    at, out = 5, []
    for k in range(count):
        if at + 4 > len(data):
            raise InputError(f"cut short: packet {k} of the {count} it lists is missing", path)
        (n,) = struct.unpack_from(">I", data, at)
        at += 4
        if n > 65536 or at + n > len(data):
            raise InputError(f"packet {k} is {n} bytes long, past the file's end", path)
        out.append(data[at:at + n])
        at += n
    if at != len(data):
        raise InputError(f"{len(data) - at} bytes after the {count} packets it lists", path)
    return out


def write_recording(path: str | os.PathLike, packets) -> Path:
    """Write ``packets`` (bytes each) as a ``.gesichter`` recording, atomically."""
    from facegeom.io.files import atomic_path

    packets = [bytes(p) for p in packets]
    body = b"".join(struct.pack(">I", len(p)) + p for p in packets)
    with atomic_path(path) as tmp, gzip.open(tmp, "wb") as fh:
        fh.write(bytes([_RECORDING_VERSION]) + struct.pack(">I", len(packets)) + body)
    return Path(path)
