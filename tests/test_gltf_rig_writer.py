"""write_rig_glb's normals and buffer: computed and written a few targets at a time, the same bytes.

- :func:`facegeom.io.gltf._many_vertex_normals` (chunks of poses, coordinates apart, blocks of triangles) gives,
  bit for bit, the straightforward computation: ``np.cross`` of every triangle's edges, summed onto its vertices
  in triangle order (``np.add.at``), normalised by ``np.linalg.norm``; and libigl's area-weighted normals to
  rounding.
- The file is what pygltflib's ``save_to_bytes`` makes of the same document and buffer.
- ``scale`` writes the file written from the scaled arrays; writing holds no float32 copy of all the targets.
"""
from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

pytest.importorskip("pygltflib")

from facegeom.errors import InputError
from facegeom.io import gltf
from facegeom.io.gltf import read_glb_animation, shape_normal_deltas, write_rig_glb


def _reference_normals(X: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Unit area-weighted vertex normals of the poses ``X (m, n, 3)``, the plain way -> float32."""
    out = np.empty(X.shape, dtype=np.float32)
    for i, P in enumerate(X):
        c = np.cross(P[F[:, 1]] - P[F[:, 0]], P[F[:, 2]] - P[F[:, 0]])  # twice the area, along the normal
        N = np.zeros_like(P)
        np.add.at(N, F.reshape(-1), np.repeat(c, 3, axis=0))  # each vertex's triangles, in triangle order
        length = np.linalg.norm(N, axis=1, keepdims=True)
        out[i] = np.where(length > 1e-300, N / np.where(length > 0, length, 1.0), (0.0, 0.0, 1.0))
    return out


def _mesh(seed: int, n: int = 300, m: int = 600, K: int = 11):
    rng = np.random.default_rng(seed)
    V = rng.normal(size=(n, 3)) * 10.0 ** rng.integers(-3, 3)
    F = rng.integers(0, n, size=(m, 3))
    F[: m // 10, 2] = F[: m // 10, 0]  # degenerate triangles
    V[:5] = 0.0  # coincident vertices, and signed zeros
    V[5] = -0.0
    D = rng.normal(size=(K, n, 3)) * rng.uniform(0, 0.3, size=(K, 1, 1))
    D[0] = 0.0
    D[1, : n // 2] = 0.0  # a shape moving half the mesh
    D[2, 7] = -0.0
    return V, F, D


@pytest.mark.parametrize("seed", range(4))
def test_vertex_normals_are_the_straightforward_ones_bit_for_bit(seed, monkeypatch):
    V, F, D = _mesh(seed)
    X = V[None] + D
    ref = _reference_normals(X, F)
    for poses, block in ((1, 7), (4, 4096), (5, 64)):  # chunks of poses and blocks of triangles change nothing
        monkeypatch.setattr(gltf, "_NORMAL_POSES", poses)
        monkeypatch.setattr(gltf, "_FACE_BLOCK", block)
        assert np.array_equal(gltf._many_vertex_normals(X, F).view(np.int32), ref.view(np.int32))
        dN = shape_normal_deltas(V, F, D)
        assert dN.dtype == np.float32 and dN.shape == D.shape
        assert np.array_equal(dN.view(np.int32), (ref - _reference_normals(V[None], F)[0]).view(np.int32))


def test_vertex_normals_are_libigls_area_weighted_ones():
    import igl

    from tests.conftest import grid_mesh

    V, F = grid_mesh(12, 9, bump=0.4)
    F = np.asarray(F, dtype=np.int64)
    ours = gltf._many_vertex_normals(V[None], F)[0]
    theirs = igl.per_vertex_normals(V, F, igl.PerVertexNormalsWeightingType.PER_VERTEX_NORMALS_WEIGHTING_TYPE_AREA)
    np.testing.assert_allclose(ours, theirs, atol=1e-6)


def _rig(seed: int = 0, n: int = 400, K: int = 9, T: int = 50):
    from tests.conftest import grid_mesh

    rng = np.random.default_rng(seed)
    V, F = grid_mesh(20, 20, bump=0.3)
    V, F = V[:n] * 7.0, np.asarray(F)
    F = F[(F < n).all(axis=1)]
    D = rng.normal(size=(K, V.shape[0], 3)) * 0.5
    W = rng.uniform(-0.05, 1.05, size=(T, K))
    from scipy.spatial.transform import Rotation

    R = Rotation.from_rotvec(rng.normal(size=(T, 3)) * 0.2).as_matrix()
    t = rng.normal(size=(T, 3))
    return V, F, D, [f"s{k}" for k in range(K)], W, R, t


def test_the_file_is_what_pygltflib_writes(tmp_path, monkeypatch):
    """The header, JSON and padding are pygltflib's ``save_to_bytes`` of the document with the binary chunk
    written; the chunk holds the targets, their normal offsets and the weights."""
    import struct

    made = {}
    save = gltf._save_glb

    def keep(doc, blob, fh):
        made["doc"] = doc
        save(doc, blob, fh)

    monkeypatch.setattr(gltf, "_save_glb", keep)
    V, F, D, names, W, R, t = _rig()
    data = write_rig_glb(tmp_path / "r.glb", V, F, D, names, W, 30.0, R, t).read_bytes()
    n_json = struct.unpack_from("<I", data, 12)[0]
    made["doc"].set_binary_blob(data[12 + 8 + n_json + 8:])
    assert data == b"".join(made["doc"].save_to_bytes())
    a = read_glb_animation(tmp_path / "r.glb")
    np.testing.assert_array_equal(a.deltas, D.astype(np.float32))
    np.testing.assert_array_equal(a.weights, W.astype(np.float32))
    import pygltflib

    doc = pygltflib.GLTF2.load(tmp_path / "r.glb")
    blob = doc.binary_blob()
    for k, target in enumerate(doc.meshes[0].primitives[0].targets):
        view = doc.bufferViews[doc.accessors[target["NORMAL"]].bufferView]
        got = np.frombuffer(blob[view.byteOffset:view.byteOffset + view.byteLength], np.float32).reshape(-1, 3)
        np.testing.assert_array_equal(got, shape_normal_deltas(V, F, D)[k])


def test_scale_writes_the_file_of_the_scaled_arrays(tmp_path):
    V, F, D, names, W, R, t = _rig(1)
    s = 0.01
    a = write_rig_glb(tmp_path / "a.glb", V * s, F, D * s, names, W, 60.0, R, t * s).read_bytes()
    b = write_rig_glb(tmp_path / "b.glb", V, F, D, names, W, 60.0, R, t, scale=s).read_bytes()
    assert a == b
    assert write_rig_glb(tmp_path / "c.glb", V, F, D, names, W, 60.0).read_bytes() == \
        write_rig_glb(tmp_path / "d.glb", V, F, D, names, W, 60.0, scale=1).read_bytes()
    for bad in (0, -1.0, float("nan"), float("inf"), "x"):
        with pytest.raises(InputError, match="scale") as exc:
            write_rig_glb(tmp_path / "e.glb", V, F, D, names, W, 60.0, scale=bad)
        assert str(tmp_path / "e.glb") in str(exc.value)
    with pytest.raises(InputError, match="NaN or inf"):
        write_rig_glb(tmp_path / "e.glb", V, F, D * 1e300, names, W, 60.0, scale=1e10)
    Dn = D.copy()
    Dn[3, 5, 1] = np.nan
    with pytest.raises(InputError, match="NaN or inf"):
        write_rig_glb(tmp_path / "e.glb", V, F, Dn, names, W, 60.0)
    assert not (tmp_path / "e.glb").exists()


def test_the_curves_glb_is_the_scaled_rigs(tmp_path):
    """``write_curves`` to a .glb scales as it writes: the file write_rig_animation writes from scaled copies."""
    from types import SimpleNamespace

    from facegeom.io.delivery import write_rig_animation
    from facegeom.pipelines.solve import GLB_SCALE, write_curves_glb

    V, F, D, names, W, R, t = _rig(2)
    rig = SimpleNamespace(neutral=V, triangles=F, deltas=D)
    solve = SimpleNamespace(names=tuple(names), weights=W, rotations=R, translations=t, info={"head_motion": True})
    solved = SimpleNamespace(rig=rig, solve=solve, fps=30.0)
    got = write_curves_glb(tmp_path / "a.glb", solved).read_bytes()
    ref = write_rig_animation(tmp_path / "b.glb", V * GLB_SCALE, F, D * GLB_SCALE, names, W, 30.0, R,
                              t * GLB_SCALE).read_bytes()
    assert got == ref


def test_writing_holds_a_few_targets_not_all(tmp_path):
    """A 5,000-vertex, 240-shape rig (29 MB of float64 offsets) and 2,000 frames: besides its inputs, writing
    allocates less than a float32 copy of the offsets (14 MB): 6.4 MB measured, whatever the number of shapes
    (the writer before streaming allocated 157 MB: a scaled copy of the offsets, the float32 targets and normal
    offsets, the buffer, its join and pygltflib's copy of it)."""
    from tests.conftest import grid_mesh

    rng = np.random.default_rng(9)
    V, F = grid_mesh(100, 50, bump=0.3)
    K, T = 240, 2000
    D = rng.normal(size=(K, V.shape[0], 3)) * 0.1
    W = rng.uniform(0, 1, size=(T, K))
    names = [f"s{k}" for k in range(K)]
    write_rig_glb(tmp_path / "warm.glb", V[:9], np.array([[0, 1, 2]]), D[:1, :9], names[:1], W[:2, :1], 30.0)
    tracemalloc.start()
    try:
        write_rig_glb(tmp_path / "r.glb", V, F, D, names, W, 30.0, scale=0.01)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    bound = D.nbytes // 2
    assert peak < bound, f"peak {peak / 1e6:.1f} MB, at most {bound / 1e6:.1f} MB"
    a = read_glb_animation(tmp_path / "r.glb")
    np.testing.assert_array_equal(a.deltas, (D * 0.01).astype(np.float32))


def test_quaternions_are_scipys():
    """The writer's own matrix -> quaternion (no scipy.spatial import on the rig route) is scipy's, up to rounding
    and the sign convention w >= 0, on random turns and the hard ones (half turns about each axis, the identity)."""
    from scipy.spatial.transform import Rotation

    from facegeom.io.gltf import quaternions

    rng = np.random.default_rng(0)
    R = np.concatenate([Rotation.random(2000, random_state=1).as_matrix(), np.eye(3)[None],
                        Rotation.from_rotvec(np.pi * np.eye(3)).as_matrix(),
                        Rotation.from_rotvec(rng.normal(size=(50, 3)) * 1e-9).as_matrix()])
    q = quaternions(R)
    ref = Rotation.from_matrix(R).as_quat()
    ref *= np.where(ref[:, 3:] < 0, -1.0, 1.0)
    same = np.minimum(np.abs(q - ref).max(axis=1), np.abs(q + ref).max(axis=1))  # w = 0: either sign is the turn
    assert same.max() < 1e-14
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-15)
    np.testing.assert_allclose(Rotation.from_quat(q).as_matrix(), R, atol=1e-14)
