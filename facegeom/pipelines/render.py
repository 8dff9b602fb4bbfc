"""Pictures of a face through a known pinhole camera: the frames of the synthetic photo and video benchmarks.

polyscope renders off-screen (EGL on Mesa's software renderer, no display or
GPU needed) through the same camera convention as
:class:`facegeom.model.camera.PinholeCamera` (OpenGL-like: x right, y up, the
camera looking down -z): the view matrix is ``[R t; 0 1]`` and the vertical
field of view follows from the focal length, so a vertex projects by the
camera to the pixel it is drawn at (within the rasteriser's half pixel).

The face is drawn with one skin colour under polyscope's light, its back faces
culled (the inner surfaces of a strongly shaped identity would otherwise show
through the cheek); the background is a colour or an image.
"""
from __future__ import annotations

import math

import numpy as np

from facegeom.errors import InputError
from facegeom.model.camera import PinholeCamera

__all__ = ["FaceRenderer", "SKIN_TONES", "HAIR_TONES", "face_colours"]

KEY = (0.0, 1.0, 0.0)  # the key colour an image background replaces (no skin, hair or prop is pure green)

# skin colours (linear RGB in [0, 1]) from light to dark, for varied renders
SKIN_TONES = ((0.87, 0.70, 0.60), (0.80, 0.60, 0.47), (0.66, 0.47, 0.34), (0.48, 0.33, 0.23), (0.32, 0.21, 0.15))


class FaceRenderer:
    """Render triangle meshes through a :class:`PinholeCamera` into ``(H, W, 3)`` uint8 RGB frames.

    Parameters
    ----------
    width, height : int
        The frame's size in pixels.

    Notes
    -----
    polyscope is one window per process: one renderer at a time (a second one
    takes the window over and resizes it).
    """

    def __init__(self, width: int = 640, height: int = 480):
        import polyscope as ps

        if not (16 <= width <= 4096 and 16 <= height <= 4096):
            raise InputError(f"the frame must be 16-4096 pixels a side, not {width} x {height}")
        self.width, self.height = int(width), int(height)
        if not ps.is_initialized():
            ps.set_program_name("facegeom render")
            ps.set_use_prefs_file(False)
            ps.set_verbosity(0)
            ps.set_errors_throw_exceptions(True)
            ps.set_allow_headless_backends(True)
            ps.set_frame_tick_limit_fps_mode("ignore_limits")  # as the viewer starts it: scripted frames run
            try:
                ps.init("openGL3_egl")
            except Exception as exc:  # noqa: BLE001 - EGL missing
                raise InputError(f"polyscope could not start an off-screen renderer ({exc}); install EGL: "
                                 "apt install libegl1 libegl-mesa0 libgl1-mesa-dri") from None
        ps.set_ground_plane_mode("none")
        ps.set_SSAA_factor(1)
        ps.set_window_size(self.width, self.height)
        ps.set_give_focus_on_show(False)
        self._ps = ps

    def camera_for(self, focal: float) -> PinholeCamera:
        """A camera with this focal length and the principal point at the frame's centre (0-based pixels)."""
        return PinholeCamera(focal, (self.width - 1) / 2.0, (self.height - 1) / 2.0)

    def render(self, vertices: np.ndarray, triangles: np.ndarray, camera: PinholeCamera,
               color=SKIN_TONES[1], background=(0.2, 0.22, 0.25), extra=()) -> np.ndarray:
        """One frame: the mesh ``(vertices, triangles)`` seen by ``camera`` (posed: ``R``, ``t``).

        ``color`` is one RGB colour in [0, 1] or an ``(n, 3)`` colour per vertex.

        ``background`` is an RGB colour in [0, 1] (polyscope brightens it a little) or an ``(H, W, 3)`` uint8
        image put behind the face (where the render shows the pure green key colour).
        ``extra`` is a sequence of ``(vertices, triangles, color)`` drawn too (eyeballs, props).
        """
        ps = self._ps
        ps.remove_all_structures()
        if abs(camera.cx - (self.width - 1) / 2) > 1e-6 or abs(camera.cy - (self.height - 1) / 2) > 1e-6:
            raise InputError("the renderer draws with the principal point at the frame's centre")
        view = np.eye(4)
        view[:3, :3] = camera.R
        view[:3, 3] = camera.t
        fov = math.degrees(2.0 * math.atan(self.height / 2.0 / camera.focal))
        params = ps.CameraParameters(ps.CameraIntrinsics(fov_vertical_deg=fov, aspect=self.width / self.height),
                                     ps.CameraExtrinsics(mat=view))
        image_bg = not isinstance(background, tuple | list)
        # an image background is composited by a key colour: the screenshot's alpha comes back opaque under EGL
        ps.set_background_color(KEY if image_bg else tuple(float(c) for c in background))
        meshes = [(vertices, triangles, color), *extra]
        for k, (V, F, c) in enumerate(meshes):
            c = np.asarray(c, dtype=np.float64)
            plain = c.shape == (3,)
            m = ps.register_surface_mesh(f"m{k}", np.asarray(V, dtype=np.float64), np.asarray(F), smooth_shade=True,
                                         color=tuple(float(x) for x in c) if plain else (0.8, 0.6, 0.5),
                                         material="clay")
            if not plain:  # a colour per vertex (brows, lips painted on the skin)
                m.add_color_quantity("colour", c, defined_on="vertices", enabled=True)
            m.set_back_face_policy("cull")
        ps.set_view_camera_parameters(params)
        buf = ps.screenshot_to_buffer(transparent_bg=False, vertical_flip=True)
        rgb = np.ascontiguousarray(buf[..., :3])
        if image_bg:
            bg = np.asarray(background)
            if bg.shape != rgb.shape or bg.dtype != np.uint8:
                raise InputError(f"the background image must be {self.height} x {self.width} x 3 uint8, not "
                                 f"{bg.shape} {bg.dtype}")
            key = np.all(rgb == np.array([0, 255, 0], dtype=np.uint8), axis=2)
            rgb[key] = bg[key]
        return rgb


HAIR_TONES = ((0.10, 0.07, 0.05), (0.25, 0.16, 0.09), (0.45, 0.32, 0.18), (0.06, 0.05, 0.05))
"""Brow colours (dark brown, brown, light brown, black), linear RGB in [0, 1]."""


def _polyline_distance(P: np.ndarray, line: np.ndarray) -> np.ndarray:
    """Distance of each point ``P (n, 3)`` to the polyline through ``line (k, 3)``."""
    best = np.full(P.shape[0], np.inf)
    for a, b in zip(line[:-1], line[1:]):
        ab = b - a
        u = np.clip((P - a) @ ab / max(float(ab @ ab), 1e-12), 0.0, 1.0)
        best = np.minimum(best, np.linalg.norm(P - (a + u[:, None] * ab), axis=1))
    return best


def face_colours(model, neutral=None, skin=SKIN_TONES[1], hair=HAIR_TONES[0], brow_width: float = 0.9,
                 lip_tint: float = 0.5) -> np.ndarray:
    """A colour per vertex ``(n, 3)``: the skin, brows painted along the brow landmarks, lips tinted red.

    The brows are a band ``brow_width`` cm wide under the brow landmarks' line (17-21, 22-26; annotators mark a
    brow's upper edge), fading at its edges; the lips are the vertices inside the outer lip contour (48-59),
    seen from the front, mixed ``lip_tint`` of the way to a lip red. Cues a face detector looks for that the bare
    face model lacks.
    """
    V = np.asarray(model.neutral if neutral is None else neutral, dtype=np.float64)
    L = V[np.asarray(model.landmarks)]
    out = np.tile(np.asarray(skin, dtype=np.float64), (V.shape[0], 1))
    front = V[:, 2] > np.percentile(V[:, 2], 40)  # the face's front, not the back of the head
    for brow in (L[17:22], L[22:27]):
        low = brow - np.array([0.0, brow_width / 2, 0.0])  # the band's middle, under the upper edge
        d = _polyline_distance(V, low)
        a = np.clip(1.0 - (d - 0.5 * brow_width / 2) / (0.5 * brow_width), 0.0, 1.0) * front
        out = out * (1 - 0.85 * a[:, None]) + np.asarray(hair) * (0.85 * a[:, None])
    from matplotlib.path import Path as Polygon

    lips = Polygon(L[48:60, :2]).contains_points(V[:, :2]) & front & (V[:, 2] > L[48:60, 2].min() - 0.5)
    red = np.array([0.60, 0.18, 0.20])
    out[lips] = out[lips] * (1 - lip_tint) + red * lip_tint
    return np.clip(out, 0.0, 1.0)
