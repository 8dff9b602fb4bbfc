"""``facegeom demo``: the main job in one command (info, the three benchmarks, a batch run and the viewer)."""
from __future__ import annotations

from pathlib import Path

import click

from facegeom.cli.bench import bench_drive, bench_fit, bench_retarget
from facegeom.errors import FacegeomError


@click.command()
@click.option("--cases", default=5, show_default=True, type=click.IntRange(1, 1000))
@click.option("--out", type=click.Path(file_okay=False), default="bench-out/demo", show_default=True)
@click.pass_context
def demo(ctx, cases, out):
    """The main job: face driving, expression retargeting and blendshape fitting compared on a few real faces."""
    import time

    started = time.time()
    root = ctx.find_root()  # `info` lives in facegeom.cli.main, which imports this module
    ctx.invoke(root.command.get_command(root, "info"))
    click.echo("")
    ctx.invoke(bench_drive, cases=cases, seed=0, methods="all", layout_name="ict80", layout_seed=0, out=out,
               no_plot=False, quiet=False)
    click.echo("")
    from facegeom.model import default_takes_path

    have_takes = default_takes_path().is_dir()
    ctx.invoke(bench_retarget, sequences=cases, frames=100, seed=0, methods="copy;rbf;tangent", labels="10,20",
               takes_path=None, synthetic_only=not have_takes, layout_name="ict80", layout_seed=0,
               out=str(Path(out) / "retarget"), no_plot=False, quiet=False)
    click.echo("")
    ctx.invoke(bench_fit, cases=cases, seed=0, methods="sem-ls;sem;sem+=sem:clamp=true,stop=ric;l1reg;l2reg;pcadel",
               experiments="landmarks,meshes", noise_px=1.0, cloud_cases=1, samplings=1, points=30000,
               take_path=None, takes_path=None, start=0, frames=300, out=str(Path(out) / "fit"), no_plot=False,
               quiet=False)
    click.echo("")
    _demo_batch(ctx.obj.face_model(), Path(out) / "batch")
    click.echo("")
    _demo_capture(ctx, Path(out) / "capture")
    click.echo("")
    _demo_viewer(obj_model=ctx.obj.face_model(), path=Path(out) / "view-drive.png")
    click.echo("")
    click.echo(results_line(Path(out), since=started))


RESULT_KINDS = (("summaries", ("*-summary.md", "batch-summary.csv")), ("images", ("*.png",)),
                ("animation", ("*.glb",)))
"""What the demo's last line lists, by kind: the file name patterns (searched in the whole output folder)."""


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
        ``results in <folder>: summaries a, b; images c; animation d`` (one line).
    """
    out = Path(out)
    parts = []
    for kind, patterns in RESULT_KINDS:
        found = sorted({p for pat in patterns for p in out.rglob(pat)
                        if p.is_file() and (since is None or p.stat().st_mtime >= since - 1.0)},
                       key=lambda p: (len(p.relative_to(out).parts), str(p)))
        if found:
            parts.append(f"{kind} {', '.join(str(p.relative_to(out)) for p in found)}")
    return f"results in {out.resolve()}: " + ("; ".join(parts) if parts else "no files written")


def _demo_batch(model, folder: Path, count: int = 128) -> None:
    """The demo's batch step: SEM fits of ``count`` landmark files on a local Dask cluster, with a summary."""
    import shutil

    import numpy as np

    from facegeom.bench.batch import CX, CY, FOCAL, make_landmark_inputs
    from facegeom.pipelines.batch import job_from_dict, run_job

    folder = Path(folder).resolve()
    shutil.rmtree(folder, ignore_errors=True)  # generated here, fitted again on every demo
    click.echo(f"batch: {count} landmark files (random expressions, random head pose, 1 px noise) fitted by "
               f"sem-ls (the default fitter) on a local Dask cluster")
    lm, truth = make_landmark_inputs(model, folder / "inputs", count, seed=11)
    job = job_from_dict({"operation": "fit", "method": "sem-ls", "inputs": str(lm), "output": str(folder / "fit"),
                         "truth": str(truth / "{stem}.json"),
                         "shared": {"focal": FOCAL, "cx": CX, "cy": CY}, "data": str(model.path)},
                        base=folder, source="<demo batch job>")
    res = run_job(job, echo=click.echo)
    err = [float(r["err_mean"]) * 10 for r in res.rows if r["status"] == "ok"]
    c = res.counts
    click.echo(f"{c['ok']} ok, {c['failed']} failed in {res.seconds:.1f} s; median face error against the truth "
               f"{np.median(err):.2f} mm -> {res.summary}")


def _demo_capture(ctx, folder: Path, frames: int = 300) -> None:
    """The demo's capture step: a real take as an 80-marker C3D (mm, noise, head motion) solved to a ``.glb``."""
    import numpy as np

    from facegeom.bench.solve import make_sequence
    from facegeom.cli.solve import solve_cmd
    from facegeom.io.c3d import write_c3d
    from facegeom.io.gltf import read_glb_animation
    from facegeom.io.takes import find_takes, ict_weights, read_take
    from facegeom.model import BlendshapeRig, locate_takes
    from facegeom.model.layouts import ict80
    from facegeom.pipelines.solve import take_fps

    model = ctx.obj.face_model()
    rig = BlendshapeRig.from_face_model(model)
    rng = np.random.default_rng(3)
    fps = 60.0
    try:
        take = read_take(find_takes(locate_takes(None))[0])
        W = np.clip(ict_weights(take, rig.names)[:frames], 0.0, 1.0)
        fps = take_fps(take)
        what = f"take {Path(take.path).name}"
    except FacegeomError:  # no takes on this machine: a synthetic performance instead
        s = np.linspace(0.0, 1.0, frames)[:, None]
        W = np.clip(0.5 + 0.5 * np.sin(2 * np.pi * (s * rng.uniform(0.5, 3, rig.n_shapes) + rng.random(rig.n_shapes))),
                    0, 1) * (rng.random(rig.n_shapes) < 0.2)
        what = "a synthetic performance"
    ids = ict80(model)
    X, _, _ = make_sequence(rig, ids, W, noise=0.05, lost=0.01, rng=rng)  # 0.5 mm noise, 1 % markers lost
    folder.mkdir(parents=True, exist_ok=True)
    c3d = write_c3d(folder / "capture.c3d", X * 10.0, [f"v{i}" for i in ids], fps=fps, unit="mm")
    click.echo(f"capture: {what}, {W.shape[0]} frames, as an 80-marker optical capture ({c3d}: mm, head motion, "
               "0.5 mm noise, 1 % markers lost) solved onto the ICT rig")
    glb = folder / "capture.glb"
    ctx.invoke(solve_cmd, capture=str(c3d), rig_path=None, output=str(glb), fitter="sem-ls", params=(),
               markers=None, smooth="auto")
    back = read_glb_animation(glb)
    click.echo(f"weight error against the truth {np.abs(back.weights - W).mean():.4f} (mean abs); open {glb} in any "
               "glTF viewer (Blender, three.js editor, https://gltf-viewer.donmccurdy.com)")


def _demo_viewer(obj_model, path: Path) -> None:
    """The demo's last step: the face-driving comparison as a PNG; the viewer itself when a display is present."""
    try:
        from facegeom.viewer.drive import DriveView
    except ImportError as exc:  # polyscope missing: the tables above are the demo's result
        click.echo(f"viewer skipped ({exc})")
        return
    view = DriveView(obj_model, "rbf;laplacian;biharmonic;tangent", seed=0, expression="happiness", intensity=0.9,
                     layout_name="ict80", layout_seed=0, bench_case=None)
    try:
        view.run(screenshot=str(path), echo=click.echo, show=True)
    except FacegeomError:
        raise
    except Exception as exc:  # noqa: BLE001 - no OpenGL/EGL on this machine: say so, keep the tables
        click.echo(f"viewer screenshot skipped: could not render headless here ({type(exc).__name__}: {exc}); "
                   "see the README's viewer section for the system packages EGL needs")

