"""Video files: frames read one at a time as RGB arrays, and a writer of preview videos.

Reading (:func:`open_video`) goes through FFmpeg by PyAV, an optional
package (``pip install 'facegeom[video]'``, :mod:`facegeom.io.extras`). A
video is decoded one frame at a time: memory stays at a few frames whatever
the video's length (FFmpeg's threaded decoding holds one frame per thread).

What is refused, each in one line naming the file (:class:`~facegeom.errors.InputError`):

- not a video: text, random bytes, an image (PNG, JPEG, HEIC, ...: read those
  with :func:`facegeom.io.images.read_image`), audio without a video stream,
  an MP4 cut short before its index was written, a playlist or a format
  outside :data:`VIDEO_FORMATS` (a playlist such as HLS could make FFmpeg
  open other files or addresses; only local files are ever opened);
- frames over ``max_pixels``, refused from the stream header before a frame
  is decoded (FFmpeg's decoders are given the same limit, so a stream that
  grows part-way fails there too); the default :data:`MAX_FRAME_PIXELS` is DCI
  8K, 8192 x 4320, the largest standard video frame (106 MB as RGB);
- a video of which no frame decodes.

Damage part-way (what a user wants from a phone video cut short by a full
disk or a crash, or copied with errors): the frames before the damage are
usually good, and so are most after it. So by default a packet that fails to
decode is skipped and counted (:attr:`VideoReader.damaged`), and a file that
ends before the frames its index lists (MP4, MOV, AVI), or whose reading
fails part-way, sets :attr:`VideoReader.truncated` (a Matroska or MPEG-TS
file lists no frame count: cut short, it simply ends early);
the frames that decoded are all yielded, and :attr:`VideoReader.problem`
says in one line (naming the file and the frame) what was wrong, for a
warning. With ``strict=True`` the first damaged frame raises an InputError
naming the file and the frame index instead, and a truncated file raises one
after its last good frame.

Frame times: :attr:`VideoFrame.time_s` is the frame's presentation time from
the stream's start. Phones often record at a variable rate, so the frame index
divided by the rate is not the time; :attr:`VideoReader.variable_rate` tells
when timestamps are not evenly spaced (from the container's sample table when it
has one, else found while reading).

Rotation: phones store a portrait video as landscape frames plus a display
matrix (the ISO BMFF track header's matrix, FFmpeg's display-matrix side
data; older files a ``rotate`` tag). Frames are turned as players show them,
and :attr:`VideoReader.width` / :attr:`VideoReader.height` are the shown size.
Mirroring in the matrix is ignored.

Writing (:class:`VideoWriter`): H.264 (libx264) when the PyAV build has it,
else MPEG-4 Part 2; yuv420p; written to a temporary file in the destination
folder and renamed into place on :meth:`VideoWriter.close`
(:func:`facegeom.io.files.atomic_path`), so a failure or an interruption
leaves no half-written video.
"""
from __future__ import annotations

import contextlib
import math
import os
from collections.abc import Iterator
from fractions import Fraction
from itertools import chain
from pathlib import Path
from typing import NamedTuple

import numpy as np

from facegeom.errors import InputError
from facegeom.io.extras import require_video_extra
from facegeom.io.files import atomic_path

__all__ = ["MAX_FRAME_PIXELS", "VIDEO_SUFFIXES", "VIDEO_FORMATS", "WRITER_SUFFIXES", "VideoFrame", "VideoReader",
           "open_video", "VideoWriter", "writer_codec"]

#: Most pixels (width x height) of a frame decoded by default: DCI 8K (8192 x 4320), the largest standard frame.
MAX_FRAME_PIXELS = 8192 * 4320

#: File names taken as videos by a command given a file (compared lower-case); reading itself goes by content.
VIDEO_SUFFIXES = (".mp4", ".mov", ".m4v", ".mkv", ".webm", ".avi", ".mts", ".m2ts", ".ts", ".mpg", ".mpeg", ".wmv",
                  ".flv", ".3gp", ".mxf", ".gif")

#: FFmpeg demuxers :func:`open_video` lets FFmpeg use: containers and raw streams of video files. Playlists and
#: other demuxers that open further files or addresses (HLS, DASH, concat) are not among them.
VIDEO_FORMATS = ("mov", "matroska", "avi", "mpegts", "mpeg", "mpegvideo", "flv", "asf", "mxf", "nut", "ogg", "dv",
                 "ivf", "gif", "h264", "hevc", "m4v", "obu", "yuv4mpegpipe", "mjpeg")

#: Suffixes :class:`VideoWriter` writes.
WRITER_SUFFIXES = (".mp4", ".mov", ".mkv")

# MP4 brands of still pictures (HEIF / AVIF photos are ISO BMFF files that FFmpeg's mov demuxer opens)
_IMAGE_BRANDS = ("heic", "heix", "mif1", "avif")
_ATTACHED_PIC = 0x0400  # AV_DISPOSITION_ATTACHED_PIC: a cover picture, not a video


class VideoFrame(NamedTuple):
    """One decoded frame.

    Attributes
    ----------
    index : int
        The frame's number among the frames decoded from the start (0-based,
        presentation order). A frame skipped as damaged takes no number.
    time_s : float
        Presentation time in seconds from the stream's start.
    image : (H, W, 3) uint8
        RGB pixels turned as players show them (the rotation applied).
    """

    index: int
    time_s: float
    image: np.ndarray


class _Pass:
    """What one reading pass found: frames decoded, packets damaged, a truncated end."""

    def __init__(self):
        self.decoded = 0
        self.packets = 0
        self.damaged = 0
        self.first_damaged: int | None = None
        self.truncated = False
        self.stopped: str | None = None  # why reading stopped early (a demuxer error)
        self.variable = False
        self.finished = False


def _error_name(exc: BaseException) -> str:
    return exc.__class__.__name__


def _check_file(path: Path) -> None:
    if not path.exists():
        raise InputError("file not found", path)
    if path.is_dir():
        raise InputError("is a folder, not a video file", path)
    if not path.is_file():
        raise InputError("is not a regular file (a device or a pipe), not a video file", path)
    if path.stat().st_size == 0:
        raise InputError("empty file", path)


def _ffmpeg_name(path: Path) -> str:
    """``path`` for FFmpeg: ``file:`` first, so a name with a colon (``take:1.mp4``) is not read as a protocol."""
    return "file:" + os.fspath(path)


def _quarter_turn(degrees: float) -> int:
    """``degrees`` rounded to a multiple of 90, in 0, 90, 180, 270."""
    if not math.isfinite(degrees):
        return 0
    return round(degrees / 90.0) % 4 * 90


class VideoReader:
    """A video opened for reading (made by :func:`open_video`): its properties, and its frames one at a time.

    Iterating (``for frame in reader``) yields every frame as a
    :class:`VideoFrame`, decoding one at a time; :meth:`frames` takes a part
    or every n-th frame. Each new iteration reads from the start again. Use
    it as a context manager, or call :meth:`close`.

    Attributes
    ----------
    path : Path
        The file.
    fps : float or None
        The average frame rate (frames per second) the container states, or
        the guessed rate; None if the file gives none.
    n_frames : int or None
        The frame count the container states (:attr:`n_frames_exact` True),
        else an estimate from the duration and the rate, else None.
    n_frames_exact : bool
        Whether :attr:`n_frames` is the container's count.
    width, height : int
        Frame size in pixels as shown, after the rotation.
    rotation : int
        Degrees (0, 90, 180, 270) by which frames are turned clockwise for
        display: what phones record (an upright iPhone writes 90); frames
        come out already turned.
    duration_s : float or None
        The stream's (else the file's) duration in seconds, if stated.
    codec : str
        FFmpeg's name of the video codec (``h264``, ``hevc``, ...).
    max_pixels : int
        The frame-size limit the reader was opened with.
    strict : bool
        Whether damage raises (True) or is skipped and counted (False).
    """

    def __init__(self, path: str | os.PathLike, max_pixels: int = MAX_FRAME_PIXELS, strict: bool = False):
        self.path = Path(path)
        self._first_pass = None
        self._first = None
        self._av = require_video_extra(self.path)
        _check_file(self.path)
        try:
            self.max_pixels = int(max_pixels)
        except (TypeError, ValueError):
            raise InputError(f"max_pixels must be a whole number, got {max_pixels!r}", self.path) from None
        if self.max_pixels < 1:
            raise InputError(f"max_pixels must be positive, got {self.max_pixels}", self.path)
        self.strict = bool(strict)
        self._closed = False
        self._pass = _Pass()
        self._index_variable = False
        container, stream = self._open()
        try:
            self._describe(container, stream)
            self._first_pass = self._decode(container, stream, self._pass)  # owns the container from here on
        except BaseException:
            container.close()
            raise
        try:
            first = next(self._first_pass)
        except StopIteration:
            self._first_pass = None
            p = self._pass
            if p.packets:
                damaged = f", {p.damaged} failed" if p.damaged else ""
                stopped = f"; {p.stopped}" if p.stopped else ""
                raise InputError(f"no frame of the video decodes ({p.packets} packets read{damaged}{stopped})",
                                 self.path) from None
            raise InputError("the video has no frames", self.path) from None
        except BaseException:
            self._first_pass.close()
            raise
        self._first: tuple | None = first
        self._set_rotation(first[2], stream)

    # ------------------------------------------------------------------ opening
    def _open(self):
        """Open the container and pick its video stream, refusing non-videos and frames over the limit."""
        av = self._av
        path = self.path
        formats = ",".join(VIDEO_FORMATS + tuple(f for f in sorted(av.formats_available) if f.endswith("_pipe")))
        try:
            container = av.open(_ffmpeg_name(path), "r", metadata_errors="replace",
                                container_options={"format_whitelist": formats, "protocol_whitelist": "file"},
                                # reaches the decoders avformat_find_stream_info runs while probing (it decodes up
                                # to 7 frames of H.264): a frame over the limit is never allocated there either
                                options={"max_pixels": str(self.max_pixels)})
        except Exception as exc:  # noqa: BLE001 - FFmpegError subclasses, UnicodeDecodeError, ValueError, ...
            if isinstance(exc, MemoryError) and not isinstance(exc, av.error.FFmpegError):
                raise  # Python's own; FFmpeg's ENOMEM is its answer to a size in the file it will not allocate
            if isinstance(exc, PermissionError):
                raise InputError("cannot open: permission denied", path) from None
            if isinstance(exc, getattr(av.error, "EOFError", ())):
                why = "the file ends inside its header: cut short, or not a video"
            else:
                why = "not a video, a format not read, or damaged (an MP4 cut short before its index was written)"
            raise InputError(f"cannot read as a video ({_error_name(exc)}): {why}", path) from None
        try:
            stream = self._pick_stream(container)
        except BaseException:
            container.close()
            raise
        return container, stream

    def _pick_stream(self, container):
        path = self.path
        fmt = container.format.name or ""
        names = fmt.split(",")
        pipes = [n for n in names if n.endswith("_pipe")]
        if pipes:
            kind = pipes[0][: -len("_pipe")].upper()
            raise InputError(f"is an image ({kind}), not a video: read it as a photo", path)
        meta = container.metadata or {}
        brand = str(meta.get("major_brand", "")).strip().lower()
        if "mov" in names and brand in _IMAGE_BRANDS:
            raise InputError(f"is an image ({brand.upper()}), not a video: read it as a photo", path)
        videos = [s for s in container.streams.video if not int(s.disposition) & _ATTACHED_PIC]
        if not len(container.streams):
            raise InputError("the video has no frames (the file holds no stream)", path)
        if not videos:
            audio = " (audio only)" if len(container.streams.audio) else ""
            raise InputError(f"has no video stream{audio}", path)
        stream = videos[0]
        cc = stream.codec_context
        if cc is None:
            raise InputError("FFmpeg has no decoder for its video codec", path)
        w, h = int(cc.width or 0), int(cc.height or 0)
        if w * h > self.max_pixels:
            raise InputError(f"frames of {w} x {h} pixels ({w * h / 1e6:.1f} megapixels) are over the limit of "
                             f"{self.max_pixels / 1e6:.1f} megapixels: refused before decoding", path)
        cc.options = {"max_pixels": str(self.max_pixels)}  # also for a stream whose frames grow part-way
        with contextlib.suppress(Exception):
            cc.thread_type = "AUTO"  # frame and slice threads, as the codec allows
            cc.thread_count = 0  # one per core
        return stream

    def _describe(self, container, stream) -> None:
        """Rate, count, duration, codec and the container's sample table's regularity."""
        cc = stream.codec_context
        self.codec = str(cc.name or "")
        rate = None
        for r in (stream.average_rate, stream.guessed_rate, stream.base_rate):
            if r is not None and r > 0 and math.isfinite(float(r)):
                rate = r
                break
        self._rate = Fraction(rate) if rate is not None else None
        self.fps = float(rate) if rate is not None else None
        tb = stream.time_base
        self._time_base = Fraction(tb) if tb else None
        duration = None
        if stream.duration and self._time_base and stream.duration > 0:
            duration = float(stream.duration * self._time_base)
        elif container.duration and container.duration > 0:
            duration = container.duration / 1_000_000
        self.duration_s = duration if duration is not None and math.isfinite(duration) else None
        frames = int(stream.frames or 0)
        self.n_frames_exact = frames > 0
        if frames > 0:
            self.n_frames = frames
        elif self.duration_s and self.fps and math.isfinite(self.duration_s * self.fps):
            self.n_frames = max(1, round(self.duration_s * self.fps))
        else:
            self.n_frames = None
        self._listed = frames
        self._start = stream.start_time
        self.width, self.height = int(cc.width or 0), int(cc.height or 0)  # set again from the first frame
        self.rotation = 0
        self._index_variable = self._uneven_index(stream, frames)

    def _uneven_index(self, stream, frames: int) -> bool:
        """Whether the container's sample table (MP4 / MOV: every frame's time) is unevenly spaced."""
        try:
            entries = stream.index_entries
            n = len(entries) if entries is not None else 0
            if n < 3 or n != frames:  # a table of key frames only (Matroska cues) says nothing of the rate
                return False
            times = np.array([entries[i].timestamp for i in range(min(n, 20_000))], dtype=np.float64)
        except Exception:  # noqa: BLE001 - an index PyAV cannot read is no reason to refuse the video
            return False
        return self._uneven(np.diff(np.sort(times)))

    def _uneven(self, deltas: np.ndarray) -> bool:
        """Whether timestamp steps (in time-base ticks) differ from one frame period by more than a tick and 1 %."""
        if deltas.size == 0:
            return False
        if self._rate is not None and self._time_base:
            period = float(1 / (self._rate * self._time_base))
        else:
            period = float(np.median(deltas))
        tolerance = max(1.0, 0.01 * period) + 1e-9
        return bool(np.any(np.abs(deltas - period) > tolerance))

    def _set_rotation(self, frame, stream) -> None:
        """Rotation from the first frame's display matrix (else a ``rotate`` tag), and the shown size."""
        try:
            counterclockwise = float(frame.rotation)  # FFmpeg's display-matrix angle, counter-clockwise
        except Exception:  # noqa: BLE001 - a malformed matrix: shown as stored
            counterclockwise = 0.0
        turn = _quarter_turn(-counterclockwise)
        if turn == 0:
            tag = (stream.metadata or {}).get("rotate")
            with contextlib.suppress(TypeError, ValueError):
                turn = _quarter_turn(float(tag)) if tag is not None else 0
        self.rotation = turn
        w, h = int(frame.width), int(frame.height)
        self.width, self.height = (h, w) if turn in (90, 270) else (w, h)

    # ------------------------------------------------------------------ reading
    @property
    def variable_rate(self) -> bool:
        """Whether frame timestamps are not evenly spaced (from the container's table, or found while reading)."""
        return self._index_variable or self._pass.variable

    @property
    def damaged(self) -> int:
        """Packets that failed to decode and were skipped in the latest reading (0 for a sound file)."""
        return self._pass.damaged

    @property
    def truncated(self) -> bool:
        """Whether the latest reading ended before the frames the file lists (a file cut short)."""
        return self._pass.truncated

    @property
    def frames_decoded(self) -> int:
        """Frames decoded so far in the latest reading."""
        return self._pass.decoded

    @property
    def problem(self) -> str | None:
        """One line naming the file of what went wrong in the latest reading (damage, a cut), or None."""
        p = self._pass
        parts = []
        if p.damaged:
            parts.append(f"{p.damaged} damaged packet{'s' if p.damaged != 1 else ''} skipped, the first at "
                         f"frame {p.first_damaged}")
        if p.truncated:
            listed = f" of the {self._listed} it lists" if self.n_frames_exact else ""
            parts.append(f"the file is cut short: {p.decoded} frames decoded{listed}")
        if p.stopped and not p.truncated:
            parts.append(p.stopped)
        return str(InputError("; ".join(parts), self.path)) if parts else None

    def _decode(self, container, stream, state: _Pass):
        """Yield ``(index, time_s, av_frame)`` for every frame decoded, in presentation order; closes ``container``."""
        av = self._av
        path = self.path
        tb = self._time_base
        origin = self._start
        period_s = 1.0 / self.fps if self.fps else 0.0
        if self._rate is not None and tb:
            ticks = float(1 / (self._rate * tb))  # one frame period in time-base ticks
        else:
            ticks = None
        last = {"pts": None, "time": None}

        def timed(frame):
            pts = frame.pts
            nonlocal origin, ticks
            if pts is not None and tb is not None:
                if origin is None:
                    origin = pts
                if last["pts"] is not None and not state.variable:
                    step = pts - last["pts"]
                    if ticks is None:
                        ticks = float(step)
                    state.variable = abs(step - ticks) > max(1.0, 0.01 * ticks) + 1e-9
                last["pts"] = pts
                time_s = float((pts - origin) * tb)
            else:
                time_s = last["time"] + period_s if last["time"] is not None else 0.0
            last["time"] = time_s
            index = state.decoded
            state.decoded += 1
            return index, time_s, frame

        try:
            packets = container.demux(stream)
            while True:
                try:
                    packet = next(packets)
                except StopIteration:
                    break
                except av.error.FFmpegError as exc:
                    state.stopped = f"reading stopped at frame {state.decoded} ({_error_name(exc)})"
                    state.truncated = True
                    break
                if packet.size == 0:  # PyAV's end-of-stream marker (or an empty packet): flushed below, once
                    continue
                state.packets += 1
                try:
                    decoded = stream.decode(packet)
                except av.error.FFmpegError as exc:
                    if state.first_damaged is None:
                        state.first_damaged = state.decoded
                    state.damaged += 1
                    last["pts"] = None  # a gap, not a change of rate
                    if self.strict:
                        raise InputError(f"frame {state.decoded} does not decode ({_error_name(exc)}): the "
                                         "stream is damaged", path) from None
                    continue
                for frame in decoded:
                    yield timed(frame)
            try:
                tail = stream.decode(None)  # the frames still inside the decoder
            except av.error.FFmpegError:
                tail = []
            for frame in tail:
                yield timed(frame)
            if self.n_frames_exact and state.packets < self._listed:
                state.truncated = True
            state.finished = True
            if self.strict and state.truncated:
                listed = f" of the {self._listed} it lists" if self.n_frames_exact else ""
                raise InputError(f"the file is cut short after frame {state.decoded - 1}: {state.decoded} frames "
                                 f"decoded{listed}", path)
        finally:
            container.close()

    def _rgb(self, frame) -> np.ndarray:
        """An FFmpeg frame as ``(H, W, 3)`` uint8 RGB, turned as shown."""
        a = frame.to_ndarray(format="rgb24")  # a view of the converted frame's buffer, no copy
        if self.rotation:
            a = np.rot90(a, k=-(self.rotation // 90))
        return np.ascontiguousarray(a)

    def __iter__(self) -> Iterator[VideoFrame]:
        """Every frame from the start, as :class:`VideoFrame`, one at a time."""
        return self.frames()

    def frames(self, step: int = 1, start: int = 0, stop: int | None = None) -> Iterator[VideoFrame]:
        """The frames ``start, start + step, ...`` before ``stop`` (frame indices), one at a time.

        Frames between are decoded (a compressed frame depends on those
        before it) but not converted to RGB, which is most of the cost saved.
        Decoding stops at ``stop``.

        Parameters
        ----------
        step : int, optional
            Take every ``step``-th frame (default 1: all).
        start : int, optional
            Index of the first frame taken (default 0).
        stop : int, optional
            Index past the last frame taken (default None: to the end).

        Yields
        ------
        VideoFrame
            ``index`` is the frame's index in the video (``start``,
            ``start + step``, ...), ``time_s`` its time.

        Raises
        ------
        InputError
            A bad ``step`` / ``start`` / ``stop``, a closed reader, and in
            strict mode damage or a truncated file (after the frames before it).
        """
        for name, value, low in (("step", step, 1), ("start", start, 0), ("stop", stop, 0)):
            if value is None and name == "stop":
                continue
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
                raise InputError(f"{name} must be a whole number >= {low}, got {value!r}", self.path)
        if self._closed:
            raise InputError("the video reader is closed", self.path)
        return self._frames(int(step), int(start), None if stop is None else int(stop))

    def _frames(self, step: int, start: int, stop: int | None) -> Iterator[VideoFrame]:
        if self._first is not None:
            first, self._first = self._first, None
            decoder, self._first_pass = self._first_pass, None
            source = chain([first], decoder)
        else:
            container, stream = self._open()
            self._pass = _Pass()
            decoder = source = self._decode(container, stream, self._pass)
        try:
            for index, time_s, frame in source:
                if stop is not None and index >= stop:
                    break
                if index >= start and (index - start) % step == 0:
                    yield VideoFrame(index, time_s, self._rgb(frame))
        finally:
            decoder.close()  # closes the file

    def decode_from(self, time_s: float) -> Iterator[tuple[float, object]]:
        """Random access: ``(time_s, frame)`` for the frames from the key frame at or before ``time_s`` on.

        The file is opened anew and sought to ``time_s`` (seconds from the first frame, the times
        :meth:`frames` gives), so a viewer can jump about a long video without decoding it from the start;
        convert a frame with :meth:`rgb` (only the one shown, the rest are decoded and passed over). Damaged
        packets are skipped. Times are the frames' own (a variable frame rate is no problem); a file whose
        frames carry no times yields them from the start, timed by the average rate.
        """
        if self._closed:
            raise InputError("the video reader is closed", self.path)
        av = self._av
        container, stream = self._open()
        try:
            tb, origin = self._time_base, self._start
            if tb and origin is not None and time_s > 0:
                with contextlib.suppress(av.error.FFmpegError):
                    container.seek(int(origin + math.floor(float(time_s) / tb)), stream=stream, backward=True,
                                   any_frame=False)
            period = 1.0 / self.fps if self.fps else 0.0
            last = None
            for packet in container.demux(stream):
                try:
                    decoded = stream.decode(packet) if packet.size else stream.decode(None)
                except av.error.FFmpegError:
                    continue
                for frame in decoded:
                    if frame.pts is not None and tb is not None and origin is not None:
                        t = float((frame.pts - origin) * tb)
                    else:
                        t = last + period if last is not None else 0.0
                    last = t
                    yield t, frame
        except av.error.FFmpegError:
            return
        finally:
            container.close()

    def rgb(self, frame) -> np.ndarray:
        """A frame from :meth:`decode_from` as ``(H, W, 3)`` uint8 RGB, turned as shown."""
        return self._rgb(frame)

    def close(self) -> None:
        """Close the file (idempotent); the reader cannot be iterated after."""
        self._closed = True
        self._first = None
        if self._first_pass is not None:
            gen, self._first_pass = self._first_pass, None
            gen.close()

    def __enter__(self) -> VideoReader:
        """The reader itself."""
        return self

    def __exit__(self, *exc) -> None:
        """Close the reader."""
        self.close()

    def __repr__(self) -> str:
        """Path, size, rate and count."""
        return (f"VideoReader({str(self.path)!r}, {self.width} x {self.height}, fps={self.fps}, "
                f"n_frames={self.n_frames}, rotation={self.rotation})")


def open_video(path: str | os.PathLike, max_pixels: int = MAX_FRAME_PIXELS, strict: bool = False) -> VideoReader:
    """Open a video for reading frame by frame.

    The header is checked and the first frame decoded here, so a file that
    is not a video, has no frame, or has frames over ``max_pixels`` fails at
    once, and :attr:`VideoReader.rotation` is known.

    Parameters
    ----------
    path : str or os.PathLike
        A video file (MP4, MOV, MKV, WebM, AVI, MPEG-TS, ...; see
        :data:`VIDEO_FORMATS`).
    max_pixels : int, optional
        Most pixels of one frame (width x height); a stream whose header
        declares larger frames is refused before any frame is decoded.
        Default :data:`MAX_FRAME_PIXELS` (DCI 8K).
    strict : bool, optional
        False (default): a packet that fails to decode is skipped and
        counted, a file cut short yields the frames it has
        (:attr:`VideoReader.damaged`, :attr:`VideoReader.truncated`,
        :attr:`VideoReader.problem`). True: either raises an InputError
        naming the file and the frame.

    Returns
    -------
    VideoReader
        Iterate it for :class:`VideoFrame` items; close it (or use ``with``).

    Raises
    ------
    InputError
        One line naming the file: PyAV missing, missing or empty file, not a
        video (text, random bytes, an image, audio only), an unread format,
        frames over ``max_pixels``, no frame that decodes.

    Notes
    -----
    In MPEG program streams (``.mpg``, ``.vob``) and FLV, streams are found
    only by reading packets, and FFmpeg decodes a first frame while probing
    before the limit can be passed to it; the frame is refused right after.
    Every other format (MP4, MOV, MKV, WebM, AVI, MPEG-TS, raw H.264) is
    refused before any decoding.
    """
    return VideoReader(path, max_pixels=max_pixels, strict=strict)


def writer_codec() -> str:
    """The encoder :class:`VideoWriter` uses by default: ``libx264`` (H.264) if PyAV's FFmpeg has it, else ``mpeg4``.

    Returns
    -------
    str
        An FFmpeg encoder name.

    Raises
    ------
    InputError
        PyAV is not installed.
    """
    av = require_video_extra(None, "writing video")
    for name in ("libx264", "mpeg4"):
        if name in av.codec.codecs_available:
            with contextlib.suppress(Exception):
                av.codec.Codec(name, "w")
                return name
    raise InputError("PyAV's FFmpeg has neither the libx264 nor the mpeg4 encoder")  # pragma: no cover


class VideoWriter:
    """Write a preview video frame by frame: H.264 (or MPEG-4 Part 2) yuv420p, renamed into place on close.

    Parameters
    ----------
    path : str or os.PathLike
        The output, ``.mp4``, ``.mov`` or ``.mkv`` (:data:`WRITER_SUFFIXES`);
        its folder must exist.
    fps : float
        Frames per second, in (0, 1000].
    width, height : int
        Frame size in pixels; every frame written must be ``(height, width, 3)``.
        yuv420p needs even sizes: an odd width or height is encoded one pixel
        larger, the last column / row repeated.
    codec : str, optional
        An FFmpeg encoder name; default :func:`writer_codec` (libx264, else mpeg4).

    Attributes
    ----------
    path : Path
        The output.
    codec : str
        The encoder used.
    frames_written : int
        Frames written so far.

    Raises
    ------
    InputError
        PyAV missing, an unsupported suffix, a missing folder, a bad rate or size, an encoder that cannot be opened.

    Notes
    -----
    The video goes to a temporary file beside ``path``; :meth:`close` (or the
    end of a ``with`` block) finishes it and renames it onto ``path``. An
    exception in the ``with`` block, :meth:`discard`, or the writer being
    garbage-collected unclosed removes the temporary file and leaves
    ``path`` as it was. An MP4 / MOV has its index at the front
    (``faststart``), so players and browsers start it before it is fully read.
    """

    def __init__(self, path: str | os.PathLike, fps: float, width: int, height: int, codec: str | None = None):
        self.path = Path(path)
        self._stack = None
        self._container = None
        self.frames_written = 0
        av = require_video_extra(self.path, "writing video")
        self._av = av
        suffix = self.path.suffix.lower()
        if suffix not in WRITER_SUFFIXES:
            raise InputError(f"unsupported video format {suffix!r}; use one of {', '.join(WRITER_SUFFIXES)}", self.path)
        try:
            rate = float(fps)
        except (TypeError, ValueError):
            raise InputError(f"fps must be a number, got {fps!r}", self.path) from None
        if not (math.isfinite(rate) and 0 < rate <= 1000):
            raise InputError(f"fps must be in (0, 1000], got {fps!r}", self.path)
        for name, value in (("width", width), ("height", height)):
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not 1 <= value <= 16384:
                raise InputError(f"{name} must be a whole number of pixels in 1-16384, got {value!r}", self.path)
        self.width, self.height = int(width), int(height)
        if self.width * self.height > MAX_FRAME_PIXELS:
            raise InputError(f"frames of {self.width} x {self.height} pixels are over the limit of "
                             f"{MAX_FRAME_PIXELS / 1e6:.1f} megapixels", self.path)
        self.fps = rate
        self.codec = codec or writer_codec()
        self._encoded = (self.width + self.width % 2, self.height + self.height % 2)
        self._rate = Fraction(rate).limit_denominator(1001)
        self._stack = contextlib.ExitStack()
        try:
            tmp = self._stack.enter_context(atomic_path(self.path))
            options = {"movflags": "+faststart"} if suffix in (".mp4", ".mov") else {}
            options["fflags"] = "+bitexact"  # no time of writing or library version in the file: same frames, same bytes
            self._container = av.open(_ffmpeg_name(tmp), "w", options=options)
            self._stream = self._add_stream()
        except BaseException as exc:
            self._fail(exc)
            if isinstance(exc, InputError):
                raise
            if isinstance(exc, Exception) and not isinstance(exc, (MemoryError, OSError)):
                raise InputError(f"cannot write a {self.codec} video ({_error_name(exc)}: {exc})", self.path) \
                    from None
            raise

    def _add_stream(self):
        w, h = self._encoded
        if self.codec == "libx264":
            stream = self._container.add_stream(self.codec, rate=self._rate,
                                                options={"preset": "veryfast", "crf": "20", "threads": "1"})
        else:
            stream = self._container.add_stream(self.codec, rate=self._rate)
            stream.bit_rate = int(min(50e6, max(400e3, 0.3 * w * h * self.fps)))
        stream.width, stream.height, stream.pix_fmt = w, h, "yuv420p"
        return stream

    def write(self, rgb: np.ndarray) -> None:
        """Append one frame.

        Parameters
        ----------
        rgb : (height, width, 3) uint8
            RGB pixels, row 0 at the top.

        Raises
        ------
        InputError
            A closed writer, or a frame of another shape or type.
        """
        if self._container is None:
            raise InputError("the video writer is closed", self.path)
        a = np.asarray(rgb)
        if a.dtype != np.uint8 or a.shape != (self.height, self.width, 3):
            raise InputError(f"a frame must be ({self.height}, {self.width}, 3) uint8 RGB, got {a.shape} {a.dtype}",
                             self.path)
        w, h = self._encoded
        if (w, h) != (self.width, self.height):
            a = np.pad(a, ((0, h - self.height), (0, w - self.width), (0, 0)), mode="edge")
        frame = self._av.VideoFrame.from_ndarray(np.ascontiguousarray(a), format="rgb24")
        frame.pts = self.frames_written
        frame.time_base = Fraction(1) / self._rate
        for packet in self._stream.encode(frame):
            self._container.mux(packet)
        self.frames_written += 1

    def close(self) -> Path:
        """Finish the video and rename it onto :attr:`path` (idempotent once done).

        Returns
        -------
        Path
            The video written.

        Raises
        ------
        InputError
            No frame was written (nothing is left at :attr:`path`).
        """
        if self._container is None:
            if self._stack is None:
                return self.path
            raise InputError("the video writer was discarded", self.path)  # pragma: no cover
        try:
            if self.frames_written == 0:
                raise InputError("no frame was written: no video to save", self.path)
            for packet in self._stream.encode(None):
                self._container.mux(packet)
            container, self._container = self._container, None
            container.close()
        except BaseException as exc:
            self._fail(exc)
            raise
        stack, self._stack = self._stack, None
        stack.close()  # the rename
        return self.path

    def discard(self) -> None:
        """Stop writing and remove the temporary file; :attr:`path` stays as it was (idempotent)."""
        if self._stack is not None:
            self._fail(InputError("the video was discarded", self.path))

    def _fail(self, exc: BaseException) -> None:
        """Close the container quietly and let :func:`atomic_path` remove the temporary file."""
        container, self._container = self._container, None
        if container is not None:
            with contextlib.suppress(Exception):
                container.close()
        stack, self._stack = self._stack, None
        if stack is not None:
            with contextlib.suppress(BaseException):
                stack.__exit__(type(exc), exc, exc.__traceback__)

    def __enter__(self) -> VideoWriter:
        """The writer itself."""
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        """Close on success; on an exception, discard (nothing is left at :attr:`path`)."""
        if exc_type is None:
            self.close()
        elif exc is not None:
            self._fail(exc)
        else:  # pragma: no cover - an exception type without an instance
            self.discard()

    def __del__(self):
        """An unclosed writer being collected removes its temporary file."""
        with contextlib.suppress(Exception):
            if getattr(self, "_stack", None) is not None:
                self.discard()
