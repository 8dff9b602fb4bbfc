"""``facegeom data examples DIR``: ready-to-run inputs for every example of the README, from the face data."""
from __future__ import annotations

from pathlib import Path

import click

__all__ = ["examples"]


@click.command("examples")
@click.argument("folder", type=click.Path())
@click.option("--force", is_flag=True, help="Overwrite example files already in FOLDER (other files are left alone).")
@click.pass_context
def examples(ctx, folder, force):
    """Write ready-to-run inputs for every task of the README into FOLDER, made from the face data.

    A face and markers, landmarks with their camera, a photo annotation, a scan, a mesh to clean, a take, a
    C3D capture, a retargeting pair and a batch job, with a README.txt naming each file's units and the
    command that uses it. Made from the face data in use (--data, $FACEGEOM_DATA, ...) with a fixed seed:
    the same data gives the same files. All files are written or none.
    """
    from facegeom.model import load_face_model
    from facegeom.pipelines.examples import check_folder, example_paths, write_examples

    check_folder(folder, force)  # before the face data is loaded
    obj = ctx.find_root().obj
    model = obj.face_model() if obj is not None else load_face_model()
    paths = write_examples(model, folder, force=force, progress=click.echo)
    click.echo(f"wrote {len(paths)} files to {folder} (what each is and the command that uses it: "
               f"{Path(folder) / 'README.txt'}):")
    written = {p.relative_to(folder).as_posix() for p in map(Path, paths)}
    names = [n for n in example_paths() if not n.startswith("job/") and n in written]
    click.echo("  " + ", ".join(names) + ", job/ (the batch job's inputs)")
    skipped = [n for n in example_paths() if n not in written]
    if skipped:
        click.echo(f"  not written here: {', '.join(skipped)} (rendering them needs an off-screen renderer, EGL, and "
                   "PyAV: see README.txt)")
    click.echo(f"try: cd {folder} && facegeom drive face.obj markers.csv -o driven.ply")
