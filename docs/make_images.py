"""Generate the documentation's pictures into ``docs/images/`` from the face data (``make docs`` runs it).

Usage::

    python docs/make_images.py [--out docs/images] [--only NAME,...] [--force]

Every picture is made by facegeom itself, on the inputs ``facegeom data examples`` writes from the face
data (ICT-FaceKit) and the public heads of ``tests/data/heads``, with fixed seeds, then drawn with
matplotlib (Agg, no display):

==================  ==========================================================================
``driven-face.png``  ``facegeom drive``: the neutral face and the face driven by 80 markers
``retarget.png``     ``facegeom.pipelines.animate``: actor frames above the character's
``fitted-photo.png`` ``facegeom fit``: 2-D landmarks and the fitted face projected over them
``character.png``    ``facegeom transfer`` + ``facegeom animate --character``: a scanned head
                     playing a Live Link take
``transfer.png``     ``facegeom transfer``: the ICT rig's expressions carried onto that head
``cleanup.png``      ``facegeom decimate``: a scan before and after decimation
``tracked-clip.png`` ``facegeom track --preview``: frames of the example video with the landmarks found and
                     the fitted face drawn over them
``tracked-character.png`` ``facegeom track --character``: the scanned head performing the example video
``viewer.png``       ``facegeom view drive --screenshot`` (polyscope, headless); a matplotlib
                     render of the same scene when no GL context can start
==================  ==========================================================================

The pictures are derived from the face data and are never committed (``docs/images/`` is ignored).
A stamp file records what made them (this script, facegeom's source, the face data); when nothing
changed and every picture is there, the script says so and stops (``--force`` redraws).
"""
from __future__ import annotations

import argparse
import hashlib
import itertools
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from facegeom.io.render import (
    SKIN,
    SKIN_B,
    credit,
    draw_mesh,
    figure,
    frame_axes,
    head_only,
    rotation,
    save,
    visible,
)

ROOT = Path(__file__).resolve().parents[1]
HEADS = ROOT / "tests" / "data" / "heads"
SCAN = HEADS / "lee_perry_smith.ply"  # "LPS Head", Infinite-Realities, CC BY 3.0 (tests/data/heads/SOURCES.md)
SCAN_CREDIT = "Head: \"LPS Head\" by Infinite-Realities, CC BY 3.0"
PICTURES = ("driven-face", "retarget", "fitted-photo", "character", "transfer", "cleanup", "viewer", "tracked-clip",
            "tracked-character")
STAMP = ".stamp.json"
MARKER = "#d6336c"
TARGET = "#1c7ed6"


# --------------------------------------------------------------------------- running facegeom

def facegeom(*args, cwd: Path) -> str:
    """Run ``facegeom ARGS`` in ``cwd`` with this interpreter; its output, or exit naming the command."""
    cmd = [sys.executable, "-m", "facegeom", *map(str, args)]
    proc = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, check=False)
    if proc.returncode:
        sys.exit(f"make_images: `facegeom {' '.join(map(str, args))}` failed ({proc.returncode}):\n"
                 f"{proc.stdout}{proc.stderr}")
    return proc.stdout


def start_facegeom(*args, cwd: Path) -> subprocess.Popen:
    """Start ``facegeom ARGS`` in the background (the head transfer, the slowest step)."""
    cmd = [sys.executable, "-m", "facegeom", *map(str, args)]
    return subprocess.Popen(cmd, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def wait(proc: subprocess.Popen, what: str) -> None:
    out, _ = proc.communicate()
    if proc.returncode:
        sys.exit(f"make_images: {what} failed ({proc.returncode}):\n{out}")


# --------------------------------------------------------------------------- drawing meshes

# --------------------------------------------------------------------------- the pictures

def driven_face(ex: Path, out: Path) -> None:
    """Neutral face with its markers | the face driven by the moved markers, coloured by displacement."""
    from facegeom.io import read_markers, read_mesh

    facegeom("drive", "face.obj", "markers.csv", "-o", "driven.ply", cwd=ex)
    V0, F = read_mesh(ex / "face.obj")
    V1, _ = read_mesh(ex / "driven.ply")
    ids, X = read_markers(ex / "markers.csv")
    R = rotation(-25, 5)
    disp = np.linalg.norm(V1 - V0, axis=1) * 10.0  # cm -> mm
    vmax = float(np.percentile(disp, 99.5))
    fig, axes = figure(2, width=12, height=6.6)
    show = visible(V0, F, R, ids)
    P = draw_mesh(axes[0, 0], V0, F, R)
    axes[0, 0].scatter(*(V0[ids[show]] @ R.T)[:, :2].T, s=9, c=MARKER, zorder=3, linewidths=0)
    frame_axes(axes[0, 0], P, title="neutral face and its 80 markers")
    P = draw_mesh(axes[0, 1], V1, F, R, values=disp, cmap="magma", vmax=vmax)
    axes[0, 1].scatter(*(X[show] @ R.T)[:, :2].T, s=9, c=TARGET, zorder=3, linewidths=0)
    frame_axes(axes[0, 1], P, title="driven by the moved markers (tangent framework)")
    import matplotlib as mpl

    sm = mpl.cm.ScalarMappable(norm=mpl.colors.Normalize(0, vmax), cmap="magma")
    cb = fig.colorbar(sm, ax=axes[0, 1], fraction=0.035, pad=0.01)
    cb.set_label("displacement from the neutral (mm)")
    fig.tight_layout()
    save(fig, out)


def _peaks(W: np.ndarray, k: int) -> list[int]:
    """``k`` frames of ``W (T, E)``: the most intense frame of each of ``k`` equal parts of the take."""
    T = W.shape[0]
    edges = np.linspace(0, T, k + 1).astype(int)
    s = W.sum(axis=1)
    return [int(a + np.argmax(s[a:b])) for a, b in itertools.pairwise(edges)]


def retarget(ex: Path, out: Path, model) -> None:
    """Actor frames (a take on one identity) above the character's retargeted, driven frames."""
    from facegeom.model import performance
    from facegeom.pipelines.animate import animate_take
    from facegeom.registry import create

    anim, seq, ids = animate_take(model, ex / "take.csv", 0, 120, 10, 0,
                                  lambda: create("retargeter", "tangent"), lambda: create("deformer", "tangent"))
    frames = _peaks(seq.weights, 5)
    actor = performance.actor_faces(model, seq)
    F = model.triangles
    R = rotation(-20, 5)
    fig, axes = figure(len(frames), 2, width=15, height=7.4)
    for j, t in enumerate(frames):
        for row, (V, M, who, col) in enumerate(((actor[t], seq.source[t], "actor", SKIN),
                                                (anim.vertices[t], anim.markers[t], "character", SKIN_B))):
            ax = axes[row, j]
            P = draw_mesh(ax, V, F, R, color=col)
            show = visible(V, F, R, ids)
            ax.scatter(*(M[show] @ R.T)[:, :2].T, s=5, c=MARKER if row == 0 else TARGET, zorder=3, linewidths=0)
            frame_axes(ax, P, title=f"{who}, frame {t}")
    fig.text(0.01, 0.75, "actor", rotation=90, fontsize=13, va="center")
    fig.text(0.01, 0.27, "character", rotation=90, fontsize=13, va="center")
    fig.tight_layout(rect=(0.02, 0, 1, 1))
    save(fig, out)


def fitted_photo(ex: Path, out: Path) -> None:
    """Observed 2-D landmarks | the fitted face projected by the fitted camera pose, landmarks on it."""
    from facegeom.io import read_landmarks, read_mesh
    from facegeom.model import PinholeCamera

    facegeom("fit", "landmarks.csv", "--focal", 1000, "--cx", 320, "--cy", 240, "--identity", "-o", "lm.json",
             "--mesh-out", "lm_fit.obj", cwd=ex)
    V, F = read_mesh(ex / "lm_fit.obj")
    pose = json.loads((ex / "lm.json").read_text())["pose"]
    cam = PinholeCamera(1000.0, 320.0, 240.0, np.array(pose["R"]), np.array(pose["t"]))
    lm = read_landmarks(ex / "landmarks.csv")
    ids, uv = np.asarray(lm[0]), np.asarray(lm[1])
    pix = cam.project(V)
    depth = -cam.to_camera(V)[:, 2]
    fitted = pix[ids]
    fig, axes = figure(2, width=12, height=5.6)
    from matplotlib.patches import Rectangle

    lo, hi = pix.min(axis=0), pix.max(axis=0)
    c, half = (lo + hi) / 2, 0.62 * (hi - lo).max()
    for ax in axes[0]:  # the photo's frame, zoomed on the face
        ax.add_patch(Rectangle((0, 0), 640, 480, fc="#f4f4f2", ec="#999999"))
        ax.set_xlim(c[0] - 1.25 * half, c[0] + 1.25 * half)
        ax.set_ylim(c[1] + half, c[1] - half)
        ax.set_aspect("equal")
        ax.axis("off")
    axes[0, 0].scatter(*uv.T, s=14, c=MARKER, zorder=3, linewidths=0)
    axes[0, 0].set_title("input: 68 landmarks of a 640 x 480 photo (pixels)", fontsize=11)
    draw_mesh(axes[0, 1], np.c_[pix, depth], F, image_coords=True)
    axes[0, 1].scatter(*uv.T, s=18, facecolors="none", edgecolors=MARKER, zorder=3, linewidths=1.0,
                       label="input landmarks")
    axes[0, 1].scatter(*fitted.T, s=10, c=TARGET, marker="x", zorder=4, linewidths=1.0,
                       label="fitted face's landmarks")
    axes[0, 1].legend(loc="lower right", fontsize=9, frameon=True)
    err = float(np.linalg.norm(fitted - uv, axis=1).mean())
    axes[0, 1].set_title(f"fitted identity, expression and pose (mean {err:.2f} px)", fontsize=11)
    fig.tight_layout()
    save(fig, out)


def _rig(path: Path):
    d = np.load(path, allow_pickle=False)
    return d["neutral"], d["deltas"], [str(x) for x in d["names"]], d["triangles"]


def character(ex: Path, out: Path, rig_path: Path) -> None:
    """The scanned head, rigged by ``facegeom transfer``, playing the example Live Link take."""
    facegeom("animate", "--take", "take.csv", "--character", rig_path, "-o", "lps_anim.npz", cwd=ex)
    neutral, deltas, names, F = _rig(rig_path)
    a = np.load(ex / "lps_anim.npz", allow_pickle=False)
    W, anim_names = a["weights"], [str(x) for x in a["names"]]
    index = [names.index(n) for n in anim_names]
    frames = _peaks(W, 5)
    R = rotation(-20, 5)
    fig, axes = figure(len(frames), width=16, height=4.6)
    for ax, t in zip(axes[0], frames):
        V = neutral + np.tensordot(W[t], deltas[index], axes=1)
        P = draw_mesh(ax, V, F, R, color=SKIN_B)
        frame_axes(ax, P, title=f"take frame {int(a['frames'][t])}", keep=head_only(neutral))
    credit(fig, SCAN_CREDIT)
    fig.tight_layout(rect=(0, 0.03, 1, 0.95))
    save(fig, out)


def tracked_clip(ex: Path, out: Path) -> None:
    """Four frames of ``track --preview`` on the example video: the 68 landmarks found, the fitted face drawn."""
    import matplotlib.pyplot as plt

    from facegeom.io.video import open_video

    facegeom("track", "clip.mp4", "-o", "clip.npz", "--preview", "clip_preview.mp4", cwd=ex)
    W = np.load(ex / "clip.npz", allow_pickle=False)["weights"]
    frames = sorted(_peaks(W, 4))
    images = {}
    with open_video(ex / "clip_preview.mp4") as video:
        for f in video:
            if f.index in frames:
                images[f.index] = f.image
    fig, axes = plt.subplots(1, len(frames), figsize=(16, 3.3))
    for ax, t in zip(axes, frames):
        ax.imshow(images[t])
        ax.set_title(f"frame {t}")
        ax.axis("off")
    fig.tight_layout()
    save(fig, out)


def tracked_character(ex: Path, out: Path, rig_path: Path) -> None:
    """The scanned head, rigged by ``facegeom transfer``, performing the example video: the tracked weights
    (``track``'s, as ``track --character`` plays them on the rig) on the rig's shapes. The video is tracked once:
    :func:`tracked_clip`'s ``clip.npz`` is used when it ran."""
    if not (ex / "clip.npz").is_file():
        facegeom("track", "clip.mp4", "-o", "clip.npz", cwd=ex)
    neutral, deltas, names, F = _rig(rig_path)
    a = np.load(ex / "clip.npz", allow_pickle=False)
    W, anim_names = a["weights"], [str(x) for x in a["names"]]
    index = [names.index(n) if n in names else -1 for n in anim_names]
    frames = sorted(_peaks(W, 4))
    R = rotation(-20, 5)
    fig, axes = figure(len(frames), width=16, height=4.6)
    for ax, t in zip(axes[0], frames):
        V = neutral.copy()
        for k, j in enumerate(index):
            if j >= 0:
                V = V + W[t, k] * deltas[j]
        P = draw_mesh(ax, V, F, R, color=SKIN_B)
        frame_axes(ax, P, title=f"video frame {t}", keep=head_only(neutral))
    credit(fig, SCAN_CREDIT)
    fig.tight_layout(rect=(0, 0.03, 1, 0.95))
    save(fig, out)


TRANSFER_SHAPES = (("neutral", ()), ("jaw open", ("jawOpen",)), ("smile", ("mouthSmile_L", "mouthSmile_R")),
                   ("brows up", ("browInnerUp_L", "browInnerUp_R", "browOuterUp_L", "browOuterUp_R")),
                   ("pucker", ("mouthPucker",)), ("blink", ("eyeBlink_L", "eyeBlink_R")))


def transfer(out: Path, model, rig_path: Path) -> None:
    """A few ICT expression shapes (top) and the same shapes transferred onto the scanned head (bottom)."""
    neutral, deltas, names, F = _rig(rig_path)
    ict = model.neutral
    R = rotation(-20, 5)
    fig, axes = figure(len(TRANSFER_SHAPES), 2, width=16, height=6.8)
    for j, (label, shapes) in enumerate(TRANSFER_SHAPES):
        Vi = ict + sum((model.expression_deltas[model.expression_index(s)] for s in shapes), np.zeros_like(ict))
        Vh = neutral + sum((deltas[names.index(s)] for s in shapes), np.zeros_like(neutral))
        P = draw_mesh(axes[0, j], Vi, model.triangles, R)
        frame_axes(axes[0, j], P, title=f"ICT: {label}")
        P = draw_mesh(axes[1, j], Vh, F, R, color=SKIN_B)
        frame_axes(axes[1, j], P, title=f"head: {label}", keep=head_only(neutral))
    credit(fig, SCAN_CREDIT)
    fig.tight_layout(rect=(0, 0.03, 1, 1))
    save(fig, out)


def cleanup(ex: Path, out: Path) -> None:
    """The scanned head before and after ``facegeom decimate`` to 2,000 vertices (wireframe over shading)."""
    from facegeom.io import read_mesh

    facegeom("decimate", SCAN, "scan-2k.ply", "--vertices", 2000, "--preserve-boundary", cwd=ex)
    V0, F0 = read_mesh(SCAN)
    V1, F1 = read_mesh(ex / "scan-2k.ply")
    R = rotation(-25, 5)
    fig, axes = figure(2, width=12, height=6.6)
    for ax, V, F, what in ((axes[0, 0], V0, F0, "scan"), (axes[0, 1], V1, F1, "decimated")):
        P = draw_mesh(ax, V, F, R, edges=(0.15, 0.15, 0.15, 0.55))
        frame_axes(ax, P, title=f"{what}: {len(V):,} vertices, {len(F):,} triangles")
    credit(fig, SCAN_CREDIT)
    fig.tight_layout(rect=(0, 0.03, 1, 1))
    save(fig, out)


def viewer(ex: Path, out: Path, model) -> None:
    """``facegeom view drive`` rendered headless; without a GL context, the same scene drawn with matplotlib."""
    cmd = [sys.executable, "-m", "facegeom", "view", "drive", "--screenshot", str(out), "--size", "1600x900"]
    try:
        proc = subprocess.run(cmd, cwd=ex, capture_output=True, text=True, timeout=120, check=False)
    except subprocess.TimeoutExpired:
        reason = "no picture after 120 s"
    else:
        if proc.returncode == 0 and out.is_file() and out.stat().st_size > 0:
            return
        lines = (proc.stderr or proc.stdout).strip().splitlines()
        reason = lines[-1] if lines else f"exit status {proc.returncode}"
    print(f"  the polyscope viewer could not render ({reason}); drawing the same scene with matplotlib instead "
          f"into {out.name}", flush=True)
    _viewer_fallback(out, model)


def _viewer_fallback(out: Path, model) -> None:
    """The drive view's scene (source | deformers | true target, error colours) drawn with matplotlib."""
    from facegeom.model import layout
    from facegeom.model.expressions import named_expression
    from facegeom.registry import create

    identity = model.random_identity(0)
    source = model.face(identity)
    target = model.face(identity, named_expression("happiness", 0.9))
    ids = layout(model, "ict80")
    F = model.triangles
    panels = [("source", source)]
    for name in ("rbf", "biharmonic", "tangent"):
        panels.append((name, create("deformer", name).fit(source, F, ids).deform(target[ids])))
    panels.append(("target", target))
    R = rotation(0, 0)
    fig, axes = figure(len(panels), width=16, height=5.2)
    for ax, (name, V) in zip(axes[0], panels):
        err = np.linalg.norm(V - target, axis=1) * 10.0
        P = draw_mesh(ax, V, F, R, values=err, vmax=5.0)
        ax.scatter(*(target[ids] @ R.T)[:, :2].T, s=4, c="#ffd43b", zorder=3, linewidths=0)
        frame_axes(ax, P, title=name)
    fig.suptitle("distance to the true target (0-5 mm); drawn without the viewer (no GL context)", fontsize=11)
    fig.tight_layout()
    save(fig, out)


# --------------------------------------------------------------------------- cache stamp and main

def stamp() -> str:
    """What the pictures depend on: this script, facegeom's source, the heads and the face data's files."""
    from facegeom.model import locate_data

    h = hashlib.sha256(Path(__file__).read_bytes())
    for folder in ("facegeom", "baselines", "viewer"):
        for p in sorted((ROOT / folder).rglob("*.py")):
            h.update(p.relative_to(ROOT).as_posix().encode())
            h.update(p.read_bytes())
    for p in sorted(HEADS.iterdir()):
        st = p.stat()
        h.update(f"{p.name}:{st.st_size}:{st.st_mtime_ns}".encode())
    data = locate_data()
    st = data.stat()
    h.update(f"{data}:{st.st_size}:{st.st_mtime_ns}".encode())
    return h.hexdigest()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python docs/make_images.py", description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "images", help="output folder (default: docs/images)")
    ap.add_argument("--only", default=",".join(PICTURES), help=f"comma-separated subset of {', '.join(PICTURES)}")
    ap.add_argument("--force", action="store_true", help="redraw even when the pictures are up to date")
    args = ap.parse_args(argv)
    names = [x.strip() for x in args.only.split(",") if x.strip()]
    bad = [x for x in names if x not in PICTURES]
    if bad or not names:
        ap.error(f"--only: unknown picture {bad[0] if bad else '(empty)'!r}; choose from {', '.join(PICTURES)}")

    os.environ.setdefault("MPLBACKEND", "Agg")
    import matplotlib

    matplotlib.use("Agg")
    out = args.out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    key = stamp()
    stamp_path = out / STAMP
    done = json.loads(stamp_path.read_text()) if stamp_path.is_file() else {}
    todo = [n for n in names if args.force or done.get(n) != key or not (out / f"{n}.png").is_file()]
    if not todo:
        print(f"make_images: {len(names)} pictures in {out} are up to date (--force redraws)")
        return 0

    from facegeom.model import load_face_model

    t_all = time.perf_counter()
    model = load_face_model()
    with tempfile.TemporaryDirectory(prefix="facegeom-docs-") as tmp:
        ex = Path(tmp) / "examples"
        print(f"make_images: {len(todo)} pictures into {out}", flush=True)
        facegeom("data", "examples", ex, cwd=Path(tmp))
        rig = ex / "head_rig.npz"
        transferring = None
        if {"character", "transfer", "tracked-character"} & set(todo):  # the slowest step, in the background
            transferring = start_facegeom("transfer", SCAN, "-o", rig, cwd=ex)
        steps = {
            "driven-face": lambda p: driven_face(ex, p),
            "retarget": lambda p: retarget(ex, p, model),
            "fitted-photo": lambda p: fitted_photo(ex, p),
            "cleanup": lambda p: cleanup(ex, p),
            "viewer": lambda p: viewer(ex, p, model),
            "transfer": lambda p: transfer(p, model, rig),
            "character": lambda p: character(ex, p, rig),
            "tracked-clip": lambda p: tracked_clip(ex, p),
            "tracked-character": lambda p: tracked_character(ex, p, rig),
        }
        try:
            for name in sorted(todo, key=list(steps).index):
                if name in ("transfer", "character", "tracked-character") and transferring is not None:
                    print("  waiting for `facegeom transfer` of the scanned head ...", flush=True)
                    wait(transferring, f"`facegeom transfer {SCAN.name}`")
                    transferring = None
                t = time.perf_counter()
                path = out / f"{name}.png"
                steps[name](path)
                done[name] = key
                stamp_path.write_text(json.dumps(done, indent=1, sort_keys=True))
                print(f"  {path.name} ({time.perf_counter() - t:.1f} s)", flush=True)
        finally:
            if transferring is not None and transferring.poll() is None:  # a step failed: stop the transfer
                transferring.kill()
                transferring.wait()
    print(f"make_images: done in {time.perf_counter() - t_all:.1f} s", flush=True)
    return 0


if __name__ == "__main__":
    from facegeom.errors import FacegeomError

    try:
        raise SystemExit(main())
    except FacegeomError as exc:  # no face data, an unreadable input: one line, no traceback
        raise SystemExit(f"make_images: {exc}") from None
