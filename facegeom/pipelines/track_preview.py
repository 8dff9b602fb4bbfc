"""``facegeom track --preview``: the video with what was tracked drawn over it, to check a track by looking.

Each frame shows the fitted face as a wireframe (MediaPipe's canonical mesh
placed on the fitted face through the point map, so the lines follow the
fitted identity, expression and head pose, not the detected points) and the
68 landmarks found in the frame as dots; a frame without a face says so and
shows the bridged fit. Written with :class:`facegeom.io.video.VideoWriter`
(H.264 where available), renamed into place when complete.
"""
from __future__ import annotations

import functools
import os
from pathlib import Path

import numpy as np

__all__ = ["write_preview", "fitted_points", "project_fit", "draw_overlay"]

WIRE = (90, 200, 255)  # the fitted face
DOTS = (80, 255, 120)  # the detected landmarks
LOST = (255, 90, 90)


def fitted_points(result) -> np.ndarray:
    """The fitted face's 468 mapped points in every frame's image ``(T, 468, 2)`` (pixels): the frame's own fit
    (its unsmoothed, uncalibrated weights) under the tracked head pose."""
    s = result.solved.solve
    return project_fit(result.rig, s.raw_weights, s.rotations, result.camera_t, result.focal, result.width,
                       result.height)


def project_fit(rig, weights, rotations, camera_t, focal: float, width: int, height: int) -> np.ndarray:
    """The 468 mapped points of ``rig`` posed by ``weights (T, B)``, turned by ``rotations (T, 3, 3)`` and moved by
    ``camera_t (T, 3)`` (cm, the camera's space), seen by a pinhole camera of ``focal`` pixels centred on a
    ``width`` x ``height`` image -> ``(T, 468, 2)`` pixels."""
    from facegeom.vision.correspondence import mediapipe_map

    mp = mediapipe_map()
    tri = np.asarray(rig.triangles)[mp.triangle]  # (468, 3) vertex ids
    N = np.einsum("pk,pkd->pd", mp.bary, np.asarray(rig.neutral)[tri])
    D = np.einsum("pk,bpkd->bpd", mp.bary, np.asarray(rig.deltas)[:, tri])
    W = np.atleast_2d(np.asarray(weights, dtype=np.float64))
    X = N[None] + np.einsum("tb,bpd->tpd", W, D)
    Xc = np.einsum("tij,tpj->tpi", np.asarray(rotations).reshape(-1, 3, 3), X) + \
        np.asarray(camera_t).reshape(-1, 3)[:, None, :]
    depth = np.maximum(-Xc[..., 2], 1e-6)
    cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
    return np.stack([cx + focal * Xc[..., 0] / depth, cy - focal * Xc[..., 1] / depth], axis=-1)


def draw_overlay(image: np.ndarray, fitted: np.ndarray, landmarks: np.ndarray | None, found: bool,
                 wire: bool = True, dots: bool = True) -> np.ndarray:
    """``image (H, W, 3)`` uint8 with the fitted face's wireframe (``fitted (468, 2)`` pixels) and the frame's
    landmarks (``(68, 2)``) drawn over it; a frame without a face says so. Returns a new array."""
    from PIL import Image, ImageDraw

    img = Image.fromarray(np.asarray(image, dtype=np.uint8))
    draw = ImageDraw.Draw(img)
    if wire:
        P = fitted
        for a, b in _edges():
            draw.line((P[a, 0], P[a, 1], P[b, 0], P[b, 1]), fill=WIRE, width=1)
    r = max(1.5, img.width / 400)
    if found and dots and landmarks is not None:
        for x, y in landmarks:
            if np.isfinite(x) and np.isfinite(y):
                draw.ellipse((x - r, y - r, x + r, y + r), fill=DOTS)
    if not found:
        draw.text((10, 10), "no face: bridged", fill=LOST)
    return np.asarray(img)


@functools.lru_cache(maxsize=1)
def _edges() -> np.ndarray:
    from facegeom.vision.correspondence import canonical_mesh

    _, F = canonical_mesh()
    F = np.asarray(F)
    e = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    return np.unique(np.sort(e, axis=1), axis=0)


def write_preview(video: str | os.PathLike, result, path: str | os.PathLike, progress=None) -> Path:
    """Write the preview of ``result`` (a :class:`~facegeom.pipelines.track.TrackResult` of ``video``) to ``path``."""
    from facegeom.io.video import VideoWriter, open_video

    fitted = fitted_points(result)
    T = result.n_frames
    with open_video(video) as reader, VideoWriter(path, result.fps, result.width, result.height) as out:
        for frame in reader:
            i = frame.index
            if i >= T:
                break
            out.write(draw_overlay(frame.image, fitted[i], result.landmarks[i], bool(result.found[i])))
            if progress is not None:
                progress(i + 1, T)
    return Path(path)
