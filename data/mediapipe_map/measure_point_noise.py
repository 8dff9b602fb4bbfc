"""Measure how far the face-mesh model's 468 points lie from where the map puts them, point by point.

Run from the repository root (about 8 minutes on one core; needs the face data, EGL for polyscope's off-screen
renderer and LiteRT)::

    OPENBLAS_NUM_THREADS=1 .venv/bin/python data/mediapipe_map/measure_point_noise.py [--scenes 300]

Why: ``facegeom track`` weighs each point by how well the model places it. A point on a sharp feature (an eye
corner, a lip corner, a nostril) is placed to within 2-3 % of the outer-eye-corner distance; a point on the smooth
cheek or forehead, 7-10 %. Weighing them alike lets the vague points pull the fit as hard as the precise ones.

How: faces of the ``"map"`` family of :mod:`facegeom.pipelines.video_clips` (random identities, random sparse
expressions, random head turns, gazes, lenses, face sizes, skin tones, backgrounds, light and sensor noise; no
recorded take, so the benchmark's clips stay unseen) are rendered with known geometry and camera and run through
:class:`facegeom.vision.faces.FaceFinder`. For each point, its error is the detected point minus the projection of
the mapped surface point (``mediapipe_to_face_model.csv``), divided by that face's outer-eye-corner distance in the
image; the point's noise is the root mean square of its error per coordinate over the scenes (a failed detection,
any point off by more than half the eye-corner distance, is left out). Written to
``facegeom/vision/data/mediapipe_point_noise.csv`` (``point,sd``), with the split-half agreement printed as a check.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

DATA = Path(__file__).resolve().parents[2] / "facegeom" / "vision" / "data"
OUT = DATA / "mediapipe_point_noise.csv"
SEED = 4680  # not a seed of the benchmark's clips
OUTLIER = 0.5  # of the eye-corner distance: a point this far off is a failed detection, not noise


def scene_errors(model, n: int, seed: int) -> np.ndarray:
    """Render ``n`` faces, find their points -> errors ``(S, 468, 2)`` relative to the eye-corner distance."""
    from facegeom.pipelines.video_clips import ClipScene, make_specs
    from facegeom.vision.correspondence import mediapipe_map
    from facegeom.vision.faces import FaceFinder

    mp = mediapipe_map()
    tri = np.asarray(model.triangles)[mp.triangle]
    specs = make_specs(n, seed, family="map", frames=2, model=model)
    finder = FaceFinder(iris=False)
    rng = np.random.default_rng(seed)
    out, renderer = [], None
    t0 = time.perf_counter()
    for k, spec in enumerate(specs):
        scene = ClipScene(spec, model, renderer)
        renderer = scene.renderer
        w = np.zeros(model.n_expressions)
        on = rng.choice(model.n_expressions, int(rng.integers(0, 5)), replace=False)
        w[on] = rng.uniform(0.0, 1.0, on.size)
        gaze = np.radians(rng.uniform([-20, -12], [20, 12], (1, 2))).repeat(2, axis=0)
        R = Rotation.from_euler("YXZ", rng.uniform([-35, -18, -12], [35, 18, 12]), degrees=True).as_matrix()
        t = -R @ scene.centre + np.array([rng.uniform(-2, 2), rng.uniform(-2, 2), -spec.distance])
        faces = finder.find(scene.render(w, gaze, (R, t), frame=k))
        if faces:
            V = scene.vertices(w)
            X = np.einsum("pk,pkd->pd", mp.bary, V[tri]) @ R.T + t
            depth = -X[:, 2]
            cx, cy = (spec.width - 1) / 2.0, (spec.height - 1) / 2.0
            u = np.stack([cx + spec.focal * X[:, 0] / depth, cy - spec.focal * X[:, 1] / depth], axis=1)
            uv = faces[0].mesh.points[:, :2]
            out.append((uv - u) / np.linalg.norm(u[263] - u[33]))
        if (k + 1) % 50 == 0:
            print(f"  {k + 1} / {n} faces rendered, {len(out)} found, {time.perf_counter() - t0:.0f} s", flush=True)
    return np.array(out)


def main(argv=None) -> None:
    """Render, measure, write the CSV."""
    from facegeom.model.face import load_face_model

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", type=int, default=300)
    ap.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args(argv)
    E = scene_errors(load_face_model(), args.scenes, SEED)
    E = E[np.linalg.norm(E, axis=2).max(axis=1) < OUTLIER]
    sd = np.sqrt((E ** 2).sum(axis=2).mean(axis=0) / 2.0)
    half = [np.sqrt((E[i::2] ** 2).sum(axis=2).mean(axis=0) / 2.0) for i in (0, 1)]
    print(f"{E.shape[0]} faces; per-point noise (of the eye-corner distance): median {100 * np.median(sd):.2f} %, "
          f"10-90 % {100 * np.percentile(sd, 10):.2f}-{100 * np.percentile(sd, 90):.2f} %; split halves agree "
          f"r = {np.corrcoef(*half)[0, 1]:.3f}")
    with open(args.out, "w") as fh:
        fh.write("point,sd\n")
        for i, s in enumerate(sd):
            fh.write(f"{i},{s:.5f}\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
