"""``facegeom live``: a Live Link Face stream received, processed and passed on while the actor performs.

A session is a loop of three parts, each its own class:

- a **source** gives the newest frame when there is one: :class:`UDPSource`
  (the iPhone app's datagrams, :mod:`facegeom.io.livelink`) or
  :class:`ReplaySource` (a recording or a take played at its own rate);
- **processing**, each step optional: :class:`Calibration` (the first seconds
  are the actor's rest, which becomes zero), :class:`OneEuro` smoothing; with
  neither the values go through unchanged, the weights clamped to [0, 1];
- **sinks**: :class:`UDPSink` (Live Link Face packets out, so Unreal's Live
  Link sees a phone) and :class:`Recorder` (what was received, written when
  the session ends, Ctrl-C included).

Real time comes first. A source never queues: each poll drains every datagram
waiting and keeps the newest valid one (the others are counted as superseded),
so after a burst the next frame out is the newest at once. Every datagram is
parsed as hostile (:func:`facegeom.io.livelink.parse_packet`); a malformed one,
one of another subject, or one with a value that is not finite is counted and
dropped, never forwarded. :class:`LiveStats` keeps the counts and each frame's
latency from its datagram's arrival to the moment the last sink has it.
"""
from __future__ import annotations

import math
import select
import socket
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from facegeom.errors import InputError
from facegeom.io.livelink import (
    PACKET_NAMES,
    PACKET_VALUES,
    PacketError,
    encode_packet,
    parse_packet,
    read_recording,
    write_recording,
)

__all__ = ["LiveFrame", "LiveStats", "UDPSource", "ReplaySource", "Calibration", "OneEuro", "UDPSink", "Recorder",
           "CharacterSink", "OSCSink", "LiveSession", "parse_address", "solved_values", "DEFAULT_PORT",
           "RECORD_SUFFIXES"]

DEFAULT_PORT = 11111  # the Live Link Face app's default target port
N_WEIGHTS = 52
RECORD_SUFFIXES = (".csv", ".gesichter", ".npz", ".glb", ".usda", ".usdc", ".usdz")
CHARACTER_SUFFIXES = (".glb", ".usda", ".usdc", ".usdz")  # what the character performing the session is written as
LATENCY_SAMPLES = 100_000  # latencies kept for the percentiles (the last ~28 minutes at 60 fps)


def parse_address(text: str, default_host: str = "127.0.0.1", what: str = "--listen") -> tuple[str, int]:
    """``PORT``, ``HOST:PORT`` -> ``(host, port)``; :class:`InputError` naming ``what`` otherwise."""
    text = str(text).strip()
    host, _, port = text.rpartition(":")
    host = host.strip("[]") or default_host
    try:
        p = int(port)
    except ValueError:
        raise InputError(f"{what} must be PORT or HOST:PORT, e.g. 127.0.0.1:{DEFAULT_PORT}, got {text!r}") from None
    if not 0 <= p <= 65535:
        raise InputError(f"{what}: port {p} is not in 0-65535")
    return host, p


@dataclass
class LiveFrame:
    """One frame in flight: the 61 values in :data:`~facegeom.io.livelink.PACKET_NAMES` order and where it came
    from. ``arrived_ns``: :func:`time.perf_counter_ns` when its datagram was read (or it was due, replayed)."""

    values: np.ndarray
    device_id: str
    subject: str
    frame: int
    sub_frame: float
    rate: tuple[int, int]
    arrived_ns: int
    raw: bytes = b""

    @property
    def weights(self) -> np.ndarray:
        """The 52 weights (a view: changing it changes the frame)."""
        return self.values[:N_WEIGHTS]


@dataclass
class LiveStats:
    """What a session counted: datagrams in, frames out, drops by reason, and latencies (ms)."""

    datagrams: int = 0
    frames_in: int = 0  # valid frames of the chosen subject
    frames_out: int = 0
    malformed: int = 0
    superseded: int = 0  # valid, but a newer one arrived before it could be passed on
    other_subject: int = 0
    send_errors: int = 0
    senders: set = field(default_factory=set)
    first_error: str | None = None
    latencies_ms: deque = field(default_factory=lambda: deque(maxlen=LATENCY_SAMPLES))

    def percentiles(self) -> dict[str, float]:
        """p50 / p95 / p99 / max of the latencies (ms); empty without frames."""
        if not self.latencies_ms:
            return {}
        a = np.fromiter(self.latencies_ms, dtype=np.float64)
        return {"p50": float(np.percentile(a, 50)), "p95": float(np.percentile(a, 95)),
                "p99": float(np.percentile(a, 99)), "max": float(a.max())}

    def line(self) -> str:
        """The status line: frames in / out, drops, latency."""
        p = self.percentiles()
        lat = f"; latency p50 {p['p50']:.2f} ms, p99 {p['p99']:.2f} ms" if p else ""
        return (f"{self.frames_in} frames in, {self.frames_out} out; dropped: {self.malformed} malformed, "
                f"{self.superseded} superseded, {self.other_subject} other subject{lat}")


class UDPSource:
    """Live Link Face datagrams on ``host:port`` (127.0.0.1 unless another address is given explicitly).

    ``subject``: take only this subject's frames; None: the first subject heard (the others are counted and
    dropped). Port 0 binds a free port (:attr:`port` says which).
    """

    def __init__(self, host: str = "127.0.0.1", port: int = DEFAULT_PORT, subject: str | None = None,
                 stats: LiveStats | None = None):
        self.stats = stats if stats is not None else LiveStats()
        self.subject = subject
        self.sock = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.sock.bind((host, int(port)))
        except OSError as exc:
            self.sock.close()
            raise InputError(f"cannot listen on {host}:{port}: {exc.strerror or exc}") from None
        self.sock.setblocking(False)
        self.host, self.port = self.sock.getsockname()[:2]

    def poll(self, timeout: float = 0.05) -> LiveFrame | None:
        """Wait up to ``timeout`` seconds for datagrams, read every one waiting, return the newest valid frame
        (or None)."""
        ready, _, _ = select.select([self.sock], [], [], max(0.0, timeout))
        if not ready:
            return None
        newest = None
        st = self.stats
        while True:
            try:
                data, sender = self.sock.recvfrom(65536)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:  # e.g. an ICMP error reported on a UDP socket: nothing to read
                break
            now = time.perf_counter_ns()
            st.datagrams += 1
            st.senders.add(sender[:2])
            try:
                p = parse_packet(data)
            except PacketError as exc:
                st.malformed += 1
                if st.first_error is None:
                    st.first_error = f"{sender[0]}:{sender[1]}: {exc}"
                continue
            if self.subject is None:
                self.subject = p.subject
            if p.subject != self.subject:
                st.other_subject += 1
                continue
            st.frames_in += 1
            if newest is not None:
                st.superseded += 1
            newest = LiveFrame(np.array(p.values), p.device_id, p.subject, p.frame, p.sub_frame, p.rate, now, data)
        return newest

    def close(self) -> None:
        """Close the socket."""
        self.sock.close()


def _packets(values: np.ndarray, fps: float, subject: str, first: int = 0) -> list[bytes]:
    """Rows of the 61 packet values -> Live Link Face packets at ``fps`` (non-finite values sent as 0), frame
    numbers (the timecode in frames, as the phone sends it) from ``first``."""
    rate = (int(round(fps)), 1) if abs(fps - round(fps)) < 1e-3 * fps else (int(round(fps * 1000)), 1000)
    values = np.nan_to_num(np.asarray(values, dtype=np.float64))
    return [encode_packet(w, "facegeom-replay", subject, first + i, 0.0, rate) for i, w in enumerate(values)]


def _default_fitter():
    from facegeom import registry

    return registry.create("fitters", "sem-ls")


def solved_values(solved) -> np.ndarray:
    """A solved marker capture (:class:`facegeom.pipelines.solve.SolvedCapture`) -> ``(T, 61)`` packet values:
    the rig's shapes mapped to the 52 ARKit weights by name, the head's rotation from the solve and the eyes'
    from the eye-look weights, as a Live Link take carries them (the same as ``facegeom solve ... take.csv``)."""
    from facegeom.io.takes import ARKIT_NAMES
    from facegeom.pipelines.solve import arkit_map, livelink_rotations

    m = arkit_map(solved)
    if m.is_empty:
        raise InputError("none of the rig's shape names is an ICT or ARKit expression: its weights cannot be "
                         "streamed as ARKit weights")
    W = m.apply(solved.solve.weights)
    index = {n.lower(): k for k, n in enumerate(ARKIT_NAMES)}
    out = np.zeros((W.shape[0], PACKET_VALUES))
    for k, name in enumerate(PACKET_NAMES[:N_WEIGHTS]):
        out[:, k] = W[:, index[name.lower()]]
    out[:, N_WEIGHTS:] = livelink_rotations(solved, W)
    return out


class ReplaySource:
    """A recording (``.gesichter``: the packets as the phone sent them), a Live Link Face take (``.csv``) or a
    marker capture (``.c3d``, solved on ``rig`` first, as ``facegeom solve`` does) played at its own rate, as if
    a phone were streaming it (for demos and tests). ``loop`` starts over at the end; without it :meth:`poll`
    returns None for good after the last frame (:attr:`done`)."""

    def __init__(self, path, loop: bool = False, stats: LiveStats | None = None, subject: str | None = None,
                 rig=None, fitter=None, markers=None):
        self.stats = stats if stats is not None else LiveStats()
        self.path = Path(path)
        self.notes: list[str] = []
        suffix = self.path.suffix.lower()
        if suffix == ".gesichter":
            self.packets, bad = [], 0
            for raw in read_recording(self.path):
                try:
                    parse_packet(raw)
                    self.packets.append(raw)
                except PacketError:
                    bad += 1
            if not self.packets:
                raise InputError("the recording holds no valid packet", self.path)
            first = parse_packet(self.packets[0])
            self.fps = first.fps or 60.0
        elif suffix == ".csv":
            from facegeom.io.takes import ROTATION_NAMES, read_take
            from facegeom.pipelines.solve import take_fps

            take = read_take(self.path)
            self.fps = float(take_fps(take))
            index = {n.lower(): k for k, n in enumerate(take.names)}
            W = np.zeros((take.n_frames, PACKET_VALUES))
            for k, name in enumerate(PACKET_NAMES[:N_WEIGHTS]):
                W[:, k] = take.weights[:, index[name.lower()]]
            if take.rotations is not None:
                W[:, N_WEIGHTS:] = take.rotations[:, :len(ROTATION_NAMES)]
            first = int(round(take.start_s * self.fps))  # the take's own timecode goes on in the frame numbers
            self.packets = _packets(W, self.fps, subject or self.path.stem, first)
        elif suffix == ".c3d":
            from facegeom.pipelines.solve import solve_file

            if rig is None:
                raise InputError("replaying a marker capture solves it on a rig: give the rig (the face model's "
                                 "generic face by default)", self.path)
            solved = solve_file(self.path, rig, fitter if fitter is not None else _default_fitter(), "sem-ls",
                                markers)
            self.fps = float(solved.fps)
            self.notes = list(solved.notes)
            self.packets = _packets(solved_values(solved), self.fps, subject or self.path.stem)
        else:
            raise InputError(f"cannot replay {suffix or 'a file without suffix'!r}: give a .gesichter recording, "
                             "a Live Link Face .csv take or a .c3d marker capture", self.path)
        self.loop = bool(loop)
        self.index = 0
        self.done = False
        self._t0 = None

    def poll(self, timeout: float = 0.05) -> LiveFrame | None:
        """The next frame once it is due (waiting up to ``timeout`` seconds for it), else None."""
        if self.done:
            time.sleep(min(timeout, 0.01))
            return None
        now = time.perf_counter()
        if self._t0 is None:
            self._t0 = now
        due = self._t0 + self.index / self.fps
        if due - now > timeout:
            time.sleep(max(0.0, timeout))
            return None
        if due > now:
            time.sleep(due - now)
        else:  # behind (a slow consumer): the newest frame already due wins, as from a phone
            newest = int((now - self._t0) * self.fps)
            last = len(self.packets) - 1 if not self.loop else newest
            skip = max(0, min(newest, last) - self.index)
            self.stats.superseded += skip
            self.stats.frames_in += skip
            self.stats.datagrams += skip
            self.index += skip
        raw = self.packets[self.index % len(self.packets)]
        p = parse_packet(raw)
        self.index += 1
        if self.index >= len(self.packets) and not self.loop:
            self.done = True
        self.stats.datagrams += 1
        self.stats.frames_in += 1
        return LiveFrame(np.array(p.values), p.device_id, p.subject, p.frame, p.sub_frame, p.rate,
                         time.perf_counter_ns(), raw)

    def close(self) -> None:
        """Nothing to close (the packets were read at start)."""


class Calibration:
    """The actor's rest from the first ``seconds`` of the stream (the median of each weight, capped at 0.5),
    taken off every later frame: ``w' = clip((w - rest) / (1 - rest), 0, 1)``. Until it is known the weights go
    through unchanged."""

    MAX_REST = 0.5

    def __init__(self, seconds: float):
        if not (seconds > 0 and math.isfinite(seconds)):
            raise InputError(f"the calibration must last a positive number of seconds, got {seconds}")
        self.seconds = float(seconds)
        self.samples: list[np.ndarray] = []
        self.rest: np.ndarray | None = None
        self._t0: int | None = None

    def __call__(self, frame: LiveFrame) -> None:
        w = frame.values[:N_WEIGHTS]
        if self.rest is None:
            if self._t0 is None:
                self._t0 = frame.arrived_ns
            self.samples.append(w.copy())
            if (frame.arrived_ns - self._t0) / 1e9 >= self.seconds:
                self.rest = np.clip(np.median(np.array(self.samples), axis=0), 0.0, self.MAX_REST)
                self.samples = []
            return
        frame.values[:N_WEIGHTS] = np.clip((w - self.rest) / (1.0 - self.rest), 0.0, 1.0)


class OneEuro:
    """The One-Euro filter (Casiez, Roussel and Vogel, CHI 2012) on every value: a low-pass whose cut-off
    rises with the speed of the signal, ``f_c = min_cutoff + beta |dx/dt|``.

    Why this one: live there is no future to look at (the offline Whittaker smoother of ``facegeom track``
    needs it), and a fixed low-pass must choose between jitter at rest and lag in motion. The One-Euro
    smooths a still face hard and lets a fast move through with little lag; it costs a few operations per
    value and frame. Its lag is measured, not assumed (the session reports it).
    """

    def __init__(self, min_cutoff: float = 1.5, beta: float = 0.5, d_cutoff: float = 1.0):
        for name, v in (("min_cutoff", min_cutoff), ("beta", beta), ("d_cutoff", d_cutoff)):
            if not (v >= 0 and math.isfinite(v)) or (name != "beta" and v == 0):
                raise InputError(f"One-Euro {name} must be a positive number, got {v}")
        self.min_cutoff, self.beta, self.d_cutoff = float(min_cutoff), float(beta), float(d_cutoff)
        self.x: np.ndarray | None = None
        self.dx: np.ndarray | None = None
        self.t: float | None = None

    @staticmethod
    def _alpha(cutoff, dt):
        tau = 1.0 / (2.0 * math.pi * cutoff)
        return 1.0 / (1.0 + tau / dt)

    def filter(self, x: np.ndarray, t: float) -> np.ndarray:
        """The filtered ``x`` at time ``t`` (seconds)."""
        x = np.asarray(x, dtype=np.float64)
        if self.x is None or self.t is None or t <= self.t:
            dt = None
        else:
            dt = t - self.t
        if dt is None:
            self.x, self.dx, self.t = x.copy(), np.zeros_like(x), t
            return x.copy()
        a_d = self._alpha(self.d_cutoff, dt)
        self.dx = a_d * (x - self.x) / dt + (1.0 - a_d) * self.dx
        cutoff = self.min_cutoff + self.beta * np.abs(self.dx)
        a = 1.0 / (1.0 + 1.0 / (2.0 * math.pi * cutoff * dt))
        self.x = a * x + (1.0 - a) * self.x
        self.t = t
        return self.x.copy()

    def __call__(self, frame: LiveFrame) -> None:
        """Filter the frame's values in place, on the sender's clock (its frame time) when it has a rate."""
        num, den = frame.rate
        t = (frame.frame + frame.sub_frame) * den / num if num > 0 and den > 0 else frame.arrived_ns / 1e9
        frame.values[:] = self.filter(frame.values, t)


class UDPSink:
    """Live Link Face packets out to ``host:port`` (what Unreal's Live Link, or another ``facegeom live``,
    reads)."""

    def __init__(self, host: str, port: int, stats: LiveStats | None = None):
        self.stats = stats if stats is not None else LiveStats()
        self.address = (host, int(port))
        self.sock = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setblocking(False)

    def __call__(self, frame: LiveFrame) -> None:
        data = encode_packet(frame.values, frame.device_id, frame.subject, frame.frame, frame.sub_frame, frame.rate)
        try:
            self.sock.sendto(data, self.address)
        except OSError:  # no one listening (ICMP refused), a full buffer: live, the next frame will do
            self.stats.send_errors += 1

    def close(self) -> None:
        """Close the socket."""
        self.sock.close()


class OSCSink:
    """The weights as VMC-protocol OSC (VTuber apps: VSeeFace, VNyan, Warudo...): every frame one bundle of
    ``/VMC/Ext/Blend/Val`` messages, one per ARKit shape by its name (``EyeBlinkLeft`` ... : the "perfect
    sync" names), then ``/VMC/Ext/Blend/Apply``."""

    def __init__(self, host: str, port: int, stats: LiveStats | None = None):
        from facegeom.io.osc import VMCBlendEncoder

        self.stats = stats if stats is not None else LiveStats()
        self.address = (host, int(port))
        self.encoder = VMCBlendEncoder(PACKET_NAMES[:N_WEIGHTS])
        self.sock = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setblocking(False)

    def __call__(self, frame: LiveFrame) -> None:
        try:
            self.sock.sendto(self.encoder.encode(frame.values[:N_WEIGHTS]), self.address)
        except OSError:
            self.stats.send_errors += 1

    def close(self) -> None:
        """Close the socket."""
        self.sock.close()


class Recorder:
    """Everything passed on, kept in memory (61 values a frame: ~30 KB a second at 60 fps) and written to
    ``path`` when the session ends: ``.csv`` a Live Link Face take, ``.gesichter`` the packets, ``.npz`` the
    values with their names and arrival times. (A ``.glb`` is the character's: :meth:`CharacterSink.write_glb`.)"""

    def __init__(self, path):
        self.path = Path(path)
        if self.path.suffix.lower() not in RECORD_SUFFIXES[:3]:
            raise InputError(f"a recording must be one of {', '.join(RECORD_SUFFIXES[:3])}", self.path)
        self.values: list[np.ndarray] = []
        self.times: list[int] = []
        self.meta: tuple | None = None
        self.start_s: float | None = None

    def __call__(self, frame: LiveFrame) -> None:
        self.values.append(frame.values.copy())
        self.times.append(frame.arrived_ns)
        if self.meta is None:
            self.meta = (frame.device_id, frame.subject, frame.rate)
            r = frame.rate
            # the first frame's timecode (its frame number at its rate): a recorded take starts there
            self.start_s = (frame.frame + frame.sub_frame) * r[1] / r[0] if r[0] > 0 and r[1] > 0 else None

    def write(self) -> Path | None:
        """Write what was recorded (atomically); None when nothing was."""
        if not self.values:
            return None
        V = np.array(self.values)
        t = (np.array(self.times, dtype=np.int64) - self.times[0]) / 1e9
        device, subject, rate = self.meta
        fps = rate[0] / rate[1] if rate[0] > 0 and rate[1] > 0 else (
            (len(t) - 1) / t[-1] if t[-1] > 0 else 60.0)
        suffix = self.path.suffix.lower()
        if suffix == ".csv":
            from facegeom.io.takes import write_livelink_csv

            start = self.start_s % 86400.0 if self.start_s is not None and np.isfinite(self.start_s) else None
            return write_livelink_csv(self.path, V[:, :N_WEIGHTS], PACKET_NAMES[:N_WEIGHTS], fps, start=start,
                                      rotations=V[:, N_WEIGHTS:])
        if suffix == ".gesichter":
            return write_recording(self.path, [encode_packet(v, device, subject, i, 0.0, rate)
                                               for i, v in enumerate(V)])
        from facegeom.io.files import atomic_path

        with atomic_path(self.path) as tmp, open(tmp, "wb") as fh:
            np.savez_compressed(fh, values=V, names=np.array(PACKET_NAMES), times=t, fps=np.float64(fps),
                                subject=np.array(subject), device=np.array(device))
        return self.path


class CharacterSink:
    """The user's character following the stream: the ARKit weights through its name map (the mapping CSV's
    gains included), and the head's rotation. Only the weights are computed per frame (a small matrix
    product); the mesh is posed when something asks for it (:meth:`face`), so a session without a viewer pays
    nothing for it. With ``keep`` every frame's weights and rotation are kept for a ``.glb`` at the end."""

    def __init__(self, rig, keep: bool = False):
        self.rig = rig
        self.map = rig.map_from(PACKET_NAMES[:N_WEIGHTS])
        if self.map.is_empty:
            raise InputError("none of the character's shapes is an ARKit or ICT expression; give a mapping file "
                             "of its shape names")
        self.weights = np.zeros(len(rig.names))
        self.rotation = np.eye(3)
        self.frames = 0
        self.keep = bool(keep)
        self.kept_weights: list[np.ndarray] = []
        self.kept_rotations: list[np.ndarray] = []

    def __call__(self, frame: LiveFrame) -> None:
        from scipy.spatial.transform import Rotation

        self.weights = self.map.apply(frame.values[:N_WEIGHTS])
        yaw, pitch, roll = frame.values[N_WEIGHTS:N_WEIGHTS + 3]
        self.rotation = Rotation.from_euler("YXZ", [yaw, pitch, roll]).as_matrix()
        self.frames += 1
        if self.keep:
            self.kept_weights.append(self.weights.copy())
            self.kept_rotations.append(self.rotation.copy())

    def write_glb(self, path, fps: float) -> Path | None:
        """The kept frames as a ``.glb`` (or USD, by the suffix): the character with its shapes as morph targets,
        the weights and the head's rotation as an animation at ``fps`` (atomically). None when nothing was
        kept."""
        from facegeom.io.delivery import write_rig_animation
        from facegeom.pipelines.solve import GLB_SCALE

        if not self.kept_weights:
            return None
        rig = self.rig
        W = np.array(self.kept_weights)
        R = np.array(self.kept_rotations)
        return write_rig_animation(path, rig.neutral * GLB_SCALE, rig.triangles, rig.deltas * GLB_SCALE, rig.names,
                                   W, fps, rotations=R, translations=np.zeros((W.shape[0], 3)))

    def face(self) -> np.ndarray:
        """The character now: its expression, turned by the head about its neutral's centroid, ``(n, 3)``."""
        rig = self.rig
        on = np.flatnonzero(self.weights)
        P = rig.neutral + np.tensordot(self.weights[on], rig.deltas[on], axes=1) if on.size else np.array(rig.neutral)
        c = np.asarray(rig.neutral).mean(axis=0)
        return c + (P - c) @ self.rotation.T


class LiveSession:
    """Source -> processing steps -> sinks, one frame at a time, until stopped.

    Parameters
    ----------
    source : UDPSource or ReplaySource
    steps : list of callables
        Each takes a :class:`LiveFrame` and changes its values in place (:class:`Calibration`, :class:`OneEuro`).
    sinks : list of callables
        Each takes the finished frame (:class:`UDPSink`, :class:`Recorder`, a viewer).
    stats : LiveStats, optional
        Shared with the source and the sinks (default: the source's).
    """

    def __init__(self, source, steps=(), sinks=(), stats: LiveStats | None = None):
        self.source = source
        self.steps = list(steps)
        self.sinks = list(sinks)
        self.stats = stats if stats is not None else source.stats
        self.stopped = False

    def step(self, timeout: float = 0.05) -> LiveFrame | None:
        """Poll the source once and pass its newest frame on (None if there was none)."""
        frame = self.source.poll(timeout)
        if frame is None:
            return None
        for s in self.steps:
            s(frame)
        w = frame.values[:N_WEIGHTS]
        np.clip(w, 0.0, 1.0, out=w)
        if not np.isfinite(frame.values).all():  # a step cannot make one, but nothing non-finite ever leaves
            self.stats.malformed += 1
            return None
        for s in self.sinks:
            s(frame)
        self.stats.frames_out += 1
        self.stats.latencies_ms.append((time.perf_counter_ns() - frame.arrived_ns) / 1e6)
        return frame

    def run(self, frames: int | None = None, seconds: float | None = None, status=None,
            status_every: float = 0.5) -> LiveStats:
        """Run until ``frames`` frames were passed on, ``seconds`` passed, the source is done, :meth:`stop`,
        or Ctrl-C (which ends the session cleanly). ``status(line)`` is called every ``status_every`` s."""
        t_end = None if seconds is None else time.monotonic() + float(seconds)
        next_status = time.monotonic() + status_every
        try:
            while not self.stopped:
                if frames is not None and self.stats.frames_out >= frames:
                    break
                now = time.monotonic()
                if t_end is not None and now >= t_end:
                    break
                if getattr(self.source, "done", False):
                    break
                self.step(0.05 if t_end is None else min(0.05, max(0.0, t_end - now)))
                if status is not None and time.monotonic() >= next_status:
                    status(self.stats.line())
                    next_status = time.monotonic() + status_every
        except KeyboardInterrupt:
            pass
        return self.stats

    def stop(self) -> None:
        """End :meth:`run` after the current frame (from another thread or a signal handler)."""
        self.stopped = True

    def close(self) -> None:
        """Close the source and the sinks that hold sockets."""
        for part in [self.source, *self.sinks]:
            close = getattr(part, "close", None)
            if close is not None:
                close()
