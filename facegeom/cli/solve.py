"""``facegeom solve``: a marker capture -> blendshape weight curves (see :mod:`facegeom.pipelines.solve`)."""
from __future__ import annotations

from pathlib import Path

import click

from facegeom.cli.context import Context, parse_params
from facegeom.cli.flags import as_flags
from facegeom.cli.rigopts import load_cli_rig, rig_options


def parse_smooth(text: str):
    """``--smooth`` value: ``"auto"``, ``"off"`` or a non-negative finite number."""
    t = str(text).strip().lower()
    if t in ("auto", "off"):
        return t
    try:
        v = float(t)
    except ValueError:
        v = float("nan")
    if not 0 <= v < float("inf"):
        from facegeom.errors import InputError

        raise InputError(f"--smooth {text!r}: use auto, off or a number >= 0")
    return v


class _Progress:
    """A tqdm bar on stderr that learns its total from the first report (shown on runs of 2,000+ frames)."""

    def __init__(self):
        self.bar = None

    def __call__(self, done: int, total: int) -> None:
        if total < 2000:  # no bar (nor tqdm imported) for a short capture
            return
        from tqdm import tqdm

        if self.bar is None:
            self.bar = tqdm(total=total, unit="frame", desc="solve", leave=False)
        self.bar.update(done - self.bar.n)

    def close(self) -> None:
        """Close the bar if one was opened."""
        if self.bar is not None:
            self.bar.close()


@click.command("solve")
@click.argument("capture", type=click.Path(dir_okay=False))
@click.option("--rig", "rig_path", type=click.Path(), default=None,
              help="Rig: a folder of OBJs (a neutral + one OBJ per shape), a glTF file (.glb/.gltf) or an .npz "
                   "(BlendshapeRig.save_npz); default: the ICT generic face.")
@rig_options
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="Curves file: .npz (weights, head motion, solve info), .glb (the rig with named morph targets and the weights as a glTF animation) or .csv (a Live Link Face take).")
@click.option("--fitter", default="sem-ls", show_default=True, help="A registered fitter (see `facegeom methods`).")
@click.option("-p", "--param", "params", multiple=True, metavar="KEY=VALUE", help="Fitter parameter, repeatable.")
@click.option("--markers", default=None,
              help="Marker -> vertex: a map CSV (header marker,vertex_id or marker,vertex) or a layout (ict80, "
                   "landmarks68, random<k>, the markers in file order); default: the marker names are vertex ids "
                   "(v123 or 123).")
@click.option("--smooth", default="auto", show_default=True,
              help="Temporal smoothing of the curves: auto (a Whittaker smoother, strength per curve by generalised "
                   "cross-validation; on 0.5 mm marker noise it halves the weight error), off, or a strength.")
@click.option("--identity", type=click.Choice(["auto", "off"]), default="auto", show_default=True,
              help="On the generic face (no --rig): auto fits the actor's identity from the capture first (the "
                   "face's shape from frames that look neutral, so that the actor's proportions do not read as "
                   "expressions); off solves on the generic face as it is. A rig of your own is used as it is.")
@click.option("--character", "character_path", type=click.Path(), default=None,
              help="Play the solved performance on this character's rig (an OBJ folder, .glb/.gltf or .npz, e.g. from "
                   "`facegeom transfer`): its shapes driven by name from the actor's, the head's motion scaled to "
                   "it; -o then holds the character (.glb: its mesh, shapes and animation).")
@click.option("--character-names", "character_map", type=click.Path(dir_okay=False), default=None,
              help="With --character: a mapping CSV rig_shape,source_shape,gain from the actor's names to the "
                   "character's shapes (gains per shape).")
@click.pass_obj
def solve_cmd(obj: Context, capture, rig_path, neutral, names_map, units, up, output, fitter, params, markers,
              smooth, identity, character_path, character_map):
    """Solve the markers of CAPTURE (a marker sequence) to weight curves of the rig, head motion removed."""
    import numpy as np

    from facegeom import registry
    from facegeom.constants import CM_TO_MM  # the solve works in rig units, cm (RIG_UNIT)
    from facegeom.errors import InputError
    from facegeom.io import check_outputs
    from facegeom.pipelines.solve import CURVE_WRITERS, solve_file, write_curves

    amount = parse_smooth(smooth)
    map_file = markers if markers and Path(markers).suffix.lower() == ".csv" else None
    check_outputs([capture, rig_path, map_file, names_map, character_path, character_map], [output])
    if character_map and not character_path:
        raise InputError("--character-names goes with --character")
    if Path(output).suffix.lower() not in CURVE_WRITERS:
        raise InputError(f"unsupported curves format {Path(output).suffix!r}; use {', '.join(CURVE_WRITERS)}",
                         output)
    rig = load_cli_rig(rig_path, obj.face_model, neutral, names_map, units, up)
    f = registry.create("fitters", fitter, **parse_params(params))
    progress = _Progress()
    try:
        solved = solve_file(capture, rig, f, fitter, markers, amount, progress, identity)
    finally:
        progress.close()
    if character_path:
        from facegeom.pipelines.character import onto_character

        solved = onto_character(solved, load_cli_rig(character_path, obj.face_model, names_map=character_map),
                                actor=solved.rig)
    write_curves(output, solved)
    for line in solved.notes:
        click.echo(as_flags(line))
    s = solved.solve
    T = s.weights.shape[0]
    smooth_txt = "off" if not s.smoothing.any() else f"median strength {float(np.median(s.smoothing)):.3g}"
    click.echo(f"{fitter}: {T} frames x {solved.vertex_ids.size} markers -> {len(s.names)} shapes in "
               f"{s.time_s:.2f} s ({s.time_s / T * 1e3:.2f} ms/frame); marker residual median "
               f"{float(np.median(s.rms)) * CM_TO_MM:.4g} mm, {int(s.lost.sum())} lost markers; smoothing {smooth_txt}")
    click.echo(f"wrote {output}")
