"""The fit job's identity step: one identity per subject folder, then every input's expression on that rig."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from facegeom.errors import InputError
from facegeom.io import read_weights, write_mesh, write_weights
from facegeom.model import BlendshapeRig, load_rig
from facegeom.pipelines import batch as fb


@pytest.fixture(scope="module")
def subjects(tmp_path_factory, face_model):
    """Two people (random identities), three noisy scans each (0.5 mm), sparse expressions; truth weights."""
    root = tmp_path_factory.mktemp("subjects")
    rng = np.random.default_rng(12)
    people = {}
    for name in ("anna", "ben"):
        a = face_model.random_identity(rng)
        rig = BlendshapeRig.from_face_model(face_model, a)
        (root / "scans" / name).mkdir(parents=True)
        (root / "truth" / name).mkdir(parents=True)
        for k in range(3):
            w = np.zeros(rig.n_shapes)
            w[rng.choice(rig.n_shapes, 3, replace=False)] = rng.uniform(0.3, 0.9, 3)
            V = rig.evaluate(w) + rng.normal(size=(rig.n_vertices, 3)) * 0.05
            write_mesh(root / "scans" / name / f"s{k}.obj", V, face_model.triangles)
            write_weights(root / "truth" / name / f"s{k}.json", rig.names, w)
        people[name] = rig
    return root, people


def job(root: Path, out: Path, identity: bool) -> fb.Job:
    return fb.job_from_dict({"operation": "fit", "inputs": str(root / "scans" / "**" / "*.obj"), "output": str(out),
                             "shared": {"identity": identity}}, base=root, source=str(root / "job.toml"))


def test_identity_step_fits_one_rig_per_subject_folder(subjects, tmp_path, face_model):
    root, people = subjects
    res = fb.run_job(job(root, tmp_path / "with", True), inline=True, progress=False)
    assert res.counts["ok"] == 6 and res.counts["failed"] == 0
    for name, truth in people.items():
        rig = load_rig(tmp_path / "with" / name / "identity.npz")
        assert rig.n_shapes == truth.n_shapes
        err = np.linalg.norm(rig.neutral[:6706] - truth.neutral[:6706], axis=1).mean() * 10
        assert err < 0.2, (name, err)  # the person's neutral, from three noisy expressive scans
    # the expressions on the subject's rig are far closer to the truth than on the generic face
    plain = fb.run_job(job(root, tmp_path / "without", False), inline=True, progress=False)
    assert not list((tmp_path / "without").rglob("identity.npz"))
    rig = people["anna"]

    def coef_err(folder):
        return np.mean([np.abs(read_weights(p, rig.names)
                               - read_weights(root / "truth" / p.parent.name / p.name, rig.names)).mean()
                        for p in folder.rglob("s*.json")])

    assert plain.counts["ok"] == 6
    assert coef_err(tmp_path / "with") < 0.2 * coef_err(tmp_path / "without")
    # a rerun finds every output, identity files included, and recomputes nothing
    again = fb.run_job(job(root, tmp_path / "with", True), inline=True, progress=False)
    assert again.counts.get("skipped", 0) == 6


def test_identity_step_checks(subjects, tmp_path):
    root, _ = subjects
    bad = {"operation": "fit", "inputs": str(root / "scans" / "**" / "*.obj"), "output": str(tmp_path / "o")}
    with pytest.raises(InputError, match="identity must be true or false"):
        fb.run_job(fb.job_from_dict({**bad, "shared": {"identity": "yes"}}, base=root, source="job.toml"),
                   inline=True, progress=False)
    rig_file = tmp_path / "r.npz"
    BlendshapeRig(np.zeros((3, 3)), np.zeros((1, 3, 3)), ["a"], np.array([[0, 1, 2]])).save_npz(rig_file)
    with pytest.raises(InputError, match="cannot be combined with shared.rig"):
        fb.run_job(fb.job_from_dict({**bad, "shared": {"identity": True, "rig": str(rig_file)}}, base=root,
                                    source="job.toml"), inline=True, progress=False)
