"""Build ``makehuman_arkit.npz`` and ``makehuman_stylised_arkit.npz``: MakeHuman heads with 52 ARKit face units.

Usage::

    python tests/data/heads/build_makehuman_head.py [SOURCE_DIR] [-o FOLDER]

``SOURCE_DIR`` holds ``base.obj``, ``targets/*.target`` (the 52 ARKit face
units) and ``modifiers/<group>/<name>.target`` (MakeHuman's modifiers, for the
stylised head) as pinned in ``SOURCES.md``; without it, they are downloaded
from the pinned commits. Every input is checked against its SHA-256 before use.

The stylised head is the same mesh with MakeHuman's own modifier targets
pushed past a person's range (:data:`STYLISED`: a rounder, taller skull,
larger eye openings, a narrow short chin, a small nose and mouth), the face
units added unchanged on top, as MakeHuman itself applies them to any head.

What is kept: the ``body`` group's faces whose vertices all lie above the neck
(y > ``NECK_Y`` decimetres: the head and the neck, not the shoulders), and the
eyes, upper and lower teeth and tongue helpers as separate parts (the
eyelashes, cards, are left out). Quads are split into triangles. The arrays are
written in centimetres with Y up (MakeHuman's own frame is decimetres, Y up,
the face looking down +Z), so the file is an ordinary rig file; the tests turn,
move and rescale it themselves.
"""
from __future__ import annotations

import argparse
import hashlib
import sys
import urllib.request
from pathlib import Path

import numpy as np

MAKEHUMAN = "https://raw.githubusercontent.com/makehumancommunity/makehuman/a8bc2d54ff0ac92e78ff71431b1023eda42bf482"
TARGETS = ("https://raw.githubusercontent.com/makehumancommunity/extra-targets/7eaba3453134385bb5ea9811ef0b33b85b4b556d"
           "/assets/faceunits01/targets/faceunits")
BASE_SHA256 = "8e761e6624b8f54536409135d1636da63b32486a90d4897f84e121d144f6fb4c"
#: SHA-256 of the 52 target files concatenated in name order
TARGETS_SHA256 = "61676743432a73951a9d46502b65c65e55f0072f525735c5526e097efed3e7f9"
MODIFIERS = f"{MAKEHUMAN}/makehuman/data/targets"
#: SHA-256 of the modifier files of STYLISED concatenated in sorted name order
MODIFIERS_SHA256 = "54f0c774926f3c294963f0ca8a532dbfaaae4f2db3c3dc3b1a5f6560e81a5cb4"
STYLISED = {"chin/chin-height-decr": 1.5, "chin/chin-width-decr": 2.0, "eyes/l-eye-scale-incr": 3.0,
            "eyes/r-eye-scale-incr": 3.0, "head/head-round": 2.0, "head/head-scale-vert-incr": 1.0,
            "mouth/mouth-scale-horiz-decr": 1.0, "nose/nose-scale-horiz-decr": 1.5, "nose/nose-scale-vert-decr": 1.5}
ARKIT = ("browDownLeft browDownRight browInnerUp browOuterUpLeft browOuterUpRight cheekPuff cheekSquintLeft "
         "cheekSquintRight eyeBlinkLeft eyeBlinkRight eyeLookDownLeft eyeLookDownRight eyeLookInLeft eyeLookInRight "
         "eyeLookOutLeft eyeLookOutRight eyeLookUpLeft eyeLookUpRight eyeSquintLeft eyeSquintRight eyeWideLeft "
         "eyeWideRight jawForward jawLeft jawOpen jawRight mouthClose mouthDimpleLeft mouthDimpleRight mouthFrownLeft "
         "mouthFrownRight mouthFunnel mouthLeft mouthLowerDownLeft mouthLowerDownRight mouthPressLeft mouthPressRight "
         "mouthPucker mouthRight mouthRollLower mouthRollUpper mouthShrugLower mouthShrugUpper mouthSmileLeft "
         "mouthSmileRight mouthStretchLeft mouthStretchRight mouthUpperUpLeft mouthUpperUpRight noseSneerLeft "
         "noseSneerRight tongueOut").split()
NECK_Y = 5.8  # decimetres: the neck's narrowest band lies at 5.8-6.0, the shoulders start below 5.7
PARTS = (("skin", "body"), ("eye_L", "helper-l-eye"), ("eye_R", "helper-r-eye"),
         ("teeth_upper", "helper-upper-teeth"), ("teeth_lower", "helper-lower-teeth"), ("tongue", "helper-tongue"))
DM_TO_CM = 10.0


def _read(source: Path | None, name: str, url: str) -> bytes:
    if source is not None:
        return (source / name).read_bytes()
    with urllib.request.urlopen(url, timeout=30) as r:  # noqa: S310 - pinned https address
        return r.read()


def _obj(text: str):
    V, faces, group = [], [], None
    for line in text.splitlines():
        if line.startswith("v "):
            V.append([float(x) for x in line.split()[1:4]])
        elif line.startswith("g "):
            group = line.split()[1]
        elif line.startswith("f "):
            faces.append(([int(t.split("/")[0]) - 1 for t in line.split()[1:]], group))
    return np.array(V), faces


def _offsets(text: str, remap, n: int) -> np.ndarray:
    """A MakeHuman ``.target`` (``vertex dx dy dz`` lines, decimetres) -> offsets of the kept vertices ``(n, 3)``."""
    out = np.zeros((n, 3))
    for line in text.splitlines():
        parts = line.split()
        if len(parts) == 4 and not line.startswith("#") and remap[int(parts[0])] >= 0:
            out[remap[int(parts[0])]] = [float(x) for x in parts[1:]]
    return out


def build(source: Path | None, stylised: bool = False) -> dict:
    base = _read(source, "base.obj", f"{MAKEHUMAN}/makehuman/data/3dobjs/base.obj")
    if hashlib.sha256(base).hexdigest() != BASE_SHA256:
        sys.exit("base.obj does not match its pinned SHA-256")
    texts = [_read(source, f"targets/{n}.target", f"{TARGETS}/{n}.target") for n in ARKIT]
    if hashlib.sha256(b"".join(texts)).hexdigest() != TARGETS_SHA256:
        sys.exit("the target files do not match their pinned SHA-256")
    V, faces = _obj(base.decode("utf-8"))
    verts, tris, slices = [], [], []
    remap = np.full(len(V), -1)
    for part, group in PARTS:
        polys = [f for f, g in faces if g == group and (group != "body" or (V[f, 1] > NECK_Y).all())]
        ids = np.unique(np.concatenate([np.asarray(f) for f in polys]))
        start, fstart = sum(len(v) for v in verts), sum(len(t) for t in tris)
        remap[ids] = start + np.arange(len(ids))
        T = [[remap[f[0]], remap[f[k]], remap[f[k + 1]]] for f in polys for k in range(1, len(f) - 1)]
        verts.append(ids)
        tris.append(T)
        slices.append([start, start + len(ids), fstart, fstart + len(T)])
    keep = np.concatenate(verts)
    D = np.stack([_offsets(text.decode("utf-8"), remap, len(keep)) for text in texts]).astype(np.float32)
    neutral = V[keep]
    if stylised:
        names = sorted(STYLISED)
        mods = [_read(source, f"modifiers/{n}.target", f"{MODIFIERS}/{n}.target") for n in names]
        if hashlib.sha256(b"".join(mods)).hexdigest() != MODIFIERS_SHA256:
            sys.exit("the modifier files do not match their pinned SHA-256")
        for name, text in zip(names, mods):
            neutral = neutral + STYLISED[name] * _offsets(text.decode("utf-8"), remap, len(keep))
    return dict(neutral=(neutral * DM_TO_CM).astype(np.float32), deltas=D * DM_TO_CM,
                names=np.array(ARKIT, dtype=np.str_), triangles=np.concatenate(tris).astype(np.int32),
                landmark_ids=np.zeros(0, np.int64), units=np.array("cm"), up=np.array("y"),
                part_names=np.array([p for p, _ in PARTS], dtype=np.str_),
                part_slices=np.array(slices, dtype=np.int64), part_targets=np.ones(len(PARTS), dtype=bool))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("source", nargs="?", type=Path, help="folder with base.obj and targets/ (default: download)")
    ap.add_argument("-o", "--output", type=Path, default=Path(__file__).parent, help="folder for the two files")
    args = ap.parse_args(argv)
    for name, stylised in (("makehuman_arkit.npz", False), ("makehuman_stylised_arkit.npz", True)):
        np.savez_compressed(args.output / name, **build(args.source, stylised))
        print(f"wrote {args.output / name}")


if __name__ == "__main__":
    main()
