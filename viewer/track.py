"""``facegeom view track``: a tracked video checked by looking, frame by frame.

Row, left to right:

- ``video``: the video's frame on a flat panel, with the fitted face's wireframe
  (the frame's own fit: its weights under the tracked head pose, projected by
  the fitted camera) and the 68 landmarks found in the frame drawn over it;
- ``face``: the fitted actor (the identity fitted from the video, or the rig the
  track was made with) playing the delivered curves, turned by the head pose;
- ``character`` (with a character): the user's rig playing the same curves
  through its name map, as ``facegeom track --character`` writes it.

Both faces are coloured by their displacement from their own neutral (mm, one
scale). Frames come from the video on demand (:class:`VideoFrames`): played in
order they are decoded one after another; a jump seeks to the key frame before
it, so scrubbing a long video never decodes it from the start nor holds it in
memory.
"""
from __future__ import annotations

import math
import time
from collections import OrderedDict
from pathlib import Path

import numpy as np

from facegeom.constants import CM_TO_MM
from facegeom.errors import InputError
from facegeom.model import BlendshapeRig
from facegeom.pipelines.track_preview import draw_overlay, project_fit
from facegeom.viewer.app import nice_ceiling
from facegeom.viewer.playback import PlaybackView, advance_in_real_time

__all__ = ["VideoFrames", "TrackView", "MAX_TEXTURE_SIDE"]

MAX_TEXTURE_SIDE = 1280  # frames larger than this are shown scaled down (the panel is a few hundred pixels wide)
CACHE_FRAMES = 48  # frames kept as shown (about 1.5 s at 30 fps; 44 MB at 640 x 480)
SEEK_AHEAD_S = 2.0  # a jump forward further than this seeks instead of decoding the frames between
GAP = 0.12  # space between the panels of the row, relative to the face's width
SPEED_RANGE = (0.1, 4.0)
TOP = 5
SCALE_SAMPLES = 64


class VideoFrames:
    """The frames of a tracked video by index, decoded on demand.

    Parameters
    ----------
    path : str or PathLike
        The video that was tracked.
    times : (T,) float array
        Each tracked frame's time (s), as the track recorded it: frame ``i`` is the video's frame at ``times[i]``.
    width, height : int
        The frame size the track was made at; another size means another video (:class:`InputError`).
    fps : float
        The track's frame rate (for matching a decoded frame to a time within half a period).
    """

    def __init__(self, path, times, width: int, height: int, fps: float):
        from facegeom.io.video import open_video

        self.path = Path(path)
        self.reader = open_video(self.path)
        if (self.reader.width, self.reader.height) != (int(width), int(height)):
            self.reader.close()
            raise InputError(f"is {self.reader.width} x {self.reader.height}, the track was made from a "
                             f"{width} x {height} video: not the video tracked", self.path)
        self.times = np.asarray(times, dtype=np.float64)
        self.half = 0.5 / float(fps)
        self.cache: OrderedDict[int, np.ndarray] = OrderedDict()
        self._gen = None
        self._at = -math.inf  # time of the last frame the decoder gave
        self.seeks = 0
        self.missing = 0  # frames asked for that the video did not have (a black frame shown)

    def get(self, i: int) -> np.ndarray:
        """Frame ``i`` as ``(H, W, 3)`` uint8 RGB (black if the video ends before it)."""
        i = int(i)
        if i in self.cache:
            self.cache.move_to_end(i)
            return self.cache[i]
        target = float(self.times[i])
        if self._gen is None or target < self._at - 1e-9 or target - self._at > SEEK_AHEAD_S:
            if self._gen is not None:
                self._gen.close()
            self._gen = self.reader.decode_from(target)
            self._at = -math.inf
            self.seeks += 1
        image = None
        for t, frame in self._gen:
            self._at = t
            if t >= target - self.half:
                image = self.reader.rgb(frame)
                break
        if image is None:  # the video ended first
            self._gen = None
            self.missing += 1
            image = np.zeros((self.reader.height, self.reader.width, 3), dtype=np.uint8)
        self.cache[i] = image
        while len(self.cache) > CACHE_FRAMES:
            self.cache.popitem(last=False)
        return image

    def close(self) -> None:
        """Close the decoder and the file."""
        if self._gen is not None:
            self._gen.close()
            self._gen = None
        self.reader.close()


def _center(V: np.ndarray) -> np.ndarray:
    return (V.min(axis=0) + V.max(axis=0)) / 2.0


class TrackView(PlaybackView):
    """The video's frame with what was found and fitted | the fitted face | the character, scrubbable.

    Parameters
    ----------
    model : FaceModel
        The ICT face model (the fitted identity is in its modes).
    track : facegeom.pipelines.track.TrackFile
        The track, from :func:`facegeom.pipelines.track.read_track_npz`.
    video : str or PathLike
        The video that was tracked.
    rig : BlendshapeRig, optional
        The actor's rig, for a track made with ``--rig`` (it stores no identity).
    character : BlendshapeRig, optional
        A character to play the curves on.
    frame : int
        The frame shown first.
    character_name : str, optional
        How the panel names the character.

    Raises
    ------
    InputError
        A track made with a rig and none given, a rig whose shapes are not the track's, a video that is not the
        one tracked, a character none of whose shapes the track's names reach, ``frame`` outside the track.
    """

    title = "facegeom view track"
    colorbar_title = "displacement from the neutral (mm)"

    def __init__(self, model, track, video, rig=None, character=None, frame: int = 0,
                 character_name: str | None = None):
        T = track.n_frames
        if not 0 <= int(frame) < T:
            raise InputError(f"--frame {frame} is outside the track: it has {T} frames (0..{T - 1})")
        super().__init__(T, frame)
        self.track = track
        if rig is None:
            if track.identity.size == 0:
                raise InputError("the track was made with the actor's own rig (--rig) and stores no identity: give "
                                 "the same --rig", track.path)
            if track.identity.size != np.asarray(model.identity_modes).shape[0]:
                raise InputError(f"the track's identity has {track.identity.size} coefficients, the face model "
                                 f"{np.asarray(model.identity_modes).shape[0]}: made with another face model",
                                 track.path)
            rig = BlendshapeRig.from_face_model(model, track.identity)
        if tuple(rig.names) != tuple(track.names):
            raise InputError(f"the rig's {len(rig.names)} shapes are not the track's {len(track.names)} "
                             f"({', '.join(track.names[:3])}, ...): not the rig the track was made with", track.path)
        self.person = rig
        self.fps = float(track.fps)
        self.speed = 1.0
        self._t0: float | None = None
        self._f0 = self.frame
        self.show_wire = True
        self.show_landmarks = True
        self.video = VideoFrames(video, track.times, track.width, track.height, track.fps)
        self.video_name = Path(video).name
        self.character = character
        self.character_name = character_name or "character"
        self.character_weights = None
        self.notes: list[str] = []
        if character is not None:
            m = character.map_from(track.names)
            if m.is_empty:
                self.video.close()
                raise InputError(f"none of the character's shapes is reached by the track's names "
                                 f"({', '.join(track.names[:4])}, ...); give a mapping file with --character-names")
            self.character_weights = np.asarray(m.apply(track.weights), dtype=np.float64)
            driven = int(np.asarray(m.matrix).any(axis=1).sum())
            self.notes.append(f"{self.character_name}: {driven} of its {len(character.names)} shapes driven")
        self._overlay_cache: tuple[int, bool, bool, np.ndarray] | None = None
        self.shifts = self._row_shifts()
        self.vmax = self._scale()

    # ------------------------------------------------------------------ what is shown
    def _frame(self, t) -> int:
        return self.frame if t is None else int(t) % self.n_frames

    @staticmethod
    def _pose(rig, w) -> np.ndarray:
        on = np.flatnonzero(w)
        if on.size == 0:
            return np.array(rig.neutral, dtype=np.float64)
        return rig.neutral + np.tensordot(w[on], rig.deltas[on], axes=1)

    def _turned(self, rig, P, t) -> np.ndarray:
        c = np.asarray(rig.neutral).mean(axis=0)
        return c + (P - c) @ self.track.rotations[t].T

    def face(self, t: int | None = None) -> np.ndarray:
        """The fitted actor at frame ``t``: the delivered weights on the actor's rig, turned by the head pose
        about its neutral's centroid; ``(n, 3)`` cm, unshifted."""
        t = self._frame(t)
        return self._turned(self.person, self._pose(self.person, self.track.weights[t]), t)

    def character_face(self, t: int | None = None) -> np.ndarray | None:
        """The character at frame ``t`` (the mapped weights, turned by the head pose), or None without one."""
        if self.character is None:
            return None
        t = self._frame(t)
        return self._turned(self.character, self._pose(self.character, self.character_weights[t]), t)

    def displacement_mm(self, t: int | None = None) -> tuple[np.ndarray, np.ndarray | None]:
        """Per-vertex distance from the neutral at frame ``t`` (mm, the expression only: the turn is not
        counted): ``(face, character or None)``."""
        t = self._frame(t)
        a = np.linalg.norm(self._pose(self.person, self.track.weights[t]) - self.person.neutral, axis=1)
        c = None
        if self.character is not None:
            c = np.linalg.norm(self._pose(self.character, self.character_weights[t]) - self.character.neutral, axis=1)
            c = c * CM_TO_MM
        return a * CM_TO_MM, c

    def fitted_points(self, t: int | None = None) -> np.ndarray:
        """The fitted face's 468 mapped points in frame ``t``'s image (pixels): the frame's own fit (its raw
        weights) under the tracked pose and the fitted camera."""
        t = self._frame(t)
        tr = self.track
        return project_fit(self.person, tr.raw_weights[t:t + 1], tr.rotations[t:t + 1], tr.camera_t[t:t + 1],
                           tr.focal, tr.width, tr.height)[0]

    def overlay(self, t: int | None = None) -> np.ndarray:
        """Frame ``t`` of the video with the wireframe and the landmarks drawn as the panel's switches say,
        ``(H, W, 3)`` uint8 (scaled down to :data:`MAX_TEXTURE_SIDE`)."""
        from PIL import Image

        t = self._frame(t)
        key = (t, self.show_wire, self.show_landmarks)
        if self._overlay_cache is not None and self._overlay_cache[:3] == key:
            return self._overlay_cache[3]
        tr = self.track
        img = draw_overlay(self.video.get(t), self.fitted_points(t), tr.landmarks[t], bool(tr.found[t]),
                           wire=self.show_wire, dots=self.show_landmarks)
        side = max(img.shape[:2])
        if side > MAX_TEXTURE_SIDE:
            s = MAX_TEXTURE_SIDE / side
            img = np.asarray(Image.fromarray(img).resize((max(1, round(img.shape[1] * s)),
                                                          max(1, round(img.shape[0] * s))), Image.BILINEAR))
        self._overlay_cache = (*key, img)
        return img

    def _row_shifts(self) -> dict:
        """Video panel | face | character, left to right, centres level; the panel as tall as 1.4 faces."""
        A = np.asarray(self.person.neutral, dtype=np.float64)
        wa, ha = float(np.ptp(A[:, 0])), float(np.ptp(A[:, 1]))
        reach = float(np.linalg.norm(A - A.mean(axis=0), axis=1).max())  # a turned face stays within this
        gap = GAP * wa
        self.panel_h = 1.4 * ha
        self.panel_w = self.panel_h * self.track.width / self.track.height
        shifts = {"face": -A.mean(axis=0)}
        shifts["video"] = np.array([-reach - gap - self.panel_w / 2.0, 0.0, 0.0])
        if self.character is not None:
            C = np.asarray(self.character.neutral, dtype=np.float64)
            rc = float(np.linalg.norm(C - C.mean(axis=0), axis=1).max())
            s = -C.mean(axis=0)
            s[0] += reach + gap + rc
            shifts["character"] = s
        return shifts

    def _scale(self) -> float:
        """One colour scale for both faces: the 95th percentile over up to 64 frames of the larger face's
        largest displacement, rounded up to 1, 2 or 5 times a power of ten."""
        peaks = []
        for t in np.unique(np.linspace(0, self.n_frames - 1, min(self.n_frames, SCALE_SAMPLES)).astype(int)):
            a, c = self.displacement_mm(int(t))
            peaks.append(max(float(a.max()), float(c.max()) if c is not None else 0.0))
        top = float(np.percentile(peaks, 95)) if peaks else 0.0
        return nice_ceiling(top) if top > 0 else 5.0

    def copies(self) -> list[str]:
        """The panels of the row, left to right."""
        return ["video", "face"] + (["character"] if self.character is not None else [])

    def shown_faces(self) -> dict:
        """``face`` (and ``character``) -> as drawn now (row shift included)."""
        if not self._built:
            return {}
        out = {"face": self.face() + self.shifts["face"]}
        if self.character is not None:
            out["character"] = self.character_face() + self.shifts["character"]
        return out

    def head_angles_deg(self, t: int | None = None) -> tuple[float, float, float]:
        """The head's yaw, pitch and roll at frame ``t`` (degrees; yaw about Y, pitch about X, roll about Z)."""
        from scipy.spatial.transform import Rotation

        y, p, r = Rotation.from_matrix(self.track.rotations[self._frame(t)]).as_euler("YXZ", degrees=True)
        return float(y), float(p), float(r)

    def top_shapes(self, t: int | None = None, k: int = TOP) -> list[tuple[str, float]]:
        """The ``k`` strongest delivered weights at frame ``t`` (above 0.001): ``[(name, weight), ...]``."""
        w = self.track.weights[self._frame(t)]
        order = np.argsort(-w, kind="stable")[:k]
        return [(self.track.names[i], float(w[i])) for i in order if w[i] > 1e-3]

    # ------------------------------------------------------------------ polyscope
    def _panel_mesh(self):
        import polyscope as ps

        w, h = self.panel_w, self.panel_h
        c = self.shifts["video"]
        V = c + np.array([[-w / 2, -h / 2, 0.0], [w / 2, -h / 2, 0.0], [w / 2, h / 2, 0.0], [-w / 2, h / 2, 0.0]])
        F = np.array([[0, 1, 2], [0, 2, 3]])
        self._grow_bounds(V)
        m = ps.register_surface_mesh("video", V, F, material="flat", color=(0.1, 0.1, 0.1))
        m.add_parameterization_quantity("uv", np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]),
                                        defined_on="vertices")
        return m

    def build(self) -> None:
        """Register the video panel and the faces at the current frame, and frame the camera on the row."""
        self._built = True
        self._panel_mesh()
        self.mesh("face", self.face(), self.person.triangles, self.shifts["face"])
        A = np.asarray(self.person.neutral)
        reach = float(np.linalg.norm(A - A.mean(axis=0), axis=1).max())
        self._grow_bounds(np.array([[reach, 0.0, 0.0], [-reach, 0.0, 0.0]]))
        if self.character is not None:
            self.mesh("character", self.character_face(), self.character.triangles, self.shifts["character"])
            for t in np.linspace(0, self.n_frames - 1, min(self.n_frames, 8)).astype(int):
                self._grow_bounds(self.character_face(int(t)) + self.shifts["character"])
        self.show_frame()

    def show_frame(self) -> None:
        """The current frame: the video panel's image, both faces moved and coloured. Nothing before
        :meth:`build`."""
        import polyscope as ps

        if not ps.is_initialized() or not self._built or not ps.has_surface_mesh("video"):
            return
        img = self.overlay().astype(np.float32) / 255.0
        ps.get_surface_mesh("video").add_color_quantity("frame", img, defined_on="texture", param_name="uv",
                                                       image_origin="upper_left", enabled=True)
        a, c = self.displacement_mm()
        m = ps.get_surface_mesh("face")
        m.update_vertex_positions(self.face() + self.shifts["face"])
        self.error_colors(m, a, self.vmax, name="displacement (mm)")
        if self.character is not None:
            m = ps.get_surface_mesh("character")
            m.update_vertex_positions(self.character_face() + self.shifts["character"])
            self.error_colors(m, c, self.vmax, name="displacement (mm)")

    # ------------------------------------------------------------------ playback
    def play(self, on: bool = True) -> None:
        """Start (``on=True``) or pause; playing keeps the video's frame rate (times :attr:`speed`)."""
        super().play(on)
        self._t0, self._f0 = (time.monotonic(), self.frame) if on else (None, self.frame)

    def set_speed(self, speed: float) -> None:
        """Playback speed, times real time (clipped to :data:`SPEED_RANGE`)."""
        lo, hi = SPEED_RANGE
        self.speed = float(min(max(float(speed), lo), hi))
        if self.playing:
            self._t0, self._f0 = time.monotonic(), self.frame

    def advance(self) -> None:
        """Real-time playback at the video's frame rate."""
        advance_in_real_time(self, self.fps)

    def set_frame(self, t: int) -> None:
        """Show frame ``t`` (wrapped); while playing, the clock restarts there."""
        super().set_frame(t)
        if self.playing:
            self._t0, self._f0 = time.monotonic(), self.frame

    def set_overlay(self, wire: bool | None = None, landmarks: bool | None = None) -> None:
        """Switch the wireframe and the landmarks drawn over the frame on or off."""
        if wire is not None:
            self.show_wire = bool(wire)
        if landmarks is not None:
            self.show_landmarks = bool(landmarks)
        self.show_frame()

    def panel(self) -> None:
        """The files, the switches, the colour scale, playback, the frame's state, the fit residual over time
        and the frame's strongest weights."""
        import polyscope.imgui as psim

        tr, t = self.track, self.frame
        found = int(tr.found.sum())
        psim.TextWrapped(f"{self.video_name}: {tr.n_frames} frames at {self.fps:g} fps ({tr.n_frames / self.fps:.1f} s), "
                         f"{tr.width} x {tr.height}; face found in {found}, {tr.n_frames - found} bridged")
        psim.TextWrapped(f"{tr.path.name}: {len(tr.names)} shapes, focal {tr.focal:.0f} px")
        row = "the frame (the frame's fit as a wireframe, the landmarks found as dots) | the fitted face"
        if self.character is not None:
            row += f" | {self.character_name}"
        psim.TextWrapped("left to right: " + row)
        ch, v = self.ui.checkbox("wireframe", self.show_wire)
        if ch:
            self.set_overlay(wire=v)
        psim.SameLine()
        ch, v = self.ui.checkbox("landmarks", self.show_landmarks)
        if ch:
            self.set_overlay(landmarks=v)
        if self.color_max_slider():
            self.show_frame()
        self.transport_panel()
        ch, v = self.ui.slider_float("speed", self.speed, *SPEED_RANGE, "%.2fx", logarithmic=True)
        if ch:
            self.set_speed(v)
        state = "face found" if tr.found[t] else "no face: bridged"
        res = f", fit residual {tr.residual[t]:.2f} px" if np.isfinite(tr.residual[t]) else ""
        psim.TextUnformatted(f"frame {t}, {tr.times[t]:.2f} s: {state}{res}")
        yaw, pitch, roll = self.head_angles_deg()
        psim.TextUnformatted(f"head yaw {yaw:.1f}, pitch {pitch:.1f}, roll {roll:.1f} deg")
        g = np.degrees(tr.gaze[t])
        psim.TextUnformatted(f"gaze right eye {g[0, 0]:.0f}/{g[0, 1]:.0f}, left eye {g[1, 0]:.0f}/{g[1, 1]:.0f} deg "
                             "(yaw/pitch)")
        self.plot("fit residual", np.where(tr.found, tr.residual, np.nan), unit="px")
        psim.Separator()
        top = self.top_shapes()
        if not top:
            psim.TextUnformatted("no shape on (the neutral)")
        for name, w in top:
            psim.ProgressBar(float(np.clip(w, 0.0, 1.0)), (self.panel_width * 0.45, 0.0), f"{w:.2f}")
            psim.SameLine()
            psim.TextUnformatted(name)
        if self.notes:
            psim.Separator()
            for line in self.notes:
                psim.TextWrapped(line)

    def state(self) -> dict:
        """:meth:`BaseView.state` plus the frame, its time and whether a face was found, the residual, the
        overlay switches and the strongest weights."""
        out = super().state()
        tr, t = self.track, self.frame
        out.update(frame=t, n_frames=self.n_frames, fps=self.fps, speed=self.speed, playing=self.playing,
                   time_s=float(tr.times[t]), found=bool(tr.found[t]),
                   residual_px=float(tr.residual[t]) if np.isfinite(tr.residual[t]) else None,
                   wireframe=self.show_wire, landmarks=self.show_landmarks,
                   top=[[n, w] for n, w in self.top_shapes()], seeks=self.video.seeks)
        return out

    def close(self) -> None:
        """Close the video."""
        self.video.close()
        super().close()
