"""``facegeom detect``: the 68 landmarks (and all 468 face-mesh points) of the faces in photos."""
from __future__ import annotations

from pathlib import Path

import click


def _outputs(src: Path, out: Path, mesh_out: Path | None, n: int, folder: bool):
    """The ``.pts`` (and mesh CSV) paths of one image's ``n`` faces."""
    if folder:
        base = [out / (f"{src.stem}.pts" if n == 1 else f"{src.stem}_{k + 1}.pts") for k in range(n)]
        mesh = (mesh_out / f"{src.stem}.csv") if mesh_out else None
        return base, mesh
    if n == 1:
        return [out], mesh_out
    return [out.with_name(f"{out.stem}_{k + 1}{out.suffix}") for k in range(n)], mesh_out


@click.command("detect")
@click.argument("source", type=click.Path())
@click.option("-o", "--output", required=True, type=click.Path(),
              help="The .pts file (68 points, 1-based pixels); for a FOLDER of photos, a folder (one NAME.pts "
                   "per photo).")
@click.option("--mesh-points", "mesh_points", type=click.Path(), default=None,
              help="Also write all 468 face-mesh points (and the irises) as a CSV face,point,x,y,z; for a FOLDER, "
                   "a folder of NAME.csv.")
@click.option("--all", "all_faces", is_flag=True, default=False,
              help="Every face, not only the largest: OUT_1.pts, OUT_2.pts, ... largest first.")
@click.option("--detector", type=click.Choice(["auto", "short", "full"]), default="auto", show_default=True,
              help="The face detector: short range (faces near the camera), full range (small, far faces), or "
                   "auto (short, then full, then the photo zoomed out for a close-up).")
def detect_cmd(source, output, mesh_points, all_faces, detector):
    """Find the faces of a photo (or of every photo in a FOLDER): 68 landmarks as an iBUG .pts file.

    Runs MediaPipe's face detector and 468-point face-mesh model (Apache-2.0; fetched once through the package
    registry into the user cache) on the CPU, and maps the 468 points to the 68 landmarks of the iBUG / 300-W
    convention through the face model.
    """
    import numpy as np
    from tqdm import tqdm

    from facegeom.errors import InputError
    from facegeom.io import all_or_nothing, check_outputs
    from facegeom.io.detections import write_mesh_points, write_pts
    from facegeom.io.images import list_images, read_image
    from facegeom.vision.faces import FaceFinder

    src = Path(source)
    out = Path(output)
    mesh_out = Path(mesh_points) if mesh_points else None
    folder = src.is_dir()
    if folder:
        images = list_images(src)
        for o in (out, mesh_out):
            if o is not None:
                if o.exists() and not o.is_dir():
                    raise InputError("is a file: with a folder of photos, -o and --mesh-points name folders", o)
                o.mkdir(parents=True, exist_ok=True)
        check_outputs([src], [out, mesh_out])
    else:
        if not src.exists():
            raise InputError("no such file", src)
        if out.suffix.lower() != ".pts":
            raise InputError("-o must be a .pts file (the iBUG landmark format)", out)
        if mesh_out is not None and mesh_out.suffix.lower() != ".csv":
            raise InputError("--mesh-points must be a .csv file", mesh_out)
        check_outputs([src], [out, mesh_out])
        images = [src]
    finder = FaceFinder(detector=detector)
    found = missed = 0
    bar = tqdm(images, unit="photo", desc="detect", disable=True if len(images) < 2 else None, leave=False)
    for path in bar:
        rgb = read_image(path)
        faces = finder.find(rgb, all_faces=all_faces)
        if not faces:
            if not folder:
                raise InputError("no face found in the photo", path)
            missed += 1
            tqdm.write(f"{path.name}: no face found")
            continue
        pts_paths, mesh_path = _outputs(path, out, mesh_out, len(faces), folder)
        paths = pts_paths + ([mesh_path] if mesh_path else [])
        with all_or_nothing(paths) as tmps:
            for f, t in zip(faces, tmps):
                write_pts(t, f.landmarks)
            if mesh_path:
                pts = []
                for f in faces:
                    P = f.mesh.points
                    if f.mesh.iris is not None:
                        P = np.concatenate([P, f.mesh.iris.reshape(-1, 3)])
                    pts.append(P)
                write_mesh_points(tmps[-1], pts)
        found += len(faces)
        if not folder:
            for f, p in zip(faces, pts_paths):
                click.echo(f"{path.name}: face {int(round(f.detection.width))} px wide (detector score "
                           f"{f.detection.score:.2f}, mesh {f.mesh.presence:.2f}) -> {p}")
            if mesh_path:
                click.echo(f"wrote {mesh_path} ({len(faces)} face{'s' if len(faces) > 1 else ''})")
    bar.close()
    if folder:
        click.echo(f"{len(images)} photos: {found} faces -> {out}" + (f"; {missed} without a face" if missed else ""))
        if found == 0:
            raise InputError("no face found in any photo", src)

