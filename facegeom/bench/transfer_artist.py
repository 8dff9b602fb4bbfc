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

__all__ = ["compare", "summarize", "run", "MOVES_MM"]

MOVES_MM = 0.5  # a piece moved by less than this (max over its vertices) in a shape is not scored on it


def _pose(seed, units_scale):
    if seed is None:
        return np.eye(3), np.zeros(3), units_scale
    rng = np.random.default_rng(seed)
    return Rotation.random(random_state=rng).as_matrix(), rng.normal(0.0, 30.0, 3), units_scale


def compare(model, artist, engines=("deformation", "nearest"), seed=None, units_scale: float = 1.0,
            progress=None) -> dict:
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
    """
    from facegeom.io.shape_names import ShapeMap
    from facegeom.methods.transfer import register_character, transfer_character

    say = progress or (lambda line: None)
    R, t, k = _pose(seed, units_scale)
    V = (np.asarray(artist.neutral, dtype=np.float64) @ R.T) * k + t
    A = (np.asarray(artist.deltas, dtype=np.float64) @ R.T) * k  # the artist's shapes in the same frame
    t0 = time.perf_counter()
    ch = register_character(model, V, artist.triangles, parts=artist.parts, progress=say)
    t_reg = time.perf_counter() - t0
    smap = ShapeMap.between(model.expression_names, artist.names)
    W = smap.apply(np.eye(len(artist.names)))  # (A shapes, ICT shapes): the ICT weights of each artist shape
    mm = ch.registration.mm_per_unit
    regions = [(p.name, p.vertices, p.role) for p in ch.pieces]
    out = {"registration": ch.registration.report, "registration_s": t_reg, "engines": {},
           "pieces": [(p.name, p.role, p.how) for p in ch.pieces], "names": list(artist.names),
           "not_transferred": [n for n, w in zip(artist.names, W) if not np.any(w)], "mm_per_unit": mm}
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
        out["engines"][engine] = {"rows": rows, "time_s": res.time_s}
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


def run(model, artist, out=None, engines=("deformation", "nearest"), seed=None, units_scale: float = 1.0,
        name: str = "transfer-artist", echo=print, progress=None) -> dict:
    """Measure, then write ``<name>.csv`` (every shape x piece x engine), the summary and the figure of the worst."""
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
    return {"summary": summary, "result": result, "files": rep.written}
