"""docs/security.md says only what the code does: every budget the page names is the code's constant, and the
page's promises that no other test covers (native readers never see file bytes, half the machine's memory,
loopback by default, the smallest label weight) are checked here."""
from __future__ import annotations

import importlib
import re
from pathlib import Path

import numpy as np
import pytest

from facegeom.errors import InputError

ROOT = Path(__file__).resolve().parents[1]
PAGE = " ".join((ROOT / "docs" / "security.md").read_text(encoding="utf-8").split())

#: (module, constant, its value, the words of the page that state it)
BUDGETS = [
    ("facegeom.model.rig", "MAX_RIG_SHAPES", 1000, "at most 1,000 shapes"),
    ("facegeom.model.rig", "MAX_RIG_VERTICES", 5_000_000, "and 5 million vertices"),
    ("facegeom.model.rig", "MAX_COMPRESSION_RATIO", 900, "compressed beyond 900:1"),
    ("facegeom.model.rig", "RIG_DELTA_COPIES", 4, "the deltas within a quarter of half the machine's memory"),
    ("facegeom.io.gltf", "MAX_NODES", 10_000, "more than 10,000 nodes"),
    ("facegeom.io.gltf", "MAX_MESHES", 1_000, "1,000 meshes"),
    ("facegeom.io.gltf", "MAX_ACCESSORS", 20_000, "20,000 accessors or buffer views"),
    ("facegeom.io.gltf", "MAX_BUFFER_VIEWS", 20_000, "20,000 accessors or buffer views"),
    ("facegeom.io.gltf", "MAX_MORPH_TARGETS", 4_096, "4,096 morph targets on one primitive or in the rig"),
    ("facegeom.io.gltf", "MAX_ANIMATIONS", 1_000, "1,000 animations"),
    ("facegeom.io.gltf", "MAX_ANIMATION_CHANNELS", 20_000, "20,000 animation channels"),
    ("facegeom.io.mesh", "MAX_COORDINATE", 1e12, "a mesh coordinate beyond 1e12"),
    ("facegeom.interfaces", "MAX_COORDINATE", 1e12, "a mesh coordinate beyond 1e12 (and so any vertex, marker"),
    ("facegeom.io.key_labels", "MAX_COORDINATE", 1e12, "key labels beyond 1e12"),
    ("facegeom.io.c3d", "MAX_RATE", 10_000, "a C3D rate above 10,000 frames a second"),
    ("facegeom.pipelines.solve", "CAPTURE_REACH", 1e5, "a capture 1e5 face sizes from the origin"),
    ("facegeom.io.shape_names", "MAX_MAPPING_BYTES", 1 << 20, "a shape-name mapping CSV over 1 MiB"),
    ("facegeom.io.shape_names", "MAX_GAIN", 10.0, "a mapping's gain beyond ±10"),
    ("facegeom.io.shape_names", "QUOTE_CHARS", 80, "at most 80 characters"),
    ("facegeom.io.key_labels", "MAX_KEY_LABEL_BYTES", 8 << 20, "a key-label file over 8 MiB"),
    ("facegeom.io.key_labels", "MAX_OUTSIDE", 1.0, "more than a head's size outside the head"),
    ("facegeom.io.key_labels", "MIN_SPREAD", 0.25, "under a quarter of the proposed markers' spread"),
    ("facegeom.model.targets", "MIN_FACE_PX", 1.0, "landmarks spanning less than 1 px"),
    ("facegeom.pipelines.solve", "SOLVE_RESIDUAL_MAX_MM", 15.0, "a median residual above 15 mm"),
    ("facegeom.methods.transfer", "NOT_A_HEAD_RIGID_MM", 4.0, "lies more than 4 mm from it (median)"),
    ("facegeom.methods.transfer", "NOT_A_HEAD_MM", 5.0, "its identity fit lies more than 5 mm from it"),
    ("facegeom.methods.transfer", "MIN_COVERED", 0.5, "less than half the face area lies on it"),
    ("facegeom.methods.transfer", "NOT_A_HEAD_IDENTITY_RMS", 4.5, "more than 4.5 standard deviations"),
    ("facegeom.methods.transfer", "NOT_A_HEAD_STRAIN", 0.2, "stretched by more than 20 %"),
    ("facegeom.io.files", "STALE_TEMPORARY_S", 3600.0, "untouched for an hour"),
    ("facegeom.io.images", "MAX_IMAGE_PIXELS", 1 << 26, "A photo over 2^26 pixels"),
    ("facegeom.io.video", "MAX_FRAME_PIXELS", 8192 * 4320, "a video frame over 8192 x 4320"),
    ("facegeom.io.c3d", "_TIMEOUT_S", 10.0, "a time limit (10 s plus 1 s per MB)"),
    ("facegeom.io.c3d", "_TIMEOUT_PER_BYTE", 1e-6, "a time limit (10 s plus 1 s per MB)"),
]


@pytest.mark.parametrize("module,name,value,words", BUDGETS, ids=[f"{m.rsplit('.', 1)[-1]}.{n}" for m, n, _, _ in BUDGETS])
def test_the_page_states_the_codes_budget(module, name, value, words):
    assert getattr(importlib.import_module(module), name) == value, f"{module}.{name} is no longer {value}"
    assert words in PAGE, f"docs/security.md no longer says {words!r}"


def test_the_voxel_soup_threshold_is_the_pages(monkeypatch):
    """``clean`` refuses a mesh where more than 100 edges and more than 10 % of all edges have over two faces."""
    from facegeom.pipelines.cleanup.repair import _refuse_pathological

    assert "more than 100 edges and more than 10 % of all edges have more than two faces" in PAGE

    def fan(edges_shared: int, plain: int) -> np.ndarray:
        """``edges_shared`` edges with three faces each, plus a strip of ``plain`` faces elsewhere."""
        F = []
        for e in range(edges_shared):
            a, b = 2 * e, 2 * e + 1
            F += [[a, b, 10_000 + 3 * e + j] for j in range(3)]
        base = 20_000
        F += [[base + i, base + i + 1, base + i + 2] for i in range(plain)]
        return np.array(F)

    _refuse_pathological(fan(100, 0))  # 100 such edges: not more than 100
    with pytest.raises(InputError, match="voxel"):
        _refuse_pathological(fan(101, 0))
    _refuse_pathological(fan(101, 3000))  # 101 of over 3,000 edges: under 10 %


def test_native_mesh_readers_never_see_a_users_file():
    """libigl's and pymeshlab's own file readers are never called: meshes are parsed by facegeom's readers."""
    calls = re.compile(r"igl\.(read_triangle_mesh|read_obj|read_off|read_ply|readOBJ|readOFF|readPLY|read_mesh)\b"
                       r"|\.load_new_mesh\(|\bMeshSet\(\)\.load|\bload_new_mesh\b")
    found = []
    for folder in ("facegeom", "baselines", "viewer"):
        for path in (ROOT / folder).rglob("*.py"):
            for k, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
                if calls.search(line) and not line.lstrip().startswith("#"):
                    found.append(f"{path.relative_to(ROOT)}:{k}: {line.strip()}")
    assert not found, "\n".join(found)


def test_the_memory_budget_is_half_the_machines_memory():
    import os

    from facegeom.io.npzcheck import memory_budget

    assert "half the machine's memory" in PAGE
    assert memory_budget() == os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") // 2


def test_live_listens_on_loopback_unless_told():
    from facegeom.pipelines import live

    assert "127.0.0.1 unless another address is given" in PAGE
    assert live.parse_address(str(live.DEFAULT_PORT)) == ("127.0.0.1", live.DEFAULT_PORT)
    assert live.parse_address("0.0.0.0:9000") == ("0.0.0.0", 9000)
    import inspect

    from facegeom.cli import live as cli_live

    assert "parse_address(listen or str(live.DEFAULT_PORT))" in inspect.getsource(cli_live)


def test_the_local_dask_cluster_is_on_loopback(monkeypatch):
    import distributed

    from facegeom.pipelines.batch import engine

    seen = {}
    monkeypatch.setattr(distributed, "LocalCluster", lambda **kw: seen.update(kw) or "cluster")
    assert engine.local_cluster(1) == "cluster"
    assert seen["host"] == "127.0.0.1" and seen["dashboard_address"] is None
    assert seen["scheduler_kwargs"]["dashboard_address"].startswith("127.0.0.1:")


@pytest.mark.parametrize("kind", ["retargeters", "deformers"])
def test_the_smallest_label_weight_is_the_pages(kind):
    from facegeom.registry import create

    assert "`beta` now starts at 1e-6" in PAGE
    with pytest.raises(InputError, match=r"beta must be .*1e-06"):
        create(kind, "tangent", beta=1e-300)
    create(kind, "tangent", beta=1e-6)
