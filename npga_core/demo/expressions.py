"""Blendshape weight vectors of realistic expressions: named ones and a random sampler for training.

Weights follow the ARKit conventions of the ICT kit (values in [0, 1]); the sampler mixes the facial
actions people actually combine (visemes with jaw opening, smiles with cheek and eye squint, frowns, brow
raises, blinks and winks, gaze, sneers, puffs), symmetric or asymmetric, sparsely.
"""

from __future__ import annotations

import numpy as np

#: Named expressions as {blendshape: weight}; "_LR" expands to both sides.
NAMED_EXPRESSIONS: dict[str, dict[str, float]] = {
    "neutral": {},
    "jaw_open": {"jawOpen": 0.9, "mouthLowerDown_LR": 0.2},
    "smile": {"mouthSmile_LR": 0.9, "cheekSquint_LR": 0.45, "eyeSquint_LR": 0.2, "mouthDimple_LR": 0.2},
    "laugh": {"mouthSmile_LR": 1.0, "jawOpen": 0.4, "mouthUpperUp_LR": 0.35, "cheekSquint_LR": 0.6,
              "eyeSquint_LR": 0.4},
    "blink": {"eyeBlink_LR": 1.0},
    "wink_left": {"eyeBlink_L": 1.0, "cheekSquint_L": 0.35, "mouthSmile_L": 0.35},
    "brows_up": {"browInnerUp_LR": 0.9, "browOuterUp_LR": 0.9},
    "frown": {"browDown_LR": 0.8, "mouthFrown_LR": 0.7, "mouthShrugLower": 0.3, "mouthPress_LR": 0.3},
    "surprise": {"browInnerUp_LR": 1.0, "browOuterUp_LR": 0.9, "eyeWide_LR": 0.7, "jawOpen": 0.45,
                 "mouthFunnel": 0.2},
    "sad": {"browInnerUp_LR": 0.8, "mouthFrown_LR": 0.6, "mouthShrugLower": 0.35, "eyeSquint_LR": 0.15},
    "angry": {"browDown_LR": 1.0, "eyeSquint_LR": 0.5, "noseSneer_LR": 0.4, "mouthPress_LR": 0.5,
              "mouthFrown_LR": 0.3},
    "disgust": {"noseSneer_LR": 0.9, "mouthUpperUp_LR": 0.5, "browDown_LR": 0.4, "mouthFrown_LR": 0.3},
    "pucker": {"mouthPucker": 0.9, "mouthFunnel": 0.2},
    "o_mouth": {"mouthFunnel": 0.8, "jawOpen": 0.3},
    "cheek_puff": {"cheekPuff_LR": 1.0, "mouthPress_LR": 0.3},
    "look_left": {"eyeLookOut_L": 0.8, "eyeLookIn_R": 0.8},
    "look_right": {"eyeLookIn_L": 0.8, "eyeLookOut_R": 0.8},
    "look_up": {"eyeLookUp_LR": 0.8, "browOuterUp_LR": 0.15},
    "look_down": {"eyeLookDown_LR": 0.8},
}


def weights_from_dict(spec: dict[str, float], names: list[str] | tuple[str, ...]) -> np.ndarray:
    """A weight vector (E,) from {name: value}; a name ending in "_LR" sets both "_L" and "_R"."""
    w = np.zeros(len(names), np.float32)
    for key, value in spec.items():
        keys = [key[:-3] + "_L", key[:-3] + "_R"] if key.endswith("_LR") else [key]
        for k in keys:
            w[names.index(k)] = value
    return w


def named_weights(names: list[str] | tuple[str, ...]) -> dict[str, np.ndarray]:
    """All named expressions as weight vectors."""
    return {k: weights_from_dict(v, names) for k, v in NAMED_EXPRESSIONS.items()}


class ExpressionSampler:
    """Random realistic weight vectors (n, E) in [0, 1]."""

    #: Mouth shapes used in speech-like visemes alongside the jaw.
    VISEME_SHAPES = ("mouthFunnel", "mouthPucker", "mouthRollLower", "mouthRollUpper", "mouthShrugLower",
                     "mouthShrugUpper", "mouthPress_L", "mouthPress_R", "mouthLowerDown_L", "mouthLowerDown_R",
                     "mouthUpperUp_L", "mouthUpperUp_R", "mouthStretch_L", "mouthStretch_R", "mouthClose")

    def __init__(self, names: list[str] | tuple[str, ...]):
        self.names = list(names)
        self.ix = {n: i for i, n in enumerate(self.names)}

    def _pair(self, w: np.ndarray, rows: np.ndarray, base: str, amount: np.ndarray, rng: np.random.Generator,
              p_asym: float = 0.3) -> None:
        """Set base_L/base_R on rows: equal (with a little jitter) or one side weaker."""
        n = len(rows)
        left = amount * (1.0 + 0.1 * rng.standard_normal(n))
        right = amount * (1.0 + 0.1 * rng.standard_normal(n))
        asym = rng.random(n) < p_asym
        weak = rng.uniform(0.0, 0.6, n)
        side = rng.random(n) < 0.5
        left = np.where(asym & side, left * weak, left)
        right = np.where(asym & ~side, right * weak, right)
        w[rows, self.ix[base + "_L"]] = np.maximum(w[rows, self.ix[base + "_L"]], left)
        w[rows, self.ix[base + "_R"]] = np.maximum(w[rows, self.ix[base + "_R"]], right)

    def _set(self, w: np.ndarray, rows: np.ndarray, name: str, amount: np.ndarray) -> None:
        w[rows, self.ix[name]] = np.maximum(w[rows, self.ix[name]], amount)

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        e = len(self.names)
        w = np.zeros((n, e))

        def pick(p: float) -> np.ndarray:
            return np.flatnonzero(rng.random(n) < p)

        def u(rows: np.ndarray, lo: float = 0.0, hi: float = 1.0, power: float = 1.0) -> np.ndarray:
            return lo + (hi - lo) * rng.random(len(rows)) ** power

        # speech: jaw with 1-3 viseme shapes
        rows = pick(0.55)
        self._set(w, rows, "jawOpen", u(rows, power=2.0))
        for _ in range(3):
            sub = rows[rng.random(len(rows)) < 0.55]
            shapes = rng.choice(self.VISEME_SHAPES, size=len(sub))
            for s in np.unique(shapes):
                r = sub[shapes == s]
                self._set(w, r, str(s), u(r, 0.1, 0.9))
        mc = self.ix["mouthClose"]
        w[:, mc] = np.minimum(w[:, mc], w[:, self.ix["jawOpen"]])  # a corrective: only with the jaw open
        for name, p in (("jawForward", 0.06), ("mouthLeft", 0.06), ("mouthRight", 0.06)):
            rows = pick(p)
            self._set(w, rows, name, u(rows, 0.1, 0.8))
        rows = pick(0.1)
        side = np.where(rng.random(len(rows)) < 0.5, "jawLeft", "jawRight")
        for s in ("jawLeft", "jawRight"):
            r = rows[side == s]
            self._set(w, r, s, u(r, 0.1, 0.7))
        # smile family
        rows = pick(0.35)
        amt = u(rows, 0.1, 1.0)
        self._pair(w, rows, "mouthSmile", amt, rng)
        self._pair(w, rows, "cheekSquint", amt * rng.uniform(0.0, 0.7, len(rows)), rng)
        self._pair(w, rows, "eyeSquint", amt * rng.uniform(0.0, 0.5, len(rows)), rng)
        sub = rows[rng.random(len(rows)) < 0.4]
        self._pair(w, sub, "mouthDimple", u(sub, 0.1, 0.8), rng)
        # frown / sadness / anger
        rows = pick(0.2)
        self._pair(w, rows, "mouthFrown", u(rows, 0.1, 1.0), rng)
        sub = rows[rng.random(len(rows)) < 0.5]
        self._pair(w, sub, "browDown", u(sub, 0.1, 1.0), rng)
        for name in ("mouthShrugLower", "mouthRollLower"):
            sub = rows[rng.random(len(rows)) < 0.3]
            self._set(w, sub, name, u(sub, 0.1, 0.7))
        # brows
        rows = pick(0.3)
        self._pair(w, rows, "browInnerUp", u(rows, 0.1, 1.0), rng)
        sub = rows[rng.random(len(rows)) < 0.7]
        self._pair(w, sub, "browOuterUp", u(sub, 0.1, 1.0), rng)
        rows = pick(0.15)
        self._pair(w, rows, "browDown", u(rows, 0.1, 1.0), rng)
        # eyes: blinks (some winks), squint, wide
        rows = pick(0.3)
        self._pair(w, rows, "eyeBlink", u(rows, 0.2, 1.0, power=0.5), rng, p_asym=0.2)
        rows = pick(0.15)
        self._pair(w, rows, "eyeSquint", u(rows, 0.1, 1.0), rng)
        rows = pick(0.15)
        self._pair(w, rows, "eyeWide", u(rows, 0.1, 1.0), rng, p_asym=0.15)
        # gaze: both eyes turn together
        rows = pick(0.5)
        yaw = rng.uniform(-1, 1, len(rows))
        pitch = rng.uniform(-1, 1, len(rows))
        for r, names in ((yaw > 0, ("eyeLookOut_L", "eyeLookIn_R")), (yaw < 0, ("eyeLookIn_L", "eyeLookOut_R"))):
            for s in names:
                self._set(w, rows[r], s, np.abs(yaw[r]))
        for r, base in ((pitch > 0, "eyeLookUp"), (pitch < 0, "eyeLookDown")):
            for suffix in ("_L", "_R"):
                self._set(w, rows[r], base + suffix, np.abs(pitch[r]))
        # nose and cheeks
        rows = pick(0.15)
        self._pair(w, rows, "noseSneer", u(rows, 0.1, 1.0), rng)
        rows = pick(0.07)
        self._pair(w, rows, "cheekPuff", u(rows, 0.2, 1.0), rng, p_asym=0.2)
        # a few arbitrary sparse shapes, single extreme shapes, and some neutral faces
        rows = pick(0.2)
        for _ in range(2):
            cols = rng.integers(0, e, len(rows))
            w[rows, cols] = np.maximum(w[rows, cols], u(rows, 0.0, 0.7))
        rows = pick(0.04)
        w[rows] = 0.0
        w[rows, rng.integers(0, e, len(rows))] = u(rows, 0.6, 1.0)
        w[pick(0.02)] = 0.0
        w[:, mc] = np.minimum(w[:, mc], w[:, self.ix["jawOpen"]])
        return np.clip(w, 0.0, 1.0).astype(np.float32)
