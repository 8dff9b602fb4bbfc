"""Transferred shapes do not fold the skin (facegeom.methods.folds, the check in `facegeom transfer`).

Every shape at weight 1, and the pairs real takes drive together (``folds.PAIRS``: jawOpen with mouthFunnel,
mouthSmile_L/R, mouthPucker, mouthClose; both blinks), on the Lee Perry-Smith scan
(``tests/data/heads/lee_perry_smith.ply``): no triangle flipped against the rest pose (normal turned more than
90 degrees) and no new self-intersection of the skin. The scan crosses itself at rest (252 pairs: the ears, the
inner eye corners, the lips' corners); its crossed sheets sliding past each other are not counted, nor the
slivers of those folds that turn over (reported apart).
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from facegeom.methods import folds

HEADS = Path(__file__).parent / "data" / "heads"


# ---------------------------------------------------------------------------------------------- the check
def _two_triangles(offset):
    """Two separate triangles: one in z = 0, one vertical through it when ``offset`` = 0 (apart when large)."""
    V = np.array([[0, 0, 0], [2, 0, 0], [0, 2, 0],
                  [0.5, 0.5, -1 + offset], [0.5, 0.5, 1 + offset], [1.5, -0.5, offset]], dtype=np.float64)
    return V, np.array([[0, 1, 2], [3, 4, 5]])


@pytest.mark.parametrize("cgal", [True, False])
def test_crossing_pairs_finds_a_crossing_and_not_neighbours(cgal):
    V, F = _two_triangles(0.0)
    assert folds.crossing_pairs(V, F, cgal=cgal).tolist() == [[0, 1]]
    V, F = _two_triangles(5.0)
    assert folds.crossing_pairs(V, F, cgal=cgal).shape == (0, 2)
    # a folded strip: neighbours share vertices and are never counted, whatever their angle
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.0]])
    F = np.array([[0, 1, 2], [1, 3, 2]])
    folded = V.copy()
    folded[3] = [-0.5, -0.5, 0.01]  # turned over onto its neighbour
    assert folds.crossing_pairs(folded, F, cgal=cgal).shape == (0, 2)
    assert folds.flipped(V, F, folded).tolist() == [1]


def test_a_rest_crossing_is_not_new():
    V, F = _two_triangles(0.0)
    rest = folds.RestCrossings(V, F)
    assert len(rest) == 1
    assert folds.new_crossings(V, F, V + [0.0, 0.0, 0.01], rest).shape == (0, 2)  # moved, still the rest's
    V2, _ = _two_triangles(5.0)
    rest2 = folds.RestCrossings(V2, F)
    assert folds.new_crossings(V2, F, V, rest2).tolist() == [[0, 1]]


def test_cgal_and_numpy_agree_on_the_scan():
    from facegeom.io.mesh import read_mesh

    V, F = read_mesh(HEADS / "lee_perry_smith.ply")
    a = folds.crossing_pairs(V, F)
    b = folds.crossing_pairs(V, F, cgal=False)
    assert len(a) == 252 and set(map(tuple, a)) == set(map(tuple, b))


def test_crossings_checked_again_where_a_pose_changed_are_those_of_the_whole_check():
    """The unfolding's re-check tests only the triangles a correction moved: on the scan, a bump pushed through
    the surface and then partly pulled back, the pairs equal a whole check's (found, kept and lost ones)."""
    from facegeom.io.mesh import read_mesh

    V, F = read_mesh(HEADS / "lee_perry_smith.ply")
    rest = folds.RestCrossings(V, F)
    rng = np.random.default_rng(0)
    N = np.zeros_like(V)
    np.add.at(N, F.ravel(), np.repeat(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), 3, axis=0))
    N /= np.maximum(np.linalg.norm(N, axis=1, keepdims=True), 1e-300)
    edge = float(np.median(np.linalg.norm(V[F[:, 0]] - V[F[:, 1]], axis=1)))
    for seed in range(3):
        c = V[rng.integers(V.shape[0])]
        w = np.exp(-((V - c) ** 2).sum(axis=1) / (2 * (6 * edge) ** 2))
        X0 = V - (8 * edge) * w[:, None] * N  # a dent pushed in through the head: new crossings
        prev = folds.new_crossings(V, F, X0, rest)
        patch = np.linalg.norm(V - c, axis=1) < 4 * edge  # the correction moves a patch back out
        X1 = X0.copy()
        X1[patch] = V[patch] + 0.3 * (X0[patch] - V[patch])
        touched = np.flatnonzero(patch[F].any(axis=1))
        got = folds.recheck_crossings(V, F, X1, rest, prev, touched)
        whole = np.unique(np.sort(folds.new_crossings(V, F, X1, rest), axis=1), axis=0).reshape(-1, 2)
        assert got.tolist() == whole.tolist()
        assert len(prev) > 0  # the dent made crossings: the check has something to keep or lose
        assert not np.array_equal(np.unique(np.sort(prev, axis=1), axis=0), whole)  # and the correction changed them


# ---------------------------------------------------------------------------------------------- the scan
@pytest.fixture(scope="module")
def lps(face_model):
    from facegeom.io.mesh import read_mesh
    from facegeom.methods.transfer import register_character

    V, F = read_mesh(HEADS / "lee_perry_smith.ply")
    t0 = time.perf_counter()
    ch = register_character(face_model, V, F)
    print(f"\nregistration {time.perf_counter() - t0:.1f} s")
    return ch


def _check(face_model, ch, deltas):
    reg = ch.registration
    return folds.check_shapes(reg.head_vertices, reg.head_faces, deltas, face_model.expression_names)


def test_the_engine_keeps_the_mouth_with_the_lips(face_model, lps):
    """The cause of the fold by the left mouth corner: the scan's mouth (a cavity off the template) was pulled
    to stay still while the lips opened round it. Before the correction: no crossing for jawOpen and its pairs,
    a handful of flips (were 19 flipped triangles and 104 crossings for jawOpen)."""
    from facegeom.methods.transfer import transfer_expressions

    res = transfer_expressions(face_model, lps.registration, "deformation")
    fc = _check(face_model, lps, res.deltas)
    counts = fc.counts()
    print(counts)
    for case in ("jawOpen", "jawOpen+mouthSmile_R", "jawOpen+mouthPucker"):
        flips, crossings = counts.get(case, (0, 0))
        assert crossings == 0 and flips <= 12, (case, flips, crossings)


def test_no_shape_or_pair_folds_the_scan(face_model, lps):
    """What the default transfer hands back: every shape at 1 and every pair, no flipped triangle and no new
    crossing (outside the scan's own folds), checked afresh, and none at lower weights either; the report says
    what was corrected."""
    from facegeom.methods.transfer import fold_lines, transfer_character

    res = transfer_character(face_model, lps)
    rep = res.info["folds"]
    print("\n".join(fold_lines(rep)))
    assert rep["before"] > 0 and rep["after"] == 0 and not rep["not_corrected"]
    assert max(rep["corrected"].values()) < 0.2 * lps.registration.head_vertices.shape[0]
    assert "jawOpen+mouthFunnel" in rep["checked"] and "eyeBlink_L+eyeBlink_R" in rep["checked"]
    skin = lps.pieces[0].vertices
    fc = _check(face_model, lps, res.deltas[:, skin])
    assert fc.total == 0, fc.counts()
    for w in (0.25, 0.5, 0.75):  # nor on the way there
        part = _check(face_model, lps, w * res.deltas[:, skin])
        assert part.total == 0, (w, part.counts())
    assert rep["check_s"] < 10.0  # about 2-3 s on a 2-core machine
    reg = lps.registration
    rest = folds.RestCrossings(reg.head_vertices, reg.head_faces)
    for f in fc.scan_flipped:  # what is left lies in the scan's own folds
        assert rest.near[f].all()


def test_the_cli_reports_the_folds(face_model, tmp_path, capsys):
    from facegeom.cli.main import main

    main(["transfer", str(HEADS / "lee_perry_smith.ply"), "-o", str(tmp_path / "rig.npz")])
    text = capsys.readouterr().out
    assert "folds: 58 shapes and pairs checked at weight 1" in text
    assert ", 0 left after the correction" in text and "jawOpen+mouthSmile_L: flipped" in text


def test_the_nearest_copy_is_corrected_where_it_can_be(face_model, lps):
    """The baseline folds about five times as much; what the correction would reshape (more than 25 %) is kept
    as transferred and named in the report -- every fold left is in one of those shapes."""
    from facegeom.methods.transfer import fold_lines, transfer_character

    rep = transfer_character(face_model, lps, "nearest").info["folds"]
    print("\n".join(fold_lines(rep)))
    assert rep["after"] < 0.5 * rep["before"]
    kept = set(rep["not_corrected"])
    for case, v in rep["cases"].items():
        if v["flipped_after"] or v["crossings_after"]:
            assert kept & set(case.split("+")), case


def test_a_correction_that_would_reshape_the_shape_is_not_made():
    """A correction changing the shape by more than ``max_change`` is not made: the shape is kept, and named."""
    V, F = _two_triangles(5.0)
    D = np.zeros((1, 6, 3))
    D[0, 3:] = [0.0, 0.0, -5.0]  # the second triangle driven through the first
    said = []
    out, before, after, changed, kept = folds.unfold(V, F, D, ["push"], pairs=(), report_kept=True,
                                                     progress=said.append)
    assert before.total == 1 and after.total == 0 and changed == {"push": 6} and not kept  # corrected
    assert said == ["1 of 1 shapes and pairs fold at weight 1; correcting them ..."]  # said before correcting
    out, before, after, changed, kept = folds.unfold(V, F, D, ["push"], pairs=(), max_change=0.01,
                                                     report_kept=True)
    assert before.total == 1 and after.total == 1 and set(kept) == {"push"} and not changed
    np.testing.assert_array_equal(out, D)
