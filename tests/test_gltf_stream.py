"""write_sequence_glb streamed from a FrameSource: within the tolerance, K near the array path's, memory bounded."""
import tracemalloc

import numpy as np
import pytest

pytest.importorskip("pygltflib")

from facegeom.errors import InputError  # noqa: E402
from facegeom.io.frames import FrameSource  # noqa: E402
from facegeom.io.gltf import read_glb_animation, write_sequence_glb  # noqa: E402
from tests.conftest import grid_mesh  # noqa: E402

TOL = 0.01


def curves(T, rank, seed):
    """``(T, rank)`` smooth weight curves (sines of random frequency and phase), decaying in size."""
    rng = np.random.default_rng(seed)
    t = np.arange(T)[:, None]
    return np.sin(2 * np.pi * t * rng.uniform(0.002, 0.02, rank) + rng.uniform(0, 6, rank)) * 0.8 ** np.arange(rank)


def modes_of(n, rank, seed):
    return np.random.default_rng(seed + 1).normal(scale=0.05, size=(rank, 3 * n))


def linear_source(V, modes, W, chunk_frames=None, spoil=None):
    """Frames ``V + W[t] @ modes`` computed on demand (a cheap deformer); ``spoil(a, X)`` may change a chunk."""
    T, n = W.shape[0], V.shape[0]

    def fn(a, b):
        X = (V.reshape(1, -1) + W[a:b] @ modes).reshape(b - a, n, 3)
        if spoil is not None:
            spoil(a, X)
        return X

    return FrameSource(T, n, fn, chunk_frames)


def sample_of(T):
    """The frames the streamed writer samples first (evenly spaced, at most 256)."""
    return set(np.unique(np.linspace(0, T - 1, min(T, 256)).round().astype(int)).tolist())


def test_frame_source_basics():
    X = np.arange(5 * 4 * 3, dtype=np.float32).reshape(5, 4, 3)
    src = FrameSource.from_array(X, chunk_frames=2)
    assert src.shape == (5, 4, 3) and len(src) == 5 and src.chunk_frames == 2
    part = src.chunk(1, 3)
    assert part.dtype == np.float64 and np.array_equal(part, X[1:3])
    part[:] = 0  # converted to float64: a copy, the source is untouched
    assert np.array_equal(src.chunk(1, 3), X[1:3])
    view = FrameSource.from_array(X.astype(np.float64)).chunk(1, 3)
    assert not view.flags.writeable  # float64: a view of the caller's array, read-only
    assert [a for a, _ in src.chunks()] == [0, 2, 4] and src.chunk(2, 2).shape == (0, 4, 3)
    assert FrameSource(10, 10 ** 6, lambda a, b: None).chunk_frames == 2  # 64 MB of float64 a chunk
    with pytest.raises(InputError, match="asked of a 5-frame source"):
        src.chunk(3, 6)
    with pytest.raises(InputError, match="gave shape"):
        FrameSource(5, 4, lambda a, b: np.zeros((b - a, 3, 3))).chunk(0, 2)
    with pytest.raises(InputError, match="frames must have shape"):
        FrameSource.from_array(np.zeros((4, 3)))


def test_streamed_matches_the_array_path(tmp_path):
    V, F = grid_mesh(60, 50, bump=0.2)  # 3000 vertices
    T, rank, n = 600, 12, V.shape[0]
    X = V + (curves(T, rank, 0) @ modes_of(n, rank, 0)).reshape(T, n, 3)
    X += np.random.default_rng(2).normal(scale=1e-4, size=X.shape)  # tiny noise: every frame full rank
    _, ref = write_sequence_glb(tmp_path / "array.glb", X, F, 30.0, tolerance=TOL)
    assert ref["targets"] == rank
    for hold in (2 ** 30, 0):  # held once in float32, and driven again for every pass
        lines = []
        out, info = write_sequence_glb(tmp_path / f"stream{hold}.glb", FrameSource.from_array(X, chunk_frames=128),
                                       F, 30.0, tolerance=TOL, hold_bytes=hold, progress=lines.append)
        assert abs(info["targets"] - ref["targets"]) <= 2 and info["frames"] == T and info["tolerance"] == TOL
        assert type(info["max_error"]) is float
        g = read_glb_animation(out)
        err = np.linalg.norm(g.frames() - X, axis=2).max()
        assert err <= TOL and err <= info["max_error"] + 1e-9 and info["max_error"] <= TOL
        assert g.weights.shape == (T, info["targets"]) and np.array_equal(g.faces, F) and g.fps == 30.0
        assert lines and all(line.startswith("glb: pass ") and "\n" not in line for line in lines)
        assert lines[-1].endswith(f"{T:,}/{T:,} frames")


def test_a_motion_the_sample_misses_is_still_within_the_tolerance(tmp_path):
    V, F = grid_mesh(30, 20)
    T, rank, n = 600, 6, V.shape[0]
    spike = min(set(range(T)) - sample_of(T))
    bump = np.zeros((n, 3))
    bump[n // 2:n // 2 + 5, 2] = 0.5  # five vertices jump up in one frame only

    def spoil(a, X):
        if a <= spike < a + X.shape[0]:
            X[spike - a] += bump

    W = curves(T, rank, 3)
    modes = modes_of(n, rank, 3)
    for hold in (2 ** 30, 0):
        out, info = write_sequence_glb(tmp_path / "spike.glb", linear_source(V, modes, W, 64, spoil), F, 30.0,
                                       tolerance=TOL, hold_bytes=hold)
        X = (V.reshape(1, -1) + W @ modes).reshape(T, n, 3)
        X[spike] += bump
        err = np.linalg.norm(read_glb_animation(out).frames() - X, axis=2)
        assert err.max() <= TOL and err[spike].max() <= TOL
        assert info["targets"] <= rank + 2


def _peak(tmp_path, T, n_side):
    V, F = grid_mesh(n_side, 40)
    n, rank = V.shape[0], 8
    src = linear_source(V, modes_of(n, rank, 4), curves(T, rank, 4), chunk_frames=100)
    tracemalloc.start()
    try:
        _, info = write_sequence_glb(tmp_path / f"m{T}.glb", src, F, 30.0, tolerance=TOL, hold_bytes=0)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert info["targets"] <= rank + 2 and info["max_error"] <= TOL
    return peak, T * n * 3 * 8


def test_memory_does_not_grow_with_the_frames(tmp_path):
    peak, whole = _peak(tmp_path, 3000, 50)  # 2000 vertices: 144 MB of float64 frames
    assert peak < whole / 4, (peak, whole)
    peak4, _ = _peak(tmp_path, 12000, 50)  # four times the frames: the (T, K) arrays grow, nothing else
    per_frame = 8 * (8 + 2) * 8  # a few (T, r) float64 arrays of r <= rank + 2 axes
    assert peak4 < whole / 4 and peak4 - peak < 9000 * per_frame, (peak, peak4)


def test_nan_in_a_late_chunk_writes_nothing(tmp_path):
    V, F = grid_mesh(20, 20)
    T, rank, n = 900, 4, V.shape[0]
    bad = max(set(range(T - 50, T)) - sample_of(T))

    def spoil(a, X):
        if a <= bad < a + X.shape[0]:
            X[bad - a, 7, 1] = np.nan

    for hold in (2 ** 30, 0):
        out = tmp_path / "nan.glb"
        with pytest.raises(InputError) as e:
            write_sequence_glb(out, linear_source(V, modes_of(n, rank, 5), curves(T, rank, 5), 100, spoil), F, 30.0,
                               hold_bytes=hold)
        assert "nan.glb" in str(e.value) and "NaN" in str(e.value) and "\n" not in str(e.value)
        assert list(tmp_path.iterdir()) == []


def test_streamed_input_checks(tmp_path):
    V, F = grid_mesh(6, 5)
    src = FrameSource.from_array(np.repeat(V[None], 3, axis=0))
    out = tmp_path / "x.glb"
    for kwargs, msg in ((dict(tolerance=0), "tolerance"), (dict(fps=0), "frame rate"), (dict(faces=F + 100), "outside"),
                        (dict(path=tmp_path / "x.gltf"), "must end in .glb")):
        args = dict(path=out, frames=src, faces=F, fps=30.0) | kwargs
        with pytest.raises(InputError, match=msg):
            write_sequence_glb(**args)
    wrong = FrameSource(3, V.shape[0], lambda a, b: np.zeros((b - a, 2, 3)))
    with pytest.raises(InputError, match="x.glb.*gave shape"):
        write_sequence_glb(out, wrong, F, 30.0)
    assert list(tmp_path.iterdir()) == []
    _, info = write_sequence_glb(out, src, F, 30.0)  # constant frames: one zero target
    assert info["targets"] == 1 and info["max_error"] < 1e-6
    assert np.allclose(read_glb_animation(out).frames(), V, atol=1e-6)
