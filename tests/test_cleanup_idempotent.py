"""``clean(..., non_manifold='remove')`` reaches its fixed point in one pass.

Removing the extra faces of a non-manifold edge can leave a vertex where three
or more fans meet; pymeshlab's vertex repair splits one fan off per call, so
the vertex stayed non-manifold and a second ``clean`` merged the split copies
and split again (seen on chair_model.obj, cycloidal.ply and wallhole.obj of the
trimesh corpus).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from facegeom.pipelines import cleanup as C
from facegeom.pipelines.meshinput import read_input_mesh

REAL = Path(__file__).parent / "data" / "real_meshes"


def book(pages=4):
    """``pages`` triangles on the edge (0, 1), each with one more triangle at vertex 0 only."""
    V, F = [[0.0, 0.0, 0.0], [0.0, 0.0, 1.0]], []
    for i in range(pages):
        t = 2 * np.pi * i / pages
        a = len(V)
        V += [[np.cos(t), np.sin(t), 0.5], [np.cos(t + 0.5), np.sin(t + 0.5), 0.0]]
        F += [[0, 1, a], [0, a, a + 1]]
    return np.array(V), np.array(F)


def triple_bowtie():
    """Three triangles sharing only vertex 0."""
    V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [-1, 0, 0], [-1, 1, 0], [0, -1, 1], [0, -1, 2]], float)
    return V, np.array([[0, 1, 2], [0, 3, 4], [0, 5, 6]])


def assert_fixed_point(V, F, mode):
    V1, F1, imap1, rep1 = C.clean(V, F, non_manifold=mode)
    p = C.mesh_problems(V1, F1)
    assert p["non_manifold_vertices"] == 0 and p["non_manifold_edges"] == 0, p
    assert np.array_equal(V1, V[imap1.new_to_old])  # split copies sit on their sources, the map is exact
    V2, F2, imap2, rep2 = C.clean(V1, F1, non_manifold=mode)
    assert imap2.is_identity and not rep2.changed
    assert np.array_equal(V2, V1) and np.array_equal(F2, F1)
    return V1, F1, imap1, rep1


@pytest.mark.parametrize("mode", ["split", "remove"])
@pytest.mark.parametrize("pages", [3, 4, 5])
def test_removing_fin_faces_leaves_no_many_fan_vertex(mode, pages):
    V, F = book(pages)
    V1, F1, imap, rep = assert_fixed_point(V, F, mode)
    if mode == "remove":
        removed = sum(s.faces_before - s.faces_after for s in rep.steps)
        assert removed == F.shape[0] - F1.shape[0] == pages - 2  # each removed face counted once
        vstep = next(s for s in rep.steps if s.name == "repair non-manifold vertices")
        # vertex 0 ends with one fan per lone triangle plus the two pages left on the edge
        assert vstep.details.get("split_copies", 0) == pages - 2
        assert (imap.new_to_old == 0).sum() == pages - 1
        assert vstep.vertices_after - vstep.vertices_before == pages - 2
    else:
        assert F1.shape[0] == F.shape[0]


@pytest.mark.parametrize("mode", ["split", "remove"])
def test_three_fans_at_a_vertex_are_cut_at_once(mode):
    V, F = triple_bowtie()
    V1, F1, imap, _ = assert_fixed_point(V, F, mode)
    assert V1.shape[0] == V.shape[0] + 2 and (imap.new_to_old == 0).sum() == 3
    assert imap.old_to_new[0] == 0


@pytest.mark.parametrize("path", sorted(REAL.glob("*.obj")), ids=lambda p: p.name)
def test_real_meshes_remove_mode_is_idempotent(path):
    V, F = read_input_mesh(path, polygons=True)
    V1, F1, _, _ = C.clean(V, F, non_manifold="remove")
    V2, F2, imap, rep = C.clean(V1, F1, non_manifold="remove")
    assert imap.is_identity and not rep.changed
    assert np.array_equal(V2, V1) and np.array_equal(F2, F1)
