"""``facegeom bench track``: rendered face videos with known truth, tracked by ``facegeom track`` and baselines.

The clips (:mod:`facegeom.pipelines.video_clips`): random face-model identities performing windows of real
Live Link takes with head motion and eye movements, rendered under varied cameras (fields of view), face sizes,
skin tones, brows, backgrounds, light and sensor noise, encoded as H.264. Two families built to differ: ``tune``
(the defaults were chosen looking at these) and ``holdout`` (other take windows, larger turns, smaller faces,
other lenses, darker skin, textured backgrounds, more noise).

Each clip's points are found once (:func:`facegeom.pipelines.track.read_video_points`); the methods then solve
the same points:

- ``track``: facegeom's default (identity and focal length from the video, per-frame pose and weights, smoothing,
  calibration, gaze);
- ``per-frame``: no identity (the generic face), no temporal smoothing, no calibration: each frame alone;
- ``l1reg`` / ``l2reg``: the SEM paper's baselines on the same frames' 68 detected landmarks, the generic face,
  the camera from the frame's size;
- ``rest``: a reference, not a method: every weight 0 (the face at rest) with the track's head pose. Real takes
  hold many shapes at 0.1-0.3 for long stretches, so a weight MAE near this reference's says the subtle shapes
  are not recovered even where the strong ones are.

Per clip, against the truth: the face error (the mean vertex distance between the true identity posed by the
solved weights and by the true weights, over the mean distance of the true expression from the neutral), the
weight MAE, the median per-shape correlation over the shapes that move (true standard deviation over 0.05), the
median head-rotation error (degrees), the gaze error (degrees, mean of the eyes), the jitter (mean absolute second
difference of the weights over the truth's), and the end-to-end throughput of ``track`` in frames per CPU second.
"""
from __future__ import annotations

import csv
import time
from pathlib import Path

import numpy as np

__all__ = ["METHODS", "clip_scores", "run"]

METHODS = ("track", "per-frame", "l1reg", "l2reg", "rest")
MOVING_SD = 0.05  # a shape "moves" in a clip when its true weight's standard deviation exceeds this


def _scores(truth, W, R, gaze, model) -> dict:
    from scipy.spatial.transform import Rotation

    Wt = truth["weights"]
    D = np.asarray(model.expression_deltas, dtype=np.float64)
    err = np.linalg.norm(np.einsum("tb,bnk->tnk", W - Wt, D), axis=2).mean()
    ref = np.linalg.norm(np.einsum("tb,bnk->tnk", Wt, D), axis=2).mean()
    moving = np.flatnonzero(Wt.std(axis=0) > MOVING_SD)
    corr = [np.corrcoef(W[:, j], Wt[:, j])[0, 1] if W[:, j].std() > 1e-9 else 0.0 for j in moving]
    rot = np.degrees(np.linalg.norm((Rotation.from_matrix(R) * Rotation.from_matrix(truth["rotations"]).inv())
                                    .as_rotvec(), axis=1))
    jt = np.abs(np.diff(Wt, 2, axis=0)).mean()
    out = {"face": float(err / max(ref, 1e-12)), "mae": float(np.abs(W - Wt).mean()),
           "corr": float(np.median(corr)) if corr else float("nan"), "moving": int(moving.size),
           "rotation_deg": float(np.median(rot)), "jitter": float(np.abs(np.diff(W, 2, axis=0)).mean() / max(jt, 1e-9))}
    if gaze is not None and "gaze" in truth:
        out["gaze_deg"] = float(np.degrees(np.abs(gaze - truth["gaze"])).mean())
    return out


def _baseline(vp, model, name: str):
    """A landmark fitter on each frame's 68 detected landmarks, the generic face (pose estimated)."""
    from facegeom import registry
    from facegeom.model.camera import PinholeCamera
    from facegeom.model.landmarks import to_model_convention
    from facegeom.model.rig import BlendshapeRig
    from facegeom.model.targets import LandmarkTarget

    rig = BlendshapeRig.from_face_model(model)
    fitter = registry.create("fitters", name)
    w, h = int(vp.info["width"]), int(vp.info["height"])
    cam = PinholeCamera(float(max(w, h)), (w - 1) / 2.0, (h - 1) / 2.0)
    T = vp.found.size
    W = np.zeros((T, rig.n_shapes))
    R = np.repeat(np.eye(3)[None], T, axis=0)
    for i in np.flatnonzero(vp.found):
        r = fitter.fit(rig, LandmarkTarget(to_model_convention(vp.landmarks[i].astype(np.float64)),
                                           model.landmarks, cam))
        W[i] = r.weights
        c = r.info.get("camera") if isinstance(r.info, dict) else None
        if c is not None:
            R[i] = c.R
    return W, R


def clip_scores(video: Path, model, methods=METHODS) -> dict[str, dict]:
    """Every method's scores on one clip (its ``.truth.npz`` beside it)."""
    import copy

    from facegeom.pipelines.track import read_video_points, solve_points
    from facegeom.pipelines.video_clips import load_truth

    truth = load_truth(video.parent / (video.stem + ".truth.npz"))
    cpu0 = time.process_time()
    vp = read_video_points(video)
    out = {}
    tracked = None
    if "track" in methods:
        res = tracked = solve_points(vp, model)
        cpu = time.process_time() - cpu0
        s = res.solved.solve
        out["track"] = _scores(truth, s.weights, s.rotations, res.gaze, model)
        out["track"]["fps_cpu"] = vp.found.size / cpu
        out["track"]["focal_ratio"] = res.focal / float(truth["focal"])
    if "per-frame" in methods:
        from facegeom.model.rig import BlendshapeRig

        generic = BlendshapeRig.from_face_model(model)
        v2 = copy.copy(vp)
        res = solve_points(v2, model, rig=generic, smooth="off", calibration=False)
        s = res.solved.solve
        out["per-frame"] = _scores(truth, s.raw_weights, s.rotations, res.gaze, model)
    if "rest" in methods:  # the reference every method must beat: no expression at all (the track's head pose)
        tracked = tracked if tracked is not None else solve_points(vp, model)
        s = tracked.solved.solve
        out["rest"] = _scores(truth, np.zeros_like(s.weights), s.rotations, None, model)
    for name in ("l1reg", "l2reg"):
        if name in methods:
            W, R = _baseline(vp, model, name)
            out[name] = _scores(truth, W, R, None, model)
    return out


def run(model, out: Path, clips: int, frames: int, seed: int, families=("tune", "holdout"), methods=METHODS,
        echo=print, clip_dir: Path | None = None) -> Path:
    """Build (or reuse) the clips, score every method on each, write ``track.csv`` and print the table."""
    from facegeom.pipelines.video_clips import build_clips

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    clip_dir = Path(clip_dir) if clip_dir is not None else out / "clips"
    rows = []
    for family in families:
        folder = clip_dir / f"{family}-{seed}-{frames}"
        videos = sorted(folder.glob("*.mp4")) if folder.is_dir() else []
        videos = [v for v in videos if (v.parent / (v.stem + ".truth.npz")).is_file()]
        if len(videos) < clips:
            echo(f"rendering {clips} {family} clips of {frames} frames into {folder}")
            videos = build_clips(folder, clips, seed=seed, family=family, frames=frames, model=model)
        for v in videos[:clips]:
            t0 = time.perf_counter()
            scores = clip_scores(v, model, methods)
            for m, sc in scores.items():
                rows.append({"family": family, "clip": v.stem, "method": m, **sc})
            tr = scores.get("track", {})
            echo(f"  {family} {v.stem}: track face {tr.get('face', float('nan')):.2f}, MAE "
                 f"{tr.get('mae', float('nan')):.3f}, rotation {tr.get('rotation_deg', float('nan')):.1f} deg "
                 f"({time.perf_counter() - t0:.0f} s)")
    keys = ["face", "mae", "corr", "rotation_deg", "gaze_deg", "jitter", "fps_cpu", "focal_ratio"]
    path = out / "track.csv"
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["family", "clip", "method", *keys])
        for r in rows:
            w.writerow([r["family"], r["clip"], r["method"], *[f"{r[k]:.4f}" if k in r else "" for k in keys]])
    echo("")
    echo(f"{'family':8s} {'method':10s} {'face/neutral':>12s} {'MAE':>6s} {'corr':>5s} {'rot deg':>8s} "
         f"{'gaze deg':>8s} {'jitter':>7s} {'fps/CPU s':>9s}")
    for family in families:
        for m in methods:
            sel = [r for r in rows if r["family"] == family and r["method"] == m]
            if not sel:
                continue

            def med(k):
                v = [r[k] for r in sel if k in r]
                return float(np.median(v)) if v else float("nan")

            echo(f"{family:8s} {m:10s} {med('face'):12.2f} {med('mae'):6.3f} {med('corr'):5.2f} "
                 f"{med('rotation_deg'):8.2f} {med('gaze_deg'):8.2f} {med('jitter'):7.2f} {med('fps_cpu'):9.1f}")
    echo(f"(medians over {clips} clips per family; wrote {path})")
    return path
