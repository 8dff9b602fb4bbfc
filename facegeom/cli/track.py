"""``facegeom track``: a video of a face -> weight curves, head pose and gaze (Live Link CSV, npz, glTF)."""
from __future__ import annotations

from pathlib import Path

import click

OUTPUTS = (".csv", ".npz", ".glb", ".usda", ".usdc", ".usdz")


@click.command("track")
@click.argument("video", type=click.Path(dir_okay=False))
@click.option("-o", "--output", "outputs", required=True, multiple=True, type=click.Path(dir_okay=False),
              help="Output, repeatable: OUT.csv (a Live Link Face take: the 52 ARKit weights, head and eye "
                   "rotations), OUT.npz (curves, head pose, gaze, the 468 points and 68 landmarks per frame, "
                   "per-frame fit residual, identity, camera) or OUT.glb / OUT.usdc (the fitted actor animated; with "
                   "--character, your character).")
@click.option("--character", "character_path", type=click.Path(), default=None,
              help="Play the performance on this character's rig (an OBJ folder, .glb/.gltf or .npz, e.g. from "
                   "`facegeom transfer`), as `animate --character` plays a take: its shapes driven by name, the "
                   "head's turns carried over.")
@click.option("--character-names", "character_map", type=click.Path(dir_okay=False), default=None,
              help="With --character: a mapping CSV rig_shape,source_shape,gain from ARKit names to its shapes.")
@click.option("--rig", "rig_path", type=click.Path(), default=None,
              help="The actor's own rig (an .npz from `facegeom identity` or a previous track's --rig-out, with the "
                   "face model's vertices); default: the actor's identity is fitted from the video itself.")
@click.option("--rig-out", type=click.Path(), default=None, help="Write the actor's fitted rig (.npz).")
@click.option("--focal", type=float, default=None,
              help="The camera's focal length in pixels (default: estimated from the video).")
@click.option("--smooth", default="auto", show_default=True,
              help="Temporal smoothing of the curves, the head pose and the gaze: auto (a zero-phase Whittaker "
                   "smoother halving motion at 4 Hz), off, or a Whittaker strength.")
@click.option("--calibrate/--no-calibrate", "calibration", default=True, show_default=True,
              help="Neutral calibration: a shape that never relaxes in the video is the actor's rest and is taken "
                   "off.")
@click.option("--detector", type=click.Choice(["auto", "short", "full"]), default="auto", show_default=True,
              help="The face detector (short: faces near the camera; full: small faces).")
@click.option("--frames", "max_frames", type=click.IntRange(1), default=None, help="Only the first N frames.")
@click.option("--preview", type=click.Path(dir_okay=False), default=None,
              help="Also write the video with the landmarks and the fitted face drawn over it (.mp4).")
@click.pass_obj
def track_cmd(obj, video, outputs, character_path, character_map, rig_path, rig_out, focal, smooth, calibration,
              detector, max_frames, preview):
    """Track the face in VIDEO: its blendshape weights, head pose and gaze per frame, no markers.

    MediaPipe's face detector, 468-point face mesh and iris models find the face in every frame (on the CPU,
    offline); the actor's identity and the camera's focal length are fitted from the video itself, then each
    frame's pose and expression. Frames without a face are bridged and reported.
    """
    import time

    import numpy as np

    from facegeom.cli.flags import as_flags
    from facegeom.cli.solve import parse_smooth
    from facegeom.errors import InputError
    from facegeom.io import check_outputs

    outs = [Path(o) for o in outputs]
    for o in outs:
        if o.suffix.lower() not in OUTPUTS:
            raise InputError(f"unsupported output {o.suffix!r}; use {', '.join(OUTPUTS)}", o)
    if character_map and not character_path:
        raise InputError("--character-names goes with --character")
    if preview and Path(preview).suffix.lower() not in (".mp4", ".mov", ".mkv"):
        raise InputError("--preview must be a video file (.mp4, .mov or .mkv)", preview)
    if rig_out and Path(rig_out).suffix.lower() != ".npz":
        raise InputError("--rig-out must be an .npz", rig_out)
    check_outputs([video, character_path, character_map, rig_path], [*outs, preview, rig_out])
    if not Path(video).exists():
        raise InputError("no such file", video)
    smooth_value = parse_smooth(smooth)
    model = obj.face_model()
    rig = None
    if rig_path:
        from facegeom.model import load_rig

        rig = load_rig(rig_path, lambda: model)
    character = None
    if character_path:
        from facegeom.cli.rigopts import load_cli_rig

        character = load_cli_rig(character_path, obj.face_model, names_map=character_map)
    from facegeom.pipelines.track import track_video, write_track_npz
    from facegeom.pipelines.solve import write_curves

    from facegeom.cli.progress import Ticker

    progress = Ticker("track", "frame")  # a bar on a terminal, a line every few seconds in a pipe or a log
    t0 = time.process_time()
    try:
        result = track_video(video, model, rig=rig, focal=focal, smooth=smooth_value, calibration=calibration,
                             detector=detector, progress=progress, max_frames=max_frames,
                             stage=lambda line: click.echo(f"track: {line}", err=True))
    finally:
        progress.close()
    solved = result.solved
    played = solved
    if character is not None:
        from facegeom.pipelines.character import onto_character

        played = onto_character(solved, character, actor=result.rig)
    from facegeom.io import all_or_nothing

    with all_or_nothing(outs + ([Path(rig_out)] if rig_out else [])) as tmps:
        for o, tmp in zip(outs, tmps):
            if o.suffix.lower() == ".npz":
                write_track_npz(tmp, result)
            else:
                write_curves(tmp, played)
        if rig_out:
            result.rig.save_npz(tmps[-1])
    if preview:
        from facegeom.pipelines.track_preview import write_preview

        click.echo(f"track: drawing the preview, {Path(preview).name} ...", err=True)
        write_preview(video, result, preview)
    cpu = time.process_time() - t0
    lines = solved.notes + (played.notes[len(solved.notes):] if played is not solved else [])
    for line in dict.fromkeys(lines):  # each once; the writers name the temporary files they wrote into
        for o, tmp in zip(outs, tmps):
            line = line.replace(Path(tmp).name, o.name)
        click.echo(as_flags(line))
    T = result.n_frames
    s = result.seconds
    click.echo(f"{Path(video).name}: {T} frames ({T / result.fps:.1f} s at {result.fps:.3g} fps, {result.width} x "
               f"{result.height}), face in {int(result.found.sum())}; focal length {result.focal:.0f} px"
               f"{' (estimated)' if result.focal_estimated else ''}; fit residual {np.nanmedian(result.residual):.2f}"
               f" px (median)")
    click.echo(f"  {T / max(cpu, 1e-9):.1f} frames per CPU second (decode {s['decode']:.1f} s, face points "
               f"{s['points']:.1f} s, identity {s['identity']:.1f} s, frames {s['frames']:.1f} s)")
    for o in outs:
        click.echo(f"wrote {o}")
    if rig_out:
        click.echo(f"wrote {rig_out}")
    if preview:
        click.echo(f"wrote {preview}")

