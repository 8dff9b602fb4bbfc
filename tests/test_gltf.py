"""glTF 2.0 out: rigs and vertex sequences as morph targets, read back to the same numbers, Khronos-validated."""
import numpy as np
import pytest

pytest.importorskip("pygltflib")

from facegeom.errors import InputError  # noqa: E402
from facegeom.io.gltf import read_glb_animation, write_rig_glb, write_sequence_glb  # noqa: E402
from tests.conftest import validate  # noqa: E402


def grid(nx=6, ny=5):
    """A bumpy grid mesh: vertices (n, 3), triangles (m, 3)."""
    x, y = np.meshgrid(np.linspace(0, 1, nx), np.linspace(0, 1, ny))
    V = np.c_[x.ravel(), y.ravel(), 0.1 * np.sin(3 * x.ravel()) * np.cos(2 * y.ravel())]
    F = []
    for j in range(ny - 1):
        for i in range(nx - 1):
            a = j * nx + i
            F += [[a, a + 1, a + nx + 1], [a, a + nx + 1, a + nx]]
    return V, np.array(F)


def rig(K=4, T=25, seed=0):
    rng = np.random.default_rng(seed)
    V, F = grid()
    D = rng.normal(scale=0.05, size=(K, V.shape[0], 3))
    W = rng.uniform(0, 1, size=(T, K))
    return V, F, D, [f"shape{k}" for k in range(K)], W


def test_rig_round_trip(tmp_path):
    V, F, D, names, W = rig()
    out = write_rig_glb(tmp_path / "rig.glb", V, F, D, names, W, 24.0)
    g = read_glb_animation(out)
    assert np.allclose(g.neutral, V, atol=1e-6) and np.array_equal(g.faces, F)
    assert np.allclose(g.deltas, D, atol=1e-7) and g.names == tuple(names)
    assert np.allclose(g.weights, W, atol=1e-7)
    assert np.allclose(g.times, np.arange(W.shape[0]) / 24.0, atol=1e-6) and g.fps == 24.0
    assert np.allclose(g.frames(), V + np.einsum("tk,knd->tnd", W, D), atol=1e-5)


def test_rig_file_layout(tmp_path):
    """What viewers rely on: targetNames, default weights, unit normals, one LINEAR weights channel."""
    import pygltflib

    V, F, D, names, W = rig()
    doc = pygltflib.GLTF2.load(write_rig_glb(tmp_path / "r.glb", V, F, D, names, W, 30.0))
    mesh = doc.meshes[0]
    assert mesh.extras["targetNames"] == names and mesh.weights == [0.0] * len(names)
    prim = mesh.primitives[0]
    assert len(prim.targets) == len(names) and prim.attributes.NORMAL is not None
    assert doc.accessors[prim.attributes.POSITION].componentType == 5126  # float32
    smp = doc.animations[0].samplers[0]
    ch = doc.animations[0].channels[0]
    assert smp.interpolation == "LINEAR" and ch.target.path == "weights" and ch.target.node == 0
    blob = doc.binary_blob()
    acc = doc.accessors[prim.attributes.NORMAL]
    view = doc.bufferViews[acc.bufferView]
    N = np.frombuffer(blob, np.float32, acc.count * 3, view.byteOffset).reshape(-1, 3)
    assert np.allclose(np.linalg.norm(N, axis=1), 1.0, atol=1e-6) and (N[:, 2] > 0).all()


def _svd_error(X, k):
    """Largest vertex error of the best rank-k approximation of X - mean (numpy's own SVD)."""
    T, n = X.shape[:2]
    D = (X - X.mean(0)).reshape(T, -1)
    U, S, Vt = np.linalg.svd(D, full_matrices=False)
    R = D - (U[:, :k] * S[:k]) @ Vt[:k]
    return np.linalg.norm(R.reshape(T, n, 3), axis=2).max()


@pytest.mark.parametrize("tolerance", [1e-4, 0.01, 0.05])
def test_sequence_targets_meet_the_bound_with_the_fewest_targets(tmp_path, tolerance):
    rng = np.random.default_rng(1)
    V, F = grid()
    T, r = 40, 6
    modes = rng.normal(size=(r, V.shape[0], 3)) * (0.5 ** np.arange(r))[:, None, None]  # decaying sizes
    X = V + np.einsum("tr,rnd->tnd", rng.normal(size=(T, r)), modes)
    out, info = write_sequence_glb(tmp_path / "s.glb", X, F, 30.0, tolerance=tolerance)
    g = read_glb_animation(out)
    K = info["targets"]
    err = np.linalg.norm(g.frames() - X, axis=2).max()
    assert err <= tolerance and err == pytest.approx(info["max_error"], rel=1e-3, abs=1e-9)
    assert g.deltas.shape[0] == K and g.weights.shape == (T, K) and g.fps == 30.0
    assert 1 <= K <= r
    if K > 1:
        assert _svd_error(X, K - 1) > tolerance  # one target fewer would break the bound
    if tolerance == 1e-4:
        assert K == r  # the exact rank


def test_sequence_of_one_or_constant_frames(tmp_path):
    V, F = grid()
    for X in (V[None], np.repeat(V[None], 5, axis=0)):
        out, info = write_sequence_glb(tmp_path / "c.glb", X, F, 30.0)
        g = read_glb_animation(out)
        assert info["targets"] == 1 and info["max_error"] < 1e-6
        assert np.allclose(g.frames(), X, atol=1e-6)


def test_writers_check_their_input(tmp_path):
    V, F, D, names, W = rig()
    out = tmp_path / "x.glb"
    bad = [
        (dict(path=tmp_path / "x.gltf"), "must end in .glb"),
        (dict(deltas=D[:, :-1]), "deltas must have shape"),
        (dict(shape_names=names[:-1]), "shape names"),
        (dict(weights=W[:, :-1]), "weights must have shape"),
        (dict(weights=np.full_like(W, np.nan)), "NaN"),
        (dict(faces=F + 100), "outside"),
        (dict(fps=0), "frame rate"),
    ]
    for change, msg in bad:
        args = dict(path=out, neutral=V, faces=F, deltas=D, shape_names=names, weights=W, fps=30.0) | change
        with pytest.raises(InputError, match=msg):
            write_rig_glb(**args)
    with pytest.raises(InputError, match="tolerance"):
        write_sequence_glb(out, V[None], F, 30.0, tolerance=0)
    with pytest.raises(InputError, match="frames must have shape"):
        write_sequence_glb(out, V, F, 30.0)
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_reader_rejects_bad_files_with_one_error(tmp_path):
    V, F, D, names, W = rig()
    good = write_rig_glb(tmp_path / "g.glb", V, F, D, names, W, 30.0).read_bytes()
    cases = {"cut.glb": good[: len(good) // 2], "text.glb": b"hello world" * 10, "short.glb": good[:12],
             "json.glb": good[:20] + b"{" * 40 + good[60:], "v1.glb": good[:4] + b"\x01\0\0\0" + good[8:]}
    for name, data in cases.items():
        (tmp_path / name).write_bytes(data)
        with pytest.raises(InputError) as e:
            read_glb_animation(tmp_path / name)
        assert name in str(e.value) and "\n" not in str(e.value)
    with pytest.raises(InputError, match="not found"):
        read_glb_animation(tmp_path / "none.glb")


# ----------------------------------------------------------------------------- Khronos glTF-Validator


def test_validator_rejects_a_broken_file(tmp_path, validator_env):
    """The check can fail: a file whose index points past the vertices has errors."""
    V, F, D, names, W = rig(K=2, T=3)
    path = write_rig_glb(tmp_path / "bad.glb", V, F, D, names, W, 30.0)
    data = bytearray(path.read_bytes())
    start = 20 + int.from_bytes(data[12:16], "little") + 8  # the binary chunk: indices come first
    data[start:start + 4] = (10 ** 6).to_bytes(4, "little")
    path.write_bytes(bytes(data))
    assert validate(validator_env, path)["numErrors"] > 0


def test_rig_and_sequence_files_pass_the_khronos_validator(tmp_path, validator_env, face_model):
    m = face_model
    rng = np.random.default_rng(2)
    W = np.clip(rng.normal(0.2, 0.2, size=(30, m.n_expressions)), 0, 1)
    rig_path = write_rig_glb(tmp_path / "face.glb", m.neutral, m.triangles, m.expression_deltas,
                             m.expression_names, W, 30.0)
    issues = validate(validator_env, rig_path)
    assert issues["numErrors"] == 0, issues["messages"][:5]
    X = m.neutral + np.einsum("tk,knd->tnd", W[:12], m.expression_deltas.astype(np.float64))
    seq_path, info = write_sequence_glb(tmp_path / "seq.glb", X, m.triangles, 30.0)
    assert info["max_error"] <= 0.01
    issues = validate(validator_env, seq_path)
    assert issues["numErrors"] == 0, issues["messages"][:5]
