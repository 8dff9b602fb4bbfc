"""``facegeom view ...``: the interactive polyscope viewer (package ``viewer``).

Every subcommand opens a window, or with ``--screenshot PATH`` renders one PNG
headless (EGL; no display or GPU needed) and exits. Without a display and
without ``--screenshot`` it stops with one line saying how to run headless.
The viewer is imported only when a subcommand runs, so ``facegeom`` itself
does not need polyscope at import time.
"""
from __future__ import annotations

from pathlib import Path

import click

from facegeom.cli.context import TAKES_LOOKUP, other_take_sources
from facegeom.cli.rigopts import load_cli_rig, rig_options

__all__ = ["view"]


def _size(text: str) -> tuple[int, int]:
    from facegeom.viewer.app import parse_size

    return parse_size(text)


def _output_options(f):
    f = click.option("--size", default="1600x900", show_default=True, metavar="WxH",
                     help="Window (or image) size in pixels.")(f)
    f = click.option("--screenshot", type=click.Path(dir_okay=False), default=None,
                     help="Render a PNG headless (no window, no display needed) and exit.")(f)
    f = click.option("--exit-after", type=click.FloatRange(min=0, min_open=True), default=None, metavar="SECONDS",
                     help="Close the window after this many seconds (scripts, demos, tests).")(f)
    f = click.option("--state", "state_path", type=click.Path(dir_okay=False), default=None, metavar="JSON",
                     help="Write the window's state (frames, camera, panel, markers, per-method status) to this "
                          "JSON file five times a second and on exit; SIGTERM closes the window cleanly.")(f)
    return f


def _take_options(f):
    for opt in reversed([
        click.option("--take", "take_path", type=click.Path(), default=None,
                     help="A Live Link Face CSV take (default: the first take of --takes, else of the takes lookup)."),
        click.option("--takes", "takes_path", type=click.Path(), default=None,
                     help=f"Folder of takes (default: {TAKES_LOOKUP})."),
        click.option("--synthetic", is_flag=True, help="A synthetic take (onset-apex-offset) instead of a real one."),
        click.option("--start", default=0, show_default=True, type=click.IntRange(0),
                     help="First frame of the take window."),
        click.option("--frames", default=100, show_default=True, type=click.IntRange(2, 100000),
                     help="Frames of the window."),
        click.option("--labels", default=10, show_default=True, type=click.IntRange(2),
                     help="Known character frames, evenly spread."),
        click.option("--seed", default=0, show_default=True, type=int, help="Seed of the actor and the character."),
        click.option("--frame", default=0, show_default=True, type=click.IntRange(0),
                     help="Frame shown first (and in the screenshot)."),
    ]):
        f = opt(f)
    return f


def _check_screenshot(screenshot, *inputs) -> None:
    """Before rendering: the --screenshot PATH is no input and its folder can be written (one-line error)."""
    if screenshot is None:
        return
    from facegeom.io import check_outputs, check_writable_folder

    check_outputs(inputs, [screenshot])
    check_writable_folder(screenshot)


def _cli_default(command: str, option: str) -> str:
    """The default of ``option`` of the command ``facegeom COMMAND`` (``drive``, ``fit``), read from the command
    itself: the views show by default what those commands compute by default."""
    from facegeom.cli import single

    return next(p.default for p in getattr(single, command).params if p.name == option)


def _given(ctx: click.Context, *names: str) -> list[str]:
    """The options among ``names`` (parameter names) set on the command line (or the environment), as flags."""
    from click.core import ParameterSource

    given = []
    for p in ctx.command.params:
        if p.name in names and ctx.get_parameter_source(p.name) in (ParameterSource.COMMANDLINE,
                                                                    ParameterSource.ENVIRONMENT):
            given.append(max(p.opts, key=len))
    return given


def _run(view, screenshot, size, exit_after=None, state_path=None):
    w, h = _size(size)
    view.run(screenshot=screenshot, width=w, height=h, echo=click.echo, exit_after=exit_after, state_path=state_path)


@click.group("view")
def view():
    """Look before believing a table: every method's result side by side (polyscope).

    Without a display, add --screenshot PATH to render a PNG headless.
    """


#: built-in-case options of `view drive`, which pick the face model's case: they do not go with MESH MARKERS
_DRIVE_CASE_OPTIONS = ("seed", "expression", "intensity", "bench_case", "layout_name", "layout_seed")


@view.command("drive")
@click.argument("mesh", required=False, type=click.Path(dir_okay=False))
@click.argument("markers", required=False, type=click.Path(dir_okay=False))
@click.option("--methods", default=None, show_default="rbf;biharmonic;tangent; with MESH MARKERS "
                                                       "tangent;rbf;biharmonic, `facegeom drive`'s default first",
              help="';'-separated deformer specs [label=]name[:k=v,...], or 'all' (bench drive's); "
                   "more can be switched on in the panel.")
@click.option("--proxy", default=None, metavar="auto|off|N", show_default="auto",
              help="With MESH MARKERS: as `facegeom drive --proxy` (meshes over 150,000 vertices are solved on a "
                   "decimated copy).")
@click.option("--seed", default=0, show_default=True, type=int,
              help="Identity seed (or bench seed with --bench-case).")
@click.option("--expression", default="happiness", show_default=True,
              help="A named expression (facegeom.model.expressions: happiness, jaw-open, pucker, ...) "
                   "or random-sparse.")
@click.option("--intensity", default=0.9, show_default=True, type=click.FloatRange(0, 2),
              help="Scale of the named expression.")
@click.option("--bench-case", type=click.IntRange(0), default=None,
              help="Use case N of `facegeom bench drive --seed SEED` instead (the row case=N of drive.csv).")
@click.option("--layout", "layout_name", default="ict80", show_default=True,
              help="Marker layout: ict80, landmarks68 or random<k>.")
@click.option("--layout-seed", default=0, show_default=True, type=int, help="Seed of a random layout.")
@click.option("--marker", default=0, show_default=True, type=click.IntRange(0),
              help="Marker selected at start (a row of MARKERS, from 0).")
@click.option("--nudge", default=None, metavar="DX,DY,DZ",
              help="Move the selected marker by this offset (mm) before showing (e.g. for a screenshot).")
@_output_options
@click.pass_context
def view_drive(ctx, mesh, markers, methods, proxy, seed, expression, intensity, bench_case, layout_name, layout_seed,
               marker, nudge, screenshot, size, exit_after, state_path):
    """Source | every deformer | true target (or your MESH driven by your MARKERS); drag a marker, all follow live.

    With MESH MARKERS (what `facegeom drive MESH MARKERS -o OUT` reads: a mesh .obj/.ply/.off and a CSV
    vertex_id,x,y,z): your mesh | each deformer driving it by your markers, built as `facegeom drive` builds it
    (its default, tangent, first: that face is what it writes), coloured by how far each vertex moved (mm; the
    mesh's unit found from its size). No face data is needed then. Without them: a built-in case of the face
    model (--seed, --expression, --intensity, --bench-case, --layout), beside its true target.
    """
    from facegeom.errors import InputError
    from facegeom.viewer.app import check_display

    files = mesh is not None
    if files and markers is None:
        if Path(mesh).suffix.lower() == ".csv":
            raise InputError("MESH is missing: give the mesh first, then this marker file (facegeom view drive "
                             "MESH MARKERS), or neither for the built-in case", mesh)
        raise InputError("MARKERS is missing: give the marker file (a CSV vertex_id,x,y,z, as `facegeom drive` "
                         "reads) after the mesh, or neither file for the built-in case", mesh)
    if files:
        given = _given(ctx, *_DRIVE_CASE_OPTIONS)
        if given:
            raise InputError(f"{given[0]} picks a built-in case of the face model: it does not go with your files "
                             f"MESH MARKERS ({mesh}, {markers})")
    elif proxy is not None:
        raise InputError("--proxy goes with MESH MARKERS (your files; the built-in cases are never proxied)")
    check_display(screenshot)
    _check_screenshot(screenshot, mesh, markers)
    _size(size)
    delta = None
    if nudge is not None:
        try:
            delta = [float(x) for x in nudge.split(",")]
        except ValueError:
            delta = []
        if len(delta) != 3:
            raise InputError(f"--nudge must be three comma-separated numbers (mm), got {nudge!r}")
    from facegeom.viewer.drive import DEFAULT_METHODS, FILE_METHODS, DriveView, read_drive_files

    if files:
        from facegeom.pipelines.proxy import proxy_policy

        proxy = "auto" if proxy is None else proxy
        proxy_policy(proxy)
        case = read_drive_files(mesh, markers)  # the readers and checks of `facegeom drive MESH MARKERS`
        if marker >= case.handles.size:
            raise InputError(f"--marker {marker} is out of range: the file has {case.handles.size} markers",
                             markers)
        if methods is None:  # `facegeom drive`'s default first
            methods = ";".join(dict.fromkeys([_cli_default("drive", "method"), *FILE_METHODS.split(";")]))
        v = DriveView(None, methods, case=case, proxy=proxy, background=screenshot is None)
    else:
        v = DriveView(ctx.obj.face_model(), DEFAULT_METHODS if methods is None else methods, seed=seed,
                      expression=expression, intensity=intensity, layout_name=layout_name, layout_seed=layout_seed,
                      bench_case=bench_case,
                      background=screenshot is None)  # a window: fits in worker processes, it never freezes
    if marker >= v.case.handles.size:
        raise InputError(f"--marker {marker} is out of range: the layout has {v.case.handles.size} markers")
    v.marker = marker
    if delta is not None:
        v.nudge(marker, delta)
    _run(v, screenshot, size, exit_after, state_path)


@view.command("retarget")
@click.option("--methods", default="copy;rbf;tangent", show_default=True,
              help="';'-separated retargeter specs [label=]name[:k=v,...], or 'all' (bench retarget's).")
@_take_options
@_output_options
@click.pass_obj
def view_retarget(obj, methods, take_path, takes_path, synthetic, start, frames, labels, seed, frame, screenshot,
                  size, exit_after, state_path):
    """Play a take on the actor beside the character's retargeted markers, per-frame errors."""
    from facegeom.viewer.app import check_display

    check_display(screenshot)
    _check_screenshot(screenshot, take_path)
    _size(size)
    from facegeom.viewer.playback import RetargetView, load_sequence

    model = obj.face_model()
    with other_take_sources("--take FILE", "--synthetic"):
        seq = load_sequence(model, take_path, takes_path, start, frames, seed, synthetic)
    _run(RetargetView(model, seq, methods, labels, frame=min(frame, frames - 1)), screenshot, size, exit_after,
         state_path)


@view.command("animate")
@click.option("--input", "input_path", type=click.Path(dir_okay=False), default=None,
              help="Play this file instead: a .glb (a rig with a weights animation), .npz curves or a Live Link "
                   ".csv take (what `facegeom solve` writes); curves and takes play on --rig.")
@click.option("--rig", "rig_path", type=click.Path(), default=None,
              help="With --input curves or a take: the rig (an OBJ folder, .glb/.gltf or .npz); default: the ICT "
                   "generic face.")
@rig_options
@click.option("--retargeters", default="tangent", show_default=True, help="';'-separated retargeter specs.")
@click.option("--deformer", default="tangent", show_default=True, help="One deformer spec, e.g. 'biharmonic'.")
@_take_options
@_output_options
@click.pass_obj
def view_animate(obj, input_path, rig_path, neutral, names_map, units, up, retargeters, deformer, take_path, takes_path,
                 synthetic, start, frames, labels, seed, frame, screenshot, size, exit_after, state_path):
    """Play the actor beside the driven character mesh (per-vertex error) and the true character;
    or, with --input, play an animation file (.glb, curves, Live Link take)."""
    from facegeom.viewer.app import check_display

    check_display(screenshot)
    _check_screenshot(screenshot, take_path, input_path)
    _size(size)
    if input_path is not None:
        from facegeom.pipelines.solve import read_animation
        from facegeom.viewer.playback import CurvesView

        anim = read_animation(input_path, lambda: load_cli_rig(rig_path, obj.face_model, neutral, names_map, units, up))
        _run(CurvesView(anim, frame=min(frame, anim.n_frames - 1)), screenshot, size, exit_after, state_path)
        return
    from facegeom.viewer.playback import AnimateView, load_sequence

    model = obj.face_model()
    with other_take_sources("--take FILE", "--synthetic"):
        seq = load_sequence(model, take_path, takes_path, start, frames, seed, synthetic)
    _run(AnimateView(model, seq, retargeters, deformer, labels, frame=min(frame, frames - 1)), screenshot, size,
         exit_after, state_path)


#: built-in-target options of `view fit`: they pick one of the face model's cases, not --target FILE
_FIT_CASE_OPTIONS = ("case", "seed", "kind", "noise_px")


@view.command("fit")
@click.option("--methods", default=None,
              show_default="sem;l1reg;pcadel; with --target: `facegeom fit`'s default, sem-ls",
              help="';'-separated fitter specs, or 'all' (bench fit's); more can be switched on in the panel. "
                   "Fitters without the [0, 1] box (sem without clamp, the PCA baselines) are flagged when a "
                   "weight leaves it.")
@click.option("--case", default=0, show_default=True, type=click.IntRange(0),
              help="Case N of `facegeom bench fit --seed SEED` (random identity and sparse expression).")
@click.option("--seed", default=0, show_default=True, type=int)
@click.option("--kind", type=click.Choice(["landmarks", "mesh"]), default="landmarks", show_default=True,
              help="Give the fitters 23 noisy 2-D landmarks (pose unknown) or the whole mesh.")
@click.option("--noise-px", default=1.0, show_default=True, type=click.FloatRange(0),
              help="Landmark noise (pixels).")
@click.option("--target", "target_path", type=click.Path(dir_okay=False), default=None,
              help="Fit this mesh instead (in correspondence with the ICT face; generic rig), read and fitted as "
                   "`facegeom fit TARGET` does (units found, a mesh off the rig's frame aligned): with the default "
                   "--methods the weights shown are the ones it writes.")
@_output_options
@click.pass_context
def view_fit(ctx, methods, case, seed, kind, noise_px, target_path, screenshot, size, exit_after, state_path):
    """A target beside every fitter's face (error colours) and its coefficients by blendshape name.

    Without --target: case --case of `facegeom bench fit --seed SEED` (a random identity and expression, given as
    --kind landmarks or mesh), compared across --methods (default sem;l1reg;pcadel). With --target MESH: your mesh
    on the generic ICT rig, fitted by `facegeom fit`'s default fitter (sem-ls) unless --methods says otherwise.
    """
    from facegeom.errors import InputError
    from facegeom.viewer.app import check_display

    if target_path is not None:
        given = _given(ctx, *_FIT_CASE_OPTIONS)
        if given:
            raise InputError(f"{given[0]} picks a built-in target of the face model: it does not go with --target "
                             f"{target_path}")
    check_display(screenshot)
    _check_screenshot(screenshot, target_path)
    _size(size)
    from facegeom.viewer.fit import DEFAULT_METHODS, FitView

    if methods is None:  # with --target: what `facegeom fit TARGET` runs
        methods = DEFAULT_METHODS if target_path is None else _cli_default("fit", "method")
    v = FitView(ctx.obj.face_model(), methods, case=case, seed=seed, kind=kind, noise_px=noise_px,
                target=target_path, background=screenshot is None)  # a window: fits in worker processes
    for line in v.case.notes:  # what reading the target did, as `facegeom fit` says it
        click.echo(line)
    _run(v, screenshot, size, exit_after, state_path)


@view.command("rig")
@click.argument("rig_path", metavar="RIG", type=click.Path())
@rig_options
@click.option("--shape", default=None, metavar="NAME", help="Set this shape's slider at start (e.g. jawOpen).")
@click.option("--weight", type=click.FloatRange(0, 1), default=None, metavar="W",
              help="The weight --shape starts at, in [0, 1]; default 1.")
@_output_options
@click.pass_obj
def view_rig(obj, rig_path, neutral, names_map, units, up, shape, weight, screenshot, size, exit_after, state_path):
    """Pose a blendshape rig with one slider per shape, coloured by the displacement from its neutral (mm).

    RIG: an OBJ folder, a .glb / .gltf or an .npz (as --rig elsewhere); it is shown in facegeom's frame
    (cm, Y up) whatever its own units and axes.
    """
    from facegeom.errors import InputError
    from facegeom.viewer.app import check_display

    check_display(screenshot)
    _check_screenshot(screenshot, rig_path, names_map)
    _size(size)
    if weight is not None and shape is None:
        raise InputError("--weight W sets the weight of --shape NAME: give the shape too")
    rig = load_cli_rig(rig_path, obj.face_model, neutral, names_map, units, up)
    from facegeom.viewer.rig import RigView

    v = RigView(rig, path=rig_path)
    if shape is not None:
        v.set_weight(shape, 1.0 if weight is None else weight)
    _run(v, screenshot, size, exit_after, state_path)


@view.command("transfer")
@click.argument("head", type=click.Path(dir_okay=False))
@click.option("--engine", type=click.Choice(["deformation", "nearest", "tangent"]), default="deformation",
              show_default=True, help="The transfer engine (as `facegeom transfer --engine`).")
@click.option("--landmarks", type=click.Path(dir_okay=False), default=None, metavar="CSV",
              help="A CSV landmark,vertex_id (head vertex ids of iBUG landmarks, 4 or more): used in the registration "
                   "and shown as given; the others start at the head vertex closest to the registered template's.")
@click.option("--units", type=click.Choice(["auto", "mm", "cm", "m"]), default="auto", show_default=True,
              help="The head's units (auto: the power of ten that makes it face-sized).")
@click.option("--piece", "pieces", multiple=True, metavar="NAME=ROLE",
              help="How a separate piece moves (eye, jaw, stay, follow, skin), as `facegeom transfer --piece`.")
@click.option("--shape", default=None, metavar="NAME", help="Set this ICT shape's slider at start (e.g. jawOpen).")
@click.option("--weight", type=click.FloatRange(0, 1), default=None, metavar="W",
              help="The weight --shape starts at, in [0, 1]; default 1.")
@click.option("--save-landmarks", "save_landmarks", type=click.Path(dir_okay=False), default=None, metavar="CSV",
              help="Where the panel's 'save landmarks' button writes the 68 landmarks (landmark,vertex_id, what "
                   "--landmarks and `facegeom transfer --landmarks` read); without it they cannot be saved.")
@_output_options
@click.pass_obj
def view_transfer(obj, head, engine, landmarks, units, pieces, shape, weight, save_landmarks, screenshot, size,
                  exit_after, state_path):
    """Register HEAD, transfer the ICT expressions, and show the ICT template beside the character.

    One set of sliders (the 53 ICT names) drives both; the registered template is drawn over the character
    (a checkbox hides it). The 68 landmarks can be dragged over the head, saved (--save-landmarks) and used
    for a new registration from the panel. HEAD: as `facegeom transfer` (a mesh, a glTF scene, a rig .npz).
    """
    from facegeom.cli.flags import as_flags
    from facegeom.cli.transfer import parse_pieces
    from facegeom.pipelines.character import read_head
    from facegeom.errors import InputError
    from facegeom.viewer.app import check_display

    check_display(screenshot)
    _check_screenshot(screenshot, head, landmarks)
    _size(size)
    if save_landmarks is not None:
        from facegeom.io import check_outputs, check_writable_folder

        check_outputs([head], [save_landmarks, screenshot])
        check_writable_folder(save_landmarks)
    if weight is not None and shape is None:
        raise InputError("--weight W sets the weight of --shape NAME: give the shape too")
    roles = parse_pieces(pieces)
    from facegeom.methods.transfer import read_head_landmarks
    from facegeom.viewer.rig import TransferView, find_shape, register_and_transfer

    model = obj.face_model()
    if shape is not None:
        i = find_shape(model.expression_names, shape, "ICT expression")
        start = {model.expression_names[i]: 1.0 if weight is None else weight}
    else:
        start = None
    V, F, parts = read_head(head)
    click.echo(f"{Path(head).name}: {V.shape[0]} vertices, {F.shape[0]} triangles"
               + (f", {len(parts)} parts" if parts else ""))
    lm = read_head_landmarks(landmarks, V.shape[0]) if landmarks else None
    character, result = register_and_transfer(model, V, F, engine=engine, landmarks=lm, units=units, path=head,
                                              parts=parts, roles=roles,
                                              progress=lambda line: click.echo(as_flags(line)))
    v = TransferView(model, character, result, head_path=head, engine=engine, units=units, roles=roles,
                     landmarks=lm, save_path=save_landmarks, weights=start,
                     background=screenshot is None)  # a window: re-registration in a worker process
    _run(v, screenshot, size, exit_after, state_path)


@view.command("character")
@click.option("--take", "take_path", type=click.Path(dir_okay=False), default=None,
              help="A Live Link Face CSV take (default: the first take of --takes, else of the takes lookup).")
@click.option("--takes", "takes_path", type=click.Path(), default=None,
              help=f"Folder of takes, for the default take (default: {TAKES_LOOKUP}).")
@click.option("--character", "character_path", type=click.Path(), default=None, metavar="RIG|HEAD",
              help="The character's rig (an OBJ folder, .glb/.gltf or .npz, e.g. from `facegeom transfer`): its "
                   "shapes driven by name from the take's ARKit weights, as `facegeom animate --take --character`; "
                   "with --route markers any head (a mesh, a glTF scene or a rig's neutral).")
@click.option("--character-names", "character_map", type=click.Path(dir_okay=False), default=None,
              metavar="MAP.csv",
              help="With --character: a mapping CSV rig_shape,source_shape,gain from ARKit names to the "
                   "character's shapes (gains per shape).")
@click.option("--start", default=0, show_default=True, type=click.IntRange(0), help="First frame of the take played.")
@click.option("--frames", default=None, type=click.IntRange(1, 1000000),
              help="Frames played (default: the rest of the take from --start).")
@click.option("--frame", default=0, show_default=True, type=click.IntRange(0),
              help="Frame of the window shown first (and in the screenshot).")
@click.option("--route", type=click.Choice(["rig", "markers"]), default="rig", show_default=True,
              help="rig: the character's rig plays the mapped weights; markers: any head (--character HEAD: a mesh, "
                   "a glTF scene or a rig's neutral) driven through markers retargeted from key frames, whose "
                   "labels the mouse edits (as `facegeom animate --route markers`).")
@click.option("--keys", default=None, metavar="N|F1,F2,...",
              help="With --route markers: the number of key frames chosen (default 10), or the key frames (take "
                   "frames).")
@click.option("--key-labels", "key_labels", type=click.Path(dir_okay=False), default=None, metavar="CSV",
              help="With --route markers: labels of key frames (frame,marker,vertex,x,y,z, what --save-key-labels "
                   "and `facegeom animate --save-key-labels` write); its frames are key frames.")
@click.option("--save-key-labels", "save_labels", type=click.Path(dir_okay=False), default=None, metavar="CSV",
              help="With --route markers: where 'save labels' (and the key s) writes every key frame's markers "
                   "(default: key-labels.csv in the current folder); `facegeom animate --route markers "
                   "--key-labels` reads it.")
@_output_options
@click.pass_obj
def view_character(obj, take_path, takes_path, character_path, character_map, start, frames, frame, route, keys,
                   key_labels, save_labels, screenshot, size, exit_after, state_path):
    """Play a Live Link take on the actor (the ICT face) beside your character.

    Actor | character, both coloured by the displacement from their neutral (mm, one scale). With --route rig
    (the default) the character's rig plays the mapped weights and turns with the take's head rotation; with
    --route markers any head is driven through markers retargeted from key frames, and at a key frame (paused)
    its markers are dragged with the mouse and saved as key labels. Play/pause, frame slider, speed.
    """
    from facegeom.cli.context import take_files
    from facegeom.cli.flags import as_flags
    from facegeom.errors import InputError
    from facegeom.viewer.app import check_display

    check_display(screenshot)
    _check_screenshot(screenshot, take_path, character_path, character_map, key_labels)
    _size(size)
    if character_path is None:
        if character_map is not None:
            raise InputError("--character-names goes with --character")
        raise InputError("give the character: --character RIG (an OBJ folder, .glb/.gltf or .npz, e.g. from "
                         "`facegeom transfer`)")
    if route == "markers":
        if character_map is not None:
            raise InputError("--character-names maps a rig's shapes: it does not go with --route markers")
        _view_character_markers(obj, take_files(takes_path, take_path)[0], character_path, start, frames, frame,
                                keys, key_labels, save_labels, screenshot, size, exit_after, state_path)
        return
    given = [f for f, v in (("--keys", keys), ("--key-labels", key_labels), ("--save-key-labels", save_labels))
             if v is not None]
    if given:
        raise InputError(f"{given[0]} goes with --route markers")
    path = take_files(takes_path, take_path)[0]
    _check_screenshot(screenshot, path)
    from facegeom.io.takes import read_take

    take = read_take(path)
    character = load_cli_rig(character_path, obj.face_model, names_map=character_map)
    from facegeom.viewer.character import CharacterView

    v = CharacterView(obj.face_model(), take, character, start=start, frames=frames, frame=frame,
                      character_name=Path(character_path).name)
    for line in v.notes:
        click.echo(as_flags(line))
    T = v.n_frames
    click.echo(f"{path.name} frames {start}..{start + T - 1} ({T / v.fps:.1f} s at {v.fps:g} fps) on "
               f"{Path(character_path).name}: {len(character.names)} shapes, {character.n_vertices} vertices")
    _run(v, screenshot, size, exit_after, state_path)


def _view_character_markers(obj, path, head, start, frames, frame, keys, key_labels, save_labels, screenshot, size,
                            exit_after, state_path):
    """``view character --route markers``: the head registered, the route built, the labels edited in the window."""
    from facegeom.cli.flags import as_flags
    from facegeom.cli.single import parse_keys
    from facegeom.pipelines.character import read_head
    from facegeom.io import check_outputs, check_writable_folder
    from facegeom.io.key_labels import read_key_labels
    from facegeom.io.takes import read_take
    from facegeom.model.layouts import ict80

    count, listed = parse_keys(keys) if keys is not None else (None, [])
    _check_screenshot(screenshot, path)
    if save_labels is not None:  # the labels read may be saved over: editing a file is the point
        check_outputs([path, head], [save_labels, screenshot])
        check_writable_folder(save_labels)
    from facegeom.viewer.character_markers import MarkerCharacterView

    take = read_take(path)
    model = obj.face_model()
    given = read_key_labels(key_labels, len(ict80(model)), n_frames=take.n_frames) if key_labels else None
    V, F, parts = read_head(head)
    click.echo(f"{Path(head).name}: {V.shape[0]} vertices, {F.shape[0]} triangles"
               + (f", {len(parts)} parts" if parts else ""))
    v = MarkerCharacterView(model, take, V, F, start=start, frames=frames, frame=frame, keys=listed,
                            n_keys=count or 10, key_labels=given, parts=parts, character_name=Path(head).name,
                            save_path=save_labels, progress=lambda line: click.echo(as_flags(line)), echo=click.echo)
    T = v.n_frames
    click.echo(f"{path.name} frames {start}..{start + T - 1} ({T / v.fps:.1f} s at {v.fps:g} fps) on {Path(head).name} "
               f"through markers; key frames {', '.join(str(int(f) + start) for f in v.keys)} (take frames); "
               f"'save labels' writes {v.save_path}")
    _run(v, screenshot, size, exit_after, state_path)


@view.command("track")
@click.argument("track_path", metavar="TRACK.npz", type=click.Path(dir_okay=False))
@click.option("--video", "video_path", type=click.Path(dir_okay=False), default=None,
              help="The video that was tracked (default: the file the track names, if it is still there).")
@click.option("--rig", "rig_path", type=click.Path(), default=None,
              help="The actor's rig, for a track made with `facegeom track --rig` (it stores no identity).")
@click.option("--character", "character_path", type=click.Path(), default=None, metavar="RIG",
              help="Also play the curves on this character's rig (an OBJ folder, .glb/.gltf or .npz), its shapes "
                   "driven by name as `facegeom track --character` drives them.")
@click.option("--character-names", "character_map", type=click.Path(dir_okay=False), default=None,
              metavar="MAP.csv", help="With --character: a mapping CSV rig_shape,source_shape,gain.")
@click.option("--frame", default=0, show_default=True, type=click.IntRange(0), help="Frame shown first.")
@_output_options
@click.pass_obj
def view_track(obj, track_path, video_path, rig_path, character_path, character_map, frame, screenshot, size,
               exit_after, state_path):
    """Check a track by looking: the video's frame with the fit drawn over it | the fitted face | the character.

    TRACK.npz is what `facegeom track -o OUT.npz` writes. The frame shows the fitted face as a wireframe and the
    68 landmarks found; beside it the fitted actor plays the curves under the head pose (and your character,
    with --character). Play/pause, frame slider (scrubbing), speed, the fit residual over time.
    """
    from facegeom.errors import InputError
    from facegeom.viewer.app import check_display

    check_display(screenshot)
    if character_map is not None and character_path is None:
        raise InputError("--character-names goes with --character")
    _check_screenshot(screenshot, track_path, video_path, rig_path, character_path, character_map)
    _size(size)
    from facegeom.pipelines.track import read_track_npz

    track = read_track_npz(track_path)
    if video_path is None:
        if not track.source or not Path(track.source).is_file():
            where = f" (it names {track.source}, which is not there)" if track.source else ""
            raise InputError(f"give the video that was tracked: --video VIDEO{where}", track_path)
        video_path = track.source
    elif not Path(video_path).is_file():
        raise InputError("no such file", video_path)
    _check_screenshot(screenshot, video_path)
    model = obj.face_model()
    rig = load_cli_rig(rig_path, obj.face_model) if rig_path else None
    character = load_cli_rig(character_path, obj.face_model, names_map=character_map) if character_path else None
    from facegeom.viewer.track import TrackView

    v = TrackView(model, track, video_path, rig=rig, character=character, frame=frame,
                  character_name=Path(character_path).name if character_path else None)
    try:
        for line in v.notes:
            click.echo(line)
        found = int(track.found.sum())
        click.echo(f"{Path(video_path).name}: {track.n_frames} frames at {track.fps:g} fps, face found in {found}")
        _run(v, screenshot, size, exit_after, state_path)
    finally:
        v.close()
