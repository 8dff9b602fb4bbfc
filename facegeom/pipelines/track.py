"""``facegeom track``: a video of a person's face -> their blendshape weight curves, head pose and eye gaze.

The steps, each its own piece:

1. **Points** (:class:`facegeom.vision.tracking.FaceTracker`): the video is
   decoded frame by frame (never held whole) and the face's 468 face-mesh
   points and both irises found in each; the detector runs only when the face
   is lost. Frames without a face are counted.
2. **Identity and camera** (:func:`facegeom.methods.video_identity.fit_identity_frames`):
   the person's identity (the face model's 100 modes) and the focal length,
   fitted jointly on :data:`IDENTITY_FRAMES` frames chosen from the video
   itself (:func:`choose_identity_frames`: the calmest half, spread over the
   head's turns). ``rig`` (a known actor) fixes the identity; ``focal`` fixes
   the focal length.
3. **Frames** (:class:`facegeom.methods.frame_solver.FrameSolver`): pose and
   bounded weights per frame, each from the previous frame's answer. The
   points' noise, which weighs them against the weights' prior, is the larger
   of the identity fit's residual on this video and the face-mesh model's
   measured error (:data:`DETECTOR_NOISE`): most of that error moves with
   the face, so a fit absorbs it and its residual understates it (1-1.5 px
   where the points lie 4-7 px from the truth). Each point is weighed by its
   own measured error (:func:`point_weights`): the model places the eye
   corners and the nose to 2-3 % of the eye-corner distance, the forehead and
   the jaw's cheeks to 7-10 %.
4. **Gaps**: frames without a face get weights and pose interpolated from
   their neighbours (rotations along the shortest arc); they are counted in
   the result.
5. **Temporal term**: each weight curve and each pose component is smoothed
   afterwards by a zero-phase Whittaker smoother
   (:func:`facegeom.methods.marker_solve.smooth_curves`) whose strength halves
   motion at :data:`SMOOTH_HZ` (:func:`cutoff_strength`, from the frame rate):
   offline there is no lag to pay, and the cut-off is a property of faces
   (real performances keep 98-99.6 % of their power below it), not of a clip.
   Generalised cross-validation per curve, tried first, left the curves twice
   as jittery as the truth: the points' errors are correlated from frame to
   frame, which it takes for signal. (The tangent framework's temporal windows
   need known frames of the target, which a video of a person does not have.)
6. **Gaze** (:func:`gaze_angles`): each iris centre is cast back into the
   head's frame and met with the eyeball (a sphere of :data:`EYEBALL_RADIUS`
   behind the lids); the direction from its centre gives the eye's yaw and
   pitch, which set the Live Link eye columns and the ICT eye-look weights.
7. **Neutral calibration** (:func:`calibrate`): a shape that never relaxes
   during the take (its low percentile above zero) is the person's rest, not
   an expression, and is taken off.
"""
from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from facegeom.errors import InputError
from facegeom.io.sequence import MarkerSequence
from facegeom.methods.frame_solver import FrameSolver
from facegeom.methods.marker_solve import MarkerSolve, smooth_curves
from facegeom.methods.video_identity import OFFSET_SD, fit_identity_frames
from facegeom.model.camera import PinholeCamera
from facegeom.model.rig import BlendshapeRig
from facegeom.pipelines.solve import SolvedCapture

__all__ = ["SMOOTH_HZ", "cutoff_strength", "TrackResult", "VideoPoints", "read_video_points", "solve_points", "track_video", "choose_identity_frames", "gaze_angles", "calibrate", "point_vertices",
           "IDENTITY_FRAMES", "EYEBALL_RADIUS", "write_track_npz", "TrackFile", "read_track_npz", "point_weights"]

IDENTITY_FRAMES = 12  # frames of the identity fit: 12 x ~430 points; more changed the face by < 0.1 mm on tune clips
EYEBALL_RADIUS = 1.2  # cm: a human eyeball's radius (about 12 mm)
EYEBALL_DEPTH = 1.0  # cm: the eyeball's centre behind the middle of the lid opening (cornea just behind the lids)
DETECTOR_NOISE = 0.034
"""The face-mesh model's error per point and coordinate, in outer-eye-corner distances: on 18 rendered faces of
known geometry (6 identities x frontal / 25 / -30 degrees, the detector tests' renders) its points lay a median
0.040 of that distance from the mapped points' projections (0.025-0.062 per face), a per-coordinate standard
deviation of 0.040 / 1.18."""
SMOOTH_HZ = 4.0
"""The smoothing's cut-off (half gain): real Live Link takes keep 98.4-99.6 % of their weights' power below 4 Hz
(four recorded takes at 30 fps), while the tracked points' frame-to-frame noise is spread over every frequency."""
CALIBRATION_PERCENTILE = 5.0  # a shape above this percentile's value all take long is the person's rest
CALIBRATION_MAX = 0.5  # never take off more than this (a take that smiles throughout keeps half a smile)
MIN_CALIBRATION_S = 2.0  # takes shorter than this are not calibrated (too little to tell rest from expression)


def point_vertices(model) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Which of the 468 points the fits use, and where each lies on the face model -> ``(points, triangles, bary)``.

    All but the mesh's outer border (its 36 face-outline points move over the
    cheek as the head turns); each point is a barycentric blend ``bary (P, 3)``
    of the three face-model vertices ``triangles (P, 3)`` the map puts it in.
    """
    import igl

    from facegeom.vision.correspondence import canonical_mesh, mediapipe_map

    _, F = canonical_mesh()
    border = np.unique(np.asarray(igl.boundary_loop(np.asarray(F, dtype=np.int64)), dtype=np.int64))
    keep = np.setdiff1d(np.arange(468), border)
    mp = mediapipe_map()
    tri = np.asarray(model.triangles)[mp.triangle]
    return keep, tri[keep], np.asarray(mp.bary)[keep]


def point_weights(keep) -> np.ndarray:
    """The points' weights ``(P,)`` for the fits: inverse variance, ``(1 / sd_k)^2`` from the face-mesh model's
    measured error per point (:func:`facegeom.vision.correspondence.point_noise`), scaled to mean 1 over the
    points used so that :data:`DETECTOR_NOISE` stays the points' typical noise."""
    from facegeom.vision.correspondence import point_noise

    w = 1.0 / np.asarray(point_noise())[np.asarray(keep)] ** 2
    return w / w.mean()


def choose_identity_frames(points: np.ndarray, found: np.ndarray, k: int = IDENTITY_FRAMES) -> np.ndarray:
    """``k`` frames for the identity fit: from the calmer half of the found frames, spread over the head's turns.

    Calm: the mouth and the brows are closest to their median in the face's own frame (the points aligned by a
    similarity). Spread: farthest-point sampling over a yaw / pitch proxy (the nose tip against the eyes).
    """
    idx = np.flatnonzero(found)
    if idx.size <= k:
        return idx
    P = points[idx].astype(np.float64)  # (F, 468, 2)
    eyes = (P[:, 33] + P[:, 263]) / 2
    span = np.linalg.norm(P[:, 263] - P[:, 33], axis=1)[:, None]
    c = (P - eyes[:, None]) / span[:, None]
    # remove in-plane rotation (the eye line horizontal)
    d = (P[:, 263] - P[:, 33]) / span
    ca, sa = d[:, 0], d[:, 1]
    x = c[..., 0] * ca[:, None] + c[..., 1] * sa[:, None]
    y = -c[..., 0] * sa[:, None] + c[..., 1] * ca[:, None]
    mouth = np.abs(y[:, 14] - y[:, 13])  # inner lips apart
    brows = y[:, 159] - y[:, 105]  # brow over the upper lid (raised brows, frowns)
    calm = np.abs(mouth - np.median(mouth)) / (mouth.std() + 1e-9) + np.abs(brows - np.median(brows)) / \
        (brows.std() + 1e-9)
    pool = np.flatnonzero(calm <= np.median(calm))
    feats = np.stack([x[:, 4], y[:, 4]], axis=1)[pool]  # the nose tip in the eye frame: yaw, pitch proxies
    chosen = [int(np.argmin(np.linalg.norm(feats - np.median(feats, axis=0), axis=1)))]
    dist = np.linalg.norm(feats - feats[chosen[0]], axis=1)
    while len(chosen) < k:
        j = int(np.argmax(dist))
        chosen.append(j)
        dist = np.minimum(dist, np.linalg.norm(feats - feats[j], axis=1))
    return np.sort(idx[pool[chosen]])


def cutoff_strength(hz: float, fps: float) -> float:
    """The Whittaker strength whose filter halves a sinusoid of ``hz`` at ``fps`` frames a second.

    The smoother ``min |z - y|^2 + lam |D2 z|^2`` passes frequency ``f`` with the gain
    ``1 / (1 + lam (2 - 2 cos(2 pi f / fps))^2)``; the gain is 1/2 at ``f = hz`` for the returned ``lam``.
    """
    c = 2.0 - 2.0 * math.cos(2.0 * math.pi * min(hz / fps, 0.5))
    return 1.0 / (c * c)


def _bridge(values: np.ndarray, found: np.ndarray) -> np.ndarray:
    """Fill the rows of ``values (T, ...)`` where ``found`` is False by linear interpolation (ends held)."""
    T = values.shape[0]
    good = np.flatnonzero(found)
    if good.size == T:
        return values
    flat = values.reshape(T, -1)
    out = np.empty_like(flat)
    t = np.arange(T)
    for j in range(flat.shape[1]):
        out[:, j] = np.interp(t, good, flat[good, j])
    return out.reshape(values.shape)


def gaze_angles(iris: np.ndarray, R: np.ndarray, t: np.ndarray, centres: np.ndarray,
                camera: PinholeCamera) -> np.ndarray:
    """Each eye's yaw and pitch (radians) from its iris centre in the image -> ``(2, 2)``.

    ``iris (2, 2)``: the subject's right and left iris centre (pixels); ``R, t``: the head's pose; ``centres
    (2, 3)``: the eyeballs' centres in the head's frame. The pixel's ray meets the eyeball (or passes nearest
    it); yaw is positive towards the subject's left (+x), pitch positive upwards (+y), as the face model's axes.
    """
    out = np.zeros((2, 2))
    f = camera.focal
    for e in range(2):
        u, v = iris[e]
        ray = np.array([(u - camera.cx) / f, -(v - camera.cy) / f, -1.0])
        ray /= np.linalg.norm(ray)
        c = R @ centres[e] + t  # eyeball centre in camera space
        b = float(ray @ c)
        disc = b * b - float(c @ c) + EYEBALL_RADIUS ** 2
        s = b - math.sqrt(disc) if disc > 0 else b  # the nearer hit, or the ray's closest approach
        p = s * ray
        d = R.T @ (p - c)  # the gaze direction in the head's frame
        d /= np.linalg.norm(d) + 1e-12
        out[e, 0] = math.atan2(d[0], d[2])
        out[e, 1] = math.atan2(d[1], math.hypot(d[0], d[2]))
    return out


def eyeball_centres(neutral: np.ndarray, landmark_ids) -> np.ndarray:
    """The eyeballs' centres ``(2, 3)`` of a face: behind the middle of each eye's lid landmarks (36-41, 42-47)."""
    ids = np.asarray(landmark_ids)
    out = np.stack([neutral[ids[36:42]].mean(axis=0), neutral[ids[42:48]].mean(axis=0)])
    out[:, 2] -= EYEBALL_DEPTH
    return out


def calibrate(W: np.ndarray, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """Take each shape's rest value off its curve -> ``(calibrated, offsets)``.

    The rest value is the curve's :data:`CALIBRATION_PERCENTILE` percentile
    (at most :data:`CALIBRATION_MAX`); the curve becomes ``(w - rest) / (1 -
    rest)``, clipped to ``[0, 1]``, so a full expression stays full. Takes
    shorter than :data:`MIN_CALIBRATION_S` are returned as they are.
    """
    W = np.asarray(W, dtype=np.float64)
    if W.shape[0] < MIN_CALIBRATION_S * fps:
        return W.copy(), np.zeros(W.shape[1])
    rest = np.clip(np.percentile(W, CALIBRATION_PERCENTILE, axis=0), 0.0, CALIBRATION_MAX)
    return np.clip((W - rest) / (1.0 - rest), 0.0, 1.0), rest


@dataclass
class TrackResult:
    """A tracked video: the curves as a solved capture, and everything measured on the way."""

    solved: SolvedCapture
    points: np.ndarray  # (T, 468, 2) float32, NaN where no face
    iris: np.ndarray  # (T, 2, 2) float32 iris centres, NaN where none
    landmarks: np.ndarray  # (T, 68, 2) float32 (the annotators' convention), NaN where no face
    found: np.ndarray  # (T,) bool
    residual: np.ndarray  # (T,) float64 rms pixels of the frame's fit (NaN where bridged)
    gaze: np.ndarray  # (T, 2, 2) yaw, pitch per eye, radians
    identity: np.ndarray  # (I,) identity coefficients (zeros with a given rig)
    rig: BlendshapeRig
    focal: float
    focal_estimated: bool
    width: int
    height: int
    fps: float
    times: np.ndarray  # (T,) seconds
    identity_frames: np.ndarray
    calibration: np.ndarray  # (B,) rest offsets taken off
    camera_t: np.ndarray  # (T, 3) the face's translation in the camera's space (cm), as fitted
    noise_px: float
    detections: int
    most_faces: int
    seconds: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)

    @property
    def n_frames(self) -> int:
        """Frames of the video."""
        return int(self.found.size)


def _read_points(path, tracker_opts, progress, max_frames):
    from facegeom.io.video import open_video
    from facegeom.vision.faces import landmarks68
    from facegeom.vision.tracking import FaceTracker

    tracker = FaceTracker(**tracker_opts)
    pts, iris, lms, found, times = [], [], [], [], []
    most = 0
    t_decode = t_points = 0.0
    with open_video(path) as video:
        total = video.n_frames
        if max_frames is not None:
            total = min(total, max_frames) if total else max_frames
        it = iter(video)
        i = 0
        while max_frames is None or i < max_frames:
            t0 = time.perf_counter()
            frame = next(it, None)
            t1 = time.perf_counter()
            t_decode += t1 - t0
            if frame is None:
                break
            r = tracker.step(frame.image)
            most = max(most, r.faces)
            if r.points is None:
                pts.append(np.full((468, 2), np.nan, np.float32))
                lms.append(np.full((68, 2), np.nan, np.float32))
                iris.append(np.full((2, 2), np.nan, np.float32))
                found.append(False)
            else:
                pts.append(r.points[:, :2].astype(np.float32))
                lms.append(landmarks68(r.points).astype(np.float32))
                iris.append(r.iris[:, 0, :2].astype(np.float32) if r.iris is not None
                            else np.full((2, 2), np.nan, np.float32))
                found.append(True)
            times.append(frame.time_s)
            t_points += time.perf_counter() - t1
            i += 1
            if progress is not None:
                progress(i, total)
        info = dict(fps=video.fps, width=video.width, height=video.height, variable=video.variable_rate,
                    damaged=video.damaged, truncated=video.truncated, problem=video.problem)
    if not pts:
        raise InputError("the video has no frame", path)
    return (np.stack(pts), np.stack(iris), np.stack(lms), np.array(found), np.array(times, dtype=np.float64),
            info, tracker.detections, most, t_decode, t_points)


def track_video(path: str | os.PathLike, model, rig: BlendshapeRig | None = None, focal: float | None = None,
                smooth="auto", calibration: bool = True, detector: str = "auto", progress=None,
                max_frames: int | None = None, offset_sd: float | None = OFFSET_SD, stage=None) -> TrackResult:
    """Track the face of the video at ``path`` (see the module docstring).

    Parameters
    ----------
    model : FaceModel
        The face model (identity modes, expressions, the map's topology).
    rig : BlendshapeRig, optional
        The actor's own rig (the face model's topology: from ``facegeom identity`` or a previous track); default:
        the identity is fitted from the video.
    focal : float, optional
        The camera's focal length in pixels; default: estimated.
    smooth : "auto", "off" or float
        The curves' smoothing (:func:`facegeom.methods.marker_solve.smooth_curves`).
    calibration : bool
        Take each shape's rest value off (:func:`calibrate`).
    detector : {"auto", "short", "full"}
        The face detector.
    progress : callable, optional
        ``progress(frames_done, frames_total_or_None)`` after every frame.
    max_frames : int, optional
        Stop after this many frames.
    offset_sd : float or None
        The per-point offsets of the identity fit (:func:`facegeom.methods.video_identity.fit_identity_frames`).
    stage : callable, optional
        ``stage(line)`` as the fit begins, after the frames are read.

    Raises
    ------
    InputError
        Not a video, no face in any frame, a rig of another topology.
    """
    path = Path(path)
    if rig is not None and rig.n_vertices != model.n_vertices:
        raise InputError(f"the rig has {rig.n_vertices} vertices, not the face model's {model.n_vertices}: the "
                         "tracked points lie on the face model's vertices (fit the actor's rig with `facegeom "
                         "identity`, or play the track on any character afterwards)")
    if focal is not None and not (focal > 0 and math.isfinite(focal)):
        raise InputError(f"the focal length must be a positive number of pixels, not {focal!r}")
    t_start = time.perf_counter()
    vp = read_video_points(path, detector, progress, max_frames)
    if stage is not None:
        stage(f"face points found in {int(vp.found.sum())} of {vp.found.size} frames; fitting "
              + ("the camera and every frame's pose and expression ..." if rig is not None else
                 "the actor's identity, the camera and every frame's pose and expression ..."))
    return solve_points(vp, model, rig=rig, focal=focal, smooth=smooth, calibration=calibration,
                        offset_sd=offset_sd, t_start=t_start)


@dataclass
class VideoPoints:
    """What the face tracker found in every frame of a video (:func:`read_video_points`)."""

    path: Path
    points: np.ndarray  # (T, 468, 2) float32, NaN where no face
    iris: np.ndarray  # (T, 2, 2) float32
    landmarks: np.ndarray  # (T, 68, 2) float32
    found: np.ndarray  # (T,) bool
    times: np.ndarray  # (T,) seconds
    info: dict
    detections: int
    most_faces: int
    seconds: dict


def read_video_points(path, detector: str = "auto", progress=None, max_frames: int | None = None) -> VideoPoints:
    """Step 1 of :func:`track_video`: the face's points in every frame of the video at ``path``."""
    path = Path(path)
    (points, iris, lms, found, times, info, detections, most, t_decode,
     t_points) = _read_points(path, {"detector": detector}, progress, max_frames)
    return VideoPoints(path, points, iris, lms, found, times, info, detections, most,
                       {"decode": t_decode, "points": t_points})


def solve_points(vp: VideoPoints, model, rig: BlendshapeRig | None = None, focal: float | None = None,
                 smooth="auto", calibration: bool = True, offset_sd: float | None = OFFSET_SD,
                 t_start: float | None = None) -> TrackResult:
    """Steps 2-7 of :func:`track_video` on points already found (:func:`read_video_points`)."""
    t_start = time.perf_counter() if t_start is None else t_start
    path = vp.path
    points, iris, lms, found, times, info = vp.points, vp.iris, vp.landmarks, vp.found, vp.times, vp.info
    detections, most = vp.detections, vp.most_faces
    t_decode, t_points = vp.seconds["decode"], vp.seconds["points"]
    T = found.size
    notes = []
    if not found.any():
        raise InputError(f"no face found in any of the video's {T} frames", path)
    if info["problem"]:
        notes.append(f"{path.name}: {info['problem']}")
    fps = float(info["fps"]) if info["fps"] and info["fps"] > 0 else 30.0
    if info["variable"]:
        notes.append(f"{path.name}: variable frame rate; the curves are written at the average {fps:.3g} fps "
                     "(each frame's own time is in the .npz)")
    W_px, H_px = int(info["width"]), int(info["height"])
    keep, ids, bary = point_vertices(model)
    t0 = time.perf_counter()
    chosen = choose_identity_frames(points, found)
    if rig is None:
        neutral, modes, deltas = model.neutral, np.asarray(model.identity_modes), model.expression_deltas
        names = tuple(model.expression_names)
    else:
        neutral, modes, deltas, names = rig.neutral, None, rig.deltas, tuple(rig.names)
    # the points' noise: what the fit leaves, or the face-mesh model's own error against the true points where
    # that is larger (most of it moves with the face, so the fit absorbs it and its residual understates it)
    pw = point_weights(keep)
    first = fit_identity_frames(points[chosen][:, keep], ids, W_px, H_px, neutral, deltas, modes, focal=focal,
                                offset_sd=offset_sd, bary=bary, point_weights=pw)
    eyes = np.linalg.norm(points[found][:, 263] - points[found][:, 33], axis=1)
    noise = max(first.rms / math.sqrt(2.0), DETECTOR_NOISE * float(np.median(eyes)), 0.25)
    idf = fit_identity_frames(points[chosen][:, keep], ids, W_px, H_px, neutral, deltas, modes, focal=focal,
                              noise_px=noise, offset_sd=offset_sd, bary=bary, point_weights=pw)
    person = BlendshapeRig.from_face_model(model, idf.identity) if rig is None else rig
    camera = PinholeCamera(idf.focal, (W_px - 1) / 2.0, (H_px - 1) / 2.0)
    solver = FrameSolver(person.neutral, person.deltas, ids, camera, noise_px=noise, bary=bary, point_weights=pw)
    solver.N = solver.N + idf.offsets  # where the face-mesh model puts the points on this person (see the fit)
    t_identity = time.perf_counter() - t0
    B = len(names)
    Wraw = np.zeros((T, B))
    Rs = np.repeat(np.eye(3)[None], T, axis=0)
    ts = np.zeros((T, 3))
    residual = np.full(T, np.nan)
    prev = None
    last = -10
    t0 = time.perf_counter()
    for i in np.flatnonzero(found):
        uv = points[i, keep].astype(np.float64)
        if prev is None or i - last > 5:
            r = solver.solve(uv)
        else:
            r = solver.solve(uv, prev.R, prev.t, prev.w)
        Wraw[i], Rs[i], ts[i], residual[i] = r.w, r.R, r.t, r.rms
        prev, last = r, i
    t_frames = time.perf_counter() - t0
    bridged = int(T - found.sum())
    if bridged:
        from scipy.spatial.transform import Rotation, Slerp

        good = np.flatnonzero(found)
        Wraw = _bridge(Wraw, found)
        ts = _bridge(ts, found)
        if good.size >= 2:
            Rs = Slerp(good, Rotation.from_matrix(Rs[good]))(np.clip(np.arange(T), good[0], good[-1])).as_matrix()
        else:
            Rs = np.repeat(Rs[good[:1]], T, axis=0)
        runs = np.diff(np.r_[0, (~found).astype(int), 0])
        longest = int((np.flatnonzero(runs == -1) - np.flatnonzero(runs == 1)).max())
        notes.append(f"{path.name}: no face in {bridged} of {T} frames (longest gap {longest}); their weights and "
                     f"pose are interpolated from the neighbouring frames")
    # gaze from the irises, in the head's frame
    centres = eyeball_centres(person.neutral, person.landmark_ids if person.landmark_ids is not None
                              else model.landmarks)
    gaze = np.zeros((T, 2, 2))
    has_iris = found & np.isfinite(iris).all(axis=(1, 2))
    for i in np.flatnonzero(has_iris):
        gaze[i] = gaze_angles(iris[i].astype(np.float64), Rs[i], ts[i], centres, camera)
    if has_iris.any():
        gaze = _bridge(gaze, has_iris)
    # smoothing: weights, pose (rotation vectors about the mean turn, translations), gaze
    from scipy.spatial.transform import Rotation

    if smooth == "auto":
        smooth = cutoff_strength(SMOOTH_HZ, fps)
    if smooth == "off":
        W, lam = Wraw.copy(), np.zeros(B)
        gaze_s = gaze
    else:
        W, lam = smooth_curves(Wraw, smooth)
        mean = Rotation.from_matrix(Rs).mean()
        rv = (mean.inv() * Rotation.from_matrix(Rs)).as_rotvec()
        rv_s, _ = smooth_curves(np.c_[rv, ts], smooth)
        Rs = (mean * Rotation.from_rotvec(rv_s[:, :3])).as_matrix()
        ts = rv_s[:, 3:]
        gaze_s = smooth_curves(gaze.reshape(T, 4), smooth)[0].reshape(T, 2, 2)
    # the eye-look shapes from the gaze (the lids alone cannot tell where an eye looks), calibrated with the rest
    W = _eye_look(W, names, gaze_s)
    rest = np.zeros(B)
    if calibration:
        W, rest = calibrate(W, fps)
        if rest.max() > 0.02:
            top = np.argsort(-rest)[:3]
            notes.append("neutral calibration: rest values taken off " + ", ".join(
                f"{names[j]} {rest[j]:.2f}" for j in top if rest[j] > 0.02))
    ts_camera = ts.copy()
    head_t = ts - np.median(ts, axis=0)  # the head's motion, about its middle position (cm)
    eye_rot = _eye_rotations(gaze_s)
    solve = MarkerSolve(weights=W, names=names, rotations=Rs, translations=head_t, raw_weights=Wraw,
                        smoothing=np.asarray(lam, dtype=np.float64), rms=np.nan_to_num(residual, nan=0.0),
                        lost=(~found).astype(np.int64), time_s=time.perf_counter() - t_start,
                        info={"head_motion": True, "eye_rotations": eye_rot, "video": str(path)})
    seq = MarkerSequence(np.arange(T, dtype=np.int64), (), np.zeros((T, 0, 3)), str(path))
    solved = SolvedCapture(solve, seq, np.zeros(0, dtype=np.int64), "track", fps, True, person, notes)
    total = time.perf_counter() - t_start
    return TrackResult(
        solved=solved, points=points, iris=iris, landmarks=lms, found=found, residual=residual, gaze=gaze_s,
        identity=idf.identity if rig is None else np.zeros(0), rig=person, focal=float(idf.focal),
        focal_estimated=focal is None, width=W_px, height=H_px, fps=fps, times=times, identity_frames=chosen,
        calibration=rest, camera_t=ts_camera, noise_px=float(noise), detections=int(detections), most_faces=int(most),
        seconds={"decode": t_decode, "points": t_points, "identity": t_identity, "frames": t_frames,
                 "total": total}, notes=notes)


def _eye_look(W: np.ndarray, names, gaze: np.ndarray) -> np.ndarray:
    """Set the ICT / ARKit eye-look weights from the gaze (radians), as Live Link Face relates them."""
    from facegeom.io.takes import EYE_PITCH_PER_WEIGHT, EYE_YAW_PER_WEIGHT

    out = W.copy()
    index = {n.lower(): k for k, n in enumerate(names)}
    # eye 0 is the subject's right (ICT suffix _R), 1 the left (_L); yaw + is towards the subject's left
    for e, (ict, arkit) in enumerate((("_r", "right"), ("_l", "left"))):
        yaw, pitch = gaze[:, e, 0], gaze[:, e, 1]
        # the right eye looking to the subject's left looks in (towards the nose); the left eye looks out
        inward = yaw if e == 0 else -yaw
        values = {"in": np.clip(inward / EYE_YAW_PER_WEIGHT, 0, 1), "out": np.clip(-inward / EYE_YAW_PER_WEIGHT, 0, 1),
                  "up": np.clip(pitch / EYE_PITCH_PER_WEIGHT, 0, 1),
                  "down": np.clip(-pitch / EYE_PITCH_PER_WEIGHT, 0, 1)}
        for d, v in values.items():
            for key in (f"eyelook{d}{ict}", f"eyelook{d}{arkit}"):
                if key in index:
                    out[:, index[key]] = v
    return out


def _eye_rotations(gaze: np.ndarray) -> np.ndarray:
    """Live Link's eye columns ``(T, 6)``: LeftEyeYaw, LeftEyePitch, LeftEyeRoll, RightEyeYaw, ... (radians).

    The app's eye yaw is positive when the eye turns towards the subject's right... as its weights relate them
    (:func:`facegeom.io.takes.eye_rotations`): the signs follow that function, so a take written and read back
    gives the same eye-look weights.
    """
    T = gaze.shape[0]
    out = np.zeros((T, 6))
    # facegeom.io.takes.eye_rotations: LeftEyeYaw = -0.6 (out_L - in_L); left eye out = towards the subject's left
    # (+yaw), so LeftEyeYaw = -yaw_left; RightEyeYaw = +0.6 (out_R - in_R); right eye out = towards the subject's
    # right (-yaw), so RightEyeYaw = -yaw_right. Pitch: -0.5 (up - down) -> -pitch.
    out[:, 0], out[:, 1] = -gaze[:, 1, 0], -gaze[:, 1, 1]
    out[:, 3], out[:, 4] = -gaze[:, 0, 0], -gaze[:, 0, 1]
    return out


def write_track_npz(path: str | os.PathLike, result: TrackResult) -> Path:
    """Everything the track measured, as ``.npz`` (atomically): curves, head pose, gaze, points, landmarks,
    per-frame residual, the identity and the camera."""
    from facegeom.io.files import atomic_path

    s = result.solved.solve
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        np.savez_compressed(
            fh, weights=s.weights, raw_weights=s.raw_weights, names=np.array(s.names), fps=np.float64(result.fps),
            times=result.times, rotations=s.rotations, translations=s.translations, gaze=result.gaze,
            eye_rotations=s.info["eye_rotations"], points=result.points, iris=result.iris,
            landmarks=result.landmarks, found=result.found, residual=result.residual, identity=result.identity,
            focal=np.float64(result.focal), focal_estimated=np.bool_(result.focal_estimated),
            width=np.int64(result.width), height=np.int64(result.height), identity_frames=result.identity_frames,
            calibration=result.calibration, camera_translations=result.camera_t, smoothing=s.smoothing, noise_px=np.float64(result.noise_px),
            units=np.array("cm"), source=np.array(str(s.info.get("video", ""))))
    return Path(path)


@dataclass
class TrackFile:
    """A track read back from the ``.npz`` :func:`write_track_npz` writes (:func:`read_track_npz`)."""

    path: Path
    weights: np.ndarray  # (T, B) the delivered curves (smoothed, calibrated)
    raw_weights: np.ndarray  # (T, B) each frame's own fit
    names: tuple
    fps: float
    times: np.ndarray  # (T,) s
    rotations: np.ndarray  # (T, 3, 3)
    camera_t: np.ndarray  # (T, 3) cm, the camera's space
    gaze: np.ndarray  # (T, 2, 2)
    points: np.ndarray  # (T, 468, 2) px
    landmarks: np.ndarray  # (T, 68, 2) px
    found: np.ndarray  # (T,) bool
    residual: np.ndarray  # (T,) rms px
    identity: np.ndarray  # (I,) empty when the track was made with a given rig
    focal: float
    width: int
    height: int
    source: str

    @property
    def n_frames(self) -> int:
        """Frames of the track."""
        return int(self.found.size)


TRACK_ARRAYS = {  # name -> (shape, with T for the frames, B for the shapes, I for the identity; kind)
    "weights": (("T", "B"), "f"), "raw_weights": (("T", "B"), "f"), "names": (("B",), "U"), "fps": ((), "f"),
    "times": (("T",), "f"), "rotations": (("T", 3, 3), "f"), "camera_translations": (("T", 3), "f"),
    "gaze": (("T", 2, 2), "f"), "points": (("T", 468, 2), "f"), "landmarks": (("T", 68, 2), "f"),
    "found": (("T",), "b"), "residual": (("T",), "f"), "identity": (("I",), "f"), "focal": ((), "f"),
    "width": ((), "i"), "height": ((), "i"),
}


def read_track_npz(path: str | os.PathLike) -> TrackFile:
    """Read a track written by ``facegeom track -o OUT.npz`` (every array checked before use).

    Raises
    ------
    InputError
        Not an ``.npz``, an array missing or of the wrong shape or kind, values that are not finite where they
        must be, a rotation that is not one: one line naming the file and the array.
    """
    import zipfile

    from facegeom.io.npzcheck import check_npz, check_text

    path = Path(path)
    if not path.is_file():
        raise InputError("no such file", path)
    check_npz(path)
    arrays = {}
    try:
        with np.load(path, allow_pickle=False) as z:
            missing = [k for k in TRACK_ARRAYS if k not in z.files]
            if missing:
                raise InputError(f"not a track (`facegeom track -o OUT.npz` writes one): no array "
                                 f"{', '.join(repr(m) for m in missing[:3])}", path)
            for k in (*TRACK_ARRAYS, "source"):
                if k in z.files:
                    arrays[k] = np.asarray(z[k])
    except InputError:
        raise
    except (OSError, ValueError, EOFError, KeyError, TypeError, zipfile.BadZipFile) as exc:
        raise InputError(f"not a readable .npz: {type(exc).__name__}: {exc}", path) from None
    sizes: dict[str, int] = {}
    for k, (shape, kind) in TRACK_ARRAYS.items():
        a = arrays[k]
        ok = a.dtype.kind in {"f": "fiu", "i": "iu", "b": "bu", "U": "US"}[kind] and a.ndim == len(shape)
        if ok:
            for dim, n in zip(shape, a.shape):
                if isinstance(dim, str):
                    ok = ok and sizes.setdefault(dim, n) == n
                else:
                    ok = ok and dim == n
        if not ok:
            want = "(" + ", ".join(str(d) for d in shape) + ("," if len(shape) == 1 else "") + ")"
            raise InputError(f"array {k!r} must have shape {want} ({dict(sizes)}), got {a.shape} of {a.dtype}",
                             path)
    T = sizes["T"]
    if T == 0 or sizes["B"] == 0:
        raise InputError("the track has no frames or no shapes", path)
    check_text(arrays["names"], "names", path)
    if "source" in arrays:
        check_text(arrays["source"], "source", path)
    must_be_finite = ("weights", "raw_weights", "times", "rotations", "camera_translations", "gaze", "residual",
                      "identity", "fps", "focal")
    for k in must_be_finite:
        a = arrays[k].astype(np.float64)
        if k == "residual":
            a = a[arrays["found"].astype(bool)]
        if not np.isfinite(a).all():
            raise InputError(f"array {k!r} holds NaN or inf", path)
    fps, focal = float(arrays["fps"]), float(arrays["focal"])
    width, height = int(arrays["width"]), int(arrays["height"])
    if not (fps > 0 and focal > 0 and 0 < width <= 1 << 16 and 0 < height <= 1 << 16):
        raise InputError(f"the camera is not one: {width} x {height} px, focal {focal:g} px, {fps:g} fps", path)
    R = arrays["rotations"].astype(np.float64)
    if np.abs(np.einsum("tij,tkj->tik", R, R) - np.eye(3)).max() > 1e-3 or (np.linalg.det(R) < 0).any():
        raise InputError("array 'rotations' holds matrices that are not rotations", path)
    source = str(arrays["source"]) if "source" in arrays and arrays["source"].dtype.kind in "US" \
        and arrays["source"].size == 1 else ""
    return TrackFile(path=path, weights=arrays["weights"].astype(np.float64),
                     raw_weights=arrays["raw_weights"].astype(np.float64),
                     names=tuple(str(n) for n in arrays["names"]), fps=fps,
                     times=arrays["times"].astype(np.float64), rotations=R,
                     camera_t=arrays["camera_translations"].astype(np.float64),
                     gaze=arrays["gaze"].astype(np.float64), points=arrays["points"].astype(np.float32),
                     landmarks=arrays["landmarks"].astype(np.float32), found=arrays["found"].astype(bool),
                     residual=arrays["residual"].astype(np.float64), identity=arrays["identity"].astype(np.float64),
                     focal=focal, width=width, height=height, source=source)
