"""``facegeom.bench.fit_realistic.pooled_reduction``: the one-photo target's per-seed and pooled change (issue 18)."""
from __future__ import annotations

import numpy as np
import pytest

from facegeom.bench.fit_realistic import JOINT, pooled_reduction
from facegeom.errors import FacegeomError


def _rows(generic, joint, other=None):
    rows = [{"case": i, "identity": "generic", "method": "sem-ls", "vertex_mm": g} for i, g in enumerate(generic)]
    rows += [{"case": i, "identity": "fitted", "method": JOINT, "vertex_mm": j} for i, j in enumerate(joint)]
    if other is not None:  # a second generic method: only the first one is the reference
        rows += [{"case": i, "identity": "generic", "method": "l1reg", "vertex_mm": o} for i, o in enumerate(other)]
    return rows


def test_per_run_and_pooled_ratios_of_means():
    a = _rows([4.0, 6.0], [2.0, 4.0], other=[100.0, 100.0])  # 6 / 10 -> -40 %
    b = _rows([5.0, 5.0, 5.0], [4.0, 4.0, 4.0])  # -20 %
    res = pooled_reduction([a, b], resamples=500)
    assert [r[0] for r in res["runs"]] == [2, 3]
    assert res["runs"][0][3] == pytest.approx(-0.4)
    assert res["runs"][1][3] == pytest.approx(-0.2)
    n, change, low, high = res["pooled"]
    assert n == 5
    assert change == pytest.approx(18.0 / 25.0 - 1.0)  # pooled over cases, not the mean of the runs' changes
    assert low <= change <= high


def test_interval_shrinks_with_more_cases():
    rng = np.random.default_rng(1)
    g = rng.uniform(3, 6, 400)
    j = g * rng.uniform(0.5, 0.9, 400)
    wide = pooled_reduction([_rows(g[:20], j[:20])], resamples=1000)["pooled"]
    narrow = pooled_reduction([_rows(g, j)], resamples=1000)["pooled"]
    assert narrow[3] - narrow[2] < wide[3] - wide[2]


def test_runs_without_the_rows_are_refused():
    with pytest.raises(FacegeomError, match="generic"):
        pooled_reduction([[{"case": 0, "identity": "fitted", "method": JOINT, "vertex_mm": 1.0}]])
    with pytest.raises(FacegeomError, match="identity \\(joint\\)"):
        pooled_reduction([_rows([1.0], [])])
