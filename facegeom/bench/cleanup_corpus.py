"""``facegeom bench cleanup-corpus DIR``: ``clean`` and ``decimate`` on a folder of real meshes.

Every ``.obj``, ``.ply`` and ``.off`` file under ``DIR`` (recursively) is read
with :func:`facegeom.pipelines.meshinput.read_input_mesh` and checked:

* ``clean`` (``non_manifold='split'`` and ``'remove'``) does not crash (an
  :class:`~facegeom.errors.InputError` is a refusal, not a crash);
* no defect it repairs is left: no non-manifold edge, no degenerate or
  duplicate face, no wrongly wound edge inside an orientable piece;
* a second ``clean`` is the identity (same ``V``, ``F``, identity map);
* ``split`` loses no face in its non-manifold repair steps;
* ``decimate`` to 50 % of the vertices: non-manifold edges before and after,
  and whether its notes tell the truth (a note when defects are left, no
  blame on preserved vertices when none were asked).

One CSV row per mesh (``cleanup-corpus.csv``) and a summary of the counts.
The meshes are read from the user's folder and never copied into the
repository (see ``tests/data/real_meshes/SOURCES.md`` for the corpus used).
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from facegeom.bench.report import Report, format_table, machine_note

__all__ = ["find_meshes", "wrong_windings", "check_mesh", "check_isolated", "summarize", "main"]

SUFFIXES = (".obj", ".ply", ".off")


def find_meshes(folder) -> list[Path]:
    """Every ``.obj``, ``.ply`` and ``.off`` file under ``folder`` (sorted; ``folder`` may be one file).

    Parameters
    ----------
    folder : str or Path

    Returns
    -------
    list of Path
    """
    p = Path(folder)
    if p.is_file():
        return [p]
    return sorted(f for f in p.rglob("*") if f.is_file() and f.suffix.lower() in SUFFIXES)


def wrong_windings(F) -> tuple[int, int]:
    """Wrongly wound edges inside orientable pieces, and the number of non-orientable pieces.

    Independent of the repair code: a union-find with parity over the faces
    (two faces on a manifold edge traversed the same way must end up with
    opposite flips). A piece with a parity conflict is non-orientable; in the
    others, every manifold edge traversed twice the same way is wrongly wound.

    Parameters
    ----------
    F : (m, 3) int
        Triangles.

    Returns
    -------
    wrong : int
        Wrongly wound manifold edges in orientable pieces.
    non_orientable : int
        Pieces (edge-connected) that cannot be oriented.
    """
    F = np.asarray(F, dtype=np.int64)
    m = F.shape[0]
    if m == 0:
        return 0, 0
    H = np.r_[F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]
    face = np.tile(np.arange(m), 3)
    key = np.sort(H, axis=1)
    _, inv, cnt = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    inv = inv.ravel()
    sel = cnt[inv] == 2
    order = np.argsort(inv[sel], kind="stable")
    idx = np.flatnonzero(sel)[order]
    a, b = idx[0::2], idx[1::2]
    same = H[a, 0] == H[b, 0]  # both half-edges run the same way: a wrong winding
    parent = np.arange(m)
    parity = np.zeros(m, dtype=np.int64)  # flip of a face relative to its parent
    size = np.ones(m, dtype=np.int64)

    def find(x):
        p = 0
        while parent[x] != x:
            p ^= parity[x]
            x = parent[x]
        return x, p

    bad_root = set()
    for fa, fb, s in zip(face[a].tolist(), face[b].tolist(), same.tolist()):
        ra, pa = find(fa)
        rb, pb = find(fb)
        need = 1 if s else 0
        if ra == rb:
            if pa ^ pb != need:
                bad_root.add(ra)
            continue
        if size[ra] < size[rb]:  # union by size keeps the trees shallow
            ra, rb = rb, ra
        parent[rb] = ra
        parity[rb] = pa ^ pb ^ need
        size[ra] += size[rb]
    roots = np.array([find(f)[0] for f in range(m)])
    bad = {int(r) for r in roots[list(bad_root)]} if bad_root else set()
    bad = {find(r)[0] for r in bad}
    bad_face = np.isin(roots, list(bad)) if bad else np.zeros(m, bool)
    wrong = int((same & ~bad_face[face[a]]).sum())
    return wrong, len(bad)


def _clean_checks(C, V, F, mode: str) -> dict:
    """Run ``clean`` in one non-manifold mode and check its result (a dict of counts)."""
    t = time.perf_counter()
    try:
        V2, F2, imap, rep = C.clean(V, F, non_manifold=mode)
    except Exception as exc:  # noqa: BLE001 - a crash is what is measured
        from facegeom.errors import InputError

        kind = "refused" if isinstance(exc, InputError) else "crash"
        return {"status": kind, "error": " ".join(str(exc).split())[:200], "seconds": time.perf_counter() - t}
    sec = time.perf_counter() - t
    p = C.mesh_problems(V2, F2)
    wrong, non_or = wrong_windings(F2)
    lost = sum(max(s.faces_before - s.faces_after, 0) for s in rep.steps if s.name.startswith("repair non-manifold"))
    out = {"status": "ok", "error": "", "seconds": sec, "faces_in": rep.input_faces, "faces_out": int(F2.shape[0]),
           "nm_edges_left": p["non_manifold_edges"], "nm_vertices_left": p["non_manifold_vertices"],
           "degenerate_left": p["degenerate_faces"], "duplicate_faces_left": p["duplicate_faces"],
           "wrong_windings_left": wrong, "non_orientable_pieces": non_or, "split_faces_lost": lost,
           "notes": " | ".join(rep.notes)}
    try:
        V3, F3, imap3, _ = C.clean(V2, F2, non_manifold=mode)
        ident = (np.array_equal(imap3.old_to_new, np.arange(V2.shape[0])) and imap3.n_new == V2.shape[0]
                 and np.array_equal(V3, V2) and np.array_equal(F3, F2))
    except Exception as exc:  # noqa: BLE001
        ident = False
        out["error"] = "second pass: " + " ".join(str(exc).split())[:200]
    out["idempotent"] = bool(ident)
    out["_clean"] = (V2, F2)
    return out


def _decimate_checks(C, V, F) -> dict:
    """``decimate`` to half the vertices: non-manifold edges before and after, truthful notes."""
    from facegeom.pipelines.cleanup.checks import _non_manifold_edges

    before = _non_manifold_edges(F)
    q = C.mesh_problems(V, F)
    defects_before = q["non_manifold_edges"] + q["non_manifold_vertices"] + q["duplicate_faces"]
    target = max(V.shape[0] // 2, 4)
    t = time.perf_counter()
    try:
        V2, F2, _, rep = C.decimate(V, F, target)
    except Exception as exc:  # noqa: BLE001
        from facegeom.errors import InputError

        kind = "refused" if isinstance(exc, InputError) else "crash"
        return {"dec_status": kind, "dec_error": " ".join(str(exc).split())[:200],
                "dec_seconds": time.perf_counter() - t}
    p = C.mesh_problems(V2, F2)
    notes = " | ".join(rep.notes)
    left = p["non_manifold_edges"] + p["non_manifold_vertices"] + p["duplicate_faces"]
    # the note on non-manifold defects left (others say what was done about them, or speak of orientation)
    told = any(n.startswith("the result has") and "non-manifold" in n for n in rep.notes)
    truthful = (told == bool(left)) and "preserved vertices" not in notes
    if left:
        truthful = truthful and f"{p['non_manifold_edges']} non-manifold edges" in notes
    return {"dec_status": "ok", "dec_error": "", "dec_seconds": time.perf_counter() - t, "dec_nm_before": before,
            "dec_defects_before": defects_before,
            "dec_nm_after": p["non_manifold_edges"], "dec_defects_after": left, "dec_note_truthful": truthful,
            "dec_notes": notes}


def check_mesh(path, decimate: bool = True, max_faces: int = 0) -> dict:
    """Every check on one mesh file (one CSV row).

    Parameters
    ----------
    path : Path
        A mesh file.
    decimate : bool
        Also run the decimation checks.
    max_faces : int
        Skip (``read='skipped'``) a mesh with more faces (0: no limit).

    Returns
    -------
    dict
        ``file``, ``vertices``, ``faces``, then per mode (``split_``,
        ``remove_``) the clean checks, then the ``dec_`` columns.
    """
    from facegeom.pipelines import cleanup as C
    from facegeom.pipelines.meshinput import read_input_mesh

    row: dict = {"file": str(path)}
    try:
        V, F = read_input_mesh(path, polygons=True)
    except Exception as exc:  # noqa: BLE001 - unreadable files are counted, not fatal
        row.update(read="unreadable", read_error=" ".join(str(exc).split())[:200])
        return row
    if max_faces and len(F) > max_faces:
        row.update(read="skipped", read_error=f"{len(F)} faces, more than {max_faces}")
        return row
    row.update(read="ok", read_error="", vertices=int(V.shape[0]), faces=len(F))
    cleaned = None
    for mode in ("split", "remove"):
        res = _clean_checks(C, V, F, mode)
        got = res.pop("_clean", None)
        if mode == "split":
            cleaned = got
        row.update({f"{mode}_{k}": v for k, v in res.items()})
    if decimate:
        Ft = F if isinstance(F, np.ndarray) else None
        if Ft is None and cleaned is not None:
            V, Ft = cleaned
        if Ft is not None:
            row.update(_decimate_checks(C, V, Ft))
    return row


def summarize(rows: list[dict]) -> dict[str, int]:
    """The corpus counts: meshes read, crashes, defects left, non-idempotent, faces lost, untruthful notes.

    Parameters
    ----------
    rows : list of dict
        :func:`check_mesh` rows.

    Returns
    -------
    dict of str -> int
    """
    ok = [r for r in rows if r.get("read") == "ok"]
    c = {"meshes": len(rows), "read": len(ok), "process_crash_or_timeout": sum(r.get("read") == "crash" for r in rows)}
    for mode in ("split", "remove"):
        st = [r for r in ok if r.get(f"{mode}_status") == "ok"]
        c[f"{mode}_crash"] = sum(r.get(f"{mode}_status") == "crash" for r in ok)
        c[f"{mode}_refused"] = sum(r.get(f"{mode}_status") == "refused" for r in ok)
        c[f"{mode}_not_idempotent"] = sum(not r[f"{mode}_idempotent"] for r in st)
        c[f"{mode}_nm_left"] = sum(r[f"{mode}_nm_edges_left"] > 0 for r in st)
        c[f"{mode}_bad_faces_left"] = sum(r[f"{mode}_degenerate_left"] + r[f"{mode}_duplicate_faces_left"] > 0
                                          for r in st)
        c[f"{mode}_wrong_windings"] = sum(r[f"{mode}_wrong_windings_left"] > 0 for r in st)
    c["split_faces_lost"] = sum(r.get("split_split_faces_lost", 0) > 0 for r in ok if r.get("split_status") == "ok")
    dec = [r for r in ok if r.get("dec_status") == "ok"]
    c["dec_crash"] = sum(r.get("dec_status") == "crash" for r in ok)
    c["dec_nm_after"] = sum(r["dec_nm_after"] > 0 for r in dec)
    # a clean input: no non-manifold edge or vertex and no duplicate face (what decimate checks and reports)
    c["dec_nm_after_from_clean_input"] = sum(r["dec_defects_after"] > 0 and r["dec_defects_before"] == 0 for r in dec)
    c["dec_note_untruthful"] = sum(not r["dec_note_truthful"] for r in dec)
    return c


def _child(conn, path, decimate, max_faces):  # pragma: no cover - runs in a child process
    """Run :func:`check_mesh` and send the row (without the arrays) back."""
    try:
        conn.send(check_mesh(path, decimate=decimate, max_faces=max_faces))
    finally:
        conn.close()


def check_isolated(path, decimate: bool = True, max_faces: int = 0, timeout: float = 300.0) -> dict:
    """:func:`check_mesh` in a child process: a native abort or a time-out is a crash row, not the end.

    Parameters
    ----------
    path : Path
        A mesh file.
    decimate : bool
        Also run the decimation checks.
    max_faces : int
        Skip meshes with more faces (0: no limit).
    timeout : float
        Seconds before the child is stopped.

    Returns
    -------
    dict
        The :func:`check_mesh` row, or ``read='crash'`` with the reason.
    """
    import multiprocessing as mp

    ctx = mp.get_context("fork" if "fork" in mp.get_all_start_methods() else "spawn")
    recv, send = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_child, args=(send, Path(path), decimate, max_faces))
    t = time.perf_counter()
    proc.start()
    send.close()
    row = None
    if recv.poll(timeout):
        try:
            row = recv.recv()
        except EOFError:
            row = None
    proc.join(5 if row is not None else 0.1)
    if proc.is_alive():
        proc.kill()
        proc.join()
    if row is None:
        why = f"killed after {timeout:g} s" if time.perf_counter() - t >= timeout else f"exit code {proc.exitcode}"
        row = {"file": str(path), "read": "crash", "read_error": f"the process died ({why})"}
    return row


def main(folder, out=None, decimate: bool = True, max_faces: int = 0, echo=print,
         timeout: float = 300.0) -> dict[str, int]:
    """Run :func:`check_mesh` on every mesh of ``folder``; write the CSV and the summary.

    Parameters
    ----------
    folder : path-like
        Folder of meshes (searched recursively) or one mesh file.
    out : path-like, optional
        Output folder for ``cleanup-corpus.csv`` and ``cleanup-corpus-summary.md``.
    decimate : bool
        Also check ``decimate``.
    max_faces : int
        Skip meshes with more faces (0: no limit); skipped files are listed.
    echo : callable(str)
        Progress and summary output.
    timeout : float
        Seconds per mesh (each runs in its own process; a native crash or a
        time-out is counted as a crash).

    Returns
    -------
    dict of str -> int
        :func:`summarize` counts.
    """
    files = find_meshes(folder)
    rows = []
    for k, f in enumerate(files, 1):
        row = check_isolated(f, decimate=decimate, max_faces=max_faces, timeout=timeout)
        rows.append(row)
        bad = [k2 for k2 in ("split_status", "remove_status", "dec_status") if row.get(k2) not in (None, "ok")]
        echo(f"[{k}/{len(files)}] {f.name}: {row.get('read')}" + (f" ({', '.join(bad)})" if bad else ""))
    rep = Report(out, "cleanup-corpus", echo=echo)
    keys: list[str] = []
    for r in rows:
        keys += [k for k in r if k not in keys]
    rep.csv([{k: r.get(k, "") for k in keys} for r in rows])
    counts = summarize(rows)
    table = format_table(["check", "meshes"], [[k, v] for k, v in counts.items()])
    rep.summary(table, f"clean (split and remove) + decimate to 50 % on {folder}; {machine_note()}")
    rep.done()
    return counts
