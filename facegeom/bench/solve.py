"""``facegeom bench solve``: marker solve (capture -> rig weights) on sequences made from real takes.

Protocol, per case (seeded):

- a window of ``frames`` consecutive frames of a real ARKit take (its ICT
  weights, :func:`facegeom.io.takes.ict_weights`) is the ground truth ``W``;
- a random identity (ICT identity modes, N(0, 1)) gives the character's rig,
  which the solve uses (the character's rig is known; the capture is not);
- markers on a layout: ``ict80`` (68 landmarks + 12) and ``random80`` (a
  seeded random start, farthest points), on the face area;
- random smooth rigid head motion per frame (rotations up to ~20 degrees,
  translations up to ~3 cm, sums of slow sines);
- conditions, realistic first: marker noise 0.5 mm with 3% of the markers
  lost per frame, then noise-free with none lost.

Metrics (mean over frames, median over cases): ``weight_mae`` (mean absolute
weight error vs truth), ``face_mm`` (mean vertex error over the face area,
rig frame, mm), ``jitter`` (mean absolute second difference of the weights)
and ``jitter_truth`` (the same of the truth), ``ms_per_frame``. Every fitter
is run side by side, plus ``sem-ls`` with GCV smoothing (``sem-ls+smooth``).
A speed row times 1,000 frames of the 80 ``ict80`` markers on the generic rig
with the default fitter (median of 3 runs).
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from facegeom.bench.common import progress_bar
from facegeom.bench.report import Report, format_table, machine_note
from facegeom.constants import CM_TO_MM, FACE_AREA
from facegeom.errors import FacegeomError
from facegeom.methods.marker_solve import solve_markers
from facegeom.model.layouts import layout
from facegeom.model.rig import BlendshapeRig

__all__ = ["CONDITIONS", "actor_unknown", "main", "make_sequence", "run", "stuck_shapes"]

CONDITIONS = (("noise 0.5 mm, 3% lost", 0.05, 0.03), ("noise-free", 0.0, 0.0))
"""``(label, marker noise sigma in cm, fraction of markers lost per frame)``, realistic first."""

LAYOUTS = ("ict80", "random80")


def head_motion(T: int, rng) -> tuple[np.ndarray, np.ndarray]:
    """Smooth random rigid motion: ``R (T, 3, 3)`` (up to ~20 degrees) and ``t (T, 3)`` (up to ~3 cm)."""
    from scipy.spatial.transform import Rotation

    s = np.arange(T)[:, None]

    def wave(amp):
        f = rng.uniform(0.005, 0.05, (2, 3))
        ph = rng.uniform(0, 2 * np.pi, (2, 3))
        return amp * (0.6 * np.sin(2 * np.pi * f[0] * s + ph[0]) + 0.4 * np.sin(2 * np.pi * f[1] * s + ph[1]))

    return Rotation.from_rotvec(wave(np.deg2rad(20.0))).as_matrix(), wave(3.0)


def make_sequence(rig: BlendshapeRig, ids, W, noise: float, lost: float, rng):
    """Markers ``(T, p, 3)`` of ``rig`` at ``ids`` for weights ``W (T, K)``, moved, noisy, with lost markers."""
    T = W.shape[0]
    F = rig.neutral[ids][None] + np.einsum("tb,bpi->tpi", W, rig.deltas[:, ids])
    R, t = head_motion(T, rng)
    X = np.einsum("tij,tpj->tpi", R, F) + t[:, None] + noise * rng.standard_normal(F.shape)
    if lost > 0:
        X[rng.random((T, len(ids))) < lost] = np.nan
    return X, R, t


def _metrics(rig, W, E, seconds):
    Dface = rig.deltas[:, :FACE_AREA].reshape(rig.n_shapes, -1)
    dV = ((E - W) @ Dface).reshape(W.shape[0], -1, 3)
    jit = lambda A: float(np.abs(np.diff(A, 2, axis=0)).mean()) if A.shape[0] > 2 else float("nan")  # noqa: E731
    return {"weight_mae": float(np.abs(E - W).mean()),
            "face_mm": float(np.linalg.norm(dV, axis=2).mean() * CM_TO_MM),
            "jitter": jit(E), "jitter_truth": jit(W), "ms_per_frame": seconds / W.shape[0] * 1e3}


def run(model, takes, specs, cases: int, frames: int, seed: int = 0, progress: bool = True) -> list[dict]:
    """Every case x layout x condition x method -> one row (see the module docstring)."""
    if not takes:
        raise FacegeomError("the solve benchmark needs at least one take of expression weights")
    rng = np.random.default_rng([int(seed), 2020])
    plan = []
    for c in range(cases):
        name, Wt = takes[c % len(takes)]
        T = min(frames, Wt.shape[0])
        start = int(rng.integers(0, Wt.shape[0] - T + 1))
        plan.append((c, name, start, np.asarray(Wt[start:start + T], dtype=np.float64), model.random_identity(rng),
                     int(rng.integers(1 << 30))))
    rows = []
    steps = [(p, lay, cond) for cond in CONDITIONS for p in plan for lay in LAYOUTS]
    rigs: dict = {}
    for (c, name, start, W, identity, case_seed), lay, (label, noise, lost) in progress_bar(
            steps, "bench solve", progress, unit="sequence"):
        rig = rigs.get(c)
        if rig is None:
            rig = rigs[c] = BlendshapeRig.from_face_model(model, identity)
        ids = layout(model, lay, seed=case_seed)
        X, _, _ = make_sequence(rig, ids, W, noise, lost, np.random.default_rng([case_seed, len(rows)]))
        for spec in specs:
            for smooth in (("off", "auto") if spec.label == "sem-ls" else ("off",)):
                fitter = spec.build("fitters")
                t0 = time.perf_counter()
                s = solve_markers(X, ids, rig, fitter, smooth=smooth)
                dt = time.perf_counter() - t0
                rows.append({"condition": label, "layout": lay, "case": c, "take": name, "start": start,
                             "frames": W.shape[0], "method": spec.label + ("+smooth" if smooth == "auto" else ""),
                             **_metrics(rig, W, s.weights, dt)})
    return rows


IDENTITY_CONDITIONS = CONDITIONS[:1] + (("noise 1 mm, 3% lost", 0.1, 0.03),) + CONDITIONS[1:]
"""The actor-unknown table's conditions: the realistic one, a noisier system, noise-free."""

RIGS = ("actor's rig", "generic face", "generic + identity fit")
"""The actor-unknown table's rigs: the truth's own, the model's generic face as it is, and the generic face with the
actor's identity fitted from the capture (what ``facegeom solve`` does without ``--rig``)."""


def stuck_shapes(W, E, low: float = 0.2, high: float = 0.5) -> list[int]:
    """Shapes whose truth stays at or below ``low`` in every frame while the solve puts them above ``high`` in at
    least half of the frames -> their indices."""
    return [int(k) for k in range(W.shape[1]) if W[:, k].max() <= low and np.mean(E[:, k] > high) >= 0.5]


def actor_unknown(model, takes, cases: int, frames: int, seed: int = 0, progress: bool = True) -> list[dict]:
    """The actor's identity unknown: each case solved on the actor's rig, the generic face, and the generic face
    with the identity fitted from the capture -> one row per case x layout x condition x rig (sem-ls, GCV
    smoothing, as ``facegeom solve``)."""
    from facegeom.methods.marker_identity import fit_capture_identity
    from facegeom.methods.marker_solve import marker_noise
    from facegeom.pipelines.solve import fit_warning

    if not takes:
        raise FacegeomError("the solve benchmark needs at least one take of expression weights")
    rng = np.random.default_rng([int(seed), 4049])
    generic = BlendshapeRig.from_face_model(model)
    rows = []
    steps = [(c, lay, cond) for cond in IDENTITY_CONDITIONS for c in range(cases) for lay in LAYOUTS]
    plan = {}
    for c in range(cases):
        name, Wt = takes[(c + seed) % len(takes)]
        T = min(frames, Wt.shape[0])
        start = int(rng.integers(0, Wt.shape[0] - T + 1))
        identity = model.random_identity(rng)
        plan[c] = (name, start, np.asarray(Wt[start:start + T], dtype=np.float64),
                   BlendshapeRig.from_face_model(model, identity), int(rng.integers(1 << 30)))
    for c, lay, (label, noise, lost) in progress_bar(steps, "bench solve (actor unknown)", progress,
                                                     unit="sequence"):
        name, start, W, actor, case_seed = plan[c]
        ids = layout(model, lay, seed=case_seed)
        X, _, _ = make_sequence(actor, ids, W, noise, lost, np.random.default_rng([case_seed, len(rows)]))
        sigma = marker_noise(X)
        for rig_label in RIGS:
            t0 = time.perf_counter()
            rig, fit_s = (actor if rig_label == RIGS[0] else generic), 0.0
            if rig_label == RIGS[2]:
                fit = fit_capture_identity(model, X, ids)
                rig = fit.rig if fit.info["better"] else generic  # as facegeom solve decides
                fit_s = time.perf_counter() - t0
            s = solve_markers(X, ids, rig, smooth="auto")
            dt = time.perf_counter() - t0
            d = rig.neutral[:FACE_AREA] - actor.neutral[:FACE_AREA]
            res = float(np.median(s.rms)) * CM_TO_MM
            rows.append({"condition": label, "layout": lay, "case": c, "take": name, "start": start,
                         "frames": W.shape[0], "rig": rig_label, **_metrics(rig, W, s.weights, dt),
                         "stuck": len(stuck_shapes(W, s.weights)),
                         "neutral_mm": float(np.sqrt((d ** 2).sum(axis=1).mean()) * CM_TO_MM),
                         "residual_mm": res, "noise_est_mm": sigma * CM_TO_MM,
                         "warned": bool(fit_warning(s.rms, sigma)), "fit_s": fit_s})
    return rows


def actor_unknown_table(rows) -> tuple[list, list]:
    """Medians per condition x layout x rig, and the fitted / actor's-rig weight error ratio per case."""
    head = ["condition", "layout", "rig", "weight_mae", "worst_mae", "vs_actor_max", "stuck", "neutral_mm",
            "residual_mm", "warned", "fit_s"]
    table = []
    for cond in dict.fromkeys(r["condition"] for r in rows):
        for lay in LAYOUTS:
            own = {r["case"]: r["weight_mae"] for r in rows
                   if r["condition"] == cond and r["layout"] == lay and r["rig"] == RIGS[0]}
            for rig in RIGS:
                sel = [r for r in rows if r["condition"] == cond and r["layout"] == lay and r["rig"] == rig]
                if not sel:
                    continue
                ratio = max(r["weight_mae"] / max(own[r["case"]], 1e-12) for r in sel)
                table.append([cond, lay, rig, float(np.median([r["weight_mae"] for r in sel])),
                              max(r["weight_mae"] for r in sel), ratio, sum(r["stuck"] for r in sel),
                              float(np.median([r["neutral_mm"] for r in sel])),
                              float(np.median([r["residual_mm"] for r in sel])),
                              f"{sum(r['warned'] for r in sel)}/{len(sel)}",
                              float(np.median([r["fit_s"] for r in sel]))])
    return head, table


def speed(model, repeat: int = 3) -> dict:
    """Seconds to solve 1,000 frames of the ``ict80`` markers on the generic rig (default fitter), median."""
    rig = BlendshapeRig.from_face_model(model)
    ids = layout(model, "ict80")
    rng = np.random.default_rng(7)
    W = np.clip(rng.random((1000, rig.n_shapes)) * (rng.random((1000, rig.n_shapes)) < 0.15), 0, 1)
    X, _, _ = make_sequence(rig, ids, W, 0.05, 0.0, rng)
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        solve_markers(X, ids, rig)
        times.append(time.perf_counter() - t0)
    return {"frames": 1000, "markers": int(ids.size), "median_s": float(np.median(times)),
            "runs_s": [round(t, 3) for t in times]}


def main(model, takes, specs, cases: int, frames: int, seed: int, out, echo=print, progress: bool = True,
         time_it: bool = True, identity: bool = True) -> list[dict]:
    """Run the protocol, print the tables (medians over cases) and write ``solve.csv``, ``solve-identity.csv``
    (the actor-unknown rows, with ``identity``) and ``solve-summary.md``."""
    unknown = actor_unknown(model, takes, cases, frames, seed, progress) if identity else []
    rows = run(model, takes, specs, cases, frames, seed, progress)
    keys = ("weight_mae", "face_mm", "jitter", "jitter_truth", "ms_per_frame")
    table = []
    for cond in dict.fromkeys(r["condition"] for r in rows):
        for lay in LAYOUTS:
            for method in dict.fromkeys(r["method"] for r in rows):
                sel = [r for r in rows if r["condition"] == cond and r["layout"] == lay and r["method"] == method]
                if sel:
                    table.append([cond, lay, method, *(float(np.median([r[k] for r in sel])) for k in keys)])
    note = (f"{cases} cases x {frames} frames of real takes on random identities; medians over cases. "
            f"{machine_note()}.")
    if time_it:
        sp = speed(model)
        note += (f" Speed: {sp['frames']} frames x {sp['markers']} markers, default fitter: "
                 f"{sp['median_s']:.3f} s (median of {sp['runs_s']}).")
    report = Report(Path(out) if out else None, "solve", echo)
    report.csv(rows)
    text = format_table(["condition", "layout", "method", *keys], table)
    if unknown:
        report.csv(unknown, "identity")
        head, t2 = actor_unknown_table(unknown)
        text = ("The actor's identity unknown (sem-ls with smoothing, as `facegeom solve`): worst_mae is the worst "
                "case, vs_actor_max the worst case's weight error over the actor's own rig's, stuck the shapes "
                "held above 0.5 where the truth stays at or below 0.2, warned the solves whose residual gives the "
                "rig-does-not-fit warning.\n\n" + format_table(head, t2)
                + "\n\nThe actor's rig known (every fitter):\n\n" + text)
    report.summary(text, note)
    return rows
