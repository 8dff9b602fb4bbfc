"""write_sequence_glb from a frame source's linear structure (a deformer's marker-to-vertex map): every frame within
the tolerance when played back independently, target count near the streamed path's, fallbacks."""
import numpy as np
import pytest

pytest.importorskip("pygltflib")

from facegeom.errors import InputError  # noqa: E402
from facegeom.io.frames import FrameSource, LinearFrames  # noqa: E402
from facegeom.io.gltf import read_glb_animation, write_sequence_glb  # noqa: E402
from facegeom.methods.tangent import TangentDeformer  # noqa: E402
from tests.conftest import grid_mesh  # noqa: E402

TOL = 0.002


def driven(T=400, seed=0, **params):
    """A grid driven through 12 markers by the default tangent deformer: markers moving smoothly, the whole
    grid turning and moving (the robust alignment and the soft labels' weight differ frame by frame)."""
    V, F = grid_mesh(30, 24, bump=0.2)
    rng = np.random.default_rng(seed)
    H = np.unique(rng.choice(V.shape[0], 12, replace=False))
    de = TangentDeformer(**params).fit(V, F, H)
    t = np.arange(T)[:, None, None]
    P = V[H][None] + 0.05 * np.sin(2 * np.pi * t * rng.uniform(0.003, 0.03, (1, H.size, 3))
                                   + rng.uniform(0, 6, (1, H.size, 3)))
    ang = 0.2 * np.sin(np.arange(T) / 40.0)
    c, s = np.cos(ang), np.sin(ang)
    R = np.zeros((T, 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = c, -s, s, c, 1.0
    P = np.einsum("tij,tpj->tpi", R, P) + 0.1 * np.sin(np.arange(T) / 70.0)[:, None, None]
    return V, F, de, P


def source_of(de, P, linear=True, chunk_frames=64):
    T, n = P.shape[0], de.vertices_.shape[0]
    return FrameSource(T, n, lambda a, b: de.deform_many(P[a:b]), chunk_frames,
                       linear=(lambda: de.linear_many(P)) if linear else None)


def test_linear_many_is_deform_many():
    V, _, de, P = driven(50)
    C, B = de.linear_many(P)
    assert C.shape == (50, 3, 16) and B.shape == (16, V.shape[0])
    X = de.deform_many(P)
    assert np.allclose(np.einsum("tim,mn->tni", C, B), X, atol=1e-12)
    assert np.allclose(np.stack([de.deform(p) for p in P[:5]]), X[:5], atol=1e-10)
    de.solver_.map_ = None  # no dense map: no linear structure, deform_many solves
    assert de.linear_many(P) is None


def test_low_rank_path_within_the_tolerance_on_every_frame(tmp_path):
    V, F, de, P = driven()
    X = de.deform_many(P)  # the truth, driven independently of the writer
    lines = []
    out, info = write_sequence_glb(tmp_path / "lin.glb", source_of(de, P), F, 30.0, tolerance=TOL,
                                   progress=lines.append, rest=V)
    assert any("dimensional basis" in line for line in lines)  # the low-rank path, not the passes
    assert not any(line.startswith("glb: pass") for line in lines)
    g = read_glb_animation(out)
    err = np.linalg.norm(g.frames() - X, axis=2)
    assert err.max() <= TOL and err.max() <= info["max_error"] + 1e-12 and info["max_error"] <= TOL
    assert info["frames"] == P.shape[0] and info["rest"] and g.weights.shape == (P.shape[0], info["targets"] + 1)
    # the generic (streamed) path on the same frames: target counts within two
    lines2 = []
    _, ref = write_sequence_glb(tmp_path / "gen.glb", source_of(de, P, linear=False), F, 30.0, tolerance=TOL,
                                progress=lines2.append, hold_bytes=0)
    assert any(line.startswith("glb: pass") for line in lines2)
    assert abs(info["targets"] - ref["targets"]) <= 2
    _, arr = write_sequence_glb(tmp_path / "arr.glb", X, F, 30.0, tolerance=TOL)
    assert abs(info["targets"] - arr["targets"]) <= 2


def test_tight_tolerance_and_many_targets(tmp_path):
    V, F, de, P = driven(300, seed=3)
    X = de.deform_many(P)
    tol = 2e-5
    out, info = write_sequence_glb(tmp_path / "tight.glb", source_of(de, P), F, 30.0, tolerance=tol)
    err = np.linalg.norm(read_glb_animation(out).frames() - X, axis=2)
    assert err.max() <= tol and info["max_error"] <= tol
    _, arr = write_sequence_glb(tmp_path / "arr.glb", X, F, 30.0, tolerance=tol)
    assert abs(info["targets"] - arr["targets"]) <= 2


def test_falls_back_without_a_linear_structure(tmp_path):
    V, F, de, P = driven(200)
    X = de.deform_many(P)
    for linear in (None, lambda: None):  # none given; a function that finds none (a deformer without a dense map)
        src = FrameSource(P.shape[0], V.shape[0], lambda a, b: de.deform_many(P[a:b]), 64, linear=linear)
        lines = []
        out, info = write_sequence_glb(tmp_path / "fb.glb", src, F, 30.0, tolerance=TOL, progress=lines.append,
                                       hold_bytes=0)
        assert lines and all(line.startswith("glb: pass") for line in lines)
        assert np.linalg.norm(read_glb_animation(out).frames() - X, axis=2).max() <= TOL


def test_a_structure_that_is_not_the_frames_is_not_trusted(tmp_path):
    _, F, de, P = driven(200)
    V = de.vertices_
    X = de.deform_many(P)
    X[3, 10] += 0.05  # a frame of the first chunk differs from what the structure says

    src = FrameSource(P.shape[0], V.shape[0], lambda a, b: X[a:b], 64, linear=lambda: de.linear_many(P))
    lines = []
    out, info = write_sequence_glb(tmp_path / "lie.glb", src, F, 30.0, tolerance=TOL, progress=lines.append,
                                   hold_bytes=0)
    assert any("does not give the frames" in line for line in lines)
    assert any(line.startswith("glb: pass") for line in lines)  # streamed instead
    assert np.linalg.norm(read_glb_animation(out).frames() - X, axis=2).max() <= TOL


def test_linear_structure_checks():
    src = FrameSource(4, 5, lambda a, b: np.zeros((b - a, 5, 3)), linear=LinearFrames(np.zeros((4, 3, 2)),
                                                                                      np.zeros((2, 5))))
    assert src.linear.coefficients.shape == (4, 3, 2)
    for C, B in (((4, 2, 2), (2, 5)), ((4, 3, 2), (3, 5)), ((3, 3, 2), (2, 5))):
        bad = FrameSource(4, 5, lambda a, b: None, linear=(np.zeros(C), np.zeros(B)))
        with pytest.raises(InputError, match="linear structure must be"):
            _ = bad.linear
    nan = np.zeros((4, 3, 2))
    nan[1, 1, 1] = np.nan
    with pytest.raises(InputError, match="NaN or inf"):
        _ = FrameSource(4, 5, lambda a, b: None, linear=(nan, np.zeros((2, 5)))).linear
