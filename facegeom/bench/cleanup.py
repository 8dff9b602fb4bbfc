"""Benchmark of ``facegeom.pipelines.cleanup.clean`` (with its index map) on a ~100,000-vertex dirty face.

The ICT neutral face is subdivided (libigl ``upsample``, then pymeshlab midpoint
subdivision of the longest edges up to the requested vertex count), then
defects are injected: duplicated vertices (faces rewired to the copies),
zero-area faces, duplicate faces, a flipped face and a stray component. The
clean (largest component kept) is timed, median of 3, and checked.

    facegeom bench cleanup [--vertices 100000] [--repeats 3]
"""
from __future__ import annotations

import os
import platform
import statistics
import time

import numpy as np


def build_mesh(model, vertices: int):
    """The face subdivided to about ``vertices`` vertices (clean).

    Parameters
    ----------
    model : FaceModel
        The ICT face (``neutral`` (n, 3), ``triangles`` (m, 3)).
    vertices : int
        Target vertex count: libigl ``upsample`` while it stays below, then
        pymeshlab midpoint subdivision of the longest edges (within 0.5 %).

    Returns
    -------
    V : (n2, 3) float64
    F : (m2, 3) int64
    """
    import igl
    import pymeshlab as ml

    V, F = model.neutral.astype(np.float64), model.triangles.astype(np.int64)
    while V.shape[0] * 4 <= vertices:  # each upsample roughly quadruples
        V, F = igl.upsample(V, F)
    extra = vertices - V.shape[0]
    if extra > 0:
        E = igl.edges(F)
        L = np.sort(np.linalg.norm(V[E[:, 0]] - V[E[:, 1]], axis=1))[::-1]
        lo, hi = 0, L.size - 1
        best = None
        for _ in range(12):  # bisection on the edge-length threshold
            k = (lo + hi) // 2
            ms = ml.MeshSet()
            ms.add_mesh(ml.Mesh(V, F.astype(np.int32)))
            ms.meshing_surface_subdivision_midpoint(iterations=1, threshold=ml.PureValue(float(L[k])))
            n = ms.current_mesh().vertex_number()
            best = (abs(n - vertices), ms.current_mesh()) if best is None or abs(n - vertices) < best[0] else best
            if n < vertices:
                lo = k + 1
            else:
                hi = k - 1
            if lo > hi or abs(n - vertices) < vertices * 0.005:
                break
        m = best[1]
        V, F = m.vertex_matrix().astype(np.float64), m.face_matrix().astype(np.int64)
    return V, F


def inject_defects(V, F, seed: int = 0, fraction: float = 0.01):
    """Duplicated vertices, zero-area and duplicate faces, a flipped face, a stray component.

    Parameters
    ----------
    V : (n, 3) float
    F : (m, 3) int
        A clean mesh.
    seed : int
        Seed of the duplicated vertices and faces.
    fraction : float
        Share of vertices duplicated (the faces' first corner on each rewired to the copy).

    Returns
    -------
    Vd : (n + k + 3, 3) float
        ``V``, then ``k = n * fraction`` copies, then a stray triangle far away.
    Fd : (m + 2j + 1, 3) int
        ``F`` rewired (one face flipped), then ``j = m // 1000`` zero-area and
        ``j`` duplicate faces, then the stray triangle.
    """
    rng = np.random.default_rng(seed)
    n, m = V.shape[0], F.shape[0]
    src = rng.choice(n, int(n * fraction), replace=False)
    copy_id = np.full(n, -1, np.int64)
    copy_id[src] = n + np.arange(src.size)
    Fd = F.copy()
    # rewire the corners of the first face of each chosen vertex to its copy
    face_of = np.full(n, -1, np.int64)
    face_of[F[::-1].ravel()] = np.repeat(np.arange(m)[::-1], 3)
    fsel = face_of[src]
    for c in range(3):
        hit = copy_id[Fd[fsel, c]] >= 0
        hit &= Fd[fsel, c] == src
        Fd[fsel[hit], c] = copy_id[src[hit]]
    Vd = np.r_[V, V[src]]
    k = max(m // 1000, 1)
    degenerate = np.c_[F[:k, 0], F[:k, 0], F[:k, 1]]
    dup = F[rng.choice(m, k, replace=False)]
    Fd[5] = Fd[5, ::-1]
    stray_v = V[:3] + [0.0, 0.0, 100.0]
    stray_f = np.array([[0, 1, 2]]) + Vd.shape[0]
    return np.r_[Vd, stray_v], np.r_[Fd, degenerate, dup, stray_f]


def main(model, vertices: int = 100_000, repeats: int = 3, echo=print) -> float:
    """``facegeom bench cleanup``: time ``clean`` (largest component) on the dirty face and check the result.

    Parameters
    ----------
    model : FaceModel
        The ICT face.
    vertices : int
        Size of the subdivided face (see :func:`build_mesh`).
    repeats : int
        Timed runs; the median is reported.
    echo : callable(str)

    Returns
    -------
    float
        The median time (s) of clean + index map.

    Raises
    ------
    AssertionError
        A mapped vertex moved, the result is not edge-manifold, or the clean
        mesh was not recovered.
    """
    import igl

    from facegeom.pipelines.cleanup import clean, mesh_problems

    V, F = build_mesh(model, vertices)
    Vd, Fd = inject_defects(V, F)
    echo(f"machine: {platform.machine()}, {os.cpu_count()} CPUs, {platform.system()} {platform.release()}, "
         f"Python {platform.python_version()}")
    echo(f"mesh: {V.shape[0]:,} vertices, {F.shape[0]:,} faces clean; dirty: {Vd.shape[0]:,} vertices, "
         f"{Fd.shape[0]:,} faces")
    echo(f"defects: {({k: v for k, v in mesh_problems(Vd, Fd).items() if v})}")
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        V2, F2, imap, report = clean(Vd, Fd, largest_component=True)
        times.append(time.perf_counter() - t)
    echo(str(report))
    ok = imap.old_to_new >= 0
    assert np.array_equal(V2[imap.old_to_new[ok]], Vd[ok]), "a mapped vertex moved"
    assert igl.is_edge_manifold(F2)[0], "result not edge-manifold"
    assert V2.shape[0] == V.shape[0] and np.array_equal(V2, V), "the clean mesh was not recovered"
    med = statistics.median(times)
    echo(f"clean + index map: median {med:.3f} s of {repeats} ({', '.join(f'{t:.3f}' for t in times)}); "
         f"target < 5 s: {'met' if med < 5 else 'MISSED'}")
    return med
