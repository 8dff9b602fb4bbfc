"""The retargeting benchmark (the paper's section 4.1-4.2, Figs. 6-8, on real performances).

Protocol (seeded):

- ``sequences`` actor/character pairs of ``frames`` frames (default 50 x 100)
  built by :mod:`facegeom.model.performance`. Four in five are windows of the real
  ARKit takes (the takes cycled, start frame uniform in each take); every fifth
  is a synthetic onset-apex-offset take. Sequence ``i`` has its own actor
  identity and its own character (identity, per-expression intensities, warp).
- Markers: the ``ict80`` layout (or ``--layout``).
- Labels: ``L`` frames evenly spread (``round(linspace(0, T-1, L))``).
- Errors against the character's true markers: the paper's Frobenius norm
  over the whole sequence (mm), the mean marker error (mm), and the mean
  marker error relative to the character's mean marker motion (distance from
  its rest markers), in percent.

Outputs: ``retarget.csv`` (sequence x labels x method), ``retarget-frames.csv``
(per-frame error at the reference label count), ``retarget-summary.md`` and
``retarget.png`` (Figs. 6, 7, 8 side by side).
"""
from __future__ import annotations

import time

import numpy as np

from facegeom.bench.common import progress_bar
from facegeom.bench.report import Report, format_table, machine_note
from facegeom.constants import CM_TO_MM
from facegeom.errors import SolveError
from facegeom.methods.tangent_retarget import evenly_spread
from facegeom.model import layout
from facegeom.model import performance as sq
from facegeom.registry import MethodSpec

LABEL_COUNTS = (2, 3, 4, 6, 8, 10, 15, 20, 25, 30)
REFERENCE_LABELS = 10



def build_sequences(model, takes, count: int = 50, frames: int = 100, seed: int = 0, layout_name: str = "ict80",
                    layout_seed: int = 0) -> list[sq.Sequence]:
    """``count`` actor/character sequences: 4 in 5 real-take windows, every 5th synthetic.

    ``takes`` is a list of ``(name, W (T, E))`` with ICT-ordered weights; takes shorter
    than ``frames`` are skipped. With no usable take every sequence is synthetic.
    """
    ids = layout(model, layout_name, layout_seed)
    rng = np.random.default_rng([int(seed), 31337])
    usable = [(n, W) for n, W in takes if W.shape[0] >= frames]
    out, k = [], 0
    for i in range(count):
        if usable and i % 5 != 4:
            name, W = usable[k % len(usable)]
            k += 1
            start = int(rng.integers(0, W.shape[0] - frames + 1))
            weights, label = W[start:start + frames], f"{name}@{start}"
        else:
            weights, label = sq.synthetic_weights(model, rng, frames)
            label = f"synthetic:{label}"
        actor_seed = int(seed) * 100_003 + i
        out.append(sq.make_sequence(model, weights, ids, actor_seed, sq.make_character(model, actor_seed), label))
    return out


def _nanmean(values) -> float:
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    return float(v.mean()) if v.size else float("nan")



def run(model, seqs, specs: list[MethodSpec], label_counts=LABEL_COUNTS, echo=print, progress=True):
    """Retarget every sequence with every method, for every number of labelled frames.

    Parameters
    ----------
    model : FaceModel
        Not used.
    seqs : list of Sequence
        Actor/character sequences, markers ``(T, p, 3)`` float64 in cm.
    specs : list of MethodSpec
        The retargeters.
    label_counts : sequence of int
        Numbers of known character frames, evenly spread.
    echo : callable(str)
        Not used.
    progress : bool
        Show a progress bar.

    Returns
    -------
    rows : list of dict
        One row per sequence, label count and method: ``sequence``, ``name``,
        ``labels`` (distinct labelled frames), ``method``, ``frobenius_mm``
        (over the whole sequence), ``mean_mm`` (mean marker error),
        ``relative_pct`` (``mean_mm`` in percent of the character's mean marker
        motion), ``motion_mm`` and ``time_ms``; errors are NaN when the method
        raised :class:`~facegeom.errors.SolveError`.
    frame_rows : list of dict
        At the reference count only: ``sequence``, ``method``, ``frame`` and
        the frame's ``frobenius_mm``.
    ref : int
        The reference count: 10 when in ``label_counts``, else its middle entry.
    """
    rows, frame_rows = [], []
    ref = REFERENCE_LABELS if REFERENCE_LABELS in label_counts else label_counts[len(label_counts) // 2]
    it = progress_bar(list(enumerate(seqs)), "retarget", progress, unit="seq")
    for si, s in it:
        motion = s.mean_motion()
        for L in label_counts:
            lab = evenly_spread(s.n_frames, L)
            for spec in specs:
                method = spec.build("retargeters")
                t = time.perf_counter()
                try:
                    Y = method.fit(s.source, lab, s.target[lab]).transform()
                except SolveError:  # recorded as a failure (NaN), counted in the summary
                    Y = np.full_like(s.target, np.nan)
                dt = time.perf_counter() - t
                E = np.linalg.norm(Y - s.target, axis=2)  # (T, p) cm
                rows.append({
                    "sequence": si, "name": s.name, "labels": int(lab.size), "method": spec.label,
                    "frobenius_mm": float(np.linalg.norm(Y - s.target) * CM_TO_MM),
                    "mean_mm": float(E.mean() * CM_TO_MM),
                    "relative_pct": float(100.0 * E.mean() / motion) if motion > 0 else float("nan"),
                    "motion_mm": motion * CM_TO_MM, "time_ms": dt * 1e3,
                })
                if L == ref:
                    per_frame = np.linalg.norm(Y - s.target, axis=(1, 2)) * CM_TO_MM
                    frame_rows.extend({"sequence": si, "method": spec.label, "frame": t_, "frobenius_mm": float(e)}
                                      for t_, e in enumerate(per_frame))
    return rows, frame_rows, ref


REALISTIC_LABELS = (5, 10, 20)
REALISTIC_NOISE_MM = 0.2


def run_realistic(seqs, specs: list[MethodSpec], label_counts=REALISTIC_LABELS, noise_mm: float = REALISTIC_NOISE_MM,
                  seed: int = 0, progress=True) -> list[dict]:
    """The realistic retargeting protocol: unevenly labelled frames, clean and with capture and label noise.

    For every sequence and label count ``L`` the labelled frames are ``L``
    distinct frames drawn at random (sorted; not evenly spread). Every method
    runs twice on them: clean, and with Gaussian noise of ``noise_mm`` (mm per
    coordinate) on every frame of the actor's capture and on the labelled
    character frames. The error is against the clean true character markers.

    Parameters
    ----------
    seqs : list of Sequence
        Actor/character sequences (:func:`build_sequences`).
    specs : list of MethodSpec
        The retargeters.
    label_counts : sequence of int
        Numbers of labelled frames.
    noise_mm : float
        Noise standard deviation, mm per coordinate.
    seed : int
        Seed of the labelled frames and the noise (one stream per sequence and count).
    progress : bool
        Show a progress bar.

    Returns
    -------
    list of dict
        One row per sequence, count, noise level (0 or ``noise_mm``) and method:
        ``sequence``, ``name``, ``labels``, ``noise_mm``, ``method``, ``mean_mm``
        (mean marker error, NaN when the method raised
        :class:`~facegeom.errors.SolveError`) and ``time_ms``.
    """
    rows = []
    it = progress_bar(list(enumerate(seqs)), "retarget (realistic)", progress, unit="seq")
    for si, s in it:
        for L in label_counts:
            lab, src_noise, lab_noise = _realistic_draw(s, si, L, noise_mm, seed)
            for level, X, Yh in ((0.0, s.source, s.target[lab]),
                                 (float(noise_mm), s.source + src_noise, s.target[lab] + lab_noise)):
                for spec in specs:
                    mean_mm, time_ms = _score(spec, s, X, lab, Yh)
                    rows.append({"sequence": si, "name": s.name, "labels": int(lab.size), "noise_mm": level,
                                 "method": spec.label, "mean_mm": mean_mm, "time_ms": time_ms})
    return rows


def _realistic_draw(s, si: int, labels: int, noise_mm: float, seed: int):
    """The realistic protocol's random labelled frames and noise of sequence ``si``.

    One random stream per seed, sequence and label count: every method and noise source sees the same draw.
    """
    rng = np.random.default_rng([int(seed), si, int(labels), 1919])
    lab = np.sort(rng.choice(s.n_frames, size=min(int(labels), s.n_frames), replace=False))
    src_noise = rng.normal(size=s.source.shape) * noise_mm / CM_TO_MM
    lab_noise = rng.normal(size=s.target[lab].shape) * noise_mm / CM_TO_MM
    return lab, src_noise, lab_noise


def _score(spec: MethodSpec, s, X, lab, Yh) -> tuple[float, float]:
    """Retarget ``X`` with labels ``Yh`` at ``lab``: mean marker error against ``s.target`` (mm; NaN on
    :class:`~facegeom.errors.SolveError`) and the time (ms)."""
    t = time.perf_counter()
    try:
        Y = spec.build("retargeters").fit(X, lab, Yh).transform()
    except SolveError:
        Y = np.full_like(s.target, np.nan)
    time_ms = (time.perf_counter() - t) * 1e3
    return float(np.linalg.norm(Y - s.target, axis=2).mean() * CM_TO_MM), time_ms


NOISE_SOURCES = ("none", "capture", "labels", "both")


def run_noise_sources(seqs, specs: list[MethodSpec], labels: int = REFERENCE_LABELS,
                      noise_mm: float = REALISTIC_NOISE_MM, seed: int = 0, progress=False) -> list[dict]:
    """Where the noisy error comes from: the realistic protocol with the noise on the capture only, the labels only.

    The labelled frames and the noise are drawn exactly as in
    :func:`run_realistic` (same seed, same stream per sequence and count), so
    its ``"none"`` and ``"both"`` rows equal that protocol's clean and noisy
    rows; ``"capture"`` adds the noise to the actor's capture alone (clean
    labels), ``"labels"`` to the labelled character frames alone (clean capture).

    Parameters
    ----------
    seqs : list of Sequence
        Actor/character sequences (:func:`build_sequences`).
    specs : list of MethodSpec
        The retargeters.
    labels : int
        Number of labelled frames.
    noise_mm : float
        Noise standard deviation, mm per coordinate.
    seed : int
        Seed of the labelled frames and the noise.
    progress : bool
        Show a progress bar.

    Returns
    -------
    list of dict
        One row per sequence, noise source (:data:`NOISE_SOURCES`) and method:
        ``sequence``, ``noisy``, ``method``, ``mean_mm`` (NaN when the method
        raised :class:`~facegeom.errors.SolveError`) and ``time_ms``.
    """
    rows = []
    it = progress_bar(list(enumerate(seqs)), "retarget (noise sources)", progress, unit="seq")
    for si, s in it:
        lab, src_noise, lab_noise = _realistic_draw(s, si, labels, noise_mm, seed)  # the stream of run_realistic
        for noisy in NOISE_SOURCES:
            X = s.source + src_noise if noisy in ("capture", "both") else s.source
            Yh = s.target[lab] + lab_noise if noisy in ("labels", "both") else s.target[lab]
            for spec in specs:
                mean_mm, time_ms = _score(spec, s, X, lab, Yh)
                rows.append({"sequence": si, "noisy": noisy, "method": spec.label, "mean_mm": mean_mm,
                             "time_ms": time_ms})
    return rows


def summarize_noise_sources(rows, specs) -> str:
    """Mean marker error (mm) per method and noise source of :func:`run_noise_sources`, as a Markdown table."""
    header = ["method"] + [f"noise on {n}" for n in NOISE_SOURCES]
    table = [[spec.label] + [_nanmean([r["mean_mm"] for r in rows if r["method"] == spec.label and r["noisy"] == n])
                             for n in NOISE_SOURCES] for spec in specs]
    return format_table(header, table)


MAP_STUDY_RIDGES = (1e-4, 1e-3, 1e-2, 3e-2, 0.1, 0.3, 1.0, 3.0, 10.0, 1e6)
"""Ridges of :func:`run_map_study`: the default's grid and a face-wide map only (``1e6``)."""


def run_map_study(seqs, labels: int = REFERENCE_LABELS, noise_mm: float = REALISTIC_NOISE_MM, seed: int = 0,
                  sources=("labels", "both"), progress=False) -> list[dict]:
    """Which part of the default retargeter keeps the label noise, and what a per-marker affine map can reach.

    On the realistic protocol's draw (:func:`run_realistic`, same stream), for
    each noise source (:data:`NOISE_SOURCES`) the default tangent retargeter is
    fitted, and on the actor's markers as it chose to smooth them the
    per-marker affine map (:func:`~facegeom.methods.tangent_retarget.marker_affine_fit`)
    is scored with: its leave-one-label-out ridge (the default), every fixed
    ridge of :data:`MAP_STUDY_RIDGES` (the best one for all sequences, and the
    best one per marker chosen with the truth: an oracle bound for any ridge
    rule), the face-wide map alone, the labels' noise mean subtracted (the
    offset noise no per-marker method can average away, removed by an
    oracle) and the clean labels.

    Returns
    -------
    list of dict
        One row per sequence, noise source and rule: ``sequence``, ``noisy``,
        ``rule``, ``mean_mm`` (mean marker error against the clean truth).
    """
    from facegeom.methods.tangent_retarget import TangentRetargeter, marker_affine_fit

    rows = []
    it = progress_bar(list(enumerate(seqs)), "retarget (map study)", progress, unit="seq")
    for si, s in it:
        lab, src_noise, lab_noise = _realistic_draw(s, si, labels, noise_mm, seed)  # the stream of run_realistic
        for noisy in sources:
            X = s.source + src_noise if noisy in ("capture", "both") else s.source
            Yh = s.target[lab] + lab_noise if noisy in ("labels", "both") else s.target[lab]

            def err(Y):
                return np.linalg.norm(Y - s.target, axis=2).mean(axis=0) * CM_TO_MM  # per marker

            r = TangentRetargeter().fit(X, lab, Yh)
            S, _, (base, _) = r._choose_smoothing(X, lab, Yh)  # the actor's markers as the default smoothed them
            aff = marker_affine_fit(S, lab, Yh, "auto")
            fixed = np.stack([err(marker_affine_fit(S, lab, Yh, g)) for g in MAP_STUDY_RIDGES])  # (G, p)
            found = {"default retargeter": err(r.result_), "its base map (affine + kernel)": err(base),
                     "affine map, auto ridge": err(aff),
                     **{f"affine map, ridge {g:g}": e for g, e in zip(MAP_STUDY_RIDGES, fixed)},
                     "affine map, ridge per marker from the truth": fixed.min(axis=0),
                     "affine map, clean labels": err(marker_affine_fit(S, lab, s.target[lab], "auto"))}
            if noisy in ("labels", "both"):
                found["affine map, labels' noise mean removed"] = err(aff - lab_noise.mean(axis=0)[None])
            rows.extend({"sequence": si, "noisy": noisy, "rule": k, "mean_mm": float(v.mean())}
                        for k, v in found.items())
    return rows


def summarize_map_study(rows) -> str:
    """Mean marker error (mm) per rule and noise source of :func:`run_map_study`, as a Markdown table."""
    sources = list(dict.fromkeys(r["noisy"] for r in rows))
    rules = list(dict.fromkeys(r["rule"] for r in rows))
    table = [[ru] + [_nanmean([r["mean_mm"] for r in rows if r["rule"] == ru and r["noisy"] == n]) for n in sources]
             for ru in rules]
    return format_table(["rule"] + [f"noise on {n}" for n in sources], table)


def summarize_realistic(rows, specs) -> str:
    """The realistic protocol's table: mean marker error (mm) per method, label count and noise level.

    The last line divides the default ``tangent``'s error by the best
    baseline's (specs whose plugin is not ``tangent``) in every column.

    Parameters
    ----------
    rows : list of dict
        The rows of :func:`run_realistic`.
    specs : list of MethodSpec
        The methods, in table order.

    Returns
    -------
    str
        A Markdown table.
    """
    cols = sorted({(r["labels"], r["noise_mm"]) for r in rows}, key=lambda c: (c[1], c[0]))
    header = ["method"] + [f"{L} labels, noise {nz:g} mm" for L, nz in cols]
    mean = {(spec.label, c): _nanmean([r["mean_mm"] for r in rows if r["method"] == spec.label
                                       and (r["labels"], r["noise_mm"]) == c]) for spec in specs for c in cols}
    table = [[spec.label] + [mean[spec.label, c] for c in cols] for spec in specs]
    base = [spec.label for spec in specs if spec.name != "tangent"]
    if base and any(spec.label == "tangent" for spec in specs):
        line = ["tangent / best baseline"]
        for c in cols:
            best = min(base, key=lambda b: mean[b, c] if np.isfinite(mean[b, c]) else np.inf)
            line.append(f"{mean['tangent', c] / mean[best, c]:.3f} ({best})")
        table.append(line)
    return format_table(header, table)


def summarize(rows, specs, counts=(REFERENCE_LABELS, 20)):
    """Means over sequences (failed solves excluded and counted in ``failed``, over all label counts)."""
    header = ["method"]
    for L in counts:
        header += [f"Frob. L={L} (mm)", f"mean L={L} (mm)", f"% of motion L={L}"]
    header += ["failed", "time (ms)"]
    table = []
    for spec in specs:
        line = [spec.label]
        for L in counts:
            r = [x for x in rows if x["method"] == spec.label and x["labels"] == L]
            if not r:
                line += ["-", "-", "-"]
                continue
            line += [_nanmean([x["frobenius_mm"] for x in r]), _nanmean([x["mean_mm"] for x in r]),
                     _nanmean([x["relative_pct"] for x in r])]
        line.append(sum(int(np.isnan(x["mean_mm"])) for x in rows if x["method"] == spec.label))
        line.append(np.median([x["time_ms"] for x in rows if x["method"] == spec.label]))
        table.append(line)
    return format_table(header, table)


def plot(rows, frame_rows, specs, ref):
    """Figs. 6, 7 and 8 side by side (error vs labels, per sequence, per frame): a matplotlib figure."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 3, figsize=(17, 4.6))
    counts = sorted({r["labels"] for r in rows})
    for spec in specs:
        m = [_nanmean([r["frobenius_mm"] for r in rows if r["method"] == spec.label and r["labels"] == L])
             for L in counts]
        ax[0].plot(counts, m, "o-", label=spec.label)
        per = [r["frobenius_mm"] for r in rows if r["method"] == spec.label and r["labels"] == ref]
        ax[1].plot(range(len(per)), per, ".-", label=spec.label)
        fr = np.array([[r["frame"], r["frobenius_mm"]] for r in frame_rows if r["method"] == spec.label])
        T = int(fr[:, 0].max()) + 1
        ax[2].plot(range(T), np.bincount(fr[:, 0].astype(int), fr[:, 1], T) / np.bincount(fr[:, 0].astype(int), None, T),
                   label=spec.label)
    ax[0].set(xlabel="labelled frames", ylabel="mean Frobenius error (mm)", yscale="log",
              title="Fig. 6: error vs number of labels")
    ax[1].set(xlabel="sequence", ylabel="Frobenius error (mm)", yscale="log", title=f"Fig. 7: per sequence, {ref} labels")
    ax[2].set(xlabel="frame", ylabel="mean Frobenius error of the frame (mm)",
              title=f"Fig. 8: per frame, {ref} labels")
    ax[0].legend(fontsize=8)
    fig.tight_layout()
    return fig


def main(model, takes, specs, count, seed, out, layout_name="ict80", layout_seed=0, frames=100,
         label_counts=LABEL_COUNTS, echo=print, plot_it=True, progress=True, realistic=True):
    """Run the retargeting benchmark and write its report (the realistic protocol first, when asked).

    Parameters
    ----------
    model : FaceModel
        The ICT face model (positions in cm).
    takes : list of (str, ndarray)
        Named takes of ICT-ordered weights ``(T, E)``.
    specs : list of MethodSpec
        The retargeters.
    count : int
        Number of sequences (every fifth synthetic).
    seed : int
        Seed of the windows, actors and characters.
    out : path-like or None
        Output folder; ``None`` only echoes the summary.
    layout_name : str
        Marker layout.
    layout_seed : int
        Seed of a ``random<k>`` layout.
    frames : int
        Frames per sequence.
    label_counts : sequence of int
        Numbers of labelled frames to run.
    echo : callable(str)
        Receives the protocol line, the table and the list of files written.
    plot_it : bool
        Also write the plot (Figs. 6-8).
    progress : bool
        Show a progress bar.
    realistic : bool
        First run :func:`run_realistic` on the same sequences (5, 10 and 20
        unevenly placed labels, clean and with 0.2 mm noise on capture and
        labels), written to ``out/retarget-realistic.csv`` and
        ``out/retarget-realistic-summary.md``.

    Returns
    -------
    rows : list of dict
        The rows of :func:`run`, written to ``out/retarget.csv`` (the per-frame
        rows go to ``out/retarget-frames.csv``).
    table : str
        The summary at the reference label count and at 20 labels (when run),
        written to ``out/retarget-summary.md``; the plot goes to
        ``out/retarget.png``.
    """
    seqs = build_sequences(model, takes, count, frames, seed, layout_name, layout_seed)
    n_real = sum(not s.name.startswith("synthetic") for s in seqs)
    echo(f"{len(seqs)} sequences of {frames} frames ({n_real} from real takes, {len(seqs) - n_real} synthetic), "
         f"{seqs[0].source.shape[1]} markers ({layout_name}); character mean marker motion "
         f"{np.mean([s.mean_motion() for s in seqs]) * CM_TO_MM:.2f} mm")
    if realistic:
        rrows = run_realistic(seqs, specs, REALISTIC_LABELS, REALISTIC_NOISE_MM, seed, progress)
        rep = Report(out, "retarget-realistic", echo)
        rep.csv(rrows)
        rep.summary(summarize_realistic(rrows, specs),
                    f"realistic protocol: {len(seqs)} sequences, seed {seed}, layout {layout_name}, "
                    f"{'/'.join(map(str, REALISTIC_LABELS))} labelled frames at random (uneven) places, clean and "
                    f"with {REALISTIC_NOISE_MM:g} mm noise (per coordinate) on the actor's capture and on the labels; "
                    f"mean marker error (mm) against the clean truth; {machine_note()}")
        rep.done()
    rows, frame_rows, ref = run(model, seqs, specs, label_counts, echo, progress)
    report = Report(out, "retarget", echo)
    report.csv(rows)
    report.csv(frame_rows, "frames")
    counts = tuple(c for c in (ref, 20) if c in label_counts) or (ref,)
    table = summarize(rows, specs, counts)
    note = f"{len(seqs)} sequences, seed {seed}, layout {layout_name}; {machine_note()}"
    report.summary(table, note)
    if plot_it:
        report.plot(lambda: plot(rows, frame_rows, specs, ref))
    report.done()
    return rows, table


if __name__ == "__main__":  # python -m facegeom.bench.retarget study SEED [SEQUENCES]: the map study
    import sys

    from facegeom.io import find_takes, ict_weights, read_take
    from facegeom.model import load_face_model, locate_takes

    if sys.argv[1:2] != ["study"]:
        sys.exit("usage: python -m facegeom.bench.retarget study SEED [SEQUENCES]")
    _seed = int(sys.argv[2]) if len(sys.argv) > 2 else 0
    _count = int(sys.argv[3]) if len(sys.argv) > 3 else 20
    _model = load_face_model(None)
    _takes = [(f.stem, ict_weights(read_take(f), _model.expression_names)) for f in find_takes(locate_takes(None))]
    _seqs = build_sequences(_model, _takes, count=_count, frames=100, seed=_seed)
    print(f"map study: {_count} sequences of 100 frames, {REFERENCE_LABELS} random labels, "
          f"{REALISTIC_NOISE_MM} mm noise, seed {_seed}")
    print(summarize_map_study(run_map_study(_seqs, seed=_seed)))
