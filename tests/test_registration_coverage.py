"""The registered ICT face area lies on the head: its 95th percentile distance, not only its median.

Before the final untrimmed rounds of the non-rigid step (``NONRIGID_FINAL_LENGTHS_CM``) the trimming of
pairs as outliers (median + 3 MADs, a threshold that shrinks with the median: 0.8-1.4 mm in the last
round) dropped every template vertex not yet on the head, so the nostrils and the chin's underside were
never pulled there: face-area distance 95th percentile 2.35 mm (Lee Perry-Smith) and 2.81 mm (MakeHuman
head); 1.66 / 3.61 mm outside the lips and lids. Now 1.73 / 1.09 mm, and 0.32 / 0.55 mm outside the lips and
lids, which keep the trimming (their untrimmed pairs reached 0.69 mm everywhere but left the blink and the
lower lip's roll of the scan folded beyond what the fold correction may change).

One registration per head (module-scoped), as ``facegeom transfer`` does it (the skin of a rig's pieces).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

HEADS = Path(__file__).parent / "data" / "heads"
P95_MM = 1.0  # outside the lips and lids: before 1.66 mm (Lee Perry-Smith), 3.61 mm (MakeHuman); now 0.32 / 0.55
P95_ALL_MM = 2.0  # the whole face area: before 2.35 / 2.81 mm; now 1.73 / 1.09


@pytest.fixture(scope="module", params=["lee_perry_smith.ply", "makehuman_arkit.npz"])
def registered(request, face_model):
    from facegeom.methods.transfer import register_character
    from facegeom.pipelines.character import read_head

    V, F, parts = read_head(HEADS / request.param)
    return request.param, register_character(face_model, V, F, parts=parts).registration


def test_the_face_area_lies_on_the_head(registered, face_model):
    from facegeom.constants import FACE_AREA
    from facegeom.methods.transfer import _distances, _opening_bands

    name, reg = registered
    rep = reg.report["nonrigid"]
    assert rep["p95_mm"] <= P95_ALL_MM, (name, rep)
    assert rep["median_mm"] <= 0.1, (name, rep)
    assert rep["covered"] >= 0.998, (name, rep)  # before: 0.992 / 0.977
    # the report measures the template handed on (head units), not an intermediate one
    d, _, _ = _distances(reg.template[:FACE_AREA], reg.head_vertices, reg.head_faces)
    d = d * reg.mm_per_unit
    assert np.percentile(d, 95) == pytest.approx(rep["p95_mm"], rel=1e-6)
    openings = _opening_bands(face_model)[:, :FACE_AREA].any(axis=0)
    assert np.percentile(d[~openings], 95) <= P95_MM, name
