"""Actor and character sequences for expression retargeting (ground truth included).

Construction (every random choice seeded):

- **Expression weights over time** ``W (T, E)`` in ICT order: a window of a real
  ARKit take (:mod:`facegeom.io.takes`, mapped to ICT names, clipped to [0, 1]) or
  a synthetic take (:func:`synthetic_weights`: onset - apex - offset of one or
  two named expressions, smoothstep ramps).
- **Actor**: a random identity (coefficients ~ N(0, 1)) performing ``W``:
  ``actor_t = neutral(a) + sum_e W[t, e] delta_e``.
- **Character** (:class:`Character`): a *different* face that performs the same
  expressions in its own style:

  1. another random identity ``b``;
  2. its own intensity per expression, ``s_e = exp(N(0, 0.3^2))`` clipped to
     [0.5, 1.8] (left and right shapes share one factor, so the style is
     symmetric: one character smiles wider, opens the jaw less...), so
     ``char_t = neutral(b) + sum_e s_e W[t, e] delta_e``;
  3. a smooth non-rigid stylising warp of space applied to every frame
     (:func:`stylise`): each eye and the mouth scaled about its own centre
     with a Gaussian falloff (bigger eyes and mouth), and the lower face
     stretched downwards below the mouth (a softplus ramp: a longer jaw).
     The centres come from the character's neutral landmarks and stay fixed
     over the sequence, so the warp is one fixed smooth map of space.

  The character's marker motion is then neither the actor's motion plus an
  offset (per-shape intensities, identity and warp change it) nor a fixed
  function of each marker's own position (a marker moved by several shapes
  whose intensities differ traces a different path).
- **Markers**: the same vertex ids on both faces (the callers default to the
  ``ict80`` layout of :mod:`facegeom.model.layouts`); the character's markers
  are the warped vertices.

Head motion is not simulated: the markers are taken as stabilised (head pose
removed), as a marker pipeline delivers them before retargeting.

Used by ``facegeom bench retarget`` / ``bench animate``
(:mod:`facegeom.bench`), the animation pipeline
(:mod:`facegeom.pipelines.animate`) and the viewer's playback views.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from facegeom.errors import InputError
from facegeom.model.expressions import NAMED

# Landmark ids (68-point Multi-PIE order) used by the warp.
_RIGHT_EYE = np.arange(36, 42)
_LEFT_EYE = np.arange(42, 48)
_MOUTH = np.arange(48, 68)


@dataclass
class Warp:
    """Parameters of the stylising warp (centres in model units, cm)."""

    centres: np.ndarray  # (3, 3): right eye, left eye, mouth
    sigmas: np.ndarray  # (3,) Gaussian falloff radii
    scales: np.ndarray  # (3,) scale factors at the centres (>1 = bigger)
    jaw_y: float  # height below which the jaw stretches
    jaw_stretch: float  # extra length per unit of depth below jaw_y
    jaw_softness: float  # softplus width

    def __call__(self, V: np.ndarray) -> np.ndarray:
        return stylise(V, self)


def stylise(V: np.ndarray, warp: Warp) -> np.ndarray:
    """Apply the smooth warp to points ``V (..., 3)``."""
    V = np.asarray(V, dtype=np.float64)
    out = V.copy()
    for c, s, k in zip(warp.centres, warp.sigmas, warp.scales):
        r = V - c
        g = np.exp(-np.einsum("...i,...i->...", r, r) / (2.0 * s * s))
        out += (k - 1.0) * g[..., None] * r
    u = (warp.jaw_y - V[..., 1]) / warp.jaw_softness
    out[..., 1] -= warp.jaw_stretch * warp.jaw_softness * np.logaddexp(0.0, u)
    return out


@dataclass
class Character:
    """A target character: identity, per-expression intensity and stylising warp.

    Attributes
    ----------
    identity : (I,) float64
        Identity coefficients of the character's face.
    intensity : (E,) float64
        Factor applied to each expression weight (ICT order); :func:`make_character`
        draws them in [0.5, 1.8], one per left/right pair.
    warp : Warp
        The stylising warp applied to every frame.
    seed : int
        The seed :func:`make_character` built it from.
    """

    identity: np.ndarray
    intensity: np.ndarray  # (E,)
    warp: Warp
    seed: int = 0

    def weights(self, W: np.ndarray) -> np.ndarray:
        """The character's weights for the actor's weights ``W``: each expression scaled by its intensity.

        Parameters
        ----------
        W : (T, E) or (E,) float array
            Expression weights in ICT order.

        Returns
        -------
        (T, E) or (E,) float64
            ``W * intensity``.
        """
        return np.asarray(W) * self.intensity


def _paired_factors(names, rng, sigma: float, low: float, high: float) -> np.ndarray:
    base = {}
    out = np.empty(len(names))
    for i, n in enumerate(names):
        key = n[:-2] if n.endswith(("_L", "_R")) else n
        if key not in base:
            base[key] = float(np.clip(np.exp(rng.normal(0.0, sigma)), low, high))
        out[i] = base[key]
    return out


def make_character(model, seed: int, warp_strength: float = 1.0) -> Character:
    """A random character (identity, intensities, warp) from ``seed``."""
    rng = np.random.default_rng([7919, int(seed)])
    b = model.random_identity(rng)
    intensity = _paired_factors(model.expression_names, rng, 0.3, 0.5, 1.8)
    V = model.identity_neutral(b)
    L = V[model.landmarks]
    centres = np.stack([L[_RIGHT_EYE].mean(0), L[_LEFT_EYE].mean(0), L[_MOUTH].mean(0)])
    eye_w = np.linalg.norm(L[39] - L[36])
    mouth_w = np.linalg.norm(L[54] - L[48])
    sigmas = np.array([0.9 * eye_w, 0.9 * eye_w, 0.7 * mouth_w])
    scales = 1.0 + warp_strength * np.array([rng.uniform(0.1, 0.3)] * 2 + [rng.uniform(0.05, 0.2)])
    jaw_y = float(centres[2, 1] - 0.2 * mouth_w)
    warp = Warp(centres, sigmas, scales, jaw_y, warp_strength * float(rng.uniform(0.1, 0.25)),
                float(0.3 * mouth_w))
    return Character(b, intensity, warp, int(seed))


def synthetic_weights(model, rng: np.random.Generator, frames: int = 100) -> tuple[np.ndarray, str]:
    """Onset - apex - offset of one or two named expressions over ``frames`` frames.

    Each expression rises with a smoothstep over 10-25 frames, holds 10-30 frames
    at an intensity ~ U(0.7, 1) and falls back; the second one (if any) starts
    while the first is fading, so they overlap.
    """
    names = list(NAMED)
    k = int(rng.integers(1, 3))
    chosen = [names[i] for i in rng.choice(len(names), size=k, replace=False)]
    W = np.zeros((frames, model.n_expressions))
    t = np.arange(frames, dtype=np.float64)
    start = float(rng.uniform(0, 0.15 * frames))
    for name in chosen:
        rise, hold, fall = rng.uniform(10, 25), rng.uniform(10, 30), rng.uniform(10, 25)
        env = _smoothstep((t - start) / rise) * (1.0 - _smoothstep((t - start - rise - hold) / fall))
        amp = rng.uniform(0.7, 1.0)
        for shape, w in NAMED[name].items():
            W[:, model.expression_index(shape)] += amp * w * env
        start += rise + hold * rng.uniform(0.5, 1.0)
    return np.clip(W, 0.0, 1.0), "+".join(chosen)


def _smoothstep(x):
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


@dataclass
class Sequence:
    """An actor/character pair performing the same weights, with ground truth."""

    name: str
    weights: np.ndarray  # (T, E) the actor's weights
    marker_ids: np.ndarray  # (p,)
    source: np.ndarray  # (T, p, 3) actor markers, cm
    target: np.ndarray  # (T, p, 3) character markers, cm (ground truth)
    source_rest: np.ndarray  # (p, 3) actor neutral markers
    target_rest: np.ndarray  # (p, 3) character neutral markers
    actor_identity: np.ndarray
    character: Character
    info: dict = field(default_factory=dict)

    @property
    def n_frames(self) -> int:
        """Number of frames ``T``."""
        return self.source.shape[0]

    def mean_motion(self) -> float:
        """Mean distance of the character's markers from their rest positions (cm)."""
        return float(np.linalg.norm(self.target - self.target_rest, axis=2).mean())


def blend(model, identity, W, ids=None) -> np.ndarray:
    """Faces (or the vertices ``ids`` of them) for weights ``W (T, E)``: ``(T, n, 3)``."""
    W = np.asarray(W, dtype=np.float64)
    base = model.identity_neutral(identity)
    D = model.expression_deltas
    if ids is not None:
        base, D = base[ids], D[:, ids]
    D = D.astype(np.float64).reshape(D.shape[0], -1)
    return base[None] + (W @ D).reshape(W.shape[0], *base.shape)


def make_sequence(model, W, marker_ids, actor_seed: int, character: Character, name: str = "") -> Sequence:
    """Build the actor and character marker sequences for weights ``W (T, E)``."""
    W = np.asarray(W, dtype=np.float64)
    if W.ndim != 2 or W.shape[1] != model.n_expressions:
        raise InputError(f"weights must have shape (T, {model.n_expressions}), got {W.shape}")
    ids = np.asarray(marker_ids, dtype=np.int64)
    a = model.random_identity(np.random.default_rng([104729, int(actor_seed)]))
    src = blend(model, a, W, ids)
    tgt = character.warp(blend(model, character.identity, character.weights(W), ids))
    zeros = np.zeros((1, model.n_expressions))
    return Sequence(
        name=name, weights=W, marker_ids=ids, source=src, target=tgt,
        source_rest=blend(model, a, zeros, ids)[0],
        target_rest=character.warp(blend(model, character.identity, zeros, ids))[0],
        actor_identity=a, character=character,
    )


def character_faces(model, seq: Sequence) -> np.ndarray:
    """The character's full true faces for every frame, ``(T, n, 3)``."""
    return seq.character.warp(blend(model, seq.character.identity, seq.character.weights(seq.weights)))


def character_neutral(model, character: Character) -> np.ndarray:
    """The character's neutral face: the neutral of its identity, stylised by its warp.

    Parameters
    ----------
    model : FaceModel
    character : Character

    Returns
    -------
    (n, 3) float64
        Vertex positions in model units (cm).
    """
    return character.warp(model.identity_neutral(character.identity))


def actor_faces(model, seq: Sequence) -> np.ndarray:
    """The actor's full faces for every frame: its identity performing ``seq.weights``.

    Parameters
    ----------
    model : FaceModel
    seq : Sequence

    Returns
    -------
    (T, n, 3) float64
        Vertex positions in model units (cm).
    """
    return blend(model, seq.actor_identity, seq.weights)
