"""``facegeom track --preview``: the video with what was tracked drawn over it, to check a track by looking.

Each frame shows the fitted face as a wireframe (MediaPipe's canonical mesh
placed on the fitted face through the point map, so the lines follow the
fitted identity, expression and head pose, not the detected points) and the
68 landmarks found in the frame as dots; a frame without a face says so and
shows the bridged fit. Written with :class:`facegeom.io.video.VideoWriter`
(H.264 where available), renamed into place when complete.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

__all__ = ["write_preview", "fitted_points"]

WIRE = (90, 200, 255)  # the fitted face
DOTS = (80, 255, 120)  # the detected landmarks
LOST = (255, 90, 90)


def fitted_points(result) -> np.ndarray:
    """The fitted face's 468 mapped points in every frame's image ``(T, 468, 2)`` (pixels)."""
    from facegeom.vision.correspondence import mediapipe_map

    rig = result.rig
    mp = mediapipe_map()
    tri = np.asarray(rig.triangles)[mp.triangle]  # (468, 3) vertex ids
    N = np.einsum("pk,pkd->pd", mp.bary, np.asarray(rig.neutral)[tri])
    D = np.einsum("pk,bpkd->bpd", mp.bary, np.asarray(rig.deltas)[:, tri])
    s = result.solved.solve
    W = s.weights
    X = N[None] + np.einsum("tb,bpd->tpd", W, D)
    Xc = np.einsum("tij,tpj->tpi", s.rotations, X) + result.camera_t[:, None, :]
    depth = np.maximum(-Xc[..., 2], 1e-6)
    cx, cy = (result.width - 1) / 2.0, (result.height - 1) / 2.0
    return np.stack([cx + result.focal * Xc[..., 0] / depth, cy - result.focal * Xc[..., 1] / depth], axis=-1)


def _edges() -> np.ndarray:
    from facegeom.vision.correspondence import canonical_mesh

    _, F = canonical_mesh()
    F = np.asarray(F)
    e = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    return np.unique(np.sort(e, axis=1), axis=0)


def write_preview(video: str | os.PathLike, result, path: str | os.PathLike, progress=None) -> Path:
    """Write the preview of ``result`` (a :class:`~facegeom.pipelines.track.TrackResult` of ``video``) to ``path``."""
    from PIL import Image, ImageDraw

    from facegeom.io.video import VideoWriter, open_video

    fitted = fitted_points(result)
    edges = _edges()
    T = result.n_frames
    r = max(1.5, result.width / 400)
    with open_video(video) as reader, VideoWriter(path, result.fps, result.width, result.height) as out:
        for frame in reader:
            i = frame.index
            if i >= T:
                break
            img = Image.fromarray(frame.image)
            draw = ImageDraw.Draw(img)
            P = fitted[i]
            for a, b in edges:
                draw.line((P[a, 0], P[a, 1], P[b, 0], P[b, 1]), fill=WIRE, width=1)
            if result.found[i]:
                for x, y in result.landmarks[i]:
                    draw.ellipse((x - r, y - r, x + r, y + r), fill=DOTS)
            else:
                draw.text((10, 10), "no face: bridged", fill=LOST)
            out.write(np.asarray(img))
            if progress is not None:
                progress(i + 1, T)
    return Path(path)
