"""A camera (or any live video stream) as frames: always the newest one, never a backlog.

:func:`open_camera` opens what ``facegeom live --camera`` names, through FFmpeg (PyAV, ``facegeom[video]``):

- a number ``N``: the N-th camera of this machine (Linux ``/dev/videoN`` through Video4Linux2, macOS
  AVFoundation's device N; on Windows DirectShow cameras go by name: ``video=Integrated Camera``);
- a device path (``/dev/video2``), ``video=NAME`` (DirectShow), or a named pipe another program writes a
  stream into;
- a network stream's URL (``rtsp://``, ``udp://``, ``srt://``, ``rtmp://``, ``http(s)://``): an IP camera, OBS.

A thread reads and decodes the frames as they come; :meth:`CameraStream.latest` hands over the newest one not
yet taken and counts the ones nobody took (the consumer was slower than the camera). Nothing queues up, so
what the consumer sees is at most one frame old however slow it is.
"""
from __future__ import annotations

import os
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facegeom.errors import InputError

__all__ = ["CameraFrame", "CameraStream", "camera_source", "open_camera"]

URL_SCHEMES = ("rtsp://", "rtsps://", "udp://", "srt://", "rtmp://", "http://", "https://", "tcp://")
"""Network streams FFmpeg opens as they come."""

MAX_CAMERA_PIXELS = 3840 * 2160
"""Frames larger than 4K are refused (a stream is not trusted more than a file)."""


@dataclass
class CameraFrame:
    """One frame: ``image`` ``(H, W, 3)`` uint8 RGB, its number since the stream opened, its arrival time
    (``time.perf_counter_ns``)."""

    image: np.ndarray
    index: int
    arrived_ns: int


def camera_source(spec: str, platform: str | None = None) -> tuple[str, str | None]:
    """What a camera SPEC names -> ``(FFmpeg input, FFmpeg format or None to probe)``.

    Raises InputError for a number on Windows (DirectShow cameras go by name) or an empty spec."""
    spec = str(spec).strip()
    platform = platform or sys.platform
    if not spec:
        raise InputError("no camera named: give a camera number, a device, or a stream's URL")
    if spec.isdigit():
        n = int(spec)
        if platform.startswith("linux"):
            return f"/dev/video{n}", "v4l2"
        if platform == "darwin":
            return f"{n}:none", "avfoundation"
        if platform.startswith("win"):
            raise InputError(f"on Windows cameras go by name, not number: 'video=NAME' (list them with "
                             f"`ffmpeg -list_devices true -f dshow -i dummy`), not {spec}")
        raise InputError(f"cameras by number are not known on {platform}: give the device or a stream's URL")
    if spec.lower().startswith("video="):
        return spec, "dshow"
    if spec.lower().startswith(URL_SCHEMES):
        return spec, None
    if spec.startswith("/dev/video"):
        return spec, "v4l2"
    return spec, None


class CameraStream:
    """Frames of an opened camera or live stream, decoded by a thread (see the module docstring).

    Attributes
    ----------
    name : str
        What was opened.
    width, height : int
        Frame size.
    fps : float
        The rate the stream states (30 when it states none).
    superseded : int
        Frames decoded that a newer one replaced before :meth:`latest` took them.
    ended : bool
        The stream ended or broke (:attr:`error` says why).
    """

    def __init__(self, container, stream, name: str):
        self._container = container
        self._stream = stream
        self.name = name
        cc = stream.codec_context
        self.width, self.height = int(cc.width or 0), int(cc.height or 0)
        rate = stream.average_rate or stream.base_rate or stream.guessed_rate
        self.fps = float(rate) if rate and 1.0 <= float(rate) <= 1000.0 else 30.0
        self.superseded = 0
        self.ended = False
        self.error: str | None = None
        self._newest = None
        self._count = 0
        self._cond = threading.Condition()
        self._stop = False
        self._thread = threading.Thread(target=self._read, name=f"camera {name}", daemon=True)
        self._thread.start()

    def _read(self) -> None:
        try:
            for packet in self._container.demux(self._stream):
                if self._stop:
                    break
                if packet.size == 0:
                    continue
                try:
                    frames = self._stream.decode(packet)
                except Exception:  # noqa: BLE001 - a damaged packet of a live stream: skipped, as players do
                    continue
                for frame in frames:
                    if frame.width * frame.height > MAX_CAMERA_PIXELS:
                        raise InputError(f"frames of {frame.width}x{frame.height} are over the "
                                         f"{MAX_CAMERA_PIXELS}-pixel limit")
                    with self._cond:
                        if self._newest is not None:
                            self.superseded += 1
                        self._newest = (frame, self._count, time.perf_counter_ns())
                        self._count += 1
                        self._cond.notify_all()
        except Exception as exc:  # noqa: BLE001 - the stream broke: said once, the session ends cleanly
            self.error = getattr(exc, "reason", None) or f"{type(exc).__name__}: {exc}"
        finally:
            with self._cond:
                self.ended = True
                self._cond.notify_all()

    def skip_backlog(self) -> int:
        """Forget the frame waiting (filmed while the consumer was getting ready) -> the number the next frame
        will have."""
        with self._cond:
            self._newest = None
            return self._count

    def latest(self, timeout: float = 0.05) -> CameraFrame | None:
        """The newest frame not yet taken, waiting up to ``timeout`` seconds for one; None if none came (or the
        stream ended: :attr:`ended`)."""
        with self._cond:
            if self._newest is None and not self.ended:
                self._cond.wait(timeout)
            got, self._newest = self._newest, None
        if got is None:
            return None
        frame, index, arrived = got
        image = np.ascontiguousarray(frame.to_ndarray(format="rgb24"))
        return CameraFrame(image, index, arrived)

    def close(self) -> None:
        """Stop reading and close the stream."""
        self._stop = True
        try:
            self._container.close()
        except Exception:  # noqa: BLE001 - closing what already broke
            pass
        self._thread.join(timeout=2.0)


def open_camera(spec: str, platform: str | None = None, timeout_s: float = 10.0) -> CameraStream:
    """Open a camera or live stream (see the module docstring) and start reading its frames.

    Raises
    ------
    InputError
        No such camera, one that does not open (busy, no permission), a stream with no video, or PyAV missing.
    """
    from facegeom.io.video import require_video_extra

    url, fmt = camera_source(spec, platform)
    av = require_video_extra(url)
    if fmt == "v4l2" and not Path(url).exists():
        raise InputError("no such camera (is it plugged in? `ls /dev/video*` lists the cameras)", url)
    if fmt is None and not url.lower().startswith(URL_SCHEMES) and not os.path.exists(url):
        raise InputError("no such camera, device or stream (give a camera number, a device, or a stream's URL)",
                         url)
    options = {"timeout": str(int(timeout_s * 1e6))} if url.lower().startswith(URL_SCHEMES) else {}
    try:
        container = av.open(url, "r", format=fmt, options=options, timeout=timeout_s)
    except Exception as exc:  # noqa: BLE001 - FFmpeg's errors: busy, permission, no such device, no stream
        why = getattr(exc, "strerror", None) or str(exc) or type(exc).__name__
        raise InputError(f"cannot open the camera: {why}", url) from None
    videos = [s for s in container.streams if s.type == "video"]
    if not videos:
        container.close()
        raise InputError("the stream carries no video", url)
    stream = videos[0]
    stream.thread_type = "AUTO"
    return CameraStream(container, stream, url)
