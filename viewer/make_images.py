"""Regenerate the viewer's README images, one PNG per view, headless.

Usage::

    python -m facegeom.viewer.make_images --out docs/images [--only drive,fit] [--size 1600x900]

Writes ``view-drive.png``, ``view-retarget.png``, ``view-animate.png``,
``view-fit.png``, ``view-character.png`` and ``view-character-markers.png`` (the same scenes as ``facegeom view <name> --screenshot``, with
fixed, seeded settings). Needs the face data (``--data`` or ``$FACEGEOM_DATA``)
and, for retarget/animate, the ARKit takes (``--takes`` or ``$FACEGEOM_TAKES``;
a synthetic take otherwise). Renders with EGL: no display or GPU needed.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from facegeom.errors import FacegeomError

VIEWS = ("drive", "retarget", "animate", "fit", "character", "character-markers")

# fixed settings of the README scenes
DRIVE = dict(methods="rbf;laplacian;biharmonic;tangent", seed=0, expression="happiness", intensity=0.9)
TAKE = dict(take="alex_rom_3.csv", frames=120, seed=0, labels=10)  # the window around its most intense frame
RETARGET_METHODS = "copy;rbf;tangent"
ANIMATE = dict(retargeters="copy;tangent", deformer="tangent")
FIT = dict(methods="sem;l1reg;pcadel", case=0, seed=0, kind="landmarks", noise_px=1.0)
# the character view: an artist's ARKit rig (MakeHuman, CC0; see tests/data/heads/SOURCES.md) playing the take
CHARACTER = Path(__file__).resolve().parents[1] / "tests" / "data" / "heads" / "makehuman_stylised_arkit.npz"
# the marker route's view: a scanned head with no rig (Lee Perry-Smith, CC BY 3.0; see tests/data/heads/SOURCES.md)
SCANNED_HEAD = CHARACTER.with_name("lee_perry_smith.ply")


def _take_window(model, takes):
    """The README's take and window start: around the take's most intense frame -> ``(path, start, frames)``."""
    import numpy as np

    from facegeom.io import find_takes, ict_weights, read_take
    from facegeom.model import locate_takes

    n = TAKE["frames"]
    folder = locate_takes(takes)
    path = folder / TAKE["take"] if folder.is_dir() else folder
    if not path.is_file():
        path = find_takes(folder)[0]
    W = ict_weights(read_take(path), model.expression_names)
    start = int(np.clip(int(np.argmax(W.sum(axis=1))) - n // 2, 0, max(W.shape[0] - n, 0)))
    return path, start, min(n, W.shape[0])


def _sequence(model, takes):
    """The README's take window as an actor/character sequence; a synthetic take without takes."""
    from facegeom.viewer.playback import load_sequence

    try:
        path, start, n = _take_window(model, takes)
        return load_sequence(model, path, None, start, n, TAKE["seed"])
    except FacegeomError as exc:
        print(f"no take ({exc}); using a synthetic one", file=sys.stderr)
        return load_sequence(model, frames=TAKE["frames"], seed=TAKE["seed"], synthetic=True)


def _peak(seq) -> int:
    """The frame where the character's markers are farthest from rest."""
    import numpy as np

    return int(np.argmax(np.linalg.norm(seq.target - seq.target_rest, axis=2).mean(axis=1)))


def build(name: str, model, takes=None):
    """The view ``name`` with the README's settings."""
    if name == "drive":
        from facegeom.viewer.drive import DriveView

        return DriveView(model, **DRIVE)
    if name == "retarget":
        from facegeom.viewer.playback import RetargetView

        seq = _sequence(model, takes)
        return RetargetView(model, seq, RETARGET_METHODS, TAKE["labels"], frame=_peak(seq))
    if name == "animate":
        from facegeom.viewer.playback import AnimateView

        seq = _sequence(model, takes)
        return AnimateView(model, seq, labels=TAKE["labels"], frame=_peak(seq), **ANIMATE)
    if name == "fit":
        from facegeom.viewer.fit import FitView

        return FitView(model, **FIT)
    if name == "character":
        from facegeom.model import load_rig
        from facegeom.viewer.character import CharacterView

        if not CHARACTER.is_file():
            raise FacegeomError(f"the README's character rig is not here: {CHARACTER} (a source checkout has it)")
        path, start, n = _take_window(model, takes)
        return CharacterView(model, path, load_rig(CHARACTER), start=start, frames=n, frame=n // 2,
                             character_name=CHARACTER.name)
    if name == "character-markers":
        from facegeom.pipelines.character import read_head
        from facegeom.viewer.character_markers import MarkerCharacterView

        if not SCANNED_HEAD.is_file():
            raise FacegeomError(f"the README's scanned head is not here: {SCANNED_HEAD} (a source checkout has it)")
        path, start, n = _take_window(model, takes)
        V, F, parts = read_head(SCANNED_HEAD)
        view = MarkerCharacterView(model, path, V, F, start=start, frames=n, n_keys=6, parts=parts,
                                   character_name=SCANNED_HEAD.name, echo=lambda line: None)
        view.set_frame(int(view.keys[len(view.keys) // 2]))  # paused on a key frame: its markers drawn
        return view
    raise ValueError(f"unknown view {name!r}; choose from {', '.join(VIEWS)}")


def main(argv=None) -> int:
    """Command line of ``python -m facegeom.viewer.make_images``: render the views of ``--only`` into ``--out``.

    Parameters
    ----------
    argv : list of str, optional
        The arguments (default: ``sys.argv[1:]``).

    Returns
    -------
    int
        Exit status: 0 on success, 2 on a facegeom error (one line on stderr).
    """
    ap = argparse.ArgumentParser(prog="python -m facegeom.viewer.make_images", description=__doc__.split("\n")[0])
    ap.add_argument("--out", default="docs/images", help="output folder (default: docs/images)")
    ap.add_argument("--only", default=",".join(VIEWS), help=f"comma-separated subset of {', '.join(VIEWS)}")
    ap.add_argument("--size", default="1600x900", help="image size WxH (default: 1600x900)")
    ap.add_argument("--data", default=None, help="face data bundle (default: $FACEGEOM_DATA)")
    ap.add_argument("--takes", default=None, help="folder of ARKit takes (default: $FACEGEOM_TAKES)")
    args = ap.parse_args(argv)
    try:
        from facegeom.model import load_face_model
        from facegeom.viewer.app import init_polyscope, parse_size

        names = [x.strip() for x in args.only.split(",") if x.strip()]
        bad = [x for x in names if x not in VIEWS]
        if bad or not names:
            what = repr(bad[0]) if bad else "(empty)"
            raise FacegeomError(f"--only: unknown view {what}; choose from {', '.join(VIEWS)}")
        w, h = parse_size(args.size)
        model = load_face_model(args.data)
        init_polyscope(headless=True)
        out = Path(args.out)
        for name in names:
            t = time.perf_counter()
            view = build(name, model, args.takes)
            view.setup_scene(w, h, headless=True)
            path = view.screenshot(out / f"view-{name}.png")
            print(f"wrote {path} ({time.perf_counter() - t:.1f} s)")
    except FacegeomError as exc:
        print(f"make_images: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
