"""``fit``: blendshape coefficients of landmark files (a chunk at a time when the fitter can), meshes, clouds."""
from __future__ import annotations

import time

import numpy as np

from facegeom.errors import InputError
from facegeom.interfaces import batched_targets, fit_many
from facegeom.pipelines.batch.cache import load_model, stamp
from facegeom.pipelines.batch.job import job_error
from facegeom.pipelines.batch.operations.base import (
    Operation,
    check_method,
    need_data,
    shared_path,
    timed,
)

__all__ = ["FitOperation"]


class FitOperation(Operation):
    """``fit``: coefficients ``(B,)`` per target -> ``.json``/``.csv`` weights; metrics against truth weights."""

    name = "fit"

    def prepare(self, job, spec, files):
        from facegeom.io import TARGET_KINDS
        from facegeom.model import load_rig

        kind = job.shared.get("kind", "auto")
        if kind not in TARGET_KINDS:
            raise job_error(job.source, f"shared.kind {kind!r}: choose one of {', '.join(TARGET_KINDS)}")
        rig = job.shared.get("rig")
        if rig in (None, "ict"):
            spec["data"] = need_data(job, "the default rig (the ICT face)")
            rig = None
        else:
            rig = shared_path(job, "rig", dir_ok=True)
            try:
                load_rig(rig)  # a broken rig is the job's error, found before any task runs
            except InputError as exc:
                raise job_error(job.source, f"shared.rig: {exc}") from None
        cam = [job.shared.get(k) for k in ("focal", "cx", "cy")]
        landmarks = kind == "landmarks" or (kind == "auto" and any(f.suffix.lower() == ".csv" for f in files))
        if landmarks and any(c is None for c in cam):
            raise job_error(job.source, "landmark targets need the camera: set shared.focal, shared.cx and shared.cy "
                                        "(pixels)")
        fitter = check_method(job, "fitters")
        spec["shared"] = {"rig": rig, "kind": kind, "camera": cam,
                          "vectorised": "landmarks" in batched_targets(fitter)}
        spec["stamp"] = stamp([rig] if rig else [spec.get("data")])

    def outputs(self, job, spec, src, stem):
        return [stem.with_name(stem.name + "." + spec["format"])], {}

    def _is_landmarks(self, spec, path: str) -> bool:
        kind = spec["shared"]["kind"]
        return kind == "landmarks" or (kind == "auto" and path.lower().endswith(".csv"))

    def default_chunk(self, job, spec, items):
        lm = spec["shared"]["vectorised"] and all(self._is_landmarks(spec, it["input"]) for it in items)
        return 64 if lm else 1

    def state(self, spec):
        from facegeom import registry
        from facegeom.model import load_rig

        rig = load_rig(spec["shared"]["rig"], lambda: load_model(spec))
        rig.gram()  # the Gram matrix, once per worker
        rig.delta_matrix()
        return {"rig": rig, "fitter": registry.create("fitters", spec["method"], **spec["params"])}

    def compute(self, state, spec, items):
        from facegeom.model import read_fit_target
        from facegeom.pipelines.single import FitOutcome, fit_file

        rig, fitter = state["rig"], state["fitter"]
        cam = spec["shared"]["camera"]
        batch = [it for it in items if spec["shared"]["vectorised"] and self._is_landmarks(spec, it["input"])]
        in_batch = {it["index"] for it in batch}
        single = [it for it in items if it["index"] not in in_batch]
        if batch:
            good, targets = [], []
            for it, res, dt in timed(lambda it: read_fit_target(it["input"], rig, "landmarks", *cam), batch):
                if isinstance(res, BaseException):
                    yield it, res, dt
                else:
                    good.append((it, dt))
                    targets.append(res[1])
            if targets:
                t0 = time.perf_counter()
                try:
                    res = fit_many(fitter, rig, targets)
                except Exception:  # noqa: BLE001 - one target broke the batch: fit them one by one to find it
                    single = [it for it, _ in good] + single
                else:
                    share = (time.perf_counter() - t0) / len(targets)
                    for k, (it, dt) in enumerate(good):
                        yield it, FitOutcome("landmarks", res[k].weights, res[k].info["camera"]), dt + share

        yield from timed(lambda it: fit_file(rig, it["input"], lambda: fitter, spec["shared"]["kind"], *cam), single)

    def write(self, state, spec, item, result):
        from facegeom.pipelines.single import write_fit

        write_fit(item["outputs"][0], state["rig"].names, result, spec["method"], item["input"])
        return {"active": int(result.active.size)}

    def evaluate(self, state, spec, item, result, truth):
        return self.evaluate_many(state, spec, [(item, result)])[0]

    def evaluate_many(self, state, spec, pairs):
        """Coefficient and vertex errors; the faces of all pairs from one product ``D (W - W_true)``."""
        from facegeom.io import read_weights

        rig = state["rig"]
        out, dW, slots = [], [], []
        for it, res in pairs:
            try:
                wt = read_weights(it["truth"], rig.names)
            except Exception as exc:  # noqa: BLE001
                out.append(exc)
                continue
            dW.append(np.asarray(res.weights, dtype=np.float64) - wt)
            slots.append(len(out))
            out.append(None)
        if dW:
            dW = np.stack(dW)  # (K, B)
            E = rig.delta_matrix() @ dW.T  # (3n, K): the face difference of each pair, one GEMM
            d = np.sqrt((E.reshape(rig.n_vertices, 3, -1) ** 2).sum(axis=1))  # (n, K) per-vertex distances
            for j, slot in enumerate(slots):
                out[slot] = {"coef_mae": float(np.abs(dW[j]).mean()), "coef_max": float(np.abs(dW[j]).max()),
                             "err_mean": float(d[:, j].mean()), "err_max": float(d[:, j].max())}
        return out
