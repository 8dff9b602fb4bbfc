"""``facegeom drive | retarget | fit | animate``: one method run on one input (see :mod:`facegeom.pipelines.single`)."""
from __future__ import annotations

import time
from pathlib import Path

import click

from facegeom.cli.context import TAKES_LOOKUP, Context, parse_params, take_files
from facegeom.cli.identity import IMAGE_HELP
from facegeom.cli.rigopts import load_cli_rig, rig_options, rig_options_given


def _make_folder(folder, role: str = "with --method all the output is a folder (one file per method)") -> list[Path]:
    """Create ``folder`` and its missing parents; return the folders created (outermost first).

    A file in the way is one line naming it and ``role`` (why a folder is expected there)."""
    from facegeom.errors import InputError

    folder = Path(folder)
    for p in [folder, *folder.parents]:
        if p.exists() and not p.is_dir():
            raise InputError(f"is a file; {role}", p)
    missing = [p for p in [folder, *folder.parents] if not p.exists()][::-1]
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot create the output folder ({exc.strerror or exc})", folder) from None
    return missing


def _remove_folders(created: list[Path]) -> None:
    """Remove the folders :func:`_make_folder` created, innermost first, as far as they are empty."""
    import contextlib
    import os

    for p in reversed(created):
        with contextlib.suppress(OSError):
            os.rmdir(p)


@click.command()
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
@click.option("--proxy", default="auto", show_default=True, metavar="auto|off|N",
              help="Large meshes: solve on a decimated copy of N vertices (markers kept exactly) and move every "
                   "vertex as its closest point on it; auto: 100,000 for meshes over 150,000 vertices; off: always "
                   "solve on the mesh itself.")
def drive(mesh, markers, output, method, params, fmt, proxy):
    """Deform MESH so that the vertices of MARKERS (CSV vertex_id,x,y,z) reach their positions."""
    from facegeom import registry
    from facegeom.io import all_or_nothing, check_outputs, read_markers, read_mesh
    from facegeom.pipelines.proxy import PROXY_ABOVE, ProxyDeformer, proxy_policy

    check_outputs([mesh, markers], [] if method == "all" else [output])
    size = proxy_policy(proxy)
    V, F = read_mesh(mesh)
    ids, pos = read_markers(markers, n_vertices=V.shape[0])
    kw = parse_params(params)
    shared: dict = {}  # with --method all: one proxy for every method

    def make(name, **kwargs):
        deformer = registry.create("deformers", name, **kwargs)
        if size is None:
            return deformer
        above = PROXY_ABOVE if proxy.strip().lower() == "auto" else size
        return ProxyDeformer(deformer, vertices=size, above=above, progress=lambda msg: click.echo(msg, err=True),
                             shared=shared)

    if method != "all":
        _drive_one(make(method, **kw), method, V, F, ids, pos, output, output)
        return
    if kw:
        raise click.BadParameter("parameters apply to one method; drop --param with --method all",
                                 param_hint="--param")
    out_dir = Path(output)
    suffix = "." + (fmt or Path(mesh).suffix.lstrip(".").lower())
    names = list(registry.available("deformers"))
    targets = [out_dir / f"{name}{suffix}" for name in names]
    check_outputs([mesh, markers], targets)
    created = _make_folder(out_dir)
    try:  # every method's mesh or none (and no folder left behind)
        with all_or_nothing(targets) as tmps:
            for name, target, tmp in zip(names, targets, tmps):
                _drive_one(make(name), name, V, F, ids, pos, tmp, target)
    except BaseException:
        _remove_folders(created)
        raise


def _drive_one(deformer, label, V, F, ids, pos, path, shown) -> None:
    """Fit ``deformer`` on ``V (n,3)``, ``F (m,3)`` with handles ``ids (k,)``, deform to ``pos (k,3)``, write ``path``.

    Prints the fit and deform times with ``shown`` (the final output path; ``path`` may be its temporary file).
    """
    from facegeom.io import write_mesh

    t = time.perf_counter()
    deformer.fit(V, F, ids)
    fit_s = time.perf_counter() - t
    t = time.perf_counter()
    Y = deformer.deform(pos)
    deform_ms = (time.perf_counter() - t) * 1e3
    write_mesh(path, Y, F)
    click.echo(f"{label:<14} fit {fit_s:.3f} s, deform {deform_ms:.2f} ms -> {shown}")


@click.command()
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

    Both files are marker sequences (CSV with header frame,marker,x,y,z, npz
    with 'markers' (T,p,3) and 'frames', or C3D motion capture); the frames of
    LABELS index SOURCE.
    """
    from facegeom import registry
    from facegeom.io import check_outputs
    from facegeom.pipelines.single import retarget_files, write_retargeted

    check_outputs([source, labels], [output])
    res = retarget_files(source, labels, lambda: registry.create("retargeters", method, **parse_params(params)),
                         fill_gaps, echo=click.echo)
    write_retargeted(output, res)
    unit = res.source.unit or "in the markers' length unit"  # the source's unit (C3D states one; CSV and npz do not)
    click.echo(f"{method}: {res.source.n_frames} frames x {res.source.n_markers} markers from {res.labels.n_frames} "
               f"labelled frames in {res.seconds * 1e3:.1f} ms (largest deviation from a label "
               f"{res.label_deviation:.3g} {unit}) -> {output}")


@click.command()
@click.argument("target", type=click.Path(dir_okay=False))
@click.option("--kind", type=click.Choice(["auto", "mesh", "landmarks", "points"]), default="auto", show_default=True,
              help="What TARGET is: a mesh in correspondence with the rig, landmarks (a photo itself, whose face's 68 "
                   "landmarks are found in it; a vertex_id,u,v CSV; or an iBUG .pts annotation of the 68-point "
                   "convention) or a point cloud (auto: a photo (.jpg, .png, ...) / .csv / .pts = landmarks, a mesh "
                   "with the rig's vertex count = mesh, else points).")
@click.option("--rig", "rig_path", type=click.Path(), default=None,
              help="Rig: a folder of OBJs (a neutral + one OBJ per shape), a glTF file (.glb/.gltf) or an .npz "
                   "(BlendshapeRig.save_npz); default: the ICT generic face with its 53 expressions.")
@rig_options
@click.option("-m", "--method", default="sem-ls", show_default=True, help="A registered fitter (facegeom methods); sem-ls: SEM with least-squares coefficients where the data determine them, sem: the published algorithm.")
@click.option("-p", "--param", "params", multiple=True, metavar="KEY=VALUE", help="Method parameter, repeatable.")
@click.option("--focal", type=float, default=None, help="Landmarks: focal length in pixels.")
@click.option("--cx", type=float, default=None, help="Landmarks: principal point x (pixels).")
@click.option("--cy", type=float, default=None, help="Landmarks: principal point y (pixels).")
@click.option("--image", type=click.Path(dir_okay=False), default=None, help=IMAGE_HELP)
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Coefficients by shape name (.json or .csv).")
@click.option("--mesh-out", type=click.Path(dir_okay=False), default=None, help="Also write the fitted face mesh.")
@click.option("--identity/--no-identity", default=None,
              help="Also fit the person's identity (face model modes, pose and expression together); the weights "
                   "are the joint fit's, or with an explicit --method that fitter's on the fitted rig. Default: on "
                   "for landmarks (a photo's face is rarely the generic one) unless --rig is given, off for meshes "
                   "and scans.")
@click.option("--id-param", "id_params", multiple=True, metavar="KEY=VALUE",
              help="With --identity: identity fitter parameter, repeatable (e.g. --id-param noise_px=2).")
@click.option("--rig-out", type=click.Path(), default=None,
              help="With --identity: write the user-specific rig (.npz or a new OBJ folder).")
@click.option("--scale", default="auto", show_default=True,
              help="Meshes and point clouds: the factor into the rig's units, or auto: the power of ten that makes "
                   "the scan the size of the rig's face (a scan in mm for the ICT rig in cm gets 0.1).")
@click.pass_context
def fit(ctx, target, kind, rig_path, neutral, names_map, units, up, method, params, focal, cx, cy, image, output,
        mesh_out, identity, id_params, rig_out, scale):
    """Fit the rig's blendshape coefficients to TARGET (a photo, landmarks with a camera, a mesh or a point cloud).

    A photo (JPEG, PNG, ...) needs nothing else: its largest face's 68 landmarks are found in it and the camera is
    taken from its size.
    """
    import numpy as np

    from facegeom import registry
    from facegeom.cli.identity import camera_defaults, parse_scale
    from facegeom.io import all_or_nothing, check_outputs, write_mesh
    from facegeom.pipelines.single import fit_file, write_fit

    obj: Context = ctx.obj
    check_outputs([target, rig_path, image, names_map], [output, mesh_out, rig_out])
    tp = Path(target)
    scale = parse_scale(scale)
    from facegeom.io.images import IMAGE_SUFFIXES

    pixels = tp.suffix.lower() in IMAGE_SUFFIXES and kind in ("auto", "landmarks")  # a photo itself: faces found in it
    if pixels and image is None:
        image = target
    focal, cx, cy = camera_defaults(focal, cx, cy, image)
    if identity is None:  # a photo: the person's identity with the expression, unless a rig says who it is
        photo = kind == "landmarks" or pixels or (kind == "auto" and tp.suffix.lower() in (".csv", ".pts"))
        identity = photo and not rig_path and not rig_options_given(neutral, names_map, units, up)
        if identity:
            click.echo("landmarks: fitting the identity with the expression (a photo's face is rarely the generic "
                       "one; --no-identity fits the generic face)")
    if identity or rig_out or id_params:
        from facegeom.cli.identity import fit_identity_target, write_rig
        from facegeom.errors import InputError

        if not identity:
            raise InputError("--rig-out and --id-param go with --identity")
        if rig_path:
            raise InputError("--identity fits the rig from the face model: drop --rig")
        if rig_options_given(neutral, names_map, units, up):
            raise InputError("--neutral, --names, --units and --up describe --rig: drop them with --identity")
        explicit = ctx.get_parameter_source("method") != click.core.ParameterSource.DEFAULT
        r, rig, method = fit_identity_target(obj, tp, kind, focal, cx, cy, id_params, method, parse_params(params),
                                             explicit, scale)
        if rig_out:
            write_rig(rig, rig_out)
    else:
        rig = load_cli_rig(rig_path, obj.face_model, neutral, names_map, units, up)
        r = fit_file(rig, tp, lambda: registry.create("fitters", method, **parse_params(params)), kind, focal, cx, cy,
                     scale)
        for line in r.notes:
            click.echo(line)
    active = r.active
    frame = getattr(rig, "frame", None)
    with all_or_nothing([output] + ([mesh_out] if mesh_out else [])) as tmps:  # the weights and the mesh, or neither
        write_fit(tmps[0], rig.names, r, method, str(tp), time_s=r.seconds, rig=rig)
        if mesh_out:  # in the rig's own units and axes, to lie on the rig it came from
            write_mesh(tmps[1], r.vertices if frame is None else frame.to_source(r.vertices), rig.triangles)
    click.echo(f"{method}: {r.kind} target, {active.size} active shapes in {r.seconds * 1e3:.1f} ms -> {output}")
    for i in active[np.argsort(-np.abs(r.weights[active]))][:8]:
        click.echo(f"  {rig.names[i]:<20} {r.weights[i]:.3f}")
    if mesh_out:
        click.echo(f"wrote {mesh_out}" + ("" if frame is None else f" (the rig's own units and axes: {frame.label})"))
    if rig_out:
        click.echo(f"wrote {rig_out}")


@click.command()
@click.option("--take", "take_path", type=click.Path(), default=None,
              help="A Live Link Face CSV take (default: the first take of --takes, else of the takes lookup).")
@click.option("--takes", "takes_path", type=click.Path(), default=None, help=f"Folder of takes (for the default take; default: {TAKES_LOOKUP}).")
@click.option("--start", default=0, show_default=True, type=click.IntRange(0), help="First frame of the window.")
@click.option("--frames", default=None, type=click.IntRange(2, 100000),
              help="Frames of the window (default 100; with --character: the rest of the take).")
@click.option("--labels", default=10, show_default=True, type=click.IntRange(2), help="Known character frames.")
@click.option("--seed", default=0, show_default=True, type=int, help="Seed of the actor and the character.")
@click.option("--retargeter", default="tangent", show_default=True, help="Retargeter spec, e.g. 'rbf'.")
@click.option("--deformer", default="tangent", show_default=True, help="Deformer spec, e.g. 'biharmonic'.")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Output .npz (with --rig or --character also .glb, USD (.usda/.usdc/.usdz) or a Live Link .csv).")
@click.option("--obj-dir", type=click.Path(file_okay=False), default=None, help="Also write one OBJ per frame here.")
@click.option("--rig", "rig_path", type=click.Path(), default=None,
              help="Solve the retargeted markers on this rig (an OBJ folder, .glb/.gltf or .npz with the ICT face's "
                   "vertices, or 'ict' for the generic ICT rig) and write weight curves (.npz, .glb or a Live Link "
                   ".csv) instead of driving the mesh.")
@rig_options
@click.option("--fitter", default="sem-ls", show_default=True, help="With --rig: the fitter.")
@click.option("--smooth", default="auto", show_default=True, help="With --rig: curve smoothing (auto, off, a number).")
@click.option("--character", "character_path", type=click.Path(), default=None,
              help="Play the take on this character's rig (an OBJ folder, .glb/.gltf or .npz, e.g. from `facegeom "
                   "transfer`): its shapes driven by name from the take's ARKit weights, the take's head rotation "
                   "carried over; -o: .glb (the character's mesh, shapes and animation), .csv or .npz.")
@click.option("--character-names", "character_map", type=click.Path(dir_okay=False), default=None,
              help="With --character: a mapping CSV rig_shape,source_shape,gain from ARKit names to the "
                   "character's shapes (gains per shape).")
@click.option("--route", type=click.Choice(["rig", "markers"]), default="rig", show_default=True,
              help="With --character: rig (its shapes driven by name) or markers (no rig needed: the actor's "
                   "markers retargeted onto the head's by the tangent framework from --keys key frames, the head "
                   "driven through them; --character is then any head: a mesh, a glTF scene or a rig file).")
@click.option("--keys", default="10", show_default=True,
              help="With --route markers: how many key frames (chosen: the frame nearest the neutral, then the "
                   "farthest apart), or which (take frames, e.g. 0,120,344); their labels proposed from the "
                   "actor's displacements.")
@click.option("--key-labels", "key_labels", type=click.Path(dir_okay=False), default=None,
              help="With --route markers: a key-labels CSV (frame,marker[,vertex],x,y,z in the head's units, "
                   "e.g. saved and edited in `facegeom view character --route markers`): the character's markers "
                   "at its frames, which become key frames; markers it leaves out stay proposed.")
@click.option("--save-key-labels", "save_key_labels", type=click.Path(dir_okay=False), default=None,
              help="With --route markers: write the labels used (proposed or given) as a key-labels CSV to edit.")
@click.pass_obj
def animate(obj: Context, take_path, takes_path, start, frames, labels, seed, retargeter, deformer, output, obj_dir,
            rig_path, neutral, names_map, units, up, fitter, smooth, character_path, character_map, route, keys,
            key_labels, save_key_labels):
    """Performance-driven animation: a take on an actor -> 80 markers -> retargeted -> character mesh per frame.

    With --rig: the retargeted markers are solved on the rig -> blendshape weight curves.
    With --character: the take plays on your character's rig -> its animated .glb (or curves).
    """
    from facegeom.errors import InputError

    if character_path is not None:
        if route == "markers":
            _animate_markers(obj, take_path, takes_path, start, frames, output, obj_dir, rig_path, character_path,
                             character_map, (keys, key_labels, save_key_labels), retargeter, deformer,
                             (neutral, names_map, units, up))
            return
        _animate_character(obj, take_path, takes_path, start, frames, output, obj_dir, rig_path, character_path,
                           character_map, (neutral, names_map, units, up))
        return
    if character_map is not None:
        raise InputError("--character-names goes with --character")
    frames = 100 if frames is None else frames
    if rig_path is not None:
        _animate_rig(obj, take_path, takes_path, start, frames, labels, seed, retargeter, output, obj_dir,
                     rig_path, fitter, smooth, (neutral, names_map, units, up))
        return
    if rig_options_given(neutral, names_map, units, up):
        raise InputError("--neutral, --names, --units and --up go with --rig")
    from facegeom.io import all_or_nothing, check_outputs, write_mesh
    from facegeom.pipelines.animate import animate_take, write_animation_npz
    from facegeom.registry import parse_method

    model = obj.face_model()
    path = take_files(takes_path, take_path)[0]
    objs = [Path(obj_dir) / f"frame_{t:05d}.obj" for t in range(frames)] if obj_dir else []
    check_outputs([path], [output] + objs)
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
    created = _make_folder(obj_dir, "the OBJ frames go into a folder") if obj_dir else []
    try:  # the npz and every OBJ, or nothing (a folder made here is removed again)
        with all_or_nothing([out] + objs) as tmps:
            write_animation_npz(tmps[0], anim, ids)
            for t, tmp in enumerate(tmps[1:]):
                write_mesh(tmp, anim.vertices[t], anim.faces)
    except BaseException:
        _remove_folders(created)
        raise
    click.echo(f"wrote {out}")
    if obj_dir:
        click.echo(f"wrote {frames} OBJ files to {Path(obj_dir)}")



def _animate_character(obj: Context, take_path, takes_path, start, frames, output, obj_dir, rig_path,
                       character_path, character_map, rig_opts):
    """``animate --character``: the take's ARKit weights -> the character's rig (the industry route)."""
    from facegeom.cli.flags import as_flags
    from facegeom.errors import InputError
    from facegeom.io import check_outputs
    from facegeom.pipelines.character import take_onto_character
    from facegeom.pipelines.solve import write_curves

    if obj_dir or rig_path is not None or rig_options_given(*rig_opts):
        raise InputError("--character plays the take on the character's rig: --obj-dir, --rig and its options do not "
                         "go with it")
    path = take_files(takes_path, take_path)[0]
    check_outputs([path, character_path, character_map], [output])
    character = load_cli_rig(character_path, obj.face_model, names_map=character_map)
    played = take_onto_character(path, character, start, frames)
    write_curves(output, played)
    for line in played.notes:
        click.echo(as_flags(line))
    T = played.solve.weights.shape[0]
    click.echo(f"{path.name} frames {start}..{start + T - 1} ({T / played.fps:.1f} s at {played.fps:g} fps) on "
               f"{Path(character_path).name}: {len(character.names)} shapes, {character.n_vertices} vertices")
    click.echo(f"wrote {output}")


GLB_TOLERANCE_M = 1e-4  # --route markers: the .glb's frames within 0.1 mm of the driven mesh (metres)
PROGRESS_S = 5.0  # --route markers: seconds between progress lines while the .glb is written


def parse_keys(text: str) -> tuple[int | None, list[int]]:
    """``--keys``: a count (``"10"``) or take frames (``"0,120,344"``) -> ``(count or None, frames)``."""
    from facegeom.errors import InputError

    cells = [c.strip() for c in str(text).split(",")]
    try:
        values = [int(c) for c in cells]
    except ValueError:
        raise InputError(f"--keys {text!r}: give a number of key frames (e.g. 10) or take frames (e.g. 0,120,344)") \
            from None
    if len(values) == 1:
        if not 2 <= values[0] <= 1000:
            raise InputError(f"--keys {values[0]}: between 2 and 1000 key frames")
        return values[0], []
    if min(values) < 0 or len(set(values)) != len(values):
        raise InputError(f"--keys {text!r}: take frames must be distinct and not negative")
    return None, sorted(values)


def _animate_markers(obj: Context, take_path, takes_path, start, frames, output, obj_dir, rig_path, character_path,
                     character_map, key_opts, retargeter, deformer, rig_opts):
    """``animate --character HEAD --route markers``: the paper's route onto a head no one rigged."""
    from facegeom.cli.flags import as_flags
    from facegeom.pipelines.character import read_head, stored_registration
    from facegeom.errors import InputError
    from facegeom.io import check_outputs
    from facegeom.io.gltf import write_sequence_glb
    from facegeom.io.key_labels import read_key_labels, write_key_labels
    from facegeom.io.takes import read_take
    from facegeom.pipelines.character_markers import (key_labels_comment, markers_onto_character, resolve_keys,
                                                      take_markers)
    from facegeom.pipelines.solve import take_fps
    from facegeom.registry import parse_method

    keys, key_labels, save_labels = key_opts
    if obj_dir or rig_path is not None or character_map is not None or any(
            v not in (None, "auto") for v in rig_opts):
        raise InputError("--route markers drives the head through markers: --obj-dir, --rig and its options and "
                         "--character-names do not go with it")
    if Path(output).suffix.lower() != ".glb":
        raise InputError("with --route markers the output is the character's animated .glb", output)
    count, listed = parse_keys(keys)
    path = take_files(takes_path, take_path)[0]
    check_outputs([path, character_path, key_labels], [output, save_labels])
    model = obj.face_model()
    take = read_take(path)
    X, X0, ids = take_markers(model, take, start, frames)
    stop = start + len(X)
    given = read_key_labels(key_labels, len(ids)) if key_labels else None  # its frames: checked on the window
    rel, labels = resolve_keys(given, listed, start, stop, len(ids))
    V, F, parts = read_head(character_path)
    click.echo(f"{Path(character_path).name}: {V.shape[0]} vertices; {path.name} frames {start}..{stop - 1}")
    stored = stored_registration(model, character_path, V, F)
    if stored is not None:
        click.echo("registration: the one `facegeom transfer` stored with the rig")
    mr = markers_onto_character(model, X, X0, ids, V, F, keys=rel, n_keys=count or 10, labels=labels, parts=parts,
                                character=stored, labels_path=key_labels, first_frame=start,
                                retargeter=parse_method(retargeter).build("retargeters"),
                                deformer=parse_method(deformer).build("deformers"),
                                progress=lambda line: click.echo(as_flags(line)))
    if given is not None:
        given.check_vertices(mr.marker_vertices)
    metres = mr.character.registration.units / 100.0
    t0 = time.perf_counter()
    shown = [t0]

    def progress(line: str) -> None:  # the writer reports twice a second: a line every few seconds is enough
        now = time.perf_counter()
        if now - shown[0] >= PROGRESS_S:
            shown[0] = now
            click.echo(f"  {line} ({now - t0:.0f} s)")

    _, info = write_sequence_glb(output, mr.source(metres), F, take_fps(take), tolerance=GLB_TOLERANCE_M,
                                 hold_bytes=0, progress=progress,  # driving again is cheaper than keeping
                                 rest=V * metres)  # every weight at 0: the character's own neutral
    click.echo(f"wrote {output} ({info['frames']} frames driven and stored as {info['targets']} morph targets in "
               f"{time.perf_counter() - t0:.2f} s, every vertex within {info['max_error'] * 1000:.3f} mm)")
    if save_labels:
        write_key_labels(save_labels, mr.key_frames + start, mr.labels, mr.marker_vertices,
                         comment=key_labels_comment(Path(character_path).name, V.shape[0], path.name))
        click.echo(f"wrote {save_labels} ({mr.key_frames.size} key frames x {len(ids)} markers)")


def _animate_rig(obj: Context, take_path, takes_path, start, frames, labels, seed, retargeter, output, obj_dir,
                 rig_path, fitter, smooth, rig_opts):
    """``animate --rig``: take -> retargeted character markers -> rig weight curves (see ``solve_take``)."""
    import numpy as np

    from facegeom.cli.solve import parse_smooth
    from facegeom.errors import InputError
    from facegeom.io import check_outputs
    from facegeom.io.markerseq import MarkerSequence
    from facegeom.cli.flags import as_flags
    from facegeom.pipelines.animate import solve_take
    from facegeom.pipelines.solve import SolvedCapture, write_curves
    from facegeom.registry import parse_method

    if obj_dir:
        raise InputError("--obj-dir writes driven meshes; with --rig the output is weight curves")
    amount = parse_smooth(smooth)
    model = obj.face_model()
    path = take_files(takes_path, take_path)[0]
    rig_file = None if rig_path == "ict" else rig_path
    check_outputs([path, rig_file, rig_opts[1]], [output])
    rig = load_cli_rig(rig_file, lambda: model, *rig_opts)
    res, seq, ids, info = solve_take(model, path, start, frames, labels, seed,
                                     lambda: parse_method(retargeter).build("retargeters"), rig,
                                     lambda: parse_method(fitter).build("fitters"), amount)
    ms = MarkerSequence(np.arange(start, start + frames, dtype=np.int64), tuple(f"v{i}" for i in ids),
                        info["markers"], str(path))
    from facegeom.io.takes import read_take
    from facegeom.pipelines.solve import take_fps

    tk = read_take(path)  # the take's rate and timecode carry over to what is written
    start_s = tk.start_s + float(tk.times[start]) if start < tk.n_frames else None
    solved = SolvedCapture(res, ms, ids, fitter, float(take_fps(tk)), True, rig, start_s=start_s)
    write_curves(output, solved)
    for line in solved.notes:
        click.echo(as_flags(line))
    err = f"; weight error vs the take {info['weight_mae']:.4f}" if "weight_mae" in info else ""
    click.echo(f"{path.name} frames {start}..{start + frames - 1}: {labels} labelled frames; retarget "
               f"{info['retarget_s'] * 1e3:.1f} ms, solve {res.time_s:.2f} s on {len(res.names)} shapes{err}")
    click.echo(f"wrote {output}")
