"""``facegeom identity`` and ``facegeom fit --identity``: a person's identity from their faces -> a user-specific rig.

The protocol of the SEM paper (Sec. V-A): the identity is fitted to one or
several neutral frames of a subject (:class:`~facegeom.methods.identity.IdentityFitter`),
the user-specific rig is written, and ``facegeom fit --rig RIG`` then fits
expressions on it.
"""
from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path

import click

from facegeom.cli.context import Context, parse_params

TARGET_HELP = ("What the TARGETS are: meshes in correspondence with the model, landmarks (a vertex_id,u,v CSV or an "
               "iBUG .pts annotation) or point clouds (auto: .csv / .pts = landmarks, a mesh with the model's vertex "
               "count = mesh, else points).")

IMAGE_HELP = ("Landmarks: the photo they were marked on; its size sets --cx / --cy (the centre) and, when --focal is "
              "not given, the focal length (the larger side in pixels, a ~53 degree field of view).")


SCALE_HELP = ("Meshes and point clouds: the factor into the model's units (cm), or auto: the power of ten that "
              "makes the scan face-sized (a scan in mm gets 0.1).")


def read_targets(paths, model, kind="auto", focal=None, cx=None, cy=None, scale="auto"):
    """Read every target file for ``model`` (as ``facegeom fit`` reads one) -> ``(kinds, targets)``.

    Says on the terminal when a scan was rescaled into the model's units.
    """
    from facegeom.model import BlendshapeRig, read_fit_target

    rig = BlendshapeRig.from_face_model(model)
    kinds, targets, notes = [], [], []
    for p in paths:
        k, t = read_fit_target(Path(p), rig, kind, focal, cx, cy, scale, notes)
        kinds.append(k)
        targets.append(t)
    for line in notes:
        click.echo(line)
    return kinds, targets


def camera_defaults(focal, cx, cy, image):
    """``--focal / --cx / --cy`` completed from ``--image`` (:func:`facegeom.model.photo_camera`), said aloud."""
    if image is None:
        return focal, cx, cy
    from facegeom.io import image_size
    from facegeom.model import photo_camera

    given = focal is not None
    focal, cx, cy, assumed = photo_camera(focal, cx, cy, image)
    if assumed:
        w, h = image_size(image)
        click.echo(f"{Path(image).name}: {w} x {h} px; focal length not given, assumed {focal:g} px (the larger "
                   f"side; give --focal if you know it)")
    elif not given:
        from facegeom.io.images import focal_35mm

        w, h = image_size(image)
        click.echo(f"{Path(image).name}: {w} x {h} px; focal length {focal:.0f} px from the photo's EXIF (a "
                   f"{focal_35mm(image):g} mm lens, 35 mm equivalent)")
    return focal, cx, cy


def parse_scale(value: str):
    """``--scale``: ``auto`` or a positive number."""
    from facegeom.errors import InputError

    if value == "auto":
        return value
    try:
        f = float(value)
    except ValueError:
        f = float("nan")
    if not (f > 0 and f < float("inf")):
        raise InputError(f"--scale must be auto or a positive number, got {value!r}")
    return f


def write_rig(rig, path) -> Path:
    """Write ``rig`` to ``path``: an ``.npz`` (:meth:`BlendshapeRig.save_npz`), else a new folder of OBJs.

    The OBJ folder is written into a temporary folder next to it and renamed
    into place, so it appears complete or not at all.
    """
    from facegeom.errors import InputError

    path = Path(path)
    if path.suffix.lower() == ".npz":
        return rig.save_npz(path)
    if path.suffix:
        raise InputError(f"unsupported rig format {path.suffix!r}; use .npz or a folder name (OBJ folder)", path)
    if path.exists() and (not path.is_dir() or any(path.iterdir())):
        raise InputError("the rig folder already exists and is not empty", path)
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise InputError("the parent folder does not exist", path)
    if not os.access(parent, os.W_OK | os.X_OK):
        raise InputError(f"cannot write here: the folder {parent} is not writable", path)
    from facegeom.io.files import sweep_stale_temporaries

    sweep_stale_temporaries(parent, path)  # what a killed write of this folder left
    try:
        tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", dir=parent))
    except OSError as exc:  # the error names the rig folder, not the hidden one it would be built in
        raise InputError(f"cannot create the rig folder ({exc.strerror or exc})", path) from None
    try:
        rig.write_obj_folder(tmp)
        if path.exists():
            path.rmdir()
        os.replace(tmp, path)
    except OSError as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        raise InputError(f"cannot write the rig folder ({exc.strerror or exc})", path) from None
    except InputError as exc:  # named after the rig folder, not the hidden one it was built in
        shutil.rmtree(tmp, ignore_errors=True)
        raise InputError(str(exc.reason).replace(str(tmp), str(path)), path) from None
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return path


def write_coefficients(path, fit, names, files) -> Path:
    """Write the identity coefficients and, per target, its file, kind, weights by name, pose and RMS (JSON)."""
    from facegeom.errors import InputError
    from facegeom.io import atomic_path

    path = Path(path)
    if path.suffix.lower() != ".json":
        raise InputError("the coefficients file must be .json", path)
    data = {
        "identity": [float(a) for a in fit.identity],
        "targets": [{"file": str(f), **pose, "weights": {n: float(x) for n, x in zip(names, w)},
                     "rms": float(rms)}
                    for f, pose, w, rms in zip(files, fit.pose_dicts(), fit.weights, fit.info["rms"])],
        "time_s": float(fit.info["time_s"]),
        "rounds": int(fit.info["rounds"]),
    }
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(data, indent=2) + "\n")
    return path


@click.command("identity")
@click.argument("targets", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(),
              help="The user-specific rig: an .npz, or a new folder of OBJs (neutral.obj + one per expression).")
@click.option("--kind", type=click.Choice(["auto", "mesh", "landmarks", "points"]), default="auto", show_default=True,
              help=TARGET_HELP)
@click.option("--focal", type=float, default=None, help="Landmarks: focal length in pixels.")
@click.option("--cx", type=float, default=None, help="Landmarks: principal point x (pixels).")
@click.option("--cy", type=float, default=None, help="Landmarks: principal point y (pixels).")
@click.option("--image", type=click.Path(dir_okay=False), default=None, help=IMAGE_HELP)
@click.option("--scale", default="auto", show_default=True, help=SCALE_HELP)
@click.option("-p", "--param", "params", multiple=True, metavar="KEY=VALUE",
              help="Identity fitter parameter, repeatable (e.g. -p noise_px=2 -p n_identities=50).")
@click.option("--coefficients", type=click.Path(dir_okay=False), default=None,
              help="Also write the identity coefficients, per-target weights and poses (.json).")
@click.option("--with-expressions", is_flag=True,
              help="The targets are not neutral: fit an expression per target too (default: neutral frames).")
@click.pass_obj
def identity_cmd(obj: Context, targets, output, kind, focal, cx, cy, image, scale, params, coefficients,
                 with_expressions):
    """Fit one identity to TARGETS (neutral frames of one person) and write the user-specific rig.

    Then fit expressions on it with `facegeom fit TARGET --rig RIG`.
    """
    import numpy as np

    from facegeom.errors import InputError
    from facegeom.io import check_outputs
    from facegeom.methods.identity import IdentityFitter

    check_outputs(list(targets) + ([image] if image else []), [output] + ([coefficients] if coefficients else []))
    if coefficients and Path(coefficients).suffix.lower() != ".json":
        raise InputError("the coefficients file must be .json", coefficients)
    model = obj.face_model()
    focal, cx, cy = camera_defaults(focal, cx, cy, image)
    kinds, tgs = read_targets(targets, model, kind, focal, cx, cy, parse_scale(scale))
    fitter = IdentityFitter(**{"expressions": with_expressions, **parse_params(params)})
    fit = fitter.fit(model, tgs)
    write_rig(fit.rig, output)
    if coefficients:
        write_coefficients(coefficients, fit, fit.rig.names, targets)
    a = fit.identity
    click.echo(f"identity from {len(tgs)} target(s) ({', '.join(sorted(set(kinds)))}) in "
               f"{fit.info['time_s'] * 1e3:.1f} ms, {fit.info['rounds']} rounds; |a| = {np.linalg.norm(a):.2f} "
               f"over {a.size} modes -> {output}")
    for f, k, rms, found in zip(targets, kinds, fit.info["rms"], fit.info["searched"]):
        where = "; off the model's frame: posed by a global rigid search" if found else ""
        click.echo(f"  {Path(f).name:<24} {k:<9} rms {rms:.3g} {'px' if k == 'landmarks' else 'mm'}{where}")


def fit_identity_target(obj: Context, target, kind, focal, cx, cy, params, method, method_params, explicit_method,
                        scale="auto"):
    """``facegeom fit --identity``: identity + expression for one target.

    Returns ``(outcome, rig, label)``: a :class:`~facegeom.pipelines.single.FitOutcome`
    (the joint fit's weights, or those of ``method`` refitted on the user's rig
    when ``explicit_method``), the user-specific rig and the method label.
    """
    import time

    from facegeom import registry
    from facegeom.methods.fitting import to_rig_frame
    from facegeom.methods.identity import IdentityFitter
    from facegeom.pipelines.single import FitOutcome
    from facegeom.registration import RigidAlignment

    model = obj.face_model()
    (k,), (tg,) = read_targets([target], model, kind, focal, cx, cy, scale)
    fitter = IdentityFitter(**parse_params(params))
    t = time.perf_counter()
    fit = fitter.fit(model, tg)
    rig = fit.rig
    pose = fit.cameras[0]
    if k != "landmarks":  # model -> scan
        pose = RigidAlignment(fit.rotations[0], fit.translations[0])
    if explicit_method:
        m = registry.create("fitters", method, **method_params)
        if k != "landmarks":  # the refit sees the mesh or scan in the model's frame, where the identity fit posed it
            tg = to_rig_frame(tg, pose)
        r = m.fit(rig, tg)
        cam = r.info.get("camera") if k == "landmarks" else pose
        out = FitOutcome(k, r.weights, cam, r.vertices, time.perf_counter() - t)
        return out, rig, f"identity+{method}"
    out = FitOutcome(k, fit.weights[0], pose, fit.vertices(0), time.perf_counter() - t)
    return out, rig, "identity"
