"""Expression transfer measured against an artist's own rig: its neutral in, its shapes as the reference.

Protocol: the artist's rig (ARKit or ICT names, any topology, separate pieces
as its parts) gives only its neutral to :func:`~facegeom.methods.transfer.register_character`
(turned by a random rotation and rescaled to another unit first when asked:
the registration is told neither), and every engine transfers the ICT
expressions onto it. Each of the artist's shapes that the ICT set drives
(``tongueOut`` has no ICT shape) is compared with the transferred shapes
driven the same way (ARKit's ``browInnerUp`` = both ICT sides at weight 1),
per piece of the rig (its skin and, where the artist moves them, the eyes,
teeth and tongue):

- relative error ``|D - D_artist| / |D_artist|`` (Frobenius over the piece's
  vertices, the head's units: the registration's scale is inside ``D``);
- cosine between the two displacement fields (the direction of the motion,
  whatever its size);
- the oracle: the relative error of the best gain ``g`` for that one shape
  (``min_g |g D - D_artist| / |D_artist|``): what no per-shape gain can close,
  the artist's style.

Shapes whose artist motion on a piece is below :data:`MOVES_MM` at every
vertex are not scored on that piece. The engines' median relative error on the
skin is the headline; the default must be at most 0.95 x the ``nearest`` copy.
"""
from __future__ import annotations

import time

import numpy as np
from scipy.spatial.transform import Rotation

from facegeom.bench.report import Report, format_table, machine_note

__all__ = ["compare", "summarize", "figure", "run", "MOVES_MM"]

MOVES_MM = 0.5  # a piece moved by less than this (max over its vertices) in a shape is not scored on it


def _pose(seed, units_scale):
    if seed is None:
        return np.eye(3), np.zeros(3), units_scale
    rng = np.random.default_rng(seed)
    return Rotation.random(random_state=rng).as_matrix(), rng.normal(0.0, 30.0, 3), units_scale


def compare(model, artist, engines=("deformation", "nearest"), seed=None, units_scale: float = 1.0,
            progress=None, character=None) -> dict:
    """Transfer onto the artist's neutral and compare with the artist's shapes -> a result dict (see module).

    Parameters
    ----------
    model : FaceModel
    artist : BlendshapeRig
        The artist's rig in facegeom's frame (cm, Y up), with ``parts`` when it has pieces.
    engines : sequence of str
        Transfer engines to measure (the first is the headline).
    seed : int or None
        Turn the head by a random rotation (and move it) first; None: as it is.
    units_scale : float
        Multiply the head's coordinates by this first (10: millimetres).
    progress : callable(str), optional
    character : Character, optional
        The artist's neutral already registered (as this function would: same
        ``seed`` and ``units_scale``); its registration is then not repeated.
        The result's ``character`` holds the one used.
    """
    from facegeom.io.shape_names import ShapeMap
    from facegeom.methods.transfer import register_character, transfer_character

    say = progress or (lambda line: None)
    R, t, k = _pose(seed, units_scale)
    V = (np.asarray(artist.neutral, dtype=np.float64) @ R.T) * k + t
    A = (np.asarray(artist.deltas, dtype=np.float64) @ R.T) * k  # the artist's shapes in the same frame
    t0 = time.perf_counter()
    ch = character or register_character(model, V, artist.triangles, parts=artist.parts, progress=say)
    t_reg = time.perf_counter() - t0
    smap = ShapeMap.between(model.expression_names, artist.names)
    W = smap.apply(np.eye(len(artist.names)))  # (A shapes, ICT shapes): the ICT weights of each artist shape
    mm = ch.registration.mm_per_unit
    regions = [(p.name, p.vertices, p.role) for p in ch.pieces]
    out = {"registration": ch.registration.report, "registration_s": t_reg, "engines": {},
           "pieces": [(p.name, p.role, p.how) for p in ch.pieces], "names": list(artist.names),
           "not_transferred": [n for n, w in zip(artist.names, W) if not np.any(w)], "mm_per_unit": mm,
           "vertices": V, "faces": np.asarray(artist.triangles), "artist_deltas": A,
           "view": (ch.registration.R, ch.registration.t, ch.registration.scale),
           "character": ch,
           "shown_faces": np.concatenate([p.faces for p in ch.pieces if p.role in ("skin", "eye", "follow")])}
    for engine in engines:
        res = transfer_character(model, ch, engine)
        D = np.tensordot(W, res.deltas, axes=1)  # (A, n, 3)
        rows = []
        for a, name in enumerate(artist.names):
            if not np.any(W[a]):
                continue
            for region, ids, role in regions:
                ref, got = A[a, ids].ravel(), D[a, ids].ravel()
                if np.abs(A[a, ids]).max() * mm < MOVES_MM:
                    continue
                nr, ng = np.linalg.norm(ref), np.linalg.norm(got)
                gain = float(ref @ got / (ng * ng)) if ng > 0 else 0.0
                rows.append({"shape": name, "piece": region, "role": role,
                             "rel_error": float(np.linalg.norm(got - ref) / nr),
                             "cosine": float(ref @ got / (nr * ng)) if ng > 0 else 0.0,
                             "oracle": float(np.linalg.norm(gain * got - ref) / nr), "gain": gain,
                             "artist_max_mm": float(np.abs(A[a, ids]).max() * mm)})
        out["engines"][engine] = {"rows": rows, "time_s": res.time_s, "deltas": D}
        say(f"{engine}: {len(rows)} shape x piece pairs scored ({res.time_s:.2f} s)")
    return out


def summarize(result: dict) -> dict:
    """Per engine: the skin's median relative error, cosine and oracle, the worst five shapes, per-piece medians."""
    summary = {}
    for engine, r in result["engines"].items():
        skin = [x for x in r["rows"] if x["role"] == "skin"]
        rel = np.array([x["rel_error"] for x in skin])
        worst = sorted(skin, key=lambda x: -x["rel_error"])[:5]
        pieces = {}
        for x in r["rows"]:
            if x["role"] != "skin":
                pieces.setdefault(x["piece"], []).append(x)
        summary[engine] = {
            "skin_median": float(np.median(rel)), "skin_p90": float(np.percentile(rel, 90)),
            "cosine_median": float(np.median([x["cosine"] for x in skin])),
            "oracle_median": float(np.median([x["oracle"] for x in skin])), "shapes": len(skin),
            "worst": [(x["shape"], x["rel_error"], x["cosine"]) for x in worst],
            "pieces": {k: {"median": float(np.median([x["rel_error"] for x in v])),
                           "cosine": float(np.median([x["cosine"] for x in v])),
                           "oracle": float(np.median([x["oracle"] for x in v])),
                           "shapes": [x["shape"] for x in v]} for k, v in pieces.items()},
            "time_s": r["time_s"]}
    return summary


def _raster(X, F, value, size: int):
    """A z-buffered front view of the mesh ``(X, F)`` (x right, y up, z to the viewer) -> ``(value image, shade)``.

    Per pixel: the nearest triangle's ``value`` (its vertices' mean) and its
    Lambert shade; NaN where no triangle covers the pixel.
    """
    lo, hi = X[:, :2].min(axis=0), X[:, :2].max(axis=0)
    k = (size - 1) / float(max(hi - lo))
    P = (X[:, :2] - lo) * k
    h, w = int(np.ceil((hi[1] - lo[1]) * k)) + 1, int(np.ceil((hi[0] - lo[0]) * k)) + 1
    depth = np.full((h, w), -np.inf)
    img = np.full((h, w), np.nan)
    shade = np.zeros((h, w))
    tri = X[F]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    fval = value[F].mean(axis=1)
    for f in np.flatnonzero(n[:, 2] > 0):
        a, b, c = P[F[f]]
        x0, x1 = int(np.floor(min(a[0], b[0], c[0]))), int(np.ceil(max(a[0], b[0], c[0])))
        y0, y1 = int(np.floor(min(a[1], b[1], c[1]))), int(np.ceil(max(a[1], b[1], c[1])))
        xs, ys = np.meshgrid(np.arange(x0, x1 + 1), np.arange(y0, y1 + 1))
        d = (b[1] - c[1]) * (a[0] - c[0]) + (c[0] - b[0]) * (a[1] - c[1])
        if abs(d) < 1e-12:
            continue
        l1 = ((b[1] - c[1]) * (xs - c[0]) + (c[0] - b[0]) * (ys - c[1])) / d
        l2 = ((c[1] - a[1]) * (xs - c[0]) + (a[0] - c[0]) * (ys - c[1])) / d
        l3 = 1.0 - l1 - l2
        inside = (l1 >= -1e-9) & (l2 >= -1e-9) & (l3 >= -1e-9) & (xs < w) & (ys < h)
        if not inside.any():
            continue
        z = l1 * tri[f, 0, 2] + l2 * tri[f, 1, 2] + l3 * tri[f, 2, 2]
        yy, xx, zz = ys[inside], xs[inside], z[inside]
        closer = zz > depth[yy, xx]
        yy, xx = yy[closer], xx[closer]
        depth[yy, xx] = zz[closer]
        img[yy, xx] = fval[f]
        shade[yy, xx] = 0.35 + 0.65 * n[f, 2]
    return img[::-1], shade[::-1]


def _front(ax, V, F, value, vmax, view, size: int = 320):
    """Draw the mesh ``(V, F)`` seen from the front of the registered face, coloured by ``value`` (per vertex)."""
    import matplotlib.pyplot as plt

    R, t, s = view
    X = ((np.asarray(V) - t) @ R) / s  # the model's frame: y up, z towards the viewer
    img, shade = _raster(X, F, np.asarray(value, dtype=np.float64), size)
    rgb = plt.get_cmap("viridis")(np.clip(np.nan_to_num(img) / vmax, 0, 1))[..., :3] * shade[..., None]
    rgba = np.dstack([rgb, np.isfinite(img).astype(float)])
    ax.imshow(rgba, interpolation="nearest")
    ax.axis("off")


def figure(result, engine: str, shapes, columns: int = 5):
    """The artist's shape (top) and the transfer's (bottom) side by side for ``shapes``, coloured by motion (mm)."""
    import matplotlib.pyplot as plt

    names = result["names"]
    shapes = list(shapes)[:columns]
    fig, axes = plt.subplots(2, len(shapes), figsize=(3.2 * len(shapes), 7.0), squeeze=False)
    V, mm = result["vertices"], result["mm_per_unit"]
    F = result["faces"][result["shown_faces"]]  # the skin, eyes and cards (the mouth's inner pieces are hidden)
    D = result["engines"][engine]["deltas"]
    for j, name in enumerate(shapes):
        a = names.index(name)
        pair = (result["artist_deltas"][a], D[a])
        vmax = max(float(np.linalg.norm(d, axis=1).max()) * mm for d in pair) or 1.0
        for i, (d, who) in enumerate(zip(pair, ("artist", f"facegeom ({engine})"))):
            _front(axes[i, j], V + d, F, np.linalg.norm(d, axis=1) * mm, vmax, result["view"])
            axes[i, j].set_title(f"{name}\n{who}" if i == 0 else who, fontsize=9)
        axes[1, j].text(0.5, -0.04, f"colour 0-{vmax:.1f} mm", transform=axes[1, j].transAxes, ha="center",
                        fontsize=8)
    fig.tight_layout()
    return fig


def run(model, artist, out=None, engines=("deformation", "nearest"), seed=None, units_scale: float = 1.0,
        name: str = "transfer-artist", echo=print, progress=None) -> dict:
    """Measure, then write ``<name>.csv`` (every shape x piece x engine), the summary and ``<name>.png``: the five
    shapes the first engine gets worst, the artist's above the transfer's."""
    result = compare(model, artist, engines, seed, units_scale, progress)
    summary = summarize(result)
    rep = Report(out, name, echo)
    rows = [{"engine": e, **x} for e, r in result["engines"].items() for x in r["rows"]]
    rep.csv(rows)
    base = summary.get("nearest")
    head = ["engine", "skin: median rel. error", "vs nearest", "cosine", "oracle (best gain)", "90th pct",
            "transfer s"]
    table_rows = []
    for e, s in summary.items():
        ratio = f"{s['skin_median'] / base['skin_median']:.3f}" if base else "-"
        table_rows.append([e, f"{s['skin_median']:.3f}", ratio, f"{s['cosine_median']:.3f}",
                           f"{s['oracle_median']:.3f}", f"{s['skin_p90']:.3f}", f"{s['time_s']:.2f}"])
    first = next(iter(summary))
    worst = format_table(["worst shapes (" + first + ")", "rel. error", "cosine"],
                         [[n, f"{r:.2f}", f"{c:.2f}"] for n, r, c in summary[first]["worst"]])
    piece_rows = [[e, p, f"{v['median']:.2f}", f"{v['cosine']:.2f}", f"{v['oracle']:.2f}", ", ".join(v["shapes"])]
                  for e, s in summary.items() for p, v in s["pieces"].items()]
    pieces = format_table(["engine", "piece", "rel. error", "cosine", "oracle", "shapes scored"], piece_rows) \
        if piece_rows else ""
    reg = result["registration"]
    note = (f"Registration {result['registration_s']:.1f} s (face-area distance median "
            f"{reg['nonrigid']['median_mm']:.2f} mm after the non-rigid step); pieces: "
            + ", ".join(f"{n} {r}" for n, r, _ in result["pieces"])
            + (f"; not transferred (no ICT shape): {', '.join(result['not_transferred'])}"
               if result["not_transferred"] else "")
            + f". Head turned by a random rotation (seed {seed})" * (seed is not None)
            + f"; coordinates x{units_scale:g}" * (units_scale != 1.0) + f". {machine_note()}.")
    rep.summary("\n\n".join(x for x in (format_table(head, table_rows), worst, pieces) if x), note)
    rep.plot(lambda: figure(result, first, [n for n, _, _ in summary[first]["worst"]]))
    return {"summary": summary, "result": result, "files": rep.written}
