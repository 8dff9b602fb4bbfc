"""The ``facegeom`` command line (also ``python -m facegeom``).

User mistakes (bad files, bad arguments, missing data) print one line on
stderr, ``facegeom: error: ...``, and exit with status 2; no traceback.
"""
from __future__ import annotations

import platform
import sys
import time
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import click

from facegeom import __version__
from facegeom.cli.flags import as_flags
from facegeom.errors import FacegeomError

DEPENDENCIES = ("numpy", "scipy", "libigl", "pymeshlab", "polyscope", "click", "tqdm", "matplotlib", "cholespy")


class _Context:
    def __init__(self, data):
        self.data = data

    def face_model(self):
        from facegeom.model import load_face_model

        return load_face_model(self.data)


@click.group(context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(__version__, prog_name="facegeom")
@click.option("--data", "data", type=click.Path(), default=None, envvar=None,
              help="Face data bundle (folder or .npz). Default: $FACEGEOM_DATA, "
                   "else ../shared/data/ict-face-light next to the repository.")
@click.pass_context
def cli(ctx, data):
    """facegeom: face driving, expression retargeting and blendshape fitting on libigl."""
    ctx.obj = _Context(data)


def _pkg_version(name: str) -> str:
    try:
        return version(name)
    except PackageNotFoundError:
        return "not installed"


@cli.command()
@click.pass_obj
def info(obj: _Context):
    """Versions, where the face data was found and what it holds."""
    from facegeom.model import locate_data

    path = locate_data(obj.data)
    model = obj.face_model()
    click.echo(f"facegeom {__version__}  (Python {platform.python_version()}, {platform.machine()})")
    for dep in DEPENDENCIES:
        click.echo(f"  {dep:<11} {_pkg_version(dep)}")
    click.echo(f"face data: {path}")
    for k, v in model.summary().items():
        if k != "path":
            click.echo(f"  {k:<18} {v}")
    click.echo(f"  expression names   {', '.join(model.expression_names[:6])}, ... ({model.n_expressions})")


@cli.command()
@click.option("--kind", type=click.Choice(["deformers", "retargeters", "fitters"]), default=None,
              help="Only this kind of method.")
def methods(kind):
    """Registered method plugins, by kind (entry points)."""
    from facegeom.registry import KINDS, available

    for k in [kind] if kind else KINDS:
        plugins = available(k)
        click.echo(f"{k}:")
        if not plugins:
            click.echo("  (none)")
        for name, target in plugins.items():
            click.echo(f"  {name:<14} {target}")


def _parse_params(items) -> dict:
    from facegeom.registry import parse_value

    out = {}
    for item in items:
        if "=" not in item:
            raise click.BadParameter(f"{item!r} must be key=value", param_hint="--param")
        k, v = item.split("=", 1)
        out[k.strip()] = parse_value(v)
    return out


@cli.command()
@click.argument("mesh", type=click.Path(dir_okay=False))
@click.argument("markers", type=click.Path(dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(),
              help="Deformed mesh (.obj/.ply/.off); with --method all, a folder (one mesh per method).")
@click.option("-m", "--method", default="tangent", show_default=True,
              help="A registered deformer (see `facegeom methods`), or 'all'.")
@click.option("-p", "--param", "params", multiple=True, metavar="KEY=VALUE",
              help="Method parameter, repeatable (e.g. -p d=3 -p rings=2).")
@click.option("--format", "fmt", type=click.Choice(["obj", "ply", "off"]), default=None,
              help="Mesh format of the per-method files with --method all (default: the input's).")
def drive(mesh, markers, output, method, params, fmt):
    """Deform MESH so that the vertices of MARKERS (CSV vertex_id,x,y,z) reach their positions."""
    from pathlib import Path

    from facegeom import registry
    from facegeom.io import read_markers, read_mesh, write_mesh

    V, F = read_mesh(mesh)
    ids, pos = read_markers(markers, n_vertices=V.shape[0])
    kw = _parse_params(params)
    names = list(registry.available("deformers")) if method == "all" else [method]
    if method == "all":
        if kw:
            raise click.BadParameter("parameters apply to one method; drop --param with --method all",
                                     param_hint="--param")
        out_dir = Path(output)
        out_dir.mkdir(parents=True, exist_ok=True)
        suffix = "." + (fmt or Path(mesh).suffix.lstrip(".").lower())
    for name in names:
        deformer = registry.create("deformers", name, **kw)
        t = time.perf_counter()
        deformer.fit(V, F, ids)
        fit_s = time.perf_counter() - t
        t = time.perf_counter()
        Y = deformer.deform(pos)
        deform_ms = (time.perf_counter() - t) * 1e3
        target = out_dir / f"{name}{suffix}" if method == "all" else Path(output)
        write_mesh(target, Y, F)
        click.echo(f"{name:<14} fit {fit_s:.3f} s, deform {deform_ms:.2f} ms -> {target}")


@cli.command()
@click.argument("source", type=click.Path(dir_okay=False))
@click.argument("labels", type=click.Path(dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="The retargeted sequence (.csv or .npz).")
@click.option("-m", "--method", default="tangent", show_default=True,
              help="A registered retargeter (see `facegeom methods --kind retargeters`).")
@click.option("-p", "--param", "params", multiple=True, metavar="KEY=VALUE",
              help="Method parameter, repeatable (e.g. -p window=2 -p strategy=marker).")
@click.option("--fill-gaps", is_flag=True,
              help="Interpolate lost (empty/NaN) source markers over time instead of refusing them.")
def retarget(source, labels, output, method, params, fill_gaps):
    """Retarget the actor's markers SOURCE onto a character known at the frames of LABELS.

    Both files are marker sequences (CSV with header frame,marker,x,y,z, or npz
    with 'markers' (T,p,3) and 'frames'); the frames of LABELS index SOURCE.
    """
    from facegeom import registry
    from facegeom.pipelines.single import retarget_files, write_retargeted

    res = retarget_files(source, labels, lambda: registry.create("retargeters", method, **_parse_params(params)),
                         fill_gaps, echo=click.echo)
    write_retargeted(output, res)
    click.echo(f"{method}: {res.source.n_frames} frames x {res.source.n_markers} markers from {res.labels.n_frames} "
               f"labelled frames in {res.seconds * 1e3:.1f} ms (largest deviation from a label "
               f"{res.label_deviation:.3g}) -> {output}")


@cli.command()
@click.argument("target", type=click.Path(dir_okay=False))
@click.option("--kind", type=click.Choice(["auto", "mesh", "landmarks", "points"]), default="auto", show_default=True,
              help="What TARGET is: a mesh in correspondence with the rig, a landmark CSV (vertex_id,u,v) or a point "
                   "cloud (auto: .csv = landmarks, a mesh with the rig's vertex count = mesh, else points).")
@click.option("--rig", "rig_path", type=click.Path(), default=None,
              help="Rig: an .npz (BlendshapeRig.save_npz) or a folder of OBJs (neutral.obj + one per shape); "
                   "default: the ICT generic face with its 53 expressions.")
@click.option("-m", "--method", default="sem", show_default=True, help="A registered fitter (facegeom methods).")
@click.option("-p", "--param", "params", multiple=True, metavar="KEY=VALUE", help="Method parameter, repeatable.")
@click.option("--focal", type=float, default=None, help="Landmarks: focal length in pixels.")
@click.option("--cx", type=float, default=None, help="Landmarks: principal point x (pixels).")
@click.option("--cy", type=float, default=None, help="Landmarks: principal point y (pixels).")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Coefficients by shape name (.json or .csv).")
@click.option("--mesh-out", type=click.Path(dir_okay=False), default=None, help="Also write the fitted face mesh.")
@click.pass_obj
def fit(obj: _Context, target, kind, rig_path, method, params, focal, cx, cy, output, mesh_out):
    """Fit the rig's blendshape coefficients to TARGET (a mesh, landmarks with a camera, or a point cloud)."""
    import numpy as np

    from facegeom import registry
    from facegeom.io import write_mesh
    from facegeom.model import load_rig
    from facegeom.pipelines.single import fit_file, write_fit

    rig = load_rig(rig_path, obj.face_model)
    tp = Path(target)
    r = fit_file(rig, tp, lambda: registry.create("fitters", method, **_parse_params(params)), kind, focal, cx, cy)
    active = r.active
    write_fit(output, rig.names, r, method, str(tp), time_s=r.seconds)
    click.echo(f"{method}: {r.kind} target, {active.size} active shapes in {r.seconds * 1e3:.1f} ms -> {output}")
    for i in active[np.argsort(-np.abs(r.weights[active]))][:8]:
        click.echo(f"  {rig.names[i]:<20} {r.weights[i]:.3f}")
    if mesh_out:
        write_mesh(mesh_out, r.vertices, rig.triangles)
        click.echo(f"wrote {mesh_out}")


@cli.group()
def bench():
    """Benchmarks that reproduce the papers' experiments (seeded; CSV + plot + table)."""


@bench.command("drive")
@click.option("--cases", default=50, show_default=True, type=click.IntRange(1, 10000), help="Source/target pairs.")
@click.option("--seed", default=0, show_default=True, type=int, help="Seed of identities and expressions.")
@click.option("--methods", default="all", show_default=True,
              help="'all' or ';'-separated specs [label=]name[:k=v,k=v], e.g. 'rbf;t1=tangent:rings=1'.")
@click.option("--layout", "layout_name", default="ict80", show_default=True,
              help="Marker layout: ict80, landmarks68 or random<k> (held-out layouts).")
@click.option("--layout-seed", default=0, show_default=True, type=int, help="Seed of a random layout.")
@click.option("--out", type=click.Path(file_okay=False), default="bench-out/drive", show_default=True,
              help="Folder for drive.csv, drive-summary.md and drive.png.")
@click.option("--no-plot", is_flag=True, help="Skip the plot.")
@click.option("--quiet", is_flag=True, help="No progress bar.")
@click.pass_obj
def bench_drive(obj: _Context, cases, seed, methods, layout_name, layout_seed, out, no_plot, quiet):
    """Face driving on the real ICT face: every deformer, errors in mm, times (cf. the paper's Fig. 10)."""
    from pathlib import Path

    from facegeom.bench import drive as bd
    from facegeom.registry import LINEUPS, parse_methods

    specs = parse_methods(methods, "deformers", LINEUPS["drive"])
    model = obj.face_model()
    bd.main(model, specs, cases, seed, layout_name, layout_seed, Path(out), progress=not quiet,
            echo=click.echo, plot_it=not no_plot)


@bench.command("retarget")
@click.option("--sequences", default=50, show_default=True, type=click.IntRange(1, 10000),
              help="Actor/character sequences (4 in 5 from real takes, every 5th synthetic).")
@click.option("--frames", default=100, show_default=True, type=click.IntRange(10, 100000), help="Frames per sequence.")
@click.option("--seed", default=0, show_default=True, type=int, help="Seed of windows, identities and characters.")
@click.option("--methods", default="all", show_default=True,
              help="'all' or ';'-separated specs [label=]name[:k=v,k=v], e.g. 'rbf;t=tangent:window=2'.")
@click.option("--labels", default="2,3,4,6,8,10,15,20,25,30", show_default=True,
              help="Numbers of labelled frames (evenly spread) to sweep.")
@click.option("--takes", "takes_path", type=click.Path(), default=None,
              help="Folder of ARKit take CSVs (or one CSV). Default: $FACEGEOM_TAKES, "
                   "else ../shared/data/arkit-takes next to the repository.")
@click.option("--synthetic-only", is_flag=True, help="Use only synthetic takes (no real recordings needed).")
@click.option("--layout", "layout_name", default="ict80", show_default=True, help="Marker layout.")
@click.option("--layout-seed", default=0, show_default=True, type=int, help="Seed of a random layout.")
@click.option("--out", type=click.Path(file_okay=False), default="bench-out/retarget", show_default=True,
              help="Folder for retarget.csv, retarget-frames.csv, retarget-summary.md and retarget.png.")
@click.option("--no-plot", is_flag=True, help="Skip the plot.")
@click.option("--quiet", is_flag=True, help="No progress bar.")
@click.pass_obj
def bench_retarget(obj: _Context, sequences, frames, seed, methods, labels, takes_path, synthetic_only, layout_name,
                   layout_seed, out, no_plot, quiet):
    """Expression retargeting on real performances: error vs labels, per sequence, per frame (Figs. 6-8)."""
    from facegeom.bench import retarget as br
    from facegeom.errors import InputError
    from facegeom.registry import LINEUPS, parse_methods

    try:
        counts = sorted({int(x) for x in labels.split(",") if x.strip()})
    except ValueError:
        raise InputError(f"--labels must be comma-separated integers, got {labels!r}") from None
    if not counts or counts[0] < 2 or counts[-1] > frames:
        raise InputError(f"--labels must lie in [2, {frames}] (the frames of a sequence)")
    specs = parse_methods(methods, "retargeters", LINEUPS["retarget"])
    model = obj.face_model()
    takes = [] if synthetic_only else _load_takes(model, takes_path)
    br.main(model, takes, specs, sequences, seed, Path(out), layout_name, layout_seed, frames, counts,
            echo=click.echo, plot_it=not no_plot, progress=not quiet)


def _load_takes(model, takes_path):
    """``[(name, W (T, E))]`` ICT weights of every take CSV found (a note per take on stderr)."""
    from facegeom.io import find_takes, ict_weights, read_take
    from facegeom.model import locate_takes

    where = locate_takes(takes_path)
    files = [where] if where.is_file() else find_takes(where)
    out = []
    for f in files:
        take = read_take(f)
        click.echo(f"take {f.name}: {take.n_frames} frames"
                   + (f" ({take.lost_rows} lost-tracking rows, policy {take.policy})" if take.lost_rows else ""), err=True)
        out.append((f.stem, ict_weights(take, model.expression_names)))
    return out


@bench.command("noise")
@click.option("--sequences", default=20, show_default=True, type=click.IntRange(1, 10000))
@click.option("--frames", default=100, show_default=True, type=click.IntRange(10, 100000), help="Frames per sequence.")
@click.option("--labels", default=10, show_default=True, type=click.IntRange(2), help="Known character frames.")
@click.option("--levels", default="0,0.1,0.2,0.5,1", show_default=True,
              help="Comma-separated noise standard deviations (mm per coordinate).")
@click.option("--seed", default=0, show_default=True, type=int)
@click.option("--methods", default="all", show_default=True, help="'all' or ';'-separated retargeter specs.")
@click.option("--takes", "takes_path", type=click.Path(), default=None,
              help="Folder of Live Link Face CSV takes (default: $FACEGEOM_TAKES or ../shared/data/arkit-takes).")
@click.option("--synthetic-only", is_flag=True, help="Use only synthetic takes.")
@click.option("--out", type=click.Path(file_okay=False), default="bench-out/noise", show_default=True)
@click.option("--no-plot", is_flag=True, help="Skip the plot.")
@click.option("--quiet", is_flag=True, help="No progress bar.")
@click.pass_obj
def bench_noise(obj: _Context, sequences, frames, labels, levels, seed, methods, takes_path, synthetic_only, out,
                no_plot, quiet):
    """Retargeting with Gaussian noise on the known character frames and on the actor's markers."""
    from facegeom.bench import noise as bn
    from facegeom.errors import InputError
    from facegeom.registry import LINEUPS, parse_methods

    try:
        lv = tuple(float(x) for x in levels.split(",") if x.strip())
    except ValueError:
        raise InputError(f"--levels must be comma-separated numbers (mm), got {levels!r}") from None
    if not lv or min(lv) < 0:
        raise InputError(f"--levels must be non-negative numbers (mm), got {levels!r}")
    if labels > frames:
        raise InputError(f"--labels {labels} exceeds --frames {frames}")
    specs = parse_methods(methods, "retargeters", LINEUPS["noise"])
    model = obj.face_model()
    takes = [] if synthetic_only else _load_takes(model, takes_path)
    bn.main(model, takes, specs, sequences, seed, out, lv, labels, frames, echo=click.echo, plot_it=not no_plot,
            progress=not quiet)


@bench.command("animate")
@click.option("--sequences", default=10, show_default=True, type=click.IntRange(1, 10000))
@click.option("--frames", default=100, show_default=True, type=click.IntRange(10, 100000), help="Frames per sequence.")
@click.option("--labels", default=10, show_default=True, type=click.IntRange(2), help="Known character frames.")
@click.option("--seed", default=0, show_default=True, type=int)
@click.option("--retargeters", default="all", show_default=True,
              help="'all' (copy, rbf, tangent) or ';'-separated retargeter specs.")
@click.option("--deformer", default="tangent", show_default=True, help="Deformer spec, e.g. 'biharmonic'.")
@click.option("--takes", "takes_path", type=click.Path(), default=None,
              help="Folder of Live Link Face CSV takes (default: $FACEGEOM_TAKES or ../shared/data/arkit-takes).")
@click.option("--synthetic-only", is_flag=True, help="Use only synthetic takes.")
@click.option("--out", type=click.Path(file_okay=False), default="bench-out/animate", show_default=True)
@click.option("--quiet", is_flag=True, help="No progress bar.")
@click.pass_obj
def bench_animate(obj: _Context, sequences, frames, labels, seed, retargeters, deformer, takes_path, synthetic_only,
                  out, quiet):
    """Performance-driven animation over many takes: face error and times per retargeter."""
    from facegeom.bench import animate as ba
    from facegeom.errors import InputError
    from facegeom.registry import LINEUPS, parse_method, parse_methods

    if labels > frames:
        raise InputError(f"--labels {labels} exceeds --frames {frames}")
    specs = parse_methods(retargeters, "retargeters", LINEUPS["animate"])
    d_spec = parse_method(deformer)
    model = obj.face_model()
    takes = [] if synthetic_only else _load_takes(model, takes_path)
    ba.main(model, takes, specs, d_spec, sequences, seed, out, labels, frames, echo=click.echo, progress=not quiet)


@bench.command("fit")
@click.option("--cases", default=100, show_default=True, type=click.IntRange(1, 100000), help="Random targets.")
@click.option("--seed", default=0, show_default=True, type=int)
@click.option("--methods", default="all", show_default=True,
              help="'all' (sem, sem+ = sem:clamp=true,stop=ric, l1reg, l2reg, pcaexp, pcadel, eos if installed) or ';'-separated specs.")
@click.option("--experiments", default="landmarks,clouds,meshes,temporal", show_default=True,
              help="Comma-separated subset of landmarks, clouds, meshes, temporal.")
@click.option("--noise-px", default=1.0, show_default=True, type=click.FloatRange(0), help="Landmark noise (pixels).")
@click.option("--cloud-cases", default=5, show_default=True, type=click.IntRange(1), help="Targets for point clouds.")
@click.option("--samplings", default=10, show_default=True, type=click.IntRange(1), help="Samplings per cloud target.")
@click.option("--points", default=30000, show_default=True, type=click.IntRange(100), help="Points per cloud.")
@click.option("--take", "take_path", type=click.Path(), default=None,
              help="Take for the temporal experiment (default: the first found via --takes / $FACEGEOM_TAKES).")
@click.option("--takes", "takes_path", type=click.Path(), default=None, help="Folder of takes.")
@click.option("--start", default=0, show_default=True, type=click.IntRange(0), help="First frame of the take window.")
@click.option("--frames", default=300, show_default=True, type=click.IntRange(3), help="Frames of the take window.")
@click.option("--out", type=click.Path(file_okay=False), default="bench-out/fit", show_default=True)
@click.option("--no-plot", is_flag=True, help="Skip the plot.")
@click.option("--quiet", is_flag=True, help="No progress bar.")
@click.pass_obj
def bench_fit(obj: _Context, cases, seed, methods, experiments, noise_px, cloud_cases, samplings, points, take_path,
              takes_path, start, frames, out, no_plot, quiet):
    """Blendshape fitting (SEM paper, Sec. V): landmarks, point clouds, meshes, temporal stability."""
    from facegeom.bench import fit as bf
    from facegeom.errors import InputError
    from facegeom.registry import LINEUPS, parse_methods

    ex = tuple(x.strip() for x in experiments.split(",") if x.strip())
    bad = [x for x in ex if x not in bf.EXPERIMENTS]
    if bad or not ex:
        raise InputError(f"--experiments: unknown {bad[0] if bad else 'empty'!r}; choose from {', '.join(bf.EXPERIMENTS)}")
    specs = parse_methods(methods, "fitters", LINEUPS["fit"])
    model = obj.face_model()
    take = None
    if "temporal" in ex:
        from facegeom.io import find_takes, ict_weights, read_take
        from facegeom.model import default_takes_path, locate_takes

        if take_path or takes_path or default_takes_path().is_dir():
            path = Path(take_path) if take_path else find_takes(locate_takes(takes_path))[0]
            W = ict_weights(read_take(path), model.expression_names)
            if start + frames > W.shape[0]:
                raise InputError(f"the take has {W.shape[0]} frames; --start {start} --frames {frames} runs past its end",
                                 path)
            take = (f"{path.stem}@{start}", W[start:start + frames])
        else:
            click.echo("no takes found: skipping the temporal experiment", err=True)
    bf.main(model, specs, ex, cases, seed, out, noise_px, cloud_cases, samplings, points, take, echo=click.echo,
            progress=not quiet, plot_it=not no_plot)


@bench.command("scaling")
@click.option("--levels", default="0,1,2", show_default=True,
              help="Subdivision levels of the face (0: 9,409 vertices, 1: ~37k, 2: ~150k).")
@click.option("--methods", default="all", show_default=True, help="'all' (tangent, biharmonic, arap) or specs.")
@click.pass_obj
def bench_scaling(obj: _Context, levels, methods):
    """Fit and deform times on the face subdivided to ~37k and ~150k vertices."""
    from facegeom.bench import scaling as bs
    from facegeom.errors import InputError
    from facegeom.registry import LINEUPS, parse_methods

    try:
        lv = [int(x) for x in levels.split(",") if x.strip()]
    except ValueError:
        raise InputError(f"--levels must be comma-separated integers, got {levels!r}") from None
    if not lv or min(lv) < 0 or max(lv) > 3:
        raise InputError("--levels must lie in 0..3")
    specs = parse_methods(methods, "deformers", LINEUPS["scaling"])
    bs.main(obj.face_model(), specs, lv, echo=click.echo)


@bench.command("batch")
@click.option("--fits", default=10000, show_default=True, type=int, help="Landmark files fitted by SEM.")
@click.option("--frames", default=2000, show_default=True, type=int, help="Marker frames driven.")
@click.option("--per-file", default=100, show_default=True, type=int, help="Frames per marker sequence file.")
@click.option("--workers", default=2, show_default=True, type=int, help="Processes of the local Dask cluster.")
@click.option("--noop", default=1000, show_default=True, type=int, help="No-op tasks (scheduler overhead).")
@click.option("--repeats", default=5, show_default=True, type=int, help="Warm drive runs each way (medians reported).")
@click.option("--blas-threads", "blas", default="1", show_default=True,
              help="BLAS threads of this process (the plain loop): a number, or 'default' (leave it).")
@click.option("--work", default=None, type=click.Path(file_okay=False),
              help="Folder for the generated inputs and outputs (default: a temporary folder, deleted at the end).")
@click.option("--out", default=None, type=click.Path(dir_okay=False), help="Also write the numbers as JSON here.")
@click.option("--example", default=None, metavar="DIR", type=click.Path(file_okay=False),
              help="Only write inputs for data/jobs/fit-landmarks.toml into DIR (e.g. data/jobs/out): "
                   "DIR/landmarks/*.csv and DIR/truth/*.json, --fits of them.")
@click.option("--data", default=None, type=click.Path(),
              help="Face data bundle (default: facegeom --data, $FACEGEOM_DATA or ../shared/data).")
@click.pass_obj
def bench_batch(obj: _Context, fits, frames, per_file, workers, noop, repeats, blas, work, out, example, data):
    """Throughput of `facegeom batch` on a local Dask cluster against a plain loop in one process."""
    from facegeom.bench import batch as bb

    model = _Context(data or obj.data).face_model()
    if example:
        bb.write_example(model, example, fits, echo=click.echo)
        return
    bb.main(model, fits, frames, per_file, workers, noop, repeats, blas, work, out, echo=click.echo)


@bench.command("cleanup")
@click.option("--vertices", default=100_000, show_default=True, type=int, help="Vertices of the subdivided face.")
@click.option("--repeats", default=3, show_default=True, type=int, help="Timed runs (median reported).")
@click.pass_obj
def bench_cleanup(obj: _Context, vertices, repeats):
    """`facegeom clean` (with its index map) on a ~100,000-vertex face with injected defects."""
    from facegeom.bench import cleanup as bc

    bc.main(obj.face_model(), vertices, repeats, echo=click.echo)


@cli.command()
@click.option("--take", "take_path", type=click.Path(), default=None,
              help="A Live Link Face CSV take (default: the first take found via --takes / $FACEGEOM_TAKES).")
@click.option("--takes", "takes_path", type=click.Path(), default=None, help="Folder of takes (for the default take).")
@click.option("--start", default=0, show_default=True, type=click.IntRange(0), help="First frame of the window.")
@click.option("--frames", default=100, show_default=True, type=click.IntRange(2, 100000))
@click.option("--labels", default=10, show_default=True, type=click.IntRange(2), help="Known character frames.")
@click.option("--seed", default=0, show_default=True, type=int, help="Seed of the actor and the character.")
@click.option("--retargeter", default="tangent", show_default=True, help="Retargeter spec, e.g. 'rbf'.")
@click.option("--deformer", default="tangent", show_default=True, help="Deformer spec, e.g. 'biharmonic'.")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="Output .npz.")
@click.option("--obj-dir", type=click.Path(file_okay=False), default=None, help="Also write one OBJ per frame here.")
@click.pass_obj
def animate(obj: _Context, take_path, takes_path, start, frames, labels, seed, retargeter, deformer, output, obj_dir):
    """Performance-driven animation: a take on an actor -> 80 markers -> retargeted -> character mesh per frame."""
    from facegeom.errors import InputError
    from facegeom.io import find_takes, write_mesh
    from facegeom.model import locate_takes
    from facegeom.pipelines.animate import animate_take, write_animation_npz
    from facegeom.registry import parse_method

    model = obj.face_model()
    path = Path(take_path) if take_path else find_takes(locate_takes(takes_path))[0]
    anim, seq, ids = animate_take(model, path, start, frames, labels, seed,
                                  lambda: parse_method(retargeter).build("retargeters"),
                                  lambda: parse_method(deformer).build("deformers"))
    click.echo(f"{path.name} frames {start}..{start + frames - 1}: {labels} labelled frames; retarget "
               f"{anim.times['retarget_s'] * 1e3:.1f} ms, deformer fit {anim.times['deformer_fit_s']:.2f} s, "
               f"{frames} frames driven in {anim.times['drive_s']:.3f} s")
    click.echo(f"mean marker error {anim.marker_error_mm.mean():.3f} mm; mean face error {anim.frame_error_mm.mean():.3f} "
               f"mm (worst frame {anim.frame_error_mm.max():.3f} mm); character mean marker motion "
               f"{seq.mean_motion() * 10:.2f} mm")
    out = Path(output)
    if out.suffix.lower() != ".npz":
        raise InputError("the output must be a .npz file", out)
    write_animation_npz(out, anim, ids)
    click.echo(f"wrote {out}")
    if obj_dir:
        d = Path(obj_dir)
        d.mkdir(parents=True, exist_ok=True)
        for t in range(frames):
            write_mesh(d / f"frame_{t:05d}.obj", anim.vertices[t], anim.faces)
        click.echo(f"wrote {frames} OBJ files to {d}")


@cli.command()
@click.option("--cases", default=5, show_default=True, type=click.IntRange(1, 1000))
@click.option("--out", type=click.Path(file_okay=False), default="bench-out/demo", show_default=True)
@click.pass_context
def demo(ctx, cases, out):
    """The main job: face driving, expression retargeting and blendshape fitting compared on a few real faces."""
    ctx.invoke(info)
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
    ctx.invoke(bench_fit, cases=cases, seed=0, methods="sem;sem+=sem:clamp=true,stop=ric;l1reg;pcadel",
               experiments="landmarks,meshes", noise_px=1.0, cloud_cases=1, samplings=1, points=30000,
               take_path=None, takes_path=None, start=0, frames=300, out=str(Path(out) / "fit"), no_plot=False,
               quiet=False)
    click.echo("")
    _demo_batch(ctx.obj.face_model(), Path(out) / "batch")
    click.echo("")
    _demo_viewer(obj_model=ctx.obj.face_model(), path=Path(out) / "view-drive.png")


def _demo_batch(model, folder: Path, count: int = 128) -> None:
    """The demo's batch step: SEM fits of ``count`` landmark files on a local Dask cluster, with a summary."""
    import shutil

    import numpy as np

    from facegeom.bench.batch import CX, CY, FOCAL, make_landmark_inputs
    from facegeom.pipelines.batch import job_from_dict, run_job

    folder = Path(folder).resolve()
    shutil.rmtree(folder, ignore_errors=True)  # generated here, fitted again on every demo
    click.echo(f"batch: {count} landmark files (random expressions, random head pose, 1 px noise) fitted by SEM "
               f"on a local Dask cluster")
    lm, truth = make_landmark_inputs(model, folder / "inputs", count, seed=11)
    job = job_from_dict({"operation": "fit", "method": "sem", "inputs": str(lm), "output": str(folder / "fit"),
                         "truth": str(truth / "{stem}.json"), "params": {"clamp": True, "stop": "ric"},
                         "shared": {"focal": FOCAL, "cx": CX, "cy": CY}, "data": str(model.path)},
                        base=folder, source="<demo batch job>")
    res = run_job(job, echo=click.echo)
    err = [float(r["err_mean"]) * 10 for r in res.rows if r["status"] == "ok"]
    c = res.counts
    click.echo(f"{c['ok']} ok, {c['failed']} failed in {res.seconds:.1f} s; median face error against the truth "
               f"{np.median(err):.2f} mm -> {res.summary}")


def _demo_viewer(obj_model, path: Path) -> None:
    """The demo's last step: the face-driving comparison as a PNG; the viewer itself when a display is present."""
    try:
        from viewer.drive import DriveView
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


def main(argv=None):
    """Entry point: run the CLI, turning user errors into one line and exit 2."""
    try:
        cli.main(args=argv, prog_name="facegeom", standalone_mode=False)
    except click.exceptions.Abort:
        click.echo("facegeom: aborted", err=True)
        sys.exit(130)
    except click.exceptions.ClickException as exc:
        exc.show()
        sys.exit(exc.exit_code)
    except FacegeomError as exc:  # library messages name Python arguments: print them as flags
        click.echo(f"facegeom: error: {as_flags(str(exc))}", err=True)
        sys.exit(2)
    except (FileNotFoundError, PermissionError, IsADirectoryError) as exc:
        click.echo(f"facegeom: error: {exc.filename}: {exc.strerror}", err=True)
        sys.exit(2)
    except KeyboardInterrupt:
        click.echo("facegeom: interrupted", err=True)
        sys.exit(130)


from facegeom.cli.cleanup import register as _register_cleanup  # noqa: E402

_register_cleanup(cli)

from facegeom.cli.view import register as _register_view  # noqa: E402

_register_view(cli)

from facegeom.cli.batch import register as _register_batch  # noqa: E402

_register_batch(cli)
