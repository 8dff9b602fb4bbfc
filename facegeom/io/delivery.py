"""A blendshape rig and its animation as a studio's tools open it: glTF (``.glb``) or USD (``.usda``, ``.usdc``,
``.usdz``), chosen by the file's suffix.

:func:`write_rig_animation` writes either, with the same content: the mesh at rest, every shape as a morph
target (glTF) or a ``BlendShape`` (UsdSkel) with its normal offsets, the weights per frame and the head's
rotation and translation. USD needs usd-core (``pip install 'facegeom[usd]'``).
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from facegeom.errors import InputError
from facegeom.io.usd import USD_SUFFIXES

__all__ = ["DELIVERY_SUFFIXES", "USD_SUFFIXES", "is_usd", "write_rig_animation"]

DELIVERY_SUFFIXES = (".glb", *USD_SUFFIXES)


def is_usd(path) -> bool:
    """Whether ``path`` names a USD file (by its suffix)."""
    return Path(path).suffix.lower() in (*USD_SUFFIXES, ".usd")


def write_rig_animation(path: str | os.PathLike, neutral, faces, deltas, shape_names, weights, fps: float,
                        rotations=None, translations=None, meters_per_unit: float = 1.0) -> Path:
    """Write a rig (``neutral (n, 3)``, ``faces (m, 3)``, ``deltas (K, n, 3)``, ``shape_names``) with its weights
    ``(T, K)`` at ``fps`` and, optionally, the head's ``rotations (T, 3, 3)`` and ``translations (T, 3)`` as a
    ``.glb`` (the positions must be in metres, glTF's unit) or a USD file (``metersPerUnit`` =
    ``meters_per_unit``, Y up). Atomic; one-line errors naming the file."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".glb":
        from facegeom.io.gltf import write_rig_glb

        return write_rig_glb(path, neutral, faces, deltas, shape_names, weights, fps, rotations, translations)
    if suffix in USD_SUFFIXES:
        from facegeom.io.gltf import shape_normal_deltas
        from facegeom.io.usd import write_rig_usd

        V = np.asarray(neutral, dtype=np.float64)
        D = np.asarray(deltas, dtype=np.float64)
        F = np.asarray(faces)
        normals = None
        if D.ndim == 3 and D.shape[1:] == V.shape and F.ndim == 2 and F.shape[1:] == (3,) and np.isfinite(D).all() \
                and np.isfinite(V).all() and F.size and 0 <= F.min() and F.max() < V.shape[0]:
            normals = shape_normal_deltas(V, F.astype(np.int64), D)  # checked again, with one-line errors, below
        return write_rig_usd(path, V, F, D, shape_names, weights, fps, rotations, translations,
                             normal_deltas=normals, meters_per_unit=meters_per_unit)
    raise InputError(f"unsupported format {suffix or 'without suffix'!r}; use {', '.join(DELIVERY_SUFFIXES)}", path)
