"""``facegeom transfer``: a bare head mesh -> the ICT expressions as a blendshape rig in the head's topology.

See :mod:`facegeom.methods.transfer` (registration, then deformation transfer
or the nearest-point shortcut). The rig is written by its suffix: ``.npz``
(:meth:`~facegeom.model.rig.BlendshapeRig.save_npz`, facegeom's rig frame: centimetres, the head's axes
turned by the signed axis permutation nearest the registration's so that Y is up),
``.glb`` (glTF, metres: converted from the head's units; its animation shows
each shape in turn) or a new folder of OBJs (the head's units).
"""
from __future__ import annotations

from pathlib import Path

import click

from facegeom.cli.context import Context

GLB_FPS = 2.0  # the .glb's preview animation: one shape per half second


def axis_turn(R):
    """The signed axis permutation (a rotation, det +1) nearest ``R (3, 3)``: ``argmax trace(S' R)``."""
    import itertools

    import numpy as np

    best, score = None, -np.inf
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            S = np.zeros((3, 3))
            S[np.arange(3), perm] = signs
            if np.linalg.det(S) > 0 and np.trace(S.T @ R) > score:
                best, score = S, float(np.trace(S.T @ R))
    return best


def in_facegeom_frame(rig, reg):
    """The rig in facegeom's frame for its own ``.npz``: centimetres, and the axes turned by the signed axis
    permutation nearest the registration's (a Z-up head becomes Y-up exactly; a Y-up head keeps its axes).
    -> ``(rig, S, k)``: the rig and the change of frame ``x' = k S x``."""
    from facegeom.model.rig import BlendshapeRig

    S = axis_turn(reg.R.T)  # head -> model axes, snapped
    k = reg.units  # head units -> cm
    return BlendshapeRig(rig.neutral @ S.T * k, rig.deltas @ S.T * k, rig.names, rig.triangles, rig.landmark_ids,
                         parts=rig.parts), S, k


def write_transfer_rig(rig, path, metres_per_unit: float, reg=None, skin=None) -> Path:
    """Write ``rig`` to ``path`` by suffix: ``.npz`` (facegeom's frame: :func:`in_facegeom_frame`, given ``reg``;
    with ``skin`` (the skin's vertex ids) the registration is stored beside the rig, so that the marker route
    reuses it), ``.glb`` (metres) or a new OBJ folder (the head's units and axes); atomically."""
    import numpy as np

    from facegeom.cli.identity import write_rig
    from facegeom.io.delivery import DELIVERY_SUFFIXES, write_rig_animation
    from facegeom.methods.transfer import character_arrays

    path = Path(path)
    if path.suffix.lower() == ".npz" and reg is not None:
        moved, S, k = in_facegeom_frame(rig, reg)
        return moved.save_npz(path, extra=None if skin is None else character_arrays(reg, skin, S, k))
    if path.suffix.lower() in DELIVERY_SUFFIXES:  # .glb or USD, in metres
        K = rig.n_shapes
        weights = np.r_[np.zeros((1, K)), np.eye(K), np.zeros((1, K))]  # neutral, each shape, neutral
        return write_rig_animation(path, rig.neutral * metres_per_unit, rig.triangles, rig.deltas * metres_per_unit,
                                   rig.names, weights, GLB_FPS)
    return write_rig(rig, path)


@click.command("transfer")
@click.argument("head", type=click.Path(dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(),
              help="The rig: .npz (facegeom's rig frame: cm, Y up), .glb (glTF, metres), .usda/.usdc/.usdz (USD "
                   "blend shapes, metres) or a new folder of OBJs "
                   "(neutral.obj + one per expression, the head's units and axes).")
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
@click.option("--piece", "pieces", multiple=True, metavar="NAME=ROLE",
              help="How a separate piece moves: eye (turns for the eye looks), jaw (follows the jaw), stay, follow "
                   "(copies the skin's motion) or skin (the surface transferred onto). NAME: the part's name in a "
                   "glTF or rig file, else 'piece N' as the command lists them. Repeatable; the rest are found.")
@click.option("--arkit-names", is_flag=True,
              help="Name the shapes as ARKit's 52 (camelCase; browInnerUp and cheekPuff one shape each) instead "
                   "of the 53 ICT names.")
@click.pass_obj
def transfer_cmd(obj: Context, head, output, engine, landmarks, units, pieces, arkit_names):
    """Give the head HEAD (any topology, units, orientation) the 53 ICT expressions as a rig.

    HEAD: a mesh (.obj, .ply, .off), a glTF scene (.glb / .gltf: every mesh, kept as parts) or a rig file
    (.npz: its neutral). Separate pieces (eyes, teeth, tongue, lashes) are found and move as their role says.
    """
    from facegeom.cli.flags import as_flags
    from facegeom.errors import InputError
    from facegeom.io import check_outputs
    from facegeom.methods.transfer import read_head_landmarks, transfer_head
    from facegeom.pipelines.character import read_head

    check_outputs([head, landmarks], [output])
    suffix = Path(output).suffix.lower()
    if suffix and suffix not in (".npz", ".glb", ".usda", ".usdc", ".usdz"):
        raise InputError(f"unsupported rig format {suffix!r}; use .npz, .glb, .usda/.usdc/.usdz or a folder name "
                         "(OBJ folder)", output)
    roles = parse_pieces(pieces)
    model = obj.face_model()
    V, F, parts = read_head(head)
    click.echo(f"{Path(head).name}: {V.shape[0]} vertices, {F.shape[0]} triangles"
               + (f", {len(parts)} parts" if parts else ""))
    lm = read_head_landmarks(landmarks, V.shape[0]) if landmarks else None
    rig, reg, res = transfer_head(model, V, F, engine=engine, landmarks=lm, units=units, path=head,
                                  progress=lambda line: click.echo(as_flags(line)), parts=parts, roles=roles)
    if arkit_names:
        from facegeom.io.shape_names import ARKIT_CAMEL_NAMES

        rig, missing = rig.renamed(ARKIT_CAMEL_NAMES)
        if missing:
            click.echo(f"ARKit names: {', '.join(missing)} left out (no ICT expression)")
    write_transfer_rig(rig, output, reg.units / 100.0, reg, res.info.get("skin_vertices"))
    frame = {".glb": "metres", ".usda": "metres", ".usdc": "metres", ".usdz": "metres",
             ".npz": "cm, Y up, facing +Z: facegeom's rig frame"}.get(
        suffix, f"{reg.report['units']['name']}, the head's axes")
    click.echo(f"wrote {output} ({rig.n_shapes} shapes, {rig.n_vertices} vertices, {frame})")


def parse_pieces(items) -> dict:
    """``--piece NAME=ROLE`` options -> ``{name: role}`` (the role checked later, with the pieces)."""
    from facegeom.errors import InputError

    roles = {}
    for item in items:
        name, sep, role = item.rpartition("=")
        if not sep or not name:
            raise InputError(f"--piece takes NAME=ROLE, got {item!r}")
        roles[name] = role
    return roles
