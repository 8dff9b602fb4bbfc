"""Still pictures of meshes with matplotlib (Agg, no display): shaded faces for reports, the demo and the docs.

A mesh is drawn as a painter's-algorithm collection of its triangles, lit by a two-sided Lambert light and
seen orthographically along -Z after a view rotation (:func:`rotation`). No OpenGL context is needed, so it
works on any machine matplotlib installs on; :func:`head_only` keeps the framing on the face of a head
with shoulders.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

DPI = 100
SKIN = np.array([0.86, 0.74, 0.66])
SKIN_B = np.array([0.70, 0.78, 0.88])  # the second face of a pair (driven, character)


def rotation(yaw: float = 0.0, pitch: float = 0.0) -> np.ndarray:
    """View rotation: turn the face ``yaw`` degrees about Y (to its left), then tilt ``pitch`` about X."""
    a, b = np.radians(yaw), np.radians(pitch)
    ry = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    rx = np.array([[1, 0, 0], [0, np.cos(b), -np.sin(b)], [0, np.sin(b), np.cos(b)]])
    return rx @ ry


def vertex_normals(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals ``(n, 3)``."""
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    N = np.zeros_like(V)
    for k in range(3):
        np.add.at(N, F[:, k], n)
    return N / np.maximum(np.linalg.norm(N, axis=1, keepdims=True), 1e-12)


def draw_mesh(ax, V, F, R=None, color=SKIN, values=None, cmap="viridis", vmin=0.0, vmax=1.0, edges=None,
              image_coords=False):
    """Draw a shaded mesh (painter's algorithm, two-sided Lambert light) into ``ax``; returns the 2-D points.

    ``V (n, 3)`` are seen along -Z after the rotation ``R`` (orthographic), or are already
    ``(u, v, depth)`` pixels with ``image_coords``. ``values (n,)`` colour the faces through ``cmap``.
    ``edges`` draws the triangle edges in that colour (a wireframe over the shading).
    """
    from matplotlib import colormaps
    from matplotlib.collections import PolyCollection

    P = np.asarray(V, dtype=np.float64) @ (np.eye(3) if R is None else R).T
    tri = P[F]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    if image_coords:  # pixel rows grow downwards; depth grows away from the camera
        light = np.array([0.25, -0.35, -1.0])
        order = np.argsort(-tri[:, :, 2].mean(axis=1))
    else:
        light = np.array([-0.3, 0.45, 1.0])
        order = np.argsort(tri[:, :, 2].mean(axis=1))
    light /= np.linalg.norm(light)
    lam = np.abs(n @ light)
    shade = 0.28 + 0.72 * lam ** 1.2
    if values is None:
        base = np.broadcast_to(np.asarray(color, dtype=np.float64), (len(F), 3))
    else:
        t = (np.asarray(values, dtype=np.float64)[F].mean(axis=1) - vmin) / max(vmax - vmin, 1e-12)
        base = colormaps[cmap](np.clip(t, 0, 1))[:, :3]
    fc = np.clip(base * shade[:, None], 0, 1)[order]
    poly = PolyCollection(tri[order][:, :, :2], facecolors=fc, edgecolors=fc if edges is None else edges,
                          linewidths=0.25 if edges is None else 0.3, antialiased=edges is not None)
    ax.add_collection(poly)
    return P


def visible(V, F, R, ids) -> np.ndarray:
    """Which of the vertices ``ids`` face the viewer after the rotation ``R``."""
    return (vertex_normals(V, F)[ids] @ R.T)[:, 2] > 0.05


def frame_axes(ax, P, pad=0.04, title=None, keep=None):
    """Fit ``ax`` to the points ``P`` (or those of the mask ``keep``): equal aspect, no axes."""
    Q = P if keep is None else P[keep]
    lo, hi = Q[:, :2].min(axis=0), Q[:, :2].max(axis=0)
    m = pad * (hi - lo).max()
    ax.set_xlim(lo[0] - m, hi[0] + m)
    ax.set_ylim(lo[1] - m, hi[1] + m)
    ax.set_aspect("equal")
    ax.axis("off")
    if title:
        ax.set_title(title, fontsize=11)


def figure(cols, rows=1, width=16.0, height=None):
    """A white figure of ``rows x cols`` panels ``width`` inches wide -> ``(fig, axes (rows, cols))``."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(rows, cols, figsize=(width, height or width / cols * rows * 1.15), squeeze=False)
    fig.patch.set_facecolor("white")
    return fig, axes


def save(fig, path: Path) -> None:
    """Write ``fig`` as a PNG at :data:`DPI` (no software stamp, so the bytes depend on the picture only) and close it."""
    import matplotlib.pyplot as plt

    fig.savefig(path, dpi=DPI, facecolor="white", metadata={"Software": None})
    plt.close(fig)


def credit(fig, text: str) -> None:
    """A small credit line (a licence's attribution) in the figure's bottom-right corner."""
    fig.text(0.995, 0.005, text, ha="right", va="bottom", fontsize=8, color="#555555")


def head_only(V: np.ndarray, height: float = 30.0) -> np.ndarray:
    """The vertices within ``height`` cm of the top of a Y-up head in cm (frames the head, not the shoulders)."""
    V = np.asarray(V)
    return V[:, 1] > V[:, 1].max() - height
