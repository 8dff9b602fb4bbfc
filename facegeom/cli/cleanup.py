"""``facegeom clean | decimate | crop``: mesh clean-up commands (see :mod:`facegeom.pipelines.cleanup`).

Every command reads IN, checks the marker files first, writes OUT and the
optional index map, marker files and JSON report all at once (temporary files
renamed into place only when everything succeeded), and prints what changed.
"""
from __future__ import annotations

from pathlib import Path

import click

PROGRESS_FROM = 100_000  # vertices: show per-step progress on stderr from this size on (auto mode)


def _common(f):
    """Options shared by the three commands (index map, markers, report, progress)."""
    opts = [
        click.option("--map", "map_path", type=click.Path(dir_okay=False), default=None,
                     help="Write the vertex index map: .csv (old_id,new_id,status,step; status kept, merged, removed, "
                          "then split/new rows for created vertices) or .npz (old_to_new, new_to_old, ...)."),
        click.option("--markers", "markers", type=click.Path(dir_okay=False), multiple=True,
                     help="Marker or landmark CSV with a vertex_id column (e.g. vertex_id,x,y,z) to carry through; "
                          "repeatable. A marker whose vertex disappears is an error."),
        click.option("--markers-out", "markers_out", type=click.Path(dir_okay=False), multiple=True,
                     help="Where to write each --markers file with its vertex_id column renumbered (same order)."),
        click.option("--drop-lost-markers", is_flag=True,
                     help="Drop (and report) markers whose vertex was removed instead of failing."),
        click.option("--report", "report_path", type=click.Path(dir_okay=False), default=None,
                     help="Also write the report (counts per step) as JSON."),
        click.option("--progress/--no-progress", default=None,
                     help=f"Per-step progress on stderr (default: on for meshes of {PROGRESS_FROM:,}+ vertices)."),
    ]
    for opt in reversed(opts):
        f = opt(f)
    return f


def _prepare_markers(markers, markers_out, n_vertices: int):
    from facegeom.errors import InputError
    from facegeom.io import read_vertex_csv

    if markers_out and len(markers_out) != len(markers):
        raise InputError(f"{len(markers_out)} --markers-out for {len(markers)} --markers: give one output per file")
    return [read_vertex_csv(m, n_vertices) for m in markers]


def _check_outputs(out: str, map_path, report_path, mesh_in=None, markers=(), markers_out=()):
    """Output formats, then no output is an input (IN, a --markers file) or another output."""
    from facegeom.errors import InputError
    from facegeom.io import MESH_FORMATS, check_outputs

    p = Path(out)
    if p.suffix.lower() not in MESH_FORMATS:
        raise InputError(f"unsupported mesh format {p.suffix!r}; use one of {', '.join(MESH_FORMATS)}", p)
    if map_path and Path(map_path).suffix.lower() not in (".csv", ".npz"):
        raise InputError("an index map must be a .csv or .npz file", map_path)
    if report_path and Path(report_path).suffix.lower() != ".json":
        raise InputError("the report must be a .json file", report_path)
    check_outputs([mesh_in, *markers], [out, map_path, *markers_out, report_path])


def _progress(flag, n_vertices: int):
    if flag or (flag is None and n_vertices >= PROGRESS_FROM):
        return lambda msg: click.echo(msg, err=True)
    return None


def _finish(operation: str, out, V, F, imap, report, sources, markers_out, drop_lost, map_path, report_path):
    """Carry the markers (may fail), then write every output all-or-nothing and print the report."""
    from facegeom.io import all_or_nothing, write_mesh
    from facegeom.pipelines.cleanup import carry_vertex_csv, write_vertex_csv

    carried = [carry_vertex_csv(s, imap, drop_lost=drop_lost, operation=operation) for s in sources]
    for k, c in enumerate(carried):
        report.markers.append(c.summary(markers_out[k] if markers_out else None))
    targets = [out] + ([map_path] if map_path else []) + list(markers_out) + ([report_path] if report_path else [])
    with all_or_nothing(targets) as tmps:
        it = iter(tmps)
        write_mesh(next(it), V, F)
        if map_path:
            imap.save(next(it))
        for c in carried if markers_out else []:
            write_vertex_csv(next(it), c)
        if report_path:
            report.write_json(next(it))
    for line in report.lines():
        click.echo(line)
    for c in carried:
        if c.dropped_rows.size:
            ids = ", ".join(str(i) for i in c.source.ids[c.dropped_rows][:10].tolist())
            click.echo(f"warning: {c.source.path}: dropped {c.dropped_rows.size} lost markers (vertex_id {ids}"
                       f"{', ...' if c.dropped_rows.size > 10 else ''})", err=True)
    click.echo(f"wrote {', '.join(str(t) for t in targets)}")


@click.command("clean")
@click.argument("mesh_in", metavar="IN", type=click.Path(dir_okay=False))
@click.argument("mesh_out", metavar="OUT", type=click.Path(dir_okay=False))
@click.option("--merge-tol", default="0", show_default=True, metavar="DIST|PCT%",
              help="Also merge vertices closer than this: an absolute distance (mesh units) or a percentage of "
                   "the bounding-box diagonal, e.g. 0.001%. 0 merges exact duplicates only.")
@click.option("--largest-component", "--largest", "largest", is_flag=True,
              help="Keep only the connected component with the most faces.")
@click.option("--non-manifold", type=click.Choice(["split", "remove"]), default="split", show_default=True,
              help="Non-manifold edges: split their vertices (no face lost; a fin becomes its own component) "
                   "or remove faces (may open holes).")
@click.option("--no-orient", is_flag=True, help="Leave face orientation as it is.")
@_common
def clean_cmd(mesh_in, mesh_out, merge_tol, largest, non_manifold, no_orient, map_path, markers, markers_out,
              drop_lost_markers, report_path, progress):
    """Repair IN into OUT: triangulate, merge duplicate vertices, remove unreferenced vertices, duplicate and
    zero-area faces, repair non-manifold edges and vertices, orient faces (pymeshlab filters).

    \b
    Example:
      facegeom clean scan.obj scan-clean.obj --largest-component --merge-tol 0.001% \\
          --markers markers.csv --markers-out markers-clean.csv --map map.csv --report report.json
    """
    from facegeom.pipelines.cleanup import clean, parse_tolerance
    from facegeom.pipelines.meshinput import read_input_mesh

    parse_tolerance(merge_tol)
    _check_outputs(mesh_out, map_path, report_path, mesh_in, markers, markers_out)
    V, F = read_input_mesh(mesh_in, polygons=True)
    sources = _prepare_markers(markers, markers_out, V.shape[0])
    V2, F2, imap, report = clean(V, F, merge_tol=merge_tol, largest_component=largest,
                                 non_manifold=non_manifold, orient=not no_orient,
                                 progress=_progress(progress, V.shape[0]))
    _finish("clean", mesh_out, V2, F2, imap, report, sources, markers_out, drop_lost_markers, map_path,
            report_path)


@click.command("decimate")
@click.argument("mesh_in", metavar="IN", type=click.Path(dir_okay=False))
@click.argument("mesh_out", metavar="OUT", type=click.Path(dir_okay=False))
@click.option("--vertices", "n_vertices", required=True, type=click.IntRange(4),
              help="Target vertex count (the result has at most this many, unless constraints stop it).")
@click.option("--preserve-boundary", is_flag=True, help="Keep the mesh boundary (eye, mouth, outline) intact.")
@click.option("--preserve-topology", is_flag=True, help="Refuse collapses that change the topology.")
@_common
def decimate_cmd(mesh_in, mesh_out, n_vertices, preserve_boundary, preserve_topology, map_path, markers,
                 markers_out, drop_lost_markers, report_path, progress):
    """Quadric edge-collapse decimation of IN (pymeshlab) to about --vertices vertices, into OUT.

    Vertices are never moved (the result is a subset of IN's vertices). The
    vertices of every --markers file are preserved.

    \b
    Example:
      facegeom decimate face.obj face-2k.obj --vertices 2000 --preserve-boundary \\
          --markers markers.csv --markers-out markers-2k.csv --map map.npz
    """
    import numpy as np

    from facegeom.errors import InputError
    from facegeom.pipelines.cleanup import decimate
    from facegeom.pipelines.meshinput import read_input_mesh

    _check_outputs(mesh_out, map_path, report_path, mesh_in, markers, markers_out)
    V, F = read_input_mesh(mesh_in)
    sources = _prepare_markers(markers, markers_out, V.shape[0])
    keep = np.concatenate([s.ids for s in sources]) if sources else None
    try:
        V2, F2, imap, report = decimate(V, F, n_vertices, preserve_boundary=preserve_boundary,
                                        preserve_topology=preserve_topology, keep=keep,
                                        progress=_progress(progress, V.shape[0]))
    except InputError as exc:  # about the mesh: name it
        if exc.path:
            raise
        raise InputError(exc.reason, mesh_in) from None
    _finish("decimate", mesh_out, V2, F2, imap, report, sources, markers_out, drop_lost_markers, map_path,
            report_path)


@click.command("crop")
@click.argument("mesh_in", metavar="IN", type=click.Path(dir_okay=False))
@click.argument("mesh_out", metavar="OUT", type=click.Path(dir_okay=False))
@click.option("--from-vertices", "from_vertices", default=None, metavar="I,J,...",
              help="Landmark vertex ids (of IN) the region grows from; use with --radius.")
@click.option("--radius", type=float, default=None,
              help="Geodesic radius of the region around --from-vertices, in mesh units (ICT: cm).")
@click.option("--geodesic", type=click.Choice(["exact", "heat", "graph"]), default="exact", show_default=True,
              help="Distance: libigl exact geodesics, heat method (fast, ~1% error) or edge paths.")
@click.option("--id-range", "id_range", default=None, metavar="A:B",
              help="Keep vertex ids A..B-1 instead (half-open; e.g. 0:6706, the ICT narrow face).")
@_common
def crop_cmd(mesh_in, mesh_out, from_vertices, radius, geodesic, id_range, map_path, markers, markers_out,
             drop_lost_markers, report_path, progress):
    """Keep the face region of IN into OUT: the vertices within a geodesic radius of landmark vertices, or an
    id range; faces with a vertex outside are removed.

    \b
    Examples:
      facegeom crop head.obj face.obj --from-vertices 3442,1234 --radius 9
      facegeom crop head.obj face.obj --id-range 0:6706 --markers m.csv --markers-out m-face.csv
    """
    import numpy as np

    from facegeom.errors import InputError
    from facegeom.pipelines.cleanup import crop, parse_id_range
    from facegeom.pipelines.meshinput import read_input_mesh

    if radius is not None and from_vertices is None:
        raise InputError("--radius goes with --from-vertices")
    if (from_vertices is None) == (id_range is None):
        raise InputError("crop needs either --from-vertices with --radius, or --id-range (one of them)")
    if from_vertices is not None and radius is None:
        raise InputError("--from-vertices needs --radius (geodesic distance in mesh units)")
    _check_outputs(mesh_out, map_path, report_path, mesh_in, markers, markers_out)
    V, F = read_input_mesh(mesh_in)
    src = rng = None
    if from_vertices is not None:
        try:
            ids = [int(x) for x in from_vertices.split(",") if x.strip()]
        except ValueError:
            raise InputError(f"--from-vertices must be comma-separated vertex ids, got {from_vertices!r}") \
                from None
        if not ids:
            raise InputError("--from-vertices is empty")
        bad = [i for i in ids if not 0 <= i < V.shape[0]]  # checked as Python ints: no overflow on huge ids
        if bad:
            raise InputError(f"--from-vertices: vertex {bad[0]} is out of range: the mesh has "
                             f"{V.shape[0]} vertices", mesh_in)
        src = np.array(ids, dtype=np.int64)
    else:
        rng = parse_id_range(id_range, V.shape[0])
    sources = _prepare_markers(markers, markers_out, V.shape[0])
    V2, F2, imap, report = crop(V, F, sources=src, radius=radius, id_range=rng, geodesic=geodesic,
                                progress=_progress(progress, V.shape[0]))
    _finish("crop", mesh_out, V2, F2, imap, report, sources, markers_out, drop_lost_markers, map_path,
            report_path)
