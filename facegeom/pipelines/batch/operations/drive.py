"""``drive``: a deformer fitted once per worker, driven by marker frames (-> meshes) or sequences (-> npz)."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from facegeom.errors import InputError
from facegeom.pipelines.batch.cache import load_model, stamp
from facegeom.pipelines.batch.job import job_error
from facegeom.pipelines.batch.operations.base import (
    Operation,
    check_method,
    need_data,
    shared_path,
    vertex_errors,
)

__all__ = ["DriveOperation"]


def _peek_header(path: Path) -> str:
    try:
        with open(path, encoding="utf-8-sig", errors="replace") as fh:
            return fh.readline().strip().lower()
    except OSError:
        return ""


def _as_int_names(names) -> np.ndarray | None:
    try:
        return np.array([int(n) for n in names], dtype=np.int64)
    except (TypeError, ValueError):
        return None


class DriveOperation(Operation):
    """``drive``: marker frames -> meshes ``(n, 3)``, marker sequences -> npz ``vertices (T, n, 3)`` float32."""

    name = "drive"

    def _type(self, job, src: Path) -> str:
        forced = job.shared.get("input", "auto")
        if forced in ("frames", "sequences"):
            return forced[:-1]
        if src.suffix.lower() in (".npz", ".c3d"):
            return "sequence"
        return "sequence" if _peek_header(src).startswith("frame") else "frame"

    def prepare(self, job, spec, files):
        """Client side: resolve the rest mesh and the marker layout, check the deformer; record them in the spec.

        The rest mesh is ``shared.mesh``, else the ICT neutral (face data in
        ``spec['data']``). The marker vertex ids come from ``shared.markers`` (a CSV
        with a ``vertex_id`` column, or a layout name of the ICT face), else from the
        first readable input. ``spec['shared']`` gets ``mesh`` (path or None),
        ``ids`` (list of int) and ``fill_gaps``.

        Raises
        ------
        InputError
            Naming the job: a bad ``shared.input``, an unreadable mesh, no face
            data, no usable marker layout, or a deformer that cannot be built.
        """
        from facegeom.io import read_mesh

        if job.shared.get("input", "auto") not in ("auto", "frames", "sequences"):
            raise job_error(job.source, f"shared.input {job.shared['input']!r}: choose auto, frames or sequences")
        mesh = shared_path(job, "mesh")
        model = None
        if mesh is None:
            spec["data"] = need_data(job, "the default rest mesh (the ICT neutral)")
            model = load_model(spec)
            n = model.n_vertices
        else:
            try:
                n = read_mesh(mesh)[0].shape[0]
            except InputError as exc:
                raise job_error(job.source, f"shared.mesh: {exc}") from None
        ids = self._layout(job, model, n, files)
        check_method(job, "deformers")
        spec["shared"] = {"mesh": mesh, "ids": ids.tolist(), "fill_gaps": bool(job.shared.get("fill_gaps", False))}
        spec["stamp"] = stamp([mesh or spec.get("data")])

    def _layout(self, job, model, n, files) -> np.ndarray:
        from facegeom.io import read_marker_sequence, read_markers, read_vertex_csv
        from facegeom.model import layout

        name = job.shared.get("markers")
        if name is not None:
            p = Path(os.path.expanduser(name))
            p = p if p.is_absolute() else job.base / p
            if not p.exists() and (name in ("ict80", "landmarks68") or name.startswith("random")):
                if model is None:
                    raise job_error(job.source, f"shared.markers {name!r} is a layout of the ICT face; with "
                                                f"shared.mesh give a marker file (a CSV with a vertex_id column)")
                try:
                    return layout(model, name)
                except InputError as exc:
                    raise job_error(job.source, f"shared.markers: {exc}") from None
            if not p.exists():
                raise job_error(job.source, f"shared.markers {p}: file not found (a CSV with a vertex_id column, "
                                            f"or a layout name: ict80, landmarks68, random<k>)")
            try:
                return read_vertex_csv(p, n).ids.astype(np.int64)
            except InputError as exc:
                raise job_error(job.source, f"shared.markers: {exc}") from None
        # no layout given: the markers of the first input that can be read
        for f in files:
            try:
                if self._type(job, f) == "frame":
                    return read_markers(f, n_vertices=n)[0]
                ids = _as_int_names(read_marker_sequence(f).names)
                if ids is not None and ids.min() >= 0 and ids.max() < n and np.unique(ids).size == ids.size:
                    return ids
            except InputError:
                continue
            break
        raise job_error(job.source, "shared.markers is needed: a marker file (CSV with a vertex_id column) or a layout "
                                    "name (ict80, landmarks68, random<k>) giving the marker vertices")

    def outputs(self, job, spec, src, stem):
        """One output for input ``src``: ``<stem>.npz`` for a marker sequence, a mesh ``<stem>.<format>`` for a frame.

        The type is ``shared.input`` when forced, else a sequence for an ``.npz`` or
        a CSV whose header starts with ``frame``, else a frame.

        Returns
        -------
        paths : list of Path
            The output.
        extra : dict
            ``type``: ``"frame"`` or ``"sequence"``.
        """
        t = self._type(job, src)
        suffix = "npz" if t == "sequence" else spec["format"]
        return [stem.with_name(stem.name + "." + suffix)], {"type": t}

    def default_chunk(self, job, spec, items):
        """16 items per task when every input is a single frame, else 1."""
        return 16 if all(it["extra"]["type"] == "frame" for it in items) else 1

    def state(self, spec):
        """Load the rest mesh and fit the deformer on it, once per worker (the factorization).

        Returns
        -------
        dict
            ``V (n, 3)`` float64, ``F (m, 3)`` int64, ``ids (k,)`` int64 and the
            fitted ``deformer``.
        """
        from facegeom import registry
        from facegeom.io import read_mesh

        if spec["shared"]["mesh"] is None:
            model = load_model(spec)
            V, F = model.neutral.copy(), model.triangles.copy()
        else:
            V, F = read_mesh(spec["shared"]["mesh"])
        ids = np.asarray(spec["shared"]["ids"], dtype=np.int64)
        d = registry.create("deformers", spec["method"], **spec["params"])
        d.fit(V, F, ids)  # the factorization, once per worker
        return {"V": V, "F": F, "ids": ids, "deformer": d}

    def one(self, state, spec, item):
        """Drive the deformer with one marker frame, or with every frame of one marker sequence.

        A frame (CSV ``vertex_id,x,y,z``) must hold exactly the layout's vertex ids,
        in any order. A sequence's markers are matched to the layout by name when
        the names are its vertex ids, else taken in file order (same count); lost
        samples are interpolated over time only with ``shared.fill_gaps``.

        Returns
        -------
        tuple
            ``("frame", V)`` with ``V (n, 3)`` float64, or
            ``("sequence", Y, frames)`` with ``Y (T, n, 3)`` float32 and the
            sequence's frame numbers ``(T,)`` int64.

        Raises
        ------
        InputError
            An unreadable input, markers that differ from the layout, or lost
            markers without ``fill_gaps`` (or that cannot be filled).
        """
        from facegeom.io import fill_gaps, read_marker_sequence, read_markers
        from facegeom.pipelines.animate import drive_frames

        ids, path = state["ids"], item["input"]
        if item["extra"]["type"] == "frame":
            got, pos = read_markers(path, n_vertices=state["V"].shape[0])
            where = {int(v): k for k, v in enumerate(got.tolist())}
            missing = [int(v) for v in ids.tolist() if v not in where]
            if missing or got.size != ids.size:
                extra = sorted(set(where) - set(ids.tolist()))
                what = f"vertex_id {missing[0]} of the layout is missing" if missing else \
                    f"vertex_id {extra[0]} is not in the layout"
                raise InputError(f"the markers differ from the layout of {ids.size} markers: {what}", path)
            return "frame", state["deformer"].deform(pos[[where[v] for v in ids.tolist()]])
        seq = read_marker_sequence(path)
        P = seq.positions
        miss = seq.missing()
        if miss.any():
            f, j = (int(x) for x in np.argwhere(miss)[0])
            if not spec["shared"]["fill_gaps"]:
                raise InputError(f"frame {int(seq.frames[f])}: marker {seq.names[j]!r} is lost (empty or NaN); set "
                                 f"shared.fill_gaps = true to interpolate lost markers over time", path)
            try:
                P, _ = fill_gaps(P)
            except InputError as exc:
                raise InputError(exc.reason, path) from None
        named = _as_int_names(seq.names)
        if named is not None and set(named.tolist()) == set(ids.tolist()) and named.size == ids.size:
            where = {int(v): k for k, v in enumerate(named.tolist())}
            P = P[:, [where[v] for v in ids.tolist()]]
        elif seq.n_markers != ids.size:
            raise InputError(f"{seq.n_markers} markers per frame, but the layout has {ids.size}", path)
        Y, _ = drive_frames(state["deformer"], P, dtype=np.float32)  # written as float32, like animate
        return "sequence", Y, seq.frames

    def write(self, state, spec, item, result):
        """Write a frame's mesh, or a sequence's npz (``vertices``, ``faces``, ``frames``, ``marker_ids``).

        The npz's ``vertices`` are ``(T, n, 3)`` float32.

        Returns
        -------
        dict
            ``{}`` for a frame, ``{"frames": T}`` for a sequence.
        """
        from facegeom.io import atomic_path, write_mesh

        out = item["outputs"][0]
        if result[0] == "frame":
            write_mesh(out, result[1], state["F"])
            return {}
        _, Y, frames = result
        with atomic_path(out) as tmp:
            with open(tmp, "wb") as fh:
                # float32 like `facegeom animate` (and mesh caches): ~1e-6 cm on a face, half the bytes to write
                np.savez(fh, vertices=Y, faces=state["F"], frames=frames, marker_ids=state["ids"])
        return {"frames": int(Y.shape[0])}

    def evaluate(self, state, spec, item, result, truth):
        """Vertex errors against the truth: a mesh for a frame, an npz with ``vertices (T, n, 3)`` for a sequence.

        Returns
        -------
        dict
            ``err_mean`` and ``err_max``: mean and largest vertex distance, in the
            mesh's units (cm for the ICT face).

        Raises
        ------
        InputError
            An unreadable truth, or one whose shape differs from the result.
        """
        from facegeom.io import read_mesh

        if result[0] == "frame":
            return vertex_errors(result[1], read_mesh(truth)[0], "the truth mesh", truth)
        try:
            with np.load(truth, allow_pickle=False) as z:
                Vt = z["vertices"]
        except Exception as exc:  # noqa: BLE001
            raise InputError(f"cannot read 'vertices' from the truth npz ({exc.__class__.__name__})", truth) from None
        return vertex_errors(result[1], Vt, "'vertices'", truth)
