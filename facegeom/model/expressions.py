"""Named expressions built from the ICT (ARKit-style) blendshapes, and random sparse ones.

The six basic emotions follow the usual FACS descriptions (Ekman) mapped onto
ARKit shape names: happiness = lip-corner puller + cheek raiser; sadness =
inner-brow raiser + lip-corner depressor; surprise = brow raisers + upper-lid
raiser + jaw drop; fear = brow raisers + upper-lid raiser + lip stretcher;
anger = brow lowerer + lid tightener + lip presser; disgust = nose wrinkler +
upper-lip raiser.
"""
from __future__ import annotations

import numpy as np

__all__ = ["NAMED", "KINDS", "named_expression", "random_sparse_expression"]


def _both(name: str, w: float) -> dict[str, float]:
    return {f"{name}_L": w, f"{name}_R": w}


NAMED: dict[str, dict[str, float]] = {
    "happiness": {**_both("mouthSmile", 0.85), **_both("cheekSquint", 0.5), **_both("eyeSquint", 0.3)},
    "sadness": {**_both("browInnerUp", 0.8), **_both("mouthFrown", 0.7), "mouthShrugLower": 0.4,
                **_both("browDown", 0.2)},
    "surprise": {**_both("browInnerUp", 0.8), **_both("browOuterUp", 0.8), **_both("eyeWide", 0.7),
                 "jawOpen": 0.5},
    "fear": {**_both("browInnerUp", 0.9), **_both("browOuterUp", 0.5), **_both("eyeWide", 0.8),
             **_both("mouthStretch", 0.6), "jawOpen": 0.2},
    "anger": {**_both("browDown", 0.9), **_both("eyeSquint", 0.5), **_both("noseSneer", 0.4),
              **_both("mouthPress", 0.6)},
    "disgust": {**_both("noseSneer", 0.9), **_both("mouthUpperUp", 0.6), **_both("mouthFrown", 0.3),
                **_both("browDown", 0.3)},
    "jaw-open": {"jawOpen": 0.8},
    "pucker": {"mouthPucker": 0.9, "mouthFunnel": 0.3},
    "blink": {**_both("eyeBlink", 1.0)},
    "asym-smile-brow": {"mouthSmile_L": 0.9, "browOuterUp_L": 0.7, "eyeSquint_L": 0.3},
    "asym-wink-mouth-left": {"eyeBlink_R": 1.0, "mouthLeft": 0.6, "cheekSquint_R": 0.4},
    "asym-jaw-sneer": {"jawLeft": 0.6, "jawOpen": 0.3, "noseSneer_R": 0.6, "mouthSmile_R": 0.4},
}
KINDS = tuple(NAMED) + ("random-sparse",)


def named_expression(name: str, intensity: float = 1.0) -> dict[str, float]:
    """The weights of a named expression scaled by ``intensity``."""
    return {k: v * intensity for k, v in NAMED[name].items()}


def random_sparse_expression(names, rng: np.random.Generator, active=(2, 6), low: float = 0.3,
                             exclude_prefixes=("eyeLook",)) -> dict[str, float]:
    """``active[0]..active[1]`` random shapes with weights ~ U(low, 1).

    Gaze shapes (``eyeLook*``) are excluded by default: they move only the eyelids a
    little on this face-only mesh.
    """
    pool = [n for n in names if not n.startswith(tuple(exclude_prefixes))]
    k = int(rng.integers(active[0], active[1] + 1))
    chosen = rng.choice(len(pool), size=k, replace=False)
    return {pool[i]: float(rng.uniform(low, 1.0)) for i in sorted(chosen)}
