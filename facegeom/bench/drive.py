"""The face-driving benchmark (the paper's section 4.3 / Fig. 10, on the real ICT face).

Two protocols, reported one after the other.

**Realistic** (first; :func:`run_realistic`), seeded: random
identities; even cases a random frame of a real ARKit take (dense weights),
odd cases a random sparse expression; every case its own random layout of
40-120 markers (``random<k>`` with a per-case seed); the labels are the true
marker positions plus Gaussian noise of each level (default 0, 0.2 and
0.5 mm per coordinate; the same noise for every method). Every method is
fitted once per case and deforms at every noise level. Error: mean vertex
distance over the face area against the clean true face, in mm. The summary
gives, per noise level, every method's mean error and the ratio of the default
``tangent`` to the best baseline (any method not registered as ``tangent``).

**Paper** (:func:`run`), seeded:

- ``cases`` source/target pairs. Source = a random identity (coefficients
  ~ N(0, 1)), neutral. Target = the same identity with an expression: the
  named expressions of :mod:`facegeom.model.expressions` (six basic emotions, jaw
  open, pucker, blink, three asymmetric combinations), cycled, each at an
  intensity ~ U(0.7, 1.0), alternating with random sparse combinations
  (2-6 shapes, weights ~ U(0.3, 1)).
- Markers: a layout of :mod:`facegeom.model.layouts` (default ``ict80``); their
  target positions are the labels.
- Every method is fitted on the source with the marker ids, then deforms it
  from the labels. Errors against the true target: mean, RMS and max vertex
  distance over the narrow face area (vertices ``[0, 6706)``, where the
  markers are) in mm, the mean over the whole mesh, and the paper's Frobenius
  error ``||Y - Y_true||_F`` over all vertices in mm. Times: ``fit`` and the
  median of 5 ``deform`` calls.

Two studies of the default ``tangent`` deformer, run as
``python -m facegeom.bench.drive study SEED CASES`` (:func:`run_selection_study`:
how its self-tuning chooses, against exact interpolation, REML and an oracle)
and ``python -m facegeom.bench.drive speed [REPEATS]`` (:func:`run_speed`: fit,
deform and ``deform_many`` times against the former default,
``tangent:smoothness=1,align=rigid,beta=None``).
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from facegeom.bench.common import median_time
from facegeom.bench.report import Report, format_table, machine_note
from facegeom.metrics import face_errors_mm
from facegeom.model import layout
from facegeom.model.scenarios import ExpressionCase, RealisticDrivingCase, driving_cases, realistic_driving_cases
from facegeom.registry import MethodSpec


def run(model, specs: list[MethodSpec], cases: list[ExpressionCase], layout_name: str = "ict80", layout_seed: int = 0,
        progress: bool = True, deform_repeat: int = 5) -> list[dict]:
    """Fit and apply every deformer on every driving case; one row of errors and times per pair.

    The markers of layout ``layout_name`` on the case's neutral face (its
    identity, no expression) are moved to their positions on the true
    expression face; each method is fitted on the neutral with those marker ids
    and deforms it.

    Parameters
    ----------
    model : FaceModel
        The ICT face model (positions in cm).
    specs : list of MethodSpec
        The deformers (a fresh instance per case).
    cases : list of ExpressionCase
        Identity and expression of every case
        (:func:`~facegeom.model.scenarios.driving_cases`).
    layout_name : str
        Marker layout: ``ict80``, ``landmarks68`` or ``random<k>``.
    layout_seed : int
        Seed of a ``random<k>`` layout.
    progress : bool
        Show a progress bar (one step per fit).
    deform_repeat : int
        ``deform`` calls timed per pair (the median is reported).

    Returns
    -------
    list of dict
        One row per case and method: ``case``, ``kind``, ``method``, the errors
        of :func:`~facegeom.metrics.face_errors_mm` in mm (``mean_mm``,
        ``rms_mm``, ``max_mm`` over the face area, ``mean_all_mm`` over all
        vertices, ``frobenius_mm``), ``fit_s`` and ``deform_ms`` (median).

    Raises
    ------
    InputError
        An unknown layout name, or inputs a method refuses.
    """
    handles = layout(model, layout_name, layout_seed)
    F = model.triangles
    rows = []
    it = cases
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(cases) * len(specs), desc="bench drive", unit="fit", mininterval=0.5)
    for case in it:
        X = model.identity_neutral(case.identity)
        T = model.face(case.identity, case.expression)
        labels = T[handles]
        for spec in specs:
            method = spec.build("deformers")
            t = time.perf_counter()
            method.fit(X, F, handles)
            fit_s = time.perf_counter() - t
            deform_s, Y = median_time(lambda: method.deform(labels), deform_repeat)
            row = {"case": case.index, "kind": case.kind, "method": spec.label}
            row.update(face_errors_mm(Y, T))
            row.update({"fit_s": fit_s, "deform_ms": deform_s * 1e3})
            rows.append(row)
            if bar:
                bar.update()
    if bar:
        bar.close()
    return rows


def run_realistic(model, specs: list[MethodSpec], cases: list[RealisticDrivingCase], noise_mm=(0.0, 0.2, 0.5),
                  progress: bool = True) -> list[dict]:
    """The realistic protocol: every deformer on every case at every marker-noise level.

    Parameters
    ----------
    model : FaceModel
        The ICT face model (positions in cm).
    specs : list of MethodSpec
        The deformers (a fresh instance per case, fitted once per case).
    cases : list of RealisticDrivingCase
        From :func:`~facegeom.model.scenarios.realistic_driving_cases`.
    noise_mm : sequence of float
        Standard deviations of the marker noise, mm per coordinate.
    progress : bool
        Show a progress bar (one step per fit).

    Returns
    -------
    list of dict
        One row per case, noise level and method: ``case``, ``kind``,
        ``markers``, ``noise_mm``, ``method``, the errors of
        :func:`~facegeom.metrics.face_errors_mm` against the clean truth,
        ``fit_s`` and ``deform_ms`` (one call).
    """
    from facegeom.constants import CM_TO_MM

    F = model.triangles
    rows = []
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(cases) * len(specs), desc="bench drive (realistic)", unit="fit", mininterval=0.5)
    for case in cases:
        handles = layout(model, f"random{case.markers}", case.layout_seed)
        X = model.identity_neutral(case.identity)
        T = model.face(case.identity, case.expression)
        rng = np.random.default_rng(case.noise_seed)
        noisy = [(float(s), T[handles] + rng.normal(0.0, float(s) / CM_TO_MM, (handles.size, 3)))
                 for s in noise_mm]
        for spec in specs:
            method = spec.build("deformers")
            t = time.perf_counter()
            method.fit(X, F, handles)
            fit_s = time.perf_counter() - t
            for level, labels in noisy:
                t = time.perf_counter()
                Y = method.deform(labels)
                deform_ms = (time.perf_counter() - t) * 1e3
                row = {"case": case.index, "kind": case.kind, "markers": case.markers, "noise_mm": level,
                       "method": spec.label}
                row.update(face_errors_mm(Y, T))
                row.update({"fit_s": fit_s, "deform_ms": deform_ms})
                rows.append(row)
            if bar:
                bar.update()
    if bar:
        bar.close()
    return rows


def summarize_realistic(rows: list[dict], specs: list[MethodSpec]) -> tuple[list[str], list[list]]:
    """The realistic protocol's table: mean face error (mm) per method and noise level, and tangent's ratio.

    Parameters
    ----------
    rows : list of dict
        The rows of :func:`run_realistic`.
    specs : list of MethodSpec
        The methods, in table order. Baselines are the specs whose plugin is
        not ``tangent``; the ratio row divides the error of the spec labelled
        ``tangent`` (the default) by the best baseline's at each level.

    Returns
    -------
    header : list of str
        ``method``, one ``noise X mm`` column per level, ``fit (s)``, ``deform (ms)`` (medians).
    table_rows : list of list
        One line per method, then ``tangent / best baseline`` when both exist.
    """
    levels = sorted({r["noise_mm"] for r in rows})
    header = ["method"] + [f"noise {lv:g} mm" for lv in levels] + ["fit (s)", "deform (ms)"]
    mean = {}
    out = []
    for s in specs:
        r = [x for x in rows if x["method"] == s.label]
        line = [s.label]
        for lv in levels:
            mean[s.label, lv] = float(np.mean([x["mean_mm"] for x in r if x["noise_mm"] == lv]))
            line.append(mean[s.label, lv])
        line += [float(np.median([x["fit_s"] for x in r])), float(np.median([x["deform_ms"] for x in r]))]
        out.append(line)
    base = [s.label for s in specs if s.name != "tangent"]
    if base and any(s.label == "tangent" for s in specs):
        ratio = ["tangent / best baseline"]
        for lv in levels:
            best = min(base, key=lambda b: mean[b, lv])
            ratio.append(f"{mean['tangent', lv] / mean[best, lv]:.3f} ({best})")
        out.append(ratio + ["", ""])
    return header, out


def summarize(rows: list[dict], specs: list[MethodSpec]) -> tuple[list[str], list[list]]:
    """Per-method aggregates of the rows of :func:`run`, for :func:`~facegeom.bench.report.format_table`.

    Parameters
    ----------
    rows : list of dict
        The rows of :func:`run`.
    specs : list of MethodSpec
        The methods, in table order (matched by ``label``).

    Returns
    -------
    header : list of str
        The column titles.
    table_rows : list of list
        One line per method: the means over cases of ``mean_mm``, ``max_mm``,
        ``mean_all_mm`` and ``frobenius_mm``, the RMS over cases of ``rms_mm``
        (all mm), and the medians of ``fit_s`` and ``deform_ms``.
    """
    header = ["method", "mean (mm)", "RMS (mm)", "max (mm)", "mean all (mm)", "Frobenius (mm)",
              "fit (s)", "deform (ms)"]
    out = []
    for s in specs:
        r = [x for x in rows if x["method"] == s.label]
        col = lambda k: np.array([x[k] for x in r])  # noqa: E731
        out.append([s.label, col("mean_mm").mean(), np.sqrt((col("rms_mm") ** 2).mean()), col("max_mm").mean(),
                    col("mean_all_mm").mean(), col("frobenius_mm").mean(), float(np.median(col("fit_s"))),
                    float(np.median(col("deform_ms")))])
    return header, out


def plot(rows: list[dict], specs: list[MethodSpec]):
    """The Frobenius error of every method per case (log scale): a matplotlib figure."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 4.5))
    for s in specs:
        r = sorted((x for x in rows if x["method"] == s.label), key=lambda x: x["case"])
        ax.plot([x["case"] for x in r], [x["frobenius_mm"] for x in r], marker="o", ms=3, lw=1, label=s.label)
    ax.set_xlabel("test case")
    ax.set_ylabel("Frobenius error ||Y - Y_true||_F (mm)")
    ax.set_title("Face driving on the ICT face (cf. Zhang et al. 2017, Fig. 10)")
    ax.set_yscale("log")
    ax.legend(fontsize=8, ncol=2)
    fig.tight_layout()
    return fig


def main(model, specs, cases: int, seed: int, layout_name: str, layout_seed: int, out: Path | None,
         progress: bool = True, echo=print, plot_it: bool = True, realistic_cases: int = 0, takes=(),
         noise_mm=(0.0, 0.2, 0.5)) -> tuple[list[dict], str]:
    """Run the face-driving benchmark and write its report: the realistic protocol first, then the paper's.

    Parameters
    ----------
    model : FaceModel
        The ICT face model (positions in cm).
    specs : list of MethodSpec
        The deformers.
    cases : int
        Cases of the paper protocol (:func:`~facegeom.model.scenarios.driving_cases`);
        0 skips it (then ``rows`` and ``table`` are the realistic protocol's).
    seed : int
        Seed of the cases (of both protocols).
    layout_name : str
        Marker layout (``ict80``, ``landmarks68``, ``random<k>``).
    layout_seed : int
        Seed of a ``random<k>`` layout.
    out : Path or None
        Output folder; ``None`` only echoes the summary.
    progress : bool
        Show a progress bar.
    echo : callable(str)
        Receives the table, the note and the list of files written.
    plot_it : bool
        Also write the plot of the Frobenius error per case.
    realistic_cases : int
        Cases of the realistic protocol (:func:`run_realistic`, seed ``seed``);
        0 skips it. Written to ``out/drive-realistic.csv`` and
        ``out/drive-realistic-summary.md``.
    takes : sequence of (str, (T, E) array)
        Real takes as ICT weights for the realistic protocol's dense expressions.
    noise_mm : sequence of float
        Marker-noise levels of the realistic protocol (mm per coordinate).

    Returns
    -------
    rows : list of dict
        The rows of :func:`run`, written to ``out/drive.csv``.
    table : str
        The Markdown table of :func:`summarize`, written with a protocol and
        machine note to ``out/drive-summary.md``; the plot goes to
        ``out/drive.png``.
    """
    rows = table = None
    if realistic_cases > 0:
        rc = realistic_driving_cases(model, realistic_cases, seed, takes)
        rows = run_realistic(model, specs, rc, noise_mm, progress=progress)
        header, table_rows = summarize_realistic(rows, specs)
        table = format_table(header, table_rows)
        kinds = ", ".join(f"{sum(c.kind == k for c in rc)} {k}" for k in dict.fromkeys(c.kind for c in rc))
        note = (f"realistic protocol: {len(rc)} cases ({kinds}), seed {seed}, random layouts of "
                f"{min(c.markers for c in rc)}-{max(c.markers for c in rc)} markers, marker noise "
                f"{', '.join(f'{x:g}' for x in noise_mm)} mm per coordinate; mean face error (mm) against the clean "
                f"truth; {machine_note()}")
        report = Report(out, "drive-realistic", echo)
        report.csv(rows)
        report.summary(table, note)
        report.done()
    if cases <= 0:
        return rows, table
    cs = driving_cases(model, cases, seed)
    rows = run(model, specs, cs, layout_name, layout_seed, progress=progress)
    header, table_rows = summarize(rows, specs)
    table = format_table(header, table_rows)
    note = (f"paper protocol: {len(cs)} cases, seed {seed}, layout {layout_name}"
            + (f" (seed {layout_seed})" if layout_name.startswith("random") else "")
            + f"; {machine_note()}")
    report = Report(out, "drive", echo)
    report.csv(rows)
    report.summary(table, note)
    if plot_it:
        report.plot(lambda: plot(rows, specs), dpi=120)
    report.done()
    return rows, table


def run_selection_study(model, cases: list[RealisticDrivingCase], smoothness=(30.0, 100.0, 1e5),
                        noise_mm=(0.0, 0.2, 0.5), layout_name: str | None = None) -> list[dict]:
    """How well does ``beta="auto"`` choose? Every candidate of the self-tuned tangent deformer, scored.

    For every case, noise level and ``smoothness``, the deformer is fitted
    with ``select="ml"`` (whose candidates hold all of GCV's: the power 1) and
    every candidate (spectral power x relative weight) is applied; the rows
    give the face error of exact interpolation, of the GCV and REML choices,
    of the best candidate chosen with the truth in hand (``oracle``, a bound
    for any selection rule from the markers), ``joint gcv``: GCV over the
    weight and the smoothness values together, ``joint oracle``: the best
    candidate over all smoothness values, and ``joint lomo``: the smoothness
    whose exact interpolant best predicts each marker from the others
    (leave-one-marker-out, closed form ``(K y)_i / K_ii`` with ``K`` the
    labels' energy), then GCV's weight at it. For every smoothness, the
    amplitude prior (:mod:`facegeom.methods.tangent_prior`, ``prior="amplitude"``): its
    GCV choice, the best of its weights chosen with the truth (``oracle
    weight``), and the same with the amplitude taken from the true
    displacements (``amplitude from the truth``: a bound for any amplitude
    estimate from the markers).

    Parameters
    ----------
    model : FaceModel
    cases : list of RealisticDrivingCase
        From :func:`~facegeom.model.scenarios.realistic_driving_cases` (the same
        cases, layouts and noise draws as :func:`run_realistic`).
    smoothness : sequence of float
        Values of the biharmonic weight to score.
    noise_mm : sequence of float
        Marker-noise levels (mm per coordinate).
    layout_name : str, optional
        One marker layout for every case (e.g. ``"ict80"``, which follows the
        face's features) instead of each case's random one.

    Returns
    -------
    list of dict
        One row per case, level and rule: ``case``, ``noise_mm``, ``rule``,
        ``mean_mm`` (the biharmonic baseline is the rule ``biharmonic``).
    """
    from facegeom.constants import CM_TO_MM
    from facegeom.methods.tangent import TangentDeformer, _AutoSmoother, robust_kabsch
    from facegeom.registry import create

    F = model.triangles
    rows = []
    for case in cases:
        handles = (layout(model, layout_name, case.layout_seed) if layout_name
                   else layout(model, f"random{case.markers}", case.layout_seed))
        X = model.identity_neutral(case.identity)
        T = model.face(case.identity, case.expression)
        rng = np.random.default_rng(case.noise_seed)
        noisy = [(float(s), T[handles] + rng.normal(0.0, float(s) / CM_TO_MM, (handles.size, 3))) for s in noise_mm]
        bh = create("deformers", "biharmonic").fit(X, F, handles)
        fitted = []
        for s in smoothness:
            d = TangentDeformer(select="ml", smoothness=float(s)).fit(X, F, handles)
            K = d.solver_.schur_complement()
            fitted.append((s, d, _AutoSmoother(K, "gcv"), K))
        for level, P in noisy:
            rows.append({"case": case.index, "noise_mm": level, "rule": "biharmonic",
                         "mean_mm": face_errors_mm(bh.deform(P), T)["mean_mm"]})
            Rm, t = robust_kabsch(X[handles], P)
            Z = (P - t) @ Rm - X[handles]

            def Ztrue_of(Rm, t):
                return (T[handles] - t) @ Rm - X[handles]  # the true displacements in the same rest frame

            def face_err(d, f, Rm=Rm, t=t):
                return face_errors_mm(((d.smoother_.U.T @ f).T @ d._coef_map).T @ Rm.T + X @ Rm.T + t, T)["mean_mm"]

            joint = []
            for s, d, gcv, K in fitted:
                sm = d.smoother_
                z = sm.U.T @ Z
                zz = np.einsum("md,md->m", z, z)[:, None]
                err = np.array([face_errors_mm(((keep[:, None] * z).T @ d._coef_map).T @ Rm.T + X @ Rm.T + t, T)
                                ["mean_mm"] for keep in sm._keep])
                one = sm.powers == 1.0
                g_gcv = int(gcv._choose(zz)[0])
                g_ml = int(sm._choose(zz)[0])
                S = gcv._lin @ zz
                lomo = float((((K @ Z) / np.diag(K)[:, None]) ** 2).sum())  # leave-one-marker-out, exact interpolant
                joint.append((float(S[g_gcv, 0]), float(err[one][g_gcv]), float(err.min()), lomo))
                for rule, e in (("exact", err[one][0]), ("gcv", err[one][g_gcv]), ("ml", err[g_ml]),
                                ("oracle (power 1)", err[one].min()), ("oracle", err.min())):
                    rows.append({"case": case.index, "noise_mm": level, "rule": f"s={s:g} {rule}", "mean_mm": float(e)})
                # the amplitude prior (prior="amplitude") at every smoothness
                rows.extend({"case": case.index, "noise_mm": level, "rule": f"s={s:g} {rule}", "mean_mm": e}
                            for rule, e in _amplitude_rows(d, Z, gcv, zz, z, Ztrue_of(Rm, t), face_err))
            rows.append({"case": case.index, "noise_mm": level, "rule": "joint gcv", "mean_mm": min(joint)[1]})
            rows.append({"case": case.index, "noise_mm": level, "rule": "joint oracle",
                         "mean_mm": min(j[2] for j in joint)})
            rows.append({"case": case.index, "noise_mm": level, "rule": "joint lomo",
                         "mean_mm": min(joint, key=lambda j: j[3])[1]})
    return rows


def _amplitude_rows(d, Z, gcv, zz, z, Ztrue, face_err):
    """Study rows of the amplitude prior: its GCV choice, an oracle weight, a true amplitude."""
    from facegeom.methods.tangent import AUTO_LAMBDAS
    from facegeom.methods.tangent_prior import AmplitudeSmoother

    amp = AmplitudeSmoother(d.solver_.schur_complement(), d.vertices_[d.handles_], AUTO_LAMBDAS)
    g = int(gcv._choose(zz)[0])
    f0 = d.smoother_.U @ (gcv._keep[g][:, None] * z)  # the uniform prior's GCV smoothing sets the amplitude
    f = amp.smooth(Z, f0, gcv.score[0])[0]  # as the deformer: the lower GCV score of the two priors
    a_est = amp.amplitude(f0[None])[0]
    a_true = amp.amplitude(Ztrue[None])[0]  # the true displacements' lengths (an oracle amplitude)
    e_est = [face_err(d, c) for c in amp.candidates(Z, a_est)]
    e_true = [face_err(d, c) for c in amp.candidates(Z, a_true)]
    f_true = amp.smooth_many(Z[None], Ztrue[None])[0]
    return [("amplitude prior, GCV", face_err(d, f)),
            ("amplitude prior, oracle weight", min(e_est)),
            ("amplitude from the truth, GCV", face_err(d, f_true[0])),
            ("amplitude from the truth, oracle weight", min(e_true))]


def summarize_selection_study(rows: list[dict]) -> tuple[list[str], list[list]]:
    """Mean face error per rule and noise level, and its ratio to biharmonic: a table for ``format_table``."""
    levels = sorted({r["noise_mm"] for r in rows})
    rules = list(dict.fromkeys(r["rule"] for r in rows))
    mean = {(ru, lv): float(np.mean([r["mean_mm"] for r in rows if r["rule"] == ru and r["noise_mm"] == lv]))
            for ru in rules for lv in levels}
    header = ["rule"] + [f"noise {lv:g} mm (x biharmonic)" for lv in levels]
    out = [[ru] + [f"{mean[ru, lv]:.4f} ({mean[ru, lv] / mean['biharmonic', lv]:.3f})" for lv in levels]
           for ru in rules]
    return header, out


def run_speed(model, specs: list[MethodSpec], layouts=("ict80", "random120"), repeats: int = 5, frames: int = 300,
              deforms: int = 20) -> list[list]:
    """Fit, ``deform`` and ``deform_many`` times of deformers on the face, interleaved in one process (medians).

    Per repeat and layout (``random<k>`` with seed 7), every spec is fitted
    once and times ``deforms`` single deforms; then three rounds of one
    ``deform_many`` call of ``frames`` frames (jaw open / smile mixes plus
    0.2 mm noise) per spec, the specs taking turns, all with one BLAS thread
    so that a loaded machine does not stall the products. Because the specs
    take turns (in alternating order), each ``deform_many`` time has a
    neighbour of the first spec measured moments apart: the ratio of the two, medianed over rounds,
    layouts and repeats, is the relative speed, steadier on a shared machine
    than the ratio of the pooled medians (which mixes layouts of different
    marker counts).

    Returns
    -------
    list of list
        One line per spec: label, fit (s), deform (ms), deform_many (ms per
        frame), deform_many relative to the first spec (median paired ratio).
    """
    from threadpoolctl import threadpool_limits

    rng = np.random.default_rng(0)
    faces = np.stack([model.face(None, {"jawOpen": float(a), "mouthSmile_L": float(b)})
                      for a, b in rng.uniform(0.0, 1.0, (frames, 2))])
    res = {s.label: ([], [], [], []) for s in specs}
    with threadpool_limits(1):
        for _ in range(repeats):
            for name in layouts:
                h = layout(model, name, 7)
                P = faces[:, h] + rng.normal(0.0, 0.02, (frames, h.size, 3))
                fitted = []
                for spec in specs:
                    d = spec.build("deformers")
                    t = time.perf_counter()
                    d.fit(model.neutral, model.triangles, h)
                    res[spec.label][0].append(time.perf_counter() - t)
                    for i in range(deforms):
                        t = time.perf_counter()
                        d.deform(P[i])
                        res[spec.label][1].append(time.perf_counter() - t)
                    fitted.append((spec.label, d))
                for r in range(3):
                    times = {}
                    for label, d in (fitted if r % 2 == 0 else fitted[::-1]):  # alternate who goes first
                        t = time.perf_counter()
                        d.deform_many(P)
                        times[label] = (time.perf_counter() - t) / frames
                    for label, dt in times.items():
                        res[label][2].append(dt)
                        res[label][3].append(dt / times[fitted[0][0]])
    return [[k, float(np.median(f)), 1e3 * float(np.median(d)), 1e3 * float(np.median(m)), float(np.median(r))]
            for k, (f, d, m, r) in res.items()]


if __name__ == "__main__":  # python -m facegeom.bench.drive study SEED CASES | speed [REPEATS]: the default's studies
    import sys

    from facegeom.model import load_face_model
    from facegeom.registry import parse_methods

    _model = load_face_model(None)
    if sys.argv[1:2] == ["speed"]:
        _specs = parse_methods("tangent-rigid=tangent:smoothness=1,align=rigid,beta=None;tangent;"
                               "tangent-amplitude=tangent:prior=amplitude", "deformers", [])
        _reps = int(sys.argv[2]) if len(sys.argv) > 2 else 5
        print(format_table(["configuration", "fit (s)", "deform (ms)", "deform_many (ms per frame)",
                            "deform_many (x first)"],
                           run_speed(_model, _specs, repeats=_reps)))
    else:
        from facegeom.io import find_takes, ict_weights, read_take
        from facegeom.model import locate_takes

        _seed, _count = (int(sys.argv[2]), int(sys.argv[3])) if len(sys.argv) > 3 else (0, 20)
        _layout = sys.argv[4] if len(sys.argv) > 4 else None  # e.g. ict80: one layout for every case
        _takes = [(f.stem, ict_weights(read_take(f), _model.expression_names)) for f in find_takes(locate_takes(None))]
        _rows = run_selection_study(_model, realistic_driving_cases(_model, _count, _seed, _takes), layout_name=_layout)
        print(f"selection study: {_count} realistic cases, seed {_seed}, layout {_layout or 'random per case'}")
        print(format_table(*summarize_selection_study(_rows)))
