"""``clean``: meshes through clean / decimate / crop -> mesh, report, index map, carried marker files."""
from __future__ import annotations

import numpy as np

from facegeom.errors import InputError
from facegeom.pipelines.batch.job import job_error, resolve_template
from facegeom.pipelines.batch.operations.base import (
    Operation,
)

_CLEAN_PARAMS = {
    "clean": ("merge_tol", "largest_component", "non_manifold", "orient"),
    "decimate": ("vertices", "preserve_boundary", "preserve_topology"),
    "crop": ("from_vertices", "radius", "id_range", "geodesic"),
}

_BOOL_PARAMS = ("largest_component", "non_manifold", "orient", "preserve_boundary", "preserve_topology", "geodesic")

__all__ = ["CleanOperation"]


class CleanOperation(Operation):
    """``clean``: meshes through clean / decimate / crop -> mesh, JSON report, index map, carried markers."""

    name = "clean"

    def prepare(self, job, spec, files):
        """Client side: check the clean method and its params, and record the shared options in ``spec['shared']``.

        ``job.method`` is ``clean``, ``decimate`` or ``crop``, each with its own
        params. ``spec['shared']`` gets ``markers`` (whether ``shared.markers`` is
        given), ``drop_lost_markers`` and ``map`` (``"csv"``, ``"npz"`` or None).

        Raises
        ------
        InputError
            Naming the job: an unknown method or param, a bad ``merge_tol``,
            ``decimate`` without an integer ``vertices >= 4``, ``crop`` without
            exactly one of ``from_vertices`` (with ``radius``) and ``id_range``, or
            a ``shared.map`` other than csv or npz.
        """
        from facegeom.pipelines.cleanup import parse_id_range, parse_tolerance

        if job.method not in _CLEAN_PARAMS:
            raise job_error(job.source, f"method {job.method!r}: clean runs one of {', '.join(_CLEAN_PARAMS)}")
        allowed = _CLEAN_PARAMS[job.method]
        bad = [k for k in job.params if k not in allowed]
        if bad:
            raise job_error(job.source, f"params.{bad[0]}: {job.method} takes {', '.join(allowed)}")
        p = job.params
        for k in _BOOL_PARAMS:
            if k in p and not isinstance(p[k], bool):
                raise job_error(job.source, f"params.{k} must be true or false, got {p[k]!r}")
        if "radius" in p and (isinstance(p["radius"], bool) or not isinstance(p["radius"], (int, float))
                              or not 0 < p["radius"] < float("inf")):
            raise job_error(job.source, f"params.radius must be a positive number, got {p['radius']!r}")
        v = p.get("from_vertices")
        if v is not None and not (isinstance(v, list) and v and all(
                isinstance(x, int) and not isinstance(x, bool) and 0 <= x < 2**63 for x in v)):
            raise job_error(job.source, f"params.from_vertices must be a list of vertex ids (non-negative integers), "
                                        f"got {v!r}")
        if "id_range" in p:
            try:
                parse_id_range(p["id_range"], 2**62)  # the mesh is not read here: any end will do
            except InputError as exc:
                raise job_error(job.source, f"params.id_range: {exc}") from None
        if "merge_tol" in p:
            try:
                parse_tolerance(p["merge_tol"])
            except InputError as exc:
                raise job_error(job.source, f"params.merge_tol: {exc}") from None
        if job.method == "decimate" and not (isinstance(p.get("vertices"), int) and p["vertices"] >= 4):
            raise job_error(job.source, "decimate needs params.vertices, the target vertex count (an integer >= 4)")
        if job.method == "crop":
            if ("from_vertices" in p) == ("id_range" in p):
                raise job_error(job.source, "crop needs either params.from_vertices with params.radius, or "
                                            "params.id_range (one of them)")
            if "from_vertices" in p and "radius" not in p:
                raise job_error(job.source, "params.from_vertices needs params.radius (geodesic distance)")
        m = job.shared.get("map")
        if m is not None and m not in ("csv", "npz"):
            raise job_error(job.source, f"shared.map {m!r}: an index map is csv or npz")
        spec["shared"] = {"markers": "markers" in job.shared, "drop_lost_markers":
                          bool(job.shared.get("drop_lost_markers", False)), "map": m}

    def outputs(self, job, spec, src, stem):
        """The output files of mesh ``src``: the mesh, [the index map], [the carried markers], the report.

        In this order: ``<stem>.<format>`` (the input's suffix when the job sets no
        format), ``<stem>.map.<csv|npz>`` with ``shared.map``,
        ``<stem>.markers.csv`` with ``shared.markers``, and ``<stem>.report.json``.

        Returns
        -------
        paths : list of Path
            The outputs.
        extra : dict
            ``markers``: the input's marker CSV (``shared.markers`` resolved for
            ``src``), when given.
        """
        fmt = spec["format"] or src.suffix.lower().lstrip(".")
        outs = [stem.with_name(stem.name + "." + fmt)]
        extra = {}
        if spec["shared"]["map"]:
            outs.append(stem.with_name(stem.name + ".map." + spec["shared"]["map"]))
        if spec["shared"]["markers"]:
            extra["markers"] = str(resolve_template(job.base, job.shared["markers"], src))
            outs.append(stem.with_name(stem.name + ".markers.csv"))
        outs.append(stem.with_name(stem.name + ".report.json"))
        return outs, extra

    def one(self, state, spec, item):
        """Read the mesh (and its marker CSV) and run ``clean``, ``decimate`` or ``crop`` on it.

        ``decimate`` keeps the marker vertices; the markers are carried through the
        index map (a lost marker is dropped with ``shared.drop_lost_markers``, else
        an error).

        Returns
        -------
        tuple
            ``(V, F, V2, F2, index_map, report, carried)``: the input vertices
            ``(n, 3)`` float64 and faces (triangles ``(m, 3)`` int64, or an OBJ's
            polygons for ``clean``), the result ``V2 (n2, 3)`` and ``F2 (m2, 3)``,
            the :class:`~facegeom.pipelines.cleanup.IndexMap`, the report, and the
            carried marker files (none or one).

        Raises
        ------
        InputError
            An unreadable mesh or marker file, ``from_vertices`` out of range, a bad
            ``id_range``, a lost marker without ``drop_lost_markers``, or a mesh the
            operation refuses.
        """
        from facegeom.io import read_vertex_csv
        from facegeom.pipelines import cleanup
        from facegeom.pipelines.meshinput import read_input_mesh

        method, p = spec["method"], dict(spec["params"])
        V, F = read_input_mesh(item["input"], polygons=method == "clean")
        sources = [read_vertex_csv(item["extra"]["markers"], V.shape[0])] if "markers" in item["extra"] \
            else []
        if method == "clean":
            V2, F2, imap, report = cleanup.clean(V, F, **p)
        elif method == "decimate":
            keep = np.concatenate([s.ids for s in sources]) if sources else None
            V2, F2, imap, report = cleanup.decimate(V, F, p.pop("vertices"), keep=keep, **p)
        else:
            src = p.pop("from_vertices", None)
            rng = p.pop("id_range", None)
            if src is not None:
                src = np.asarray(src, dtype=np.int64)
                bad = src[(src < 0) | (src >= V.shape[0])]
                if bad.size:
                    raise InputError(f"params.from_vertices: vertex {int(bad[0])} is out of range: the mesh has "
                                     f"{V.shape[0]} vertices", item["input"])
            if rng is not None:
                rng = cleanup.parse_id_range(rng, V.shape[0])
            V2, F2, imap, report = cleanup.crop(V, F, sources=src, id_range=rng, **p)
        carried = [cleanup.carry_vertex_csv(s, imap, drop_lost=spec["shared"]["drop_lost_markers"],
                                            operation=method) for s in sources]
        return V, F, V2, F2, imap, report, carried

    def write(self, state, spec, item, result):
        """Write the item's outputs all or nothing (the mesh last), the carried markers' summaries in the report.

        Returns
        -------
        dict
            ``vertices_in``, ``vertices_out``, ``faces_in``, ``faces_out`` and
            ``markers_dropped``.
        """
        from facegeom.io import all_or_nothing, write_mesh
        from facegeom.pipelines.cleanup import write_vertex_csv

        V, F, V2, F2, imap, report, carried = result
        outs = item["outputs"]  # mesh, [map], [markers], report
        for c in carried:
            report.markers.append(c.summary(outs[-2]))
        with all_or_nothing(outs) as tmps:  # renamed last to first: the mesh exists only once all others do
            write_mesh(tmps[0], V2, F2)
            if spec["shared"]["map"]:
                imap.save(tmps[1])
            for c in carried:
                write_vertex_csv(tmps[-2], c)
            report.write_json(tmps[-1])
        return {"vertices_in": int(V.shape[0]), "vertices_out": int(V2.shape[0]),
                "faces_in": int(len(F)), "faces_out": int(F2.shape[0]),
                "markers_dropped": int(sum(c.dropped_rows.size for c in carried))}
