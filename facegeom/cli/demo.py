"""``facegeom demo``: the product in about two minutes, on real data: pictures and animations to open.

The demo runs the same commands a user types (in this process, so the interpreter starts once) on the
example inputs ``facegeom data examples`` makes from the face data, and on two public heads shipped with the
package (``facegeom/data/heads``: a scanned head, CC BY 3.0, and a stylised character, CC0):

1. the example inputs (a face mesh and markers, a photo, a video, a C3D capture, a real Live Link take);
2. a face driven by 80 markers (``facegeom drive``);
3. a photograph fitted: landmarks found, identity, pose and expression (``facegeom detect``, ``facegeom fit``);
4. the scanned head given the 53 expressions (``facegeom transfer``);
5. the optical capture solved and played on the scanned head (``facegeom solve --character``);
6. the real take played on the stylised character (``facegeom animate --take --character``);
7. the video tracked onto the scanned head, with its preview (``facegeom track --character --preview``);
8. pictures of all of it (matplotlib, no display needed).

Every step prints a line as it starts (with the seconds since the demo started) and its own progress; the
last line names the pictures and files. The method comparisons are ``facegeom bench ...`` (``make bench``).
"""
from __future__ import annotations

import itertools
import time
from pathlib import Path

import click

HEADS = Path(__file__).resolve().parents[1] / "data" / "heads"
SCAN = HEADS / "lee_perry_smith.ply"
STYLISED = HEADS / "makehuman_stylised_arkit.npz"
SCAN_CREDIT = "Head: \"LPS Head\" by Infinite-Realities, CC BY 3.0; character: MakeHuman, CC0"

RESULT_KINDS = (("pictures", ("*.png",)), ("animations", ("*.glb",)), ("videos", ("*_preview.mp4",)),
                ("meshes", ("driven.ply", "photo_fit.obj")))
"""What the demo's last line lists, by kind: the file name patterns (in the output folder itself, not its inputs)."""


@click.command()
@click.option("--out", type=click.Path(file_okay=False), default="facegeom-demo", show_default=True,
              help="Folder for the demo's inputs, results and pictures (made if missing; the demo's own files "
                   "in it are rewritten).")
@click.pass_context
def demo(ctx, out):
    """The product in about two minutes on real data: a face driven by markers, a photo fitted, a capture, a
    real take and a video played on a scanned head and a stylised character; pictures and .glb files to open."""
    from facegeom.errors import InputError

    for p in (SCAN, STYLISED):
        if not p.is_file():
            raise InputError(f"{p}: the demo's head is missing from the installation (reinstall facegeom)")
    out = Path(out).resolve()
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: not a folder")
    started = time.time()
    t0 = time.perf_counter()
    data = ctx.obj.data if ctx.obj is not None else None

    def step(text: str) -> None:
        click.echo(f"\n[{time.perf_counter() - t0:6.1f} s] {text}", nl=True)

    def run(*args) -> None:
        from facegeom.cli.main import cli

        head = ["--data", str(data)] if data else []
        cli.main(args=head + [str(a) for a in args], prog_name="facegeom", standalone_mode=False)

    ex = out / "examples"
    step(f"example inputs from the face data -> {ex}")
    run("data", "examples", ex, "--force")
    step("a face driven by 80 markers: facegeom drive face.obj markers.csv")
    run("drive", ex / "face.obj", ex / "markers.csv", "-o", out / "driven.ply")
    missing = _missing_video_packages()
    step("a photograph: its 68 landmarks found, then identity, pose and expression fitted: facegeom fit face.jpg")
    if missing:
        click.echo(f"skipped: photos and video need {', '.join(missing)} (pip install 'facegeom[video]')")
    else:
        run("detect", ex / "face.jpg", "-o", out / "photo.pts")
        run("fit", ex / "face.jpg", "-o", out / "photo_fit.json", "--mesh-out", out / "photo_fit.obj")
    rig = out / "scanned_head_rig.npz"
    step(f"a scanned head ({SCAN.name}, 8,844 vertices, metres) given the 53 expressions: facegeom transfer "
         "(registration and deformation transfer; kept in the user cache, so the next run reuses it)")
    run("transfer", SCAN, "-o", rig)
    step("an optical capture (80 markers, mm, with head motion and lost samples) solved and played on the "
         "scanned head: facegeom solve capture.c3d --character")
    run("solve", ex / "capture.c3d", "--character", rig, "-o", out / "capture_on_head.glb")
    step("a real Live Link Face take played on a stylised character (an artist's rig): facegeom animate --take")
    run("animate", "--take", ex / "take.csv", "--character", STYLISED, "-o", out / "take_on_character.glb",
        )
    step("a video of a person tracked (no markers) and played on the scanned head: facegeom track --character")
    if missing:
        click.echo(f"skipped: photos and video need {', '.join(missing)} (pip install 'facegeom[video]')")
    else:
        run("track", ex / "clip.mp4", "--character", rig, "-o", out / "video_on_head.glb", "-o", out / "video.npz",
            "--preview", out / "video_preview.mp4")
    step("pictures")
    _pictures(out, ex, rig, video=not missing)
    click.echo(f"\n[{time.perf_counter() - t0:6.1f} s] done")
    click.echo(results_line(out, since=started))


def _missing_video_packages() -> list[str]:
    """The packages photos and video need (the ``video`` extra) that are not installed."""
    from importlib.util import find_spec

    return [name for name, module in (("PyAV", "av"), ("LiteRT", "ai_edge_litert")) if find_spec(module) is None]


def results_line(out: Path, since: float | None = None) -> str:
    """The demo's last line: where its results are, and the main files there (paths relative to ``out``).

    Parameters
    ----------
    out : Path
        The demo's output folder.
    since : float, optional
        Only files written at or after this time (``time.time()``): not what an earlier run left.

    Returns
    -------
    str
        ``results in <folder>: pictures a, b; animations c; ...`` (one line).
    """
    out = Path(out)
    parts = []
    for kind, patterns in RESULT_KINDS:
        found = sorted({p for pat in patterns for p in out.glob(pat)
                        if p.is_file() and (since is None or p.stat().st_mtime >= since - 1.0)})
        if found:
            parts.append(f"{kind} {', '.join(str(p.relative_to(out)) for p in found)}")
    return f"results in {out}: " + ("; ".join(parts) if parts else "no files written")


def _peaks(W, k: int) -> list[int]:
    """``k`` frames of the weight curves ``W (T, K)`` spread over the take, each the most expressive near its place."""
    import numpy as np

    T = W.shape[0]
    e = np.abs(W).sum(axis=1)
    edges = np.linspace(0, T, k + 1).astype(int)
    return [int(a + np.argmax(e[a:b])) for a, b in itertools.pairwise(edges) if b > a]


def _rig_frames(rig_path: Path, W, names, frames):
    """The rig's meshes at ``frames`` of the curves ``W`` (columns ``names``; names the rig lacks are skipped)."""
    import numpy as np

    from facegeom.model import BlendshapeRig

    rig = BlendshapeRig.from_npz(rig_path)
    index = [(k, rig.names.index(n)) for k, n in enumerate(names) if n in rig.names]
    cols, shapes = [k for k, _ in index], [j for _, j in index]
    return rig, [rig.neutral + np.tensordot(W[t, cols], rig.deltas[shapes], axes=1) for t in frames]


def _pictures(out: Path, ex: Path, rig_path: Path, video: bool = True) -> None:
    """``driven.png``, ``photo.png`` and ``performances.png`` from the demo's results (without ``video``: no
    photo picture and no video row)."""
    import matplotlib

    matplotlib.use("Agg")

    from facegeom.io import read_mesh
    from facegeom.io.markers import read_markers
    from facegeom.io.render import SKIN, SKIN_B, draw_mesh, figure, frame_axes, rotation, save

    # the face driven by its markers
    V0, F = read_mesh(ex / "face.obj")
    V1, _ = read_mesh(out / "driven.ply")
    ids, P = read_markers(ex / "markers.csv")
    R = rotation(-15, 0)
    fig, axes = figure(2, width=10, height=5.4)
    for ax, V, title, color in ((axes[0, 0], V0, "neutral face and its 80 markers", SKIN),
                                (axes[0, 1], V1, "driven by the moved markers (tangent framework)", SKIN_B)):
        Q = draw_mesh(ax, V, F, R, color=color)
        M = (P if V is V1 else V0[ids]) @ R.T
        ax.scatter(M[:, 0], M[:, 1], s=7, c="#d6336c", zorder=3)
        frame_axes(ax, Q, title=title)
    fig.tight_layout()
    save(fig, out / "driven.png")
    click.echo(f"  {out / 'driven.png'}")

    if video:
        _photo_picture(out, ex)
    _performances_picture(out, rig_path, video)


def _photo_picture(out: Path, ex: Path) -> None:
    """``photo.png``: the photograph with the landmarks found, and the fitted face."""
    import matplotlib.image as mpimg

    from facegeom.io import read_mesh
    from facegeom.io.fitfiles import read_pts
    from facegeom.io.render import SKIN, draw_mesh, figure, frame_axes, head_only, rotation, save

    img = mpimg.imread(ex / "face.jpg")
    pts = read_pts(out / "photo.pts")
    Vf, Ff = read_mesh(out / "photo_fit.obj")
    fig, axes = figure(2, width=10, height=4.2)
    axes[0, 0].imshow(img)
    axes[0, 0].scatter(pts[:, 0], pts[:, 1], s=6, c="#1c7ed6")
    axes[0, 0].set_title("the photograph and the 68 landmarks found", fontsize=11)
    axes[0, 0].axis("off")
    Q = draw_mesh(axes[0, 1], Vf, Ff, rotation(-15, 0), color=SKIN)
    frame_axes(axes[0, 1], Q, title="the fitted face: identity, expression", keep=head_only(Vf))
    fig.tight_layout()
    save(fig, out / "photo.png")
    click.echo(f"  {out / 'photo.png'}")



def _performances_picture(out: Path, rig_path: Path, video: bool) -> None:
    """``performances.png``: four frames of each performance on its character."""
    import numpy as np

    from facegeom.io.gltf import read_glb_animation
    from facegeom.io.render import SKIN, SKIN_B, credit, draw_mesh, figure, frame_axes, head_only, rotation, save

    rows = []
    cap = read_glb_animation(out / "capture_on_head.glb")
    rows.append(("capture on the scanned head", rig_path, cap.weights, cap.names))
    take = read_glb_animation(out / "take_on_character.glb")
    rows.append(("real take on the stylised character", STYLISED, take.weights, take.names))
    if video:
        vid = np.load(out / "video.npz", allow_pickle=False)
        rows.append(("video on the scanned head", rig_path, vid["weights"], [str(n) for n in vid["names"]]))
    k = 4
    fig, axes = figure(k, rows=len(rows), width=14, height=4.0 * len(rows))
    R = rotation(-20, 5)
    for r, (title, path, W, names) in enumerate(rows):
        click.echo(f"  drawing the {title}")
        frames = _peaks(np.asarray(W), k)
        rig, meshes = _rig_frames(path, np.asarray(W), list(names), frames)
        keep = head_only(rig.neutral)
        for c, (t, V) in enumerate(zip(frames, meshes)):
            Q = draw_mesh(axes[r, c], V, rig.triangles, R, color=SKIN_B if r != 1 else SKIN)
            frame_axes(axes[r, c], Q, title=f"{title}, frame {t}" if c == 0 else f"frame {t}", keep=keep)
        for c in range(len(frames), k):
            axes[r, c].axis("off")
    credit(fig, SCAN_CREDIT)
    fig.tight_layout(rect=(0, 0.02, 1, 1))
    save(fig, out / "performances.png")
    click.echo(f"  {out / 'performances.png'}")
