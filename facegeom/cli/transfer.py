"""``facegeom transfer``: a bare head mesh -> the ICT expressions as a blendshape rig in the head's topology.

See :mod:`facegeom.methods.transfer` (registration, then deformation transfer
or the nearest-point shortcut). The rig is written by its suffix: ``.npz``
(:meth:`~facegeom.model.rig.BlendshapeRig.save_npz`, the head's units),
``.glb`` (glTF, metres: converted from the head's units; its animation shows
each shape in turn) or a new folder of OBJs (the head's units).
"""
from __future__ import annotations

from pathlib import Path

import click

from facegeom.cli.context import Context

GLB_FPS = 2.0  # the .glb's preview animation: one shape per half second


def write_transfer_rig(rig, path, metres_per_unit: float) -> Path:
    """Write ``rig`` to ``path`` by suffix: ``.npz``, ``.glb`` (metres) or a new OBJ folder; atomically."""
    import numpy as np

    from facegeom.cli.identity import write_rig
    from facegeom.io.gltf import write_rig_glb

    path = Path(path)
    if path.suffix.lower() == ".glb":
        K = rig.n_shapes
        weights = np.r_[np.zeros((1, K)), np.eye(K), np.zeros((1, K))]  # neutral, each shape, neutral
        return write_rig_glb(path, rig.neutral * metres_per_unit, rig.triangles, rig.deltas * metres_per_unit,
                             rig.names, weights, GLB_FPS)
    return write_rig(rig, path)


@click.command("transfer")
@click.argument("head", type=click.Path(dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(),
              help="The rig: .npz (head units), .glb (glTF, metres) or a new folder of OBJs (neutral.obj + one per "
                   "expression, head units).")
@click.option("--engine", type=click.Choice(["deformation", "nearest", "tangent"]), default="deformation",
              show_default=True,
              help="deformation: deformation transfer (per-triangle gradients of each expression, one Poisson solve "
                   "on the head); nearest: each vertex copies the motion of its closest template point; tangent: "
                   "the tangent-framework deformer on the head driven by that motion at 1,000 markers.")
@click.option("--landmarks", type=click.Path(dir_okay=False), default=None,
              help="A CSV landmark,vertex_id: head vertex ids of the 68 iBUG landmarks (any subset of 4 or more), "
                   "used as extra correspondences in the rigid and identity steps.")
@click.option("--units", type=click.Choice(["auto", "mm", "cm", "m"]), default="auto", show_default=True,
              help="The head's units (auto: the power of ten that makes it face-sized).")
@click.pass_obj
def transfer_cmd(obj: Context, head, output, engine, landmarks, units):
    """Give the bare head mesh HEAD (any topology, units, orientation) the 53 ICT expressions as a rig."""
    from facegeom.cli.flags import as_flags
    from facegeom.errors import InputError
    from facegeom.io import check_outputs
    from facegeom.io.mesh import read_mesh
    from facegeom.methods.transfer import read_head_landmarks, transfer_head

    check_outputs([head, landmarks], [output])
    suffix = Path(output).suffix.lower()
    if suffix and suffix not in (".npz", ".glb"):
        raise InputError(f"unsupported rig format {suffix!r}; use .npz, .glb or a folder name (OBJ folder)", output)
    model = obj.face_model()
    V, F = read_mesh(head)
    click.echo(f"{Path(head).name}: {V.shape[0]} vertices, {F.shape[0]} triangles")
    lm = read_head_landmarks(landmarks, V.shape[0]) if landmarks else None
    rig, reg, res = transfer_head(model, V, F, engine=engine, landmarks=lm, units=units, path=head,
                                  progress=lambda line: click.echo(as_flags(line)))
    write_transfer_rig(rig, output, reg.units / 100.0)
    click.echo(f"wrote {output} ({rig.n_shapes} shapes, {rig.n_vertices} vertices, "
               f"{'metres' if suffix == '.glb' else reg.report['units']['name']})")
