"""A video as a live source: each frame tracked as it comes, at the video's own rate, no markers, no phone.

:class:`VideoSource` is a source of :mod:`facegeom.pipelines.live` (a ``poll`` returning the newest
:class:`~facegeom.pipelines.live.LiveFrame`). Per frame, what ``facegeom track`` does offline, but causal:
the face's 468 points (:class:`facegeom.vision.tracking.FaceTracker`), the head pose and the expression
weights from the previous frame's answer (:class:`facegeom.methods.frame_solver.FrameSolver`, each point
weighed by its measured noise), the gaze from the irises; the ICT weights go out as the 52 ARKit ones with
the head's and the eyes' rotations, as the phone sends them. There is no look-ahead: no smoothing here (add
``--smooth one-euro``), no calibration (``--calibrate``), and the actor's identity is the one given (``rig``,
e.g. a previous ``facegeom track --rig-out``) or the generic face. The frames are played at their own times;
when tracking falls behind, frames whose time has passed are skipped (counted as superseded), so the output
stays live.
"""
from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from facegeom.errors import InputError
from facegeom.pipelines.live import N_WEIGHTS, LiveFrame, LiveStats
from facegeom.pipelines.track import DETECTOR_NOISE

__all__ = ["CameraSource", "FaceValues", "VideoSource"]


def _rate(fps: float) -> tuple[int, int]:
    """A frame rate as the packet's numerator and denominator."""
    if math.isclose(fps, round(fps), rel_tol=1e-3):
        return int(round(fps)), 1
    return int(round(fps * 1000)), 1000


class FaceValues:
    """One image of a face -> the 61 Live Link values (the 52 ARKit weights, the head's and eyes' rotations).

    The face's 468 points, the head pose and the expression weights solved from the previous frame's answer
    (causal, each point weighed by its measured noise), the gaze from the irises. ``width``, ``height``: the
    images' size (the camera: :data:`facegeom.methods.video_identity.FOCAL_PRIOR` times the larger side).
    :attr:`lost` counts images without a face."""

    def __init__(self, model, rig, width: int, height: int):
        from facegeom.methods.frame_solver import FrameSolver
        from facegeom.methods.video_identity import FOCAL_PRIOR
        from facegeom.model.camera import PinholeCamera
        from facegeom.model.rig import BlendshapeRig
        from facegeom.pipelines.track import eyeball_centres, point_vertices, point_weights
        from facegeom.vision.tracking import FaceTracker

        self.person = rig if rig is not None else BlendshapeRig.from_face_model(model)
        if self.person.n_vertices != model.n_vertices:
            raise InputError(f"the actor's rig has {self.person.n_vertices} vertices, the face model "
                             f"{model.n_vertices}: give a rig of the face model (an actor's rig fitted by facegeom)")
        self.names = tuple(self.person.names)
        self.keep, ids, bary = point_vertices(model)
        w, h = int(width), int(height)
        self.size = (w, h)
        self.camera = PinholeCamera(FOCAL_PRIOR * max(w, h), (w - 1) / 2.0, (h - 1) / 2.0)
        self.solver = FrameSolver(self.person.neutral, self.person.deltas, ids, self.camera, noise_px=1.0, bary=bary,
                                  point_weights=point_weights(self.keep))
        lm = self.person.landmark_ids if self.person.landmark_ids is not None else model.landmarks
        self.centres = eyeball_centres(self.person.neutral, lm)
        self.tracker = FaceTracker()
        self.lost = 0
        self._prev = None

    def values(self, image) -> np.ndarray | None:
        """One image tracked -> the 61 packet values, or None without a face (counted in :attr:`lost`)."""
        from facegeom.io.livelink import PACKET_NAMES
        from facegeom.io.takes import head_angles, ict_to_arkit
        from facegeom.pipelines.track import _eye_rotations, gaze_angles

        r = self.tracker.step(image)
        if r.points is None:
            self._prev = None
            self.lost += 1
            return None
        uv = r.points[self.keep, :2].astype(np.float64)
        eyes = float(np.linalg.norm(r.points[263, :2] - r.points[33, :2]))
        self.solver.sigma = max(DETECTOR_NOISE * eyes, 0.25)  # the points' noise at this face's size (as track)
        p = self._prev
        pose = self.solver.solve(uv) if p is None else self.solver.solve(uv, p.R, p.t, p.w)
        self._prev = pose
        arkit, names = ict_to_arkit(pose.w[None], self.names)
        arkit = arkit[0]
        index = {n.lower(): k for k, n in enumerate(names)}
        values = np.zeros(len(PACKET_NAMES))
        for k, n in enumerate(PACKET_NAMES[:N_WEIGHTS]):
            values[k] = arkit[index[n.lower()]]
        values[N_WEIGHTS:N_WEIGHTS + 3] = head_angles(pose.R[None])[0]
        if r.iris is not None:
            gaze = gaze_angles(r.iris[:, 0, :2].astype(np.float64), pose.R, pose.t, self.centres, self.camera)
            values[N_WEIGHTS + 3:] = _eye_rotations(gaze[None])[0]
        if not np.isfinite(values).all():
            self._prev = None
            self.lost += 1
            return None
        return values


class VideoSource:
    """Frames of ``path`` tracked one by one and given out at the video's rate (see the module docstring).

    Parameters
    ----------
    path : str or PathLike
        Any video the tracker reads (``facegeom[video]``).
    model : FaceModel
        The face model (its generic face when no ``rig``).
    rig : BlendshapeRig, optional
        The actor's own rig with the face model's vertices and shapes.
    stats : LiveStats, optional
    loop : bool
        Start over at the end.
    subject : str, optional
        The subject name the frames carry (default the file's stem).
    speed : float
        Play at this multiple of the video's rate (below 1: slower, every frame has more time).
    """

    def __init__(self, path, model, rig=None, stats: LiveStats | None = None, loop: bool = False,
                 subject: str | None = None, speed: float = 1.0):
        from facegeom.io.video import open_video

        if not (np.isfinite(speed) and speed > 0):
            raise InputError(f"speed must be a positive number, got {speed}", path)
        self.stats = stats if stats is not None else LiveStats()
        self.path = Path(path)
        self.reader = open_video(self.path)
        self.speed = float(speed)
        self.fps = float(self.reader.fps or 30.0) * self.speed  # frames are due at their time over the speed
        try:
            self.face = FaceValues(model, rig, self.reader.width, self.reader.height)
        except BaseException:
            self.reader.close()
            raise
        self.loop = bool(loop)
        self.subject = subject or self.path.stem
        self.done = False
        self._frames = self.reader.frames()
        self._t0: float | None = None
        self._due = 0.0

    @property
    def lost(self) -> int:
        """Frames tracked where no face was found."""
        return self.face.lost

    def _next(self):
        frame = next(self._frames, None)
        if frame is None and self.loop:
            self._frames = self.reader.frames()
            self._t0 = None
            frame = next(self._frames, None)
        return frame

    def poll(self, timeout: float = 0.05) -> LiveFrame | None:
        """The next frame once it is due (tracked), skipping frames whose time has already passed."""
        if self.done:
            time.sleep(min(timeout, 0.01))
            return None
        now = time.perf_counter()
        if self._t0 is None:
            self._t0 = now
        if self._t0 + self._due - now > timeout:
            time.sleep(max(0.0, timeout))
            return None
        frame = self._next()
        while frame is not None:
            due = self._t0 + frame.time_s / self.speed
            nxt_due = due + 1.0 / self.fps
            if time.perf_counter() < nxt_due:  # this one is still current: track it
                break
            self.stats.superseded += 1  # tracking fell behind: this frame's time has passed
            frame = self._next()
        if frame is None:
            self.done = True
            return None
        wait = self._t0 + frame.time_s / self.speed - time.perf_counter()
        if wait > 0:
            time.sleep(wait)
        self._due = frame.time_s / self.speed + 1.0 / self.fps
        arrived = time.perf_counter_ns()
        self.stats.datagrams += 1
        values = self.face.values(frame.image)
        if values is None:
            return None
        self.stats.frames_in += 1
        # the video's own frame number: the stream's frame numbers skip what was skipped
        return LiveFrame(values, "facegeom-video", self.subject, frame.index, 0.0, _rate(self.fps), arrived)

    def close(self) -> None:
        """Close the video."""
        self._frames.close()
        self.reader.close()


class CameraSource:
    """A camera (or a live stream: :func:`facegeom.io.camera.open_camera`) tracked as it films.

    Each :meth:`poll` takes the newest frame the camera gave (the ones it gave while the previous frame was
    being tracked are counted as superseded, never queued), tracks it (:class:`FaceValues`) and gives out its
    61 values; the frame number counts the camera's frames since the start. The stream's end (a network
    stream closed, a camera unplugged) ends the session; :attr:`error` says why.
    """

    def __init__(self, spec, model, rig=None, stats: LiveStats | None = None, subject: str | None = None,
                 platform: str | None = None):
        from facegeom.io.camera import open_camera

        self.stats = stats if stats is not None else LiveStats()
        self.camera = open_camera(str(spec), platform=platform)
        self.fps = self.camera.fps
        self.subject = subject or "camera"
        self.done = False
        self._model, self._rig = model, rig
        self.face: FaceValues | None = None
        self._taken = 0
        try:
            if self.camera.width and self.camera.height:  # set up before the first frame when the stream says
                self.face = FaceValues(model, rig, self.camera.width, self.camera.height)
            elif rig is not None and rig.n_vertices != model.n_vertices:
                raise InputError(f"the actor's rig has {rig.n_vertices} vertices, the face model "
                                 f"{model.n_vertices}: give a rig of the face model (an actor's rig fitted by "
                                 "facegeom)")
        except BaseException:
            self.camera.close()
            raise
        self._taken = self.camera.skip_backlog()  # frames filmed while the models loaded are past, not dropped

    @property
    def lost(self) -> int:
        """Frames tracked where no face was found."""
        return self.face.lost if self.face is not None else 0

    @property
    def error(self) -> str | None:
        """Why the stream ended early, if it broke."""
        return self.camera.error

    def poll(self, timeout: float = 0.05) -> LiveFrame | None:
        """The newest camera frame, tracked; None when none came within ``timeout`` or it shows no face."""
        if self.done:
            time.sleep(min(timeout, 0.01))
            return None
        got = self.camera.latest(timeout)
        if got is None:
            if self.camera.ended:
                self.done = True
            return None
        h, w = got.image.shape[:2]
        if self.face is None or self.face.size != (w, h):  # the first frame (or the stream changed size)
            self.face = FaceValues(self._model, self._rig, w, h)
        self.stats.superseded += max(0, got.index - self._taken)
        self.stats.datagrams += max(0, got.index - self._taken) + 1
        self._taken = got.index + 1
        values = self.face.values(got.image)
        if values is None:
            return None
        self.stats.frames_in += 1
        return LiveFrame(values, "facegeom-camera", self.subject, got.index, 0.0, _rate(self.fps), got.arrived_ns)

    def close(self) -> None:
        """Stop the camera."""
        self.camera.close()
