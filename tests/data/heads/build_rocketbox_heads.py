"""Build ``rocketbox_female_01_arkit.npz`` and ``rocketbox_male_08_arkit.npz``: two Rocketbox heads with 52 ARKit shapes.

Usage::

    python tests/data/heads/build_rocketbox_heads.py [SOURCE_DIR] [-o FOLDER]

``SOURCE_DIR`` holds ``Female_Adult_01_facial.fbx`` and ``Male_Adult_08_facial.fbx``
(Microsoft Rocketbox avatars with HeadBox facial blendshapes, MIT licence) as pinned
in ``SOURCES.md``; without it, they are downloaded from the pinned commit. Every
input is checked against its SHA-256 before use.

The avatars are binary FBX 7.x files: one skinned mesh with the materials body,
head and opacity (hair and lash cards), and one BlendShape deformer of 175
channels. A minimal reader below takes what is needed from them: the node
records (zlib-compressed arrays), ``Objects`` and ``Connections``, the mesh's
``Vertices`` / ``PolygonVertexIndex`` / ``LayerElementMaterial`` /
``LayerElementUV``, the model's ``Lcl`` transform, and the BlendShape ->
BlendShapeChannel -> ``Shape`` geometry (``Indexes`` and their offsets).

What is kept: the polygons of the material whose name contains ``head``, and
of those only the largest UV island, the skin of the head and neck. The other
islands of the same material are left out: the two eyeballs, the teeth, tongue
and mouth interior, and the female's hair bun (the lashes and hair cards are
the opacity material, the body its own). Of the shapes, only the 52 ARKit
ones (``AK_01_BrowDownLeft`` ... ``AK_52_TongueOut``, renamed ``browDownLeft``
... ``tongueOut`` in ARKit's order); the visemes, FACS units, HeadBox and Vive
shapes are left out. ``tongueOut`` barely moves the skin: its tongue is not kept.
Polygons are fan-triangulated and unused vertices dropped.

The mesh data is centimetres, Z up with the face towards -Y; the model's
``Lcl Rotation`` (-90 degrees about X) is applied, so the arrays are written
in centimetres with Y up, the face looking down +Z and the performer's left at
+X (``eyeBlinkLeft`` moves vertices with positive x; checked when building):
an ordinary rig file, one piece, no parts.
"""
from __future__ import annotations

import argparse
import hashlib
import re
import struct
import sys
import urllib.request
import zlib
from pathlib import Path
from typing import NamedTuple

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parent))
from build_makehuman_head import ARKIT  # the 52 names in ARKit's order, as in the MakeHuman head

QUICKSTART = ("https://raw.githubusercontent.com/Takato1412/Microsoft-Rocketbox-Avatar-QuickStart"
              "/1d66dfe3fa2d7f263d642dca9154d93b2fdec16f/Assets/MicrosoftRocketboxAvatars")
#: output file -> (avatar, SHA-256 of its ``<avatar>_facial.fbx``)
HEADS = {"rocketbox_female_01_arkit.npz": ("Female_Adult_01",
                                           "2e6ba71fb83a6899e3d4dd35da07fb5b078eef0c4d593f73d70cfc05dc4644cb"),
         "rocketbox_male_08_arkit.npz": ("Male_Adult_08",
                                         "a736f359d8adb61436de72fd59ba0acac4b42d18751b22ac4d3e2b574d7a71e0")}
AK_NAME = re.compile(r"AK_(\d\d)_(\w+)")


def _read(source: Path | None, name: str, url: str) -> bytes:
    if source is not None:
        return (source / name).read_bytes()
    with urllib.request.urlopen(url, timeout=60) as r:  # a pinned https address
        return r.read()


# --------------------------------------------------------------------------- a minimal binary FBX 7.x reader


class Node(NamedTuple):
    name: str
    props: list
    children: list

    def child(self, name: str) -> Node:
        for c in self.children:
            if c.name == name:
                return c
        raise ValueError(f"{self.name} has no {name}")

    def p70(self) -> dict:
        """The ``Properties70`` block: property name -> its values."""
        for c in self.children:
            if c.name == "Properties70":
                return {p.props[0]: p.props[4:] for p in c.children}
        return {}


_SCALARS = {b"Y": "<h", b"C": "<?", b"I": "<i", b"F": "<f", b"D": "<d", b"L": "<q"}
_ARRAYS = {b"b": "<?", b"i": "<i4", b"l": "<i8", b"f": "<f4", b"d": "<f8"}


def _prop(buf: bytes, off: int):
    kind, off = buf[off:off + 1], off + 1
    if kind in _SCALARS:
        fmt = _SCALARS[kind]
        return struct.unpack_from(fmt, buf, off)[0], off + struct.calcsize(fmt)
    if kind in (b"S", b"R"):
        n = struct.unpack_from("<I", buf, off)[0]
        raw = buf[off + 4:off + 4 + n]
        return (raw.decode("utf-8") if kind == b"S" else raw), off + 4 + n
    if kind in _ARRAYS:
        count, encoding, size = struct.unpack_from("<III", buf, off)
        raw = buf[off + 12:off + 12 + size]
        raw = zlib.decompress(raw) if encoding == 1 else raw
        return np.frombuffer(raw, dtype=_ARRAYS[kind], count=count), off + 12 + size
    raise ValueError(f"unknown property type {kind!r} at byte {off - 1}")


def _node(buf: bytes, off: int, wide: bool):
    """The node record at ``off`` -> ``(node, end)``; ``node`` is None for the null record closing a list."""
    head = "<QQQB" if wide else "<IIIB"
    end, nprops, _, nlen = struct.unpack_from(head, buf, off)
    off += struct.calcsize(head)
    if end == 0:
        return None, off
    if not off < end <= len(buf):
        raise ValueError(f"a record at byte {off - struct.calcsize(head)} ends at {end}")
    name, off = buf[off:off + nlen].decode("ascii"), off + nlen
    props = []
    for _ in range(nprops):
        value, off = _prop(buf, off)
        props.append(value)
    children = []
    while off < end:
        child, off = _node(buf, off, wide)
        if child is None:
            break
        children.append(child)
    return Node(name, props, children), end


def read_fbx(data: bytes, label: str) -> Node:
    """A binary FBX 7.x file -> its root node (the top-level records as children); exits on anything else."""
    if not data.startswith(b"Kaydara FBX Binary  \x00"):
        sys.exit(f"{label}: not a binary FBX file" + (" (an ASCII FBX)" if data.lstrip().startswith(b";") else ""))
    version = struct.unpack_from("<I", data, 23)[0]
    if not 7000 <= version < 8000:
        sys.exit(f"{label}: FBX version {version}, this reader knows 7.x")
    top, off = [], 27
    try:
        while off < len(data):
            node, off = _node(data, off, wide=version >= 7500)
            if node is None:
                break
            top.append(node)
    except (ValueError, struct.error, zlib.error, UnicodeDecodeError) as exc:
        sys.exit(f"{label}: unreadable FBX record ({exc})")
    return Node("", [], top)


def _name(node: Node) -> str:
    """An object's own name: ``"blendShape1.AK_01_BrowDownLeft\\x00\\x01SubDeformer"`` -> ``"blendShape1.AK_01_..."``."""
    return node.props[1].split("\x00\x01")[0]


# --------------------------------------------------------------------------- the head


def _mesh(root: Node, label: str):
    """The one mesh, turned into the scene frame -> ``(V (n, 3) cm, polygons, material name per polygon, UV index
    lists per polygon, {channel name: (indexes, offsets (k, 3) cm)})``."""
    objects = {o.props[0]: o for o in root.child("Objects").children}
    links = [(c.props[1], c.props[2]) for c in root.child("Connections").children]  # (child, parent)
    children = {}
    for c, p in links:
        children.setdefault(p, []).append(c)
    meshes = [o for o in objects.values() if o.name == "Geometry" and o.props[2] == "Mesh"]
    if len(meshes) != 1:
        sys.exit(f"{label}: expected one mesh, found {len(meshes)}")
    mesh = meshes[0]
    models = [objects[p] for c, p in links if c == mesh.props[0] and p in objects and objects[p].name == "Model"]
    if len(models) != 1 or [p for c, p in links if c == models[0].props[0] and p in objects
                            and objects[p].name == "Model"]:
        sys.exit(f"{label}: expected the mesh's model at the scene's root")
    model = models[0]

    g = root.child("GlobalSettings").p70()
    axes = [g.get(k, [None])[0] for k in ("UpAxis", "UpAxisSign", "FrontAxis", "FrontAxisSign", "CoordAxis",
                                           "CoordAxisSign")]
    if axes != [1, 1, 2, 1, 0, 1]:
        sys.exit(f"{label}: scene axes (up, front, coord with signs) {axes}, expected Y up, Z front, X right")
    cm = float(g.get("UnitScaleFactor", [1.0])[0])  # centimetres per file unit
    m = model.p70()
    odd = [k for k in ("PreRotation", "PostRotation", "RotationOffset", "RotationPivot", "ScalingOffset",
                       "ScalingPivot", "GeometricTranslation", "GeometricRotation") if np.any(m.get(k, [0]))]
    if odd or m.get("RotationOrder", [0])[0] != 0 or m.get("GeometricScaling", [1, 1, 1]) != [1, 1, 1]:
        sys.exit(f"{label}: the model's transform has more than Lcl Translation/Rotation/Scaling: {odd}")
    R = Rotation.from_euler("xyz", m.get("Lcl Rotation", [0, 0, 0]), degrees=True).as_matrix()  # X first
    A = cm * R * np.asarray(m.get("Lcl Scaling", [1, 1, 1]), dtype=float)  # scale, then turn, in cm
    t = cm * np.asarray(m.get("Lcl Translation", [0, 0, 0]), dtype=float)

    V = mesh.child("Vertices").props[0].reshape(-1, 3) @ A.T + t
    pvi = mesh.child("PolygonVertexIndex").props[0].astype(np.int64)
    ends = np.flatnonzero(pvi < 0) + 1
    corners = np.where(pvi < 0, ~pvi, pvi)  # a polygon's last index is stored as -(i + 1)
    polys = np.split(corners, ends[:-1])
    material = mesh.child("LayerElementMaterial")
    per = material.child("Materials").props[0]
    if material.child("MappingInformationType").props[0] == "AllSame":
        per = np.repeat(per[:1], len(polys))
    mat_names = [_name(objects[c]) for c in children[model.props[0]]  # in connection order: the indices' order
                 if c in objects and objects[c].name == "Material"]
    uv = mesh.child("LayerElementUV")
    if (uv.child("MappingInformationType").props[0], uv.child("ReferenceInformationType").props[0]) != \
            ("ByPolygonVertex", "IndexToDirect") or material.child("MappingInformationType").props[0] not in \
            ("ByPolygon", "AllSame") or len(per) != len(polys) or len(uv.child("UVIndex").props[0]) != len(pvi):
        sys.exit(f"{label}: unexpected material or UV layer layout")
    uv_polys = np.split(uv.child("UVIndex").props[0].astype(np.int64), ends[:-1])

    shapes = {}
    for d in children[mesh.props[0]]:
        if d not in objects or objects[d].props[2] != "BlendShape":
            continue
        for ch in children[d]:
            geos = [objects[s] for s in children.get(ch, []) if objects[s].name == "Geometry"]
            if len(geos) != 1:
                sys.exit(f"{label}: channel {_name(objects[ch])} has {len(geos)} shapes, expected one")
            shapes[_name(objects[ch]).split(".")[-1]] = (geos[0].child("Indexes").props[0].astype(np.int64),
                                                         geos[0].child("Vertices").props[0].reshape(-1, 3) @ A.T)
    return V, polys, [mat_names[k] for k in per], uv_polys, shapes


def build(data: bytes, label: str) -> dict:
    try:
        V, polys, materials, uv_polys, shapes = _mesh(read_fbx(data, label), label)
    except (ValueError, KeyError, IndexError, AttributeError) as exc:
        sys.exit(f"{label}: not the FBX this script expects ({exc!r})")
    heads = sorted({m for m in materials if "head" in m.lower()})
    if len(heads) != 1:
        sys.exit(f"{label}: expected one material named *head*, found {heads or 'none'}")
    head = [i for i, m in enumerate(materials) if m == heads[0]]
    # the skin: the head material's largest UV island (polygons joined by a shared UV corner)
    rows = np.repeat(np.arange(len(head)), [len(uv_polys[i]) for i in head])
    cols = np.concatenate([uv_polys[i] for i in head])
    n = len(head) + cols.max() + 1
    _, label_of = connected_components(coo_matrix((np.ones(len(rows)), (rows, len(head) + cols)), shape=(n, n)),
                                       directed=False)
    islands = label_of[:len(head)]
    skin = [head[i] for i in np.flatnonzero(islands == np.bincount(islands).argmax())]

    tris = np.array([[polys[i][0], polys[i][k], polys[i][k + 1]] for i in skin for k in range(1, len(polys[i]) - 1)])
    keep = np.unique(tris)
    remap = np.full(len(V), -1)
    remap[keep] = np.arange(len(keep))

    ak = {}
    for name, (idx, offsets) in shapes.items():
        hit = AK_NAME.fullmatch(name)
        if hit:
            ak[int(hit[1])] = (hit[2][0].lower() + hit[2][1:], idx, offsets)
    names = [ak[k][0] for k in sorted(ak)]
    if sorted(ak) != list(range(1, 53)) or names != list(ARKIT):
        sys.exit(f"{label}: the AK_NN_ shapes do not map onto ARKit's 52 in order: found {len(ak)}, "
                 f"{[(k, ak[k][0]) for k, a in zip(sorted(ak), ARKIT) if ak[k][0] != a][:3]} differ")
    deltas = np.zeros((52, len(keep), 3))
    for row, k in enumerate(sorted(ak)):
        _, idx, offsets = ak[k]
        on = remap[idx] >= 0
        deltas[row, remap[idx[on]]] = offsets[on]

    neutral = V[keep]
    blink = np.linalg.norm(deltas[ARKIT.index("eyeBlinkLeft")], axis=1) > 0.1
    jaw = deltas[ARKIT.index("jawOpen")]
    if not (neutral[blink, 0].mean() > 0 and jaw[:, 1].sum() < 0
            and neutral[np.linalg.norm(jaw, axis=1) > 0.1, 2].mean() > neutral[:, 2].mean()):
        sys.exit(f"{label}: not in the expected frame (eyeBlinkLeft at +X, jawOpen down, the face towards +Z)")
    print(f"{label}: material {heads[0]!r}: {len(head)} polygons in {islands.max() + 1} UV islands; kept the largest, "
          f"the skin: {len(keep)} vertices, {len(tris)} triangles")
    return {"neutral": neutral.astype(np.float32), "deltas": deltas.astype(np.float32),
            "names": np.array(ARKIT, dtype=np.str_), "triangles": remap[tris].astype(np.int32),
            "landmark_ids": np.zeros(0, np.int64), "units": np.array("cm"), "up": np.array("y")}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("source", nargs="?", type=Path, help="folder with the two *_facial.fbx files (default: download)")
    ap.add_argument("-o", "--output", type=Path, default=Path(__file__).parent, help="folder for the two files")
    args = ap.parse_args(argv)
    for out, (avatar, sha256) in HEADS.items():
        name = f"{avatar}_facial.fbx"
        data = _read(args.source, name, f"{QUICKSTART}/{avatar}/Export/{name}")
        if hashlib.sha256(data).hexdigest() != sha256:
            sys.exit(f"{name} does not match its pinned SHA-256")
        np.savez_compressed(args.output / out, **build(data, name))
        print(f"wrote {args.output / out}")


if __name__ == "__main__":
    main()
