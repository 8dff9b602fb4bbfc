"""Mesh clean-up (facegeom.pipelines.cleanup, `facegeom clean|decimate|crop`) on a corpus of broken meshes.

The corpus is built here from the real ICT face and from small grids: every
broken mesh either comes out clean (edge-manifold, no duplicate vertices,
coherent orientation, markers on the same positions) or fails with one clear
line and no output file.
"""
from __future__ import annotations

import csv
import json
import os
import subprocess
import sys

import igl
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from facegeom.cli.main import main
from facegeom.errors import InputError
from facegeom.io import read_mesh, write_markers, write_mesh
from facegeom.pipelines import cleanup as C

from .conftest import grid_mesh, two_grids

# --------------------------------------------------------------------------- helpers


def assert_clean(V, F):
    """Edge-manifold (libigl), no duplicate/unreferenced vertex, no degenerate or repeated face, oriented."""
    assert igl.is_edge_manifold(F)[0]
    p = C.mesh_problems(V, F)
    for k in ("duplicate_vertices", "unreferenced_vertices", "degenerate_faces", "duplicate_faces",
              "non_manifold_edges", "non_manifold_vertices"):
        assert p[k] == 0, (k, p)
    assert_oriented(F)


def assert_oriented(F):
    """Coherent orientation: no directed edge is used by two faces."""
    E = np.r_[F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]
    assert np.unique(E, axis=0).shape[0] == E.shape[0]


def assert_markers_kept(imap, V_old, V_new, ids, tol=0.0):
    new = imap.old_to_new[ids]
    assert (new >= 0).all()
    np.testing.assert_allclose(V_new[new], V_old[ids], rtol=0, atol=tol)


def same_faces(F, G) -> bool:
    """Same faces in the same order and orientation (rotation of a face's corners allowed)."""
    if F.shape != G.shape:
        return False
    return bool(C._cyclic_same(F, G).all() and (np.sort(F, axis=1) == np.sort(G, axis=1)).all())


def duplicate(V, F, src, faces_per_vertex=1):
    """Copy vertices ``src`` to the end and rewire some of their faces to the copies."""
    n = V.shape[0]
    F = F.copy()
    for k, s in enumerate(src):
        fs = np.flatnonzero((F == s).any(axis=1))[:faces_per_vertex]
        F[fs] = np.where(F[fs] == s, n + k, F[fs])
    return np.r_[V, V[src]], F


def fin(V, F, face=100):
    """A third face on the first edge of ``face``: a non-manifold edge (and a new vertex)."""
    a, b, _ = F[face]
    tip = (V[a] + V[b]) / 2 + [0.0, 0.0, 1.0]
    return np.r_[V, [tip]], np.r_[F, [[a, b, V.shape[0]]]]


def stray(V, F):
    """A detached triangle far away."""
    n = V.shape[0]
    return np.r_[V, V[:3] + [0.0, 0.0, 100.0]], np.r_[F, [[n, n + 1, n + 2]]]


@pytest.fixture(scope="module")
def face(face_model):
    return face_model.neutral.copy(), face_model.triangles.copy()


@pytest.fixture(scope="module")
def marker_ids(face_model):
    from facegeom.model import ict80

    return ict80(face_model)


# --------------------------------------------------------------------------- clean: already clean


@pytest.mark.parametrize("which", ["face", "grid", "two_grids"])
def test_clean_mesh_is_unchanged(which, request):
    if which == "face":
        V, F = request.getfixturevalue("face")
    else:
        V, F = grid_mesh(9, 7, bump=0.3) if which == "grid" else two_grids()
    V2, F2, imap, rep = C.clean(V, F, largest_component=False)
    assert np.array_equal(V2, V) and np.array_equal(F2, F)
    assert imap.is_identity and not rep.changed
    assert imap.counts()["kept"] == V.shape[0]


# --------------------------------------------------------------------------- clean: the corpus


def corpus(V, F, marker_ids):
    """name -> (V, F, options, markers (old ids), expected exact recovery)."""
    n = V.shape[0]
    rng = np.random.default_rng(1)
    src = np.r_[marker_ids[:5], rng.choice(n, 40, replace=False)]
    src = np.unique(src)
    out = {}
    Vd, Fd = duplicate(V, F, src)
    out["duplicated vertices"] = (Vd, Fd, {}, np.r_[marker_ids, n + np.arange(3)], True)
    Ff = F.copy()
    Ff[[3, 500, 4000]] = Ff[[3, 500, 4000]][:, ::-1]
    out["flipped faces"] = (V, Ff, {}, marker_ids, True)
    Fz = np.r_[F, [[0, 0, 1], [5, 6, 5]], F[[7]][:, [0, 1, 1]]]
    out["zero-area faces"] = (V, Fz, {}, marker_ids, True)
    out["duplicate faces"] = (V, np.r_[F, F[[10, 20, 30]], F[[40]][:, ::-1]], {}, marker_ids, True)
    Vf, Ff = fin(V, F)
    out["non-manifold fin"] = (Vf, Ff, {"largest_component": True}, marker_ids, True)
    Vs, Fs = stray(V, F)
    out["detached component"] = (Vs, Fs, {"largest_component": True}, marker_ids, True)
    Vu = np.r_[V, [[1e3, 1e3, 1e3]]]
    out["unreferenced vertex"] = (Vu, F, {}, marker_ids, True)
    # everything at once
    Va, Fa = duplicate(V, F, src)
    Va, Fa = fin(Va, Fa, face=2000)
    Va, Fa = stray(Va, Fa)
    Fa = np.r_[Fa, [[1, 1, 2]], Fa[[50]]]
    Fa[60] = Fa[60, ::-1]
    out["all at once"] = (Va, Fa, {"largest_component": True}, np.r_[marker_ids, n + np.arange(3)], True)
    return out


CORPUS = ["duplicated vertices", "flipped faces", "zero-area faces", "duplicate faces", "non-manifold fin",
          "detached component", "unreferenced vertex", "all at once"]


@pytest.mark.parametrize("name", CORPUS)
def test_corpus_comes_out_clean(name, face, marker_ids):
    V, F = face
    Vd, Fd, opts, markers, exact = corpus(V, F, marker_ids)[name]
    V2, F2, imap, rep = C.clean(Vd, Fd, **opts)
    assert_clean(V2, F2)
    assert_markers_kept(imap, Vd, V2, markers)
    assert rep.changed and rep.output_vertices == V2.shape[0]
    if exact:  # the defects injected into the clean face are undone exactly
        assert np.array_equal(V2, V) and same_faces(F2, F)
    # the map is consistent: every surviving old vertex sits where it was (exact duplicates only here)
    ok = imap.old_to_new >= 0
    assert np.array_equal(V2[imap.old_to_new[ok]], Vd[ok])
    assert (imap.new_to_old >= 0).all()


def test_fin_without_largest_component_is_split_off(face):
    V, F = face
    Vf, Ff = fin(V, F)
    V2, F2, imap, rep = C.clean(Vf, Ff)
    assert igl.is_edge_manifold(F2)[0]
    p = C.mesh_problems(V2, F2)
    assert p["non_manifold_edges"] == 0 and p["components"] == 2
    # the only coincident vertices are the two split copies of the fin's edge, and they are labelled so
    assert imap.counts()["split"] == 2 and p["duplicate_vertices"] == 2
    assert np.array_equal(V2[: V.shape[0]], V) and same_faces(F2[: F.shape[0]], F)  # the surface is intact
    step = next(s for s in rep.steps if s.name == "repair non-manifold edges")
    assert step.details == {"split_copies": 2}


def test_non_manifold_remove_mode(face):
    V, F = face
    V2, F2, imap, rep = C.clean(*fin(V, F), non_manifold="remove")
    assert igl.is_edge_manifold(F2)[0]
    assert F2.shape[0] == F.shape[0]  # one face removed per extra face on the edge


def test_bowtie_vertex_is_split():
    V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [-1, 0, 0], [-1, -1, 0.0]])
    F = np.array([[0, 1, 2], [0, 3, 4]])
    V2, F2, imap, rep = C.clean(V, F)
    assert V2.shape[0] == 6 and C.mesh_problems(V2, F2)["non_manifold_vertices"] == 0
    assert imap.old_to_new[0] >= 0 and list(imap.new_status).count("split") == 1
    assert np.array_equal(V2[imap.new_to_old], V[imap.new_to_old])  # the copy sits on its source


def test_quads_and_polygons_are_triangulated():
    V, _ = grid_mesh(4, 4)
    idx = np.arange(16).reshape(4, 4)
    quads = np.c_[idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()]
    V2, F2, imap, rep = C.clean(V, quads)
    assert F2.shape == (18, 3) and imap.is_identity and np.array_equal(V2, V)
    assert rep.steps[0].name == "triangulate polygons" and rep.steps[0].details["split_polygons"] == 9
    assert_clean(V2, F2)
    # mixed polygons, overlapping: a triangle over half a quad and a quad given twice
    polys = [list(q) for q in quads[:4]] + [[0, 1, 5], [1, 2, 6, 5]] + [list(q) for q in quads[5:]]
    V3, F3, imap3, rep3 = C.clean(V, polys)
    assert rep3.steps[0].details["split_polygons"] == 9
    assert igl.is_edge_manifold(F3)[0] and C.mesh_problems(V3, F3)["non_manifold_vertices"] == 0
    assert_oriented(F3)
    assert np.array_equal(V3, V[imap3.new_to_old])  # exact positions (no float32 round trip)


def test_merge_tolerance(face):
    V, F = face
    n = V.shape[0]
    Vd, Fd = duplicate(V, F, np.arange(0, 200, 10))
    Vd[n:] += 1e-7  # near, not exact, duplicates
    V2, F2, imap, _ = C.clean(Vd, Fd)
    assert imap.merged.sum() == 0 and V2.shape[0] >= Vd.shape[0]  # exact only: nothing merged
    for tol in (1e-5, "0.0001%"):
        V2, F2, imap, rep = C.clean(Vd, Fd, merge_tol=tol)
        assert V2.shape[0] == n and imap.merged.sum() == 20
        assert_markers_kept(imap, Vd, V2, np.arange(n, n + 20), tol=1e-6)
        assert rep.steps[1].name.startswith("merge vertices closer than")
        assert rep.steps[1].details["merged_vertices"] == 20
        assert (imap.step[n:] == rep.steps[1].name).all()
        assert_clean(V2, F2)
    with pytest.raises(InputError, match="merge tolerance"):
        C.clean(V, F, merge_tol="abc")
    with pytest.raises(InputError, match="non-negative"):
        C.clean(V, F, merge_tol=-1)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.integers(0, 35), min_size=1, max_size=20, unique=True), st.integers(1, 3),
       st.booleans())
def test_duplicates_always_map_back_to_their_source(src, faces_per_vertex, flip):
    """Invariant: copying any vertices and rewiring their faces is undone exactly, and each copy maps to its source."""
    V, F = grid_mesh(6, 6, bump=0.2)
    src = np.array(src)
    Vd, Fd = duplicate(V, F, src, faces_per_vertex)
    if flip:
        Fd[0] = Fd[0, ::-1]
    V2, F2, imap, _ = C.clean(Vd, Fd)
    assert np.array_equal(V2, V) and same_faces(F2, F)
    copies = np.arange(V.shape[0], Vd.shape[0])
    # a copy that took every face of its source survives as the vertex and the source merges into it
    assert np.array_equal(V2[imap.old_to_new[copies]], V[src])
    assert np.array_equal(imap.old_to_new[src], imap.old_to_new[copies])


# --------------------------------------------------------------------------- bad input


def test_bad_arrays_raise_input_error(face):
    V, F = face
    bad = V.copy()
    bad[3, 1] = np.nan
    with pytest.raises(InputError, match="NaN"):
        C.clean(bad, F)
    with pytest.raises(InputError, match="outside"):
        C.clean(V, np.r_[F, [[0, 1, V.shape[0] + 5]]])
    with pytest.raises(InputError, match="nothing is left"):
        C.clean(np.zeros((3, 3)), np.array([[0, 1, 2]]))
    with pytest.raises(InputError, match="at least 3"):
        C.clean(V[:4], [[0, 1, 2], [0, 1]])


BAD_FILES = {
    "empty.obj": (b"", "empty file"),
    "nan.obj": (b"v 0 0 nan\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "NaN"),
    "past.obj": (b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n", "outside"),
    "past.off": (b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n", "outside"),
    "trunc.ply": (b"ply\nformat binary_little_endian 1.0\nelement vertex 100\nproperty float x\n"
                  b"property float y\nproperty float z\nelement face 10\n"
                  b"property list uchar int vertex_indices\nend_header\n\x00\x00", "truncated"),
}


def run_main(args, capsys):
    """Run the CLI in-process: (exit code, stdout, stderr)."""
    try:
        main(list(args))
        code = 0
    except SystemExit as e:
        code = e.code
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.mark.parametrize("name", sorted(BAD_FILES))
@pytest.mark.parametrize("command", [["clean"], ["decimate", "--vertices", "10"], ["crop", "--id-range", "0:2"]])
def test_bad_files_fail_with_one_line_and_no_output(tmp_path, capsys, name, command):
    content, problem = BAD_FILES[name]
    src = tmp_path / name
    src.write_bytes(content)
    out = tmp_path / "out.obj"
    code, so, se = run_main([command[0], str(src), str(out), *command[1:], "--map", str(tmp_path / "m.csv")],
                            capsys)
    assert code == 2
    lines = se.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("facegeom: error:") and name in lines[0] and problem in lines[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == [name]  # nothing written, no temporary left


def test_truncated_binary_ply_of_a_real_mesh(tmp_path, capsys, face):
    V, F = face
    good = write_mesh(tmp_path / "face.ply", V, F)
    raw = good.read_bytes()
    (tmp_path / "cut.ply").write_bytes(raw[: len(raw) * 2 // 3])
    good.unlink()
    code, so, se = run_main(["clean", str(tmp_path / "cut.ply"), str(tmp_path / "o.ply")], capsys)
    assert code == 2 and "cut.ply" in se and len(se.strip().splitlines()) == 1
    assert [p.name for p in tmp_path.iterdir()] == ["cut.ply"]


# --------------------------------------------------------------------------- index map


def test_index_map_files_roundtrip(tmp_path, face):
    V, F = face
    Vd, Fd = stray(*fin(*duplicate(V, F, [1, 2, 3])))
    _, _, imap, _ = C.clean(Vd, Fd)  # merged, split copies, kept
    assert imap.counts()["merged"] == 3 and imap.counts()["split"] == 2
    for ext in ("csv", "npz"):
        back = C.IndexMap.load(imap.save(tmp_path / f"map.{ext}"))
        assert np.array_equal(back.old_to_new, imap.old_to_new)
        assert np.array_equal(back.new_to_old, imap.new_to_old)
        assert np.array_equal(back.status, imap.status) and np.array_equal(back.step, imap.step)
    rows = list(csv.DictReader(open(tmp_path / "map.csv")))
    n = V.shape[0]
    merged = [r for r in rows if r["status"] == "merged"]
    assert [(int(r["old_id"]), int(r["new_id"])) for r in merged] == [(n, 1), (n + 1, 2), (n + 2, 3)] or \
        [(int(r["old_id"]), int(r["new_id"])) for r in merged] == [(1, 1), (2, 2), (3, 3)]
    assert all(r["step"] == "merge duplicate vertices" for r in merged)
    assert sum(r["status"] == "split" for r in rows) == 2


def test_index_maps_chain(face, marker_ids):
    V, F = face
    Vd, Fd = duplicate(V, F, marker_ids[:10])
    V1, F1, m1, _ = C.clean(Vd, Fd)
    V2, F2, m2, _ = C.decimate(V1, F1, 4000, keep=m1.map(marker_ids))
    both = m1.then(m2)
    assert both.n_old == Vd.shape[0] and both.n_new == V2.shape[0]
    assert_markers_kept(both, Vd, V2, np.r_[marker_ids, Vd.shape[0] - np.arange(1, 11)])
    with pytest.raises(InputError, match="cannot chain"):
        m2.then(m1)


# --------------------------------------------------------------------------- decimate


def test_decimate_preserves_markers_and_is_a_subset(face, marker_ids):
    V, F = face
    V2, F2, imap, rep = C.decimate(V, F, 3000, keep=marker_ids, preserve_boundary=True)
    assert 2900 <= V2.shape[0] <= 3000
    assert np.array_equal(V2, V[imap.new_to_old])  # no vertex moved
    assert_markers_kept(imap, V, V2, marker_ids)
    assert_clean(V2, F2)
    assert rep.steps[0].details["preserved_vertices"] == marker_ids.size
    # without the preservation most markers are collapsed away: the selection is what keeps them
    _, _, plain, _ = C.decimate(V, F, 3000)
    assert (plain.old_to_new[marker_ids] < 0).sum() > 10
    assert (imap.step[imap.removed] == "quadric edge collapse").all()


def test_decimate_arguments(face):
    V, F = face
    with pytest.raises(InputError, match="at least 4"):
        C.decimate(V, F, 2)
    with pytest.raises(InputError, match="out of range"):
        C.decimate(V, F, 100, keep=[V.shape[0]])
    V2, F2, imap, rep = C.decimate(V, F, 10**6)  # already small enough
    assert imap.is_identity and np.array_equal(F2, F)


def _misoriented(F) -> int:
    """Edges with two faces that run them the same way (counted here independently of the library)."""
    H = np.r_[F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]
    key = np.sort(H, axis=1)
    _, inv, cnt = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    pairs = {}
    for row, e in enumerate(inv.ravel()):
        if cnt[e] == 2:
            pairs.setdefault(e, []).append(tuple(H[row]))
    return sum(a == b for a, b in pairs.values())


def test_decimate_says_when_the_input_was_not_coherently_oriented():
    V, F = grid_mesh(30, 30, bump=0.3)
    F = F.copy()
    band = np.flatnonzero(np.abs(V[F].mean(axis=1)[:, 0] - 0.5) < 0.1)  # a band of faces turned over
    F[band] = F[band, ::-1]
    had = _misoriented(F)
    V2, F2, _, rep = C.decimate(V, F, 300)
    wrong = _misoriented(F2)
    assert had > 0 and wrong > 0
    note = [n for n in rep.notes if "disagree in orientation" in n]
    assert note == [f"the result has {wrong} edges whose two faces disagree in orientation; the input already had "
                    f"{had}: run `facegeom clean` first (it orients the faces)"]


def test_decimate_turns_back_a_face_the_collapses_turned_over(monkeypatch):
    import facegeom.pipelines.cleanup.decimation as D

    once = D._decimate_once

    def turning(*args):  # a collapse that leaves one face turned over against its neighbours
        V2, F2, imap, run = once(*args)
        F2 = F2.copy()
        F2[F2.shape[0] // 2] = F2[F2.shape[0] // 2, ::-1]
        return V2, F2, imap, run

    monkeypatch.setattr(D, "_decimate_once", turning)
    V, F = grid_mesh(30, 30, bump=0.3)
    V2, F2, _, rep = C.decimate(V, F, 300)
    assert _misoriented(F2) == 0
    assert "1 face turned over by the collapses was turned back to agree with its neighbours" in rep.notes
    assert not any("disagree in orientation" in n for n in rep.notes)


# --------------------------------------------------------------------------- crop


def test_crop_id_range_keeps_the_narrow_face(face, marker_ids):
    V, F = face
    V2, F2, imap, rep = C.crop(V, F, id_range=(0, 6706))
    assert np.array_equal(V2, V[:6706]) and imap.removed.sum() == V.shape[0] - 6706
    assert_markers_kept(imap, V, V2, marker_ids)
    assert igl.is_edge_manifold(F2)[0]


def test_crop_geodesic_matches_exact_distances(face, face_model):
    V, F = face
    src = face_model.landmarks[[30]]
    r = 4.0
    V2, F2, imap, rep = C.crop(V, F, sources=src, radius=r)
    d = igl.exact_geodesic(V, F, VS=src, VT=np.arange(V.shape[0]))
    kept = imap.new_to_old
    assert (d[kept] <= r + 1e-9).all()
    # every vertex well inside the disk is kept (the boundary ring may lose faces)
    assert imap.old_to_new[d < 0.8 * r].min() >= 0
    assert imap.old_to_new[src[0]] >= 0
    _, _, imap_h, _ = C.crop(V, F, sources=src, radius=r, geodesic="heat")
    assert abs(imap_h.n_new - imap.n_new) < 0.05 * imap.n_new
    with pytest.raises(InputError, match="radius"):
        C.crop(V, F, sources=src, radius=-1)
    with pytest.raises(InputError, match="either"):
        C.crop(V, F)
    with pytest.raises(InputError, match="empty"):
        C.parse_id_range("5:5")


# --------------------------------------------------------------------------- CLI end to end (real face)


@pytest.fixture
def dirty_files(tmp_path, face, marker_ids):
    """The real face with duplicated marker vertices, a fin, a stray component and quads-free faces, on disk."""
    V, F = face
    n = V.shape[0]
    Vd, Fd = duplicate(V, F, marker_ids[:8])
    Vd, Fd = stray(*fin(Vd, Fd, face=3000))
    mesh = write_mesh(tmp_path / "dirty.obj", Vd, Fd)
    Vd = read_mesh(mesh)[0]  # OBJ keeps 15 digits: the positions as the CLI will see them
    # markers on kept vertices and on some duplicated copies (which merge back)
    ids = np.r_[marker_ids[8:], n + np.arange(8)]
    markers = write_markers(tmp_path / "markers.csv", ids, Vd[ids])
    lmk = tmp_path / "landmarks.csv"
    lmk.write_text("vertex_id,u,v\n" + "".join(f"{i},{10 + i % 7}.5,{i % 11}.25\n" for i in marker_ids[:20]))
    return tmp_path, mesh, markers, lmk, Vd


def read_rows(path):
    return list(csv.DictReader(open(path)))


def test_cli_clean_end_to_end(dirty_files, capsys, face):
    d, mesh, markers, lmk, Vd = dirty_files
    out = d / "clean.ply"
    code, so, se = run_main(["clean", str(mesh), str(out), "--largest-component", "--markers", str(markers),
                             "--markers-out", str(d / "m2.csv"), "--markers", str(lmk), "--markers-out",
                             str(d / "l2.csv"), "--map", str(d / "map.npz"), "--report", str(d / "r.json")], capsys)
    assert code == 0, se
    assert "merge duplicate vertices" in so and "8 merged vertices" in so and "keep the largest component" in so
    V2, F2 = read_mesh(out)
    V, F = face
    assert np.array_equal(V2, Vd[: V.shape[0]]) and same_faces(F2, F)  # the face as it was before the damage
    assert_clean(V2, F2)
    before = read_rows(markers)
    after = read_rows(d / "m2.csv")
    assert len(after) == len(before)
    for b, a in zip(before, after):
        assert [a[k] for k in "xyz"] == [b[k] for k in "xyz"]  # the row is unchanged but for vertex_id
        assert np.array_equal(V2[int(a["vertex_id"])], Vd[int(b["vertex_id"])])  # same position
    lb, la = read_rows(lmk), read_rows(d / "l2.csv")
    assert [(r["u"], r["v"]) for r in la] == [(r["u"], r["v"]) for r in lb]
    rep = json.loads((d / "r.json").read_text())
    assert rep["operation"] == "clean" and rep["output_vertices"] == V.shape[0]
    assert {s["name"] for s in rep["steps"]} >= {"merge duplicate vertices", "repair non-manifold edges"}
    assert rep["markers"][0]["carried"] == len(before) and rep["markers"][0]["merged"] == 8
    imap = C.IndexMap.load(d / "map.npz")
    assert imap.n_old == Vd.shape[0] and imap.n_new == V.shape[0]


def test_cli_lost_marker_is_an_error_naming_it(dirty_files, capsys):
    d, mesh, markers, lmk, Vd = dirty_files
    lost = d / "lost.csv"
    stray_vertex = Vd.shape[0] - 2
    write_markers(lost, [5, stray_vertex], Vd[[5, stray_vertex]])
    args = ["clean", str(mesh), str(d / "c.obj"), "--largest", "--markers", str(lost), "--markers-out",
            str(d / "lost2.csv"), "--map", str(d / "map.csv")]
    before = sorted(p.name for p in d.iterdir())
    code, so, se = run_main(args, capsys)
    assert code == 2 and len(se.strip().splitlines()) == 1
    assert "lost.csv" in se and f"vertex_id {stray_vertex}" in se and "line 3" in se
    assert "keep the largest component" in se and "--drop-lost-markers" in se
    assert sorted(p.name for p in d.iterdir()) == before  # no mesh, no map, no markers written
    code, so, se = run_main(args + ["--drop-lost-markers"], capsys)
    assert code == 0 and "1 lost and dropped" in so and "dropped 1 lost markers" in se
    rows = read_rows(d / "lost2.csv")
    assert [r["vertex_id"] for r in rows] == ["5"]


def test_cli_merged_markers_collide(tmp_path, capsys, face):
    V, F = face
    Vd, Fd = duplicate(V, F, [7])
    mesh = write_mesh(tmp_path / "d.obj", Vd, Fd)
    m = write_markers(tmp_path / "m.csv", [7, V.shape[0]], Vd[[7, V.shape[0]]])
    code, so, se = run_main(["clean", str(mesh), str(tmp_path / "o.obj"), "--markers", str(m)], capsys)
    assert code == 2 and "same vertex" in se and "m.csv" in se
    assert not (tmp_path / "o.obj").exists()


def test_cli_decimate_and_crop_with_markers(tmp_path, capsys, face, marker_ids):
    V, F = face
    mesh = write_mesh(tmp_path / "face.obj", V, F)
    markers = write_markers(tmp_path / "m.csv", marker_ids, V[marker_ids])
    code, so, se = run_main(["decimate", str(mesh), str(tmp_path / "dec.obj"), "--vertices", "2500",
                             "--preserve-boundary", "--markers", str(markers), "--markers-out",
                             str(tmp_path / "m-dec.csv"), "--map", str(tmp_path / "dec.csv")], capsys)
    assert code == 0, se
    V2, F2 = read_mesh(tmp_path / "dec.obj")
    assert V2.shape[0] <= 2500 and igl.is_edge_manifold(F2)[0]
    for r in read_rows(tmp_path / "m-dec.csv"):  # every marker survives, at its position
        np.testing.assert_allclose(V2[int(r["vertex_id"])], [float(r[k]) for k in "xyz"], atol=1e-12)
    code, so, se = run_main(["crop", str(mesh), str(tmp_path / "crop.obj"), "--id-range", "0:6706", "--markers",
                             str(markers), "--markers-out", str(tmp_path / "m-crop.csv")], capsys)
    assert code == 0, se
    assert read_mesh(tmp_path / "crop.obj")[0].shape[0] == 6706
    code, so, se = run_main(["crop", str(mesh), str(tmp_path / "c2.obj"), "--from-vertices", "3442,1234",
                             "--radius", "3", "--geodesic", "heat", "--markers", str(markers)], capsys)
    assert code == 2 and "is lost" in se and "m.csv" in se and not (tmp_path / "c2.obj").exists()
    for bad, msg in [(["--radius", "3"], "--radius goes with"), (["--from-vertices", "1"], "needs --radius"),
                     ([], "either"), (["--from-vertices", "1,x", "--radius", "2"], "comma-separated"),
                     (["--from-vertices", "999999", "--radius", "2"], "out of range"),
                     (["--id-range", "9:3"], "empty")]:
        code, so, se = run_main(["crop", str(mesh), str(tmp_path / "c3.obj"), *bad], capsys)
        assert code == 2 and msg in se and len(se.strip().splitlines()) == 1, (bad, se)


def test_cli_obj_quads(tmp_path, capsys):
    (tmp_path / "q.obj").write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 2 0 0\nv 2 1 0\nv 0 0 0\n"
                                    "f 1 2 3 4\nf 2 5 6 3\nf 7 2 4\n")
    code, so, se = run_main(["clean", str(tmp_path / "q.obj"), str(tmp_path / "t.obj"), "--map",
                             str(tmp_path / "map.csv")], capsys)
    assert code == 0, se
    assert "triangulate polygons" in so and "2 split polygons" in so
    V, F = read_mesh(tmp_path / "t.obj")
    assert V.shape[0] == 6 and igl.is_edge_manifold(F)[0]
    rows = read_rows(tmp_path / "map.csv")
    assert rows[6]["status"] == "merged" and rows[6]["new_id"] == "0"


def test_cli_usage_errors(tmp_path, capsys, face):
    V, F = face
    mesh = write_mesh(tmp_path / "f.obj", V, F)
    m = write_markers(tmp_path / "m.csv", [1, 2], V[[1, 2]])
    cases = [
        (["clean", str(mesh), str(tmp_path / "o.stl")], "unsupported mesh format"),
        (["clean", str(mesh), str(tmp_path / "o.obj"), "--map", str(tmp_path / "m.txt")], ".csv or .npz"),
        (["clean", str(mesh), str(tmp_path / "o.obj"), "--markers", str(m), "--markers-out", "a.csv",
          "--markers-out", "b.csv"], "give one output per file"),
        (["clean", str(mesh), str(tmp_path / "o.obj"), "--markers", str(tmp_path / "none.csv")], "file not found"),
        (["clean", str(mesh), str(tmp_path / "nodir" / "o.obj")], "output folder does not exist"),
        (["clean", str(mesh), str(tmp_path / "o.obj"), "--merge-tol", "x%"], "merge tolerance"),
    ]
    for args, msg in cases:
        code, so, se = run_main(args, capsys)
        assert code == 2 and msg in se and len(se.strip().splitlines()) == 1, (args, se)
    bad = tmp_path / "far.csv"
    bad.write_text("vertex_id,x,y,z\n99999,0,0,0\n")
    code, so, se = run_main(["decimate", str(mesh), str(tmp_path / "o.obj"), "--vertices", "100", "--markers",
                             str(bad)], capsys)
    assert code == 2 and "far.csv" in se and "out of range" in se
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.obj", "far.csv", "m.csv"]


def test_cli_subprocess_help_and_error(tmp_path, face_model):
    env = dict(os.environ)
    r = subprocess.run([sys.executable, "-m", "facegeom", "decimate", "-h"], capture_output=True, text=True, env=env,
                       timeout=60)
    assert r.returncode == 0 and "--preserve-boundary" in r.stdout and "--markers" in r.stdout
    (tmp_path / "e.obj").write_bytes(b"")
    r = subprocess.run([sys.executable, "-m", "facegeom", "clean", str(tmp_path / "e.obj"), str(tmp_path / "o.obj")],
                       capture_output=True, text=True, env=env, timeout=60)
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "empty file" in r.stderr and r.stdout == ""
