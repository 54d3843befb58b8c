"""Demo animation sequences: blendshape weight curves with realistic timing, encoded as expression codes.

- ``talking``: phrases of consonant-vowel syllables (about 4-5 per second) mapped to visemes, pauses between
  phrases, brow accents on stressed syllables, blinks and a little head motion;
- ``emotions``: held expressions (smile, frown, surprise, sadness, laughter, disgust) with smooth onsets;
- ``blinks_gaze``: fixations with fast saccades (eyeLook* shapes, the eyeballs turn) and blinks every
  2-6 s lasting 150-250 ms (fast close, slower open), some accompanying saccades, one double blink.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from npga_core.demo.expression_map import ExpressionMap
from npga_core.demo.expressions import NAMED_EXPRESSIONS, weights_from_dict
from npga_core.files.sequences import ExpressionSequence

FPS = 25.0

#: Visemes as blendshape weights (ARKit names; "_LR" = both sides).
VISEMES: dict[str, dict[str, float]] = {
    "AA": {"jawOpen": 0.42, "mouthLowerDown_LR": 0.25, "mouthUpperUp_LR": 0.1},
    "EH": {"jawOpen": 0.28, "mouthStretch_LR": 0.25, "mouthSmile_LR": 0.1, "mouthLowerDown_LR": 0.15},
    "IY": {"jawOpen": 0.12, "mouthStretch_LR": 0.35, "mouthSmile_LR": 0.2},
    "OW": {"jawOpen": 0.28, "mouthFunnel": 0.6, "mouthPucker": 0.2},
    "UW": {"jawOpen": 0.1, "mouthPucker": 0.75, "mouthFunnel": 0.25},
    "MBP": {"jawOpen": 0.06, "mouthClose": 0.06, "mouthPress_LR": 0.45, "mouthRollUpper": 0.1},
    "FV": {"jawOpen": 0.08, "mouthRollLower": 0.55, "mouthUpperUp_LR": 0.2},
    "TD": {"jawOpen": 0.18, "mouthStretch_LR": 0.1},
    "SZ": {"jawOpen": 0.05, "mouthStretch_LR": 0.3, "mouthSmile_LR": 0.08},
    "RW": {"jawOpen": 0.14, "mouthPucker": 0.45, "mouthFunnel": 0.2},
}
VOWELS = ("AA", "EH", "IY", "OW", "UW")
CONSONANTS = ("MBP", "FV", "TD", "SZ", "RW")


@dataclass
class Curves:
    """Weight curves (T, E) and an optional head rotation (T, 3) axis-angle in radians."""

    weights: np.ndarray
    rotation: np.ndarray | None = None


def smoothstep(t: np.ndarray) -> np.ndarray:
    t = np.clip(t, 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def keyframes(times: np.ndarray, keys: list[tuple[float, np.ndarray]]) -> np.ndarray:
    """Values at `times` eased between consecutive (time, value) keys (held before the first, after the last)."""
    keys = sorted(keys, key=lambda k: k[0])
    out = np.repeat(np.asarray(keys[0][1], np.float64)[None], len(times), axis=0)
    for (t0, v0), (t1, v1) in zip(keys[:-1], keys[1:], strict=True):
        s = smoothstep((times - t0) / max(t1 - t0, 1e-6))[:, None]
        seg = times >= t0
        out[seg] = (1 - s[seg]) * np.asarray(v0) + s[seg] * np.asarray(v1)
    return out


def blink_profile(times: np.ndarray, start: float, duration: float) -> np.ndarray:
    """Eyelid closure of one blink: 35 % of the time closing (ease-in), a short hold, then opening (ease-out)."""
    close, hold = 0.35 * duration, 0.15 * duration
    t = times - start
    closing = smoothstep(t / close)
    opening = 1.0 - smoothstep((t - close - hold) / (duration - close - hold))
    return np.where(t < close + hold, closing, opening) * ((t >= 0) & (t <= duration))


def blink_times(rng: np.random.Generator, duration: float, first: float = 0.8) -> list[tuple[float, float]]:
    """(start, length) of blinks every 2-6 s lasting 150-250 ms."""
    out, t = [], first + rng.uniform(0.0, 1.0)
    while t < duration - 0.3:
        out.append((t, rng.uniform(0.15, 0.25)))
        t += rng.uniform(2.0, 6.0)
    return out


def add_blinks(w: np.ndarray, times: np.ndarray, blinks: list[tuple[float, float]], ix: Callable[[str], int]) -> None:
    for start, length in blinks:
        b = blink_profile(times, start, length)
        for side in ("_L", "_R"):
            k = ix("eyeBlink" + side)
            w[:, k] = np.maximum(w[:, k], b)


def head_motion(rng: np.random.Generator, times: np.ndarray, amplitude_deg: float) -> np.ndarray:
    """Small smooth head rotation (T, 3) axis-angle: sums of slow sinusoids about x (nod), y (turn), z (tilt)."""
    rot = np.zeros((len(times), 3))
    for axis, amp in ((0, 1.0), (1, 1.3), (2, 0.5)):
        for _ in range(3):
            f = rng.uniform(0.08, 0.5)
            rot[:, axis] += amp * rng.uniform(0.3, 1.0) * np.sin(2 * np.pi * f * times + rng.uniform(0, 2 * np.pi))
    return np.radians(amplitude_deg) * rot / 3.0


class SequenceBuilder:
    """Makes the demo's weight curves for the kit's blendshape names."""

    def __init__(self, names: list[str] | tuple[str, ...], fps: float = FPS):
        self.names = list(names)
        self.fps = fps

    def ix(self, name: str) -> int:
        return self.names.index(name)

    def w(self, spec: dict[str, float]) -> np.ndarray:
        return weights_from_dict(spec, self.names).astype(np.float64)

    def times(self, duration: float) -> np.ndarray:
        return np.arange(int(round(duration * self.fps))) / self.fps

    def talking(self, rng: np.random.Generator, duration: float = 16.0) -> Curves:
        t = self.times(duration)
        neutral = self.w({})
        keys: list[tuple[float, np.ndarray]] = [(0.0, neutral)]
        brows: list[tuple[float, np.ndarray]] = [(0.0, neutral)]
        now = 0.6
        while now < duration - 1.2:
            phrase_end = min(now + rng.uniform(1.5, 3.5), duration - 0.8)
            keys.append((now - 0.1, neutral))
            while now < phrase_end:
                syllable = rng.uniform(0.18, 0.26)
                scale = rng.uniform(0.7, 1.15)
                if rng.random() < 0.7:
                    keys.append((now, self.w(VISEMES[str(rng.choice(CONSONANTS))]) * scale))
                keys.append((now + 0.4 * syllable, self.w(VISEMES[str(rng.choice(VOWELS))]) * scale))
                if rng.random() < 0.12:  # stressed syllable: raise the brows briefly
                    up = self.w({"browInnerUp_LR": 0.45, "browOuterUp_LR": 0.3}) * rng.uniform(0.6, 1.0)
                    brows += [(now - 0.15, neutral), (now + 0.1, up), (now + 0.5, neutral)]
                now += syllable
            keys.append((now + 0.1, neutral))
            now += rng.uniform(0.35, 0.8)
        keys.append((duration, neutral))
        w = keyframes(t, keys)
        w = np.maximum(w, keyframes(t, brows + [(duration, neutral)]))
        w[:, self.ix("mouthClose")] = np.minimum(w[:, self.ix("mouthClose")], w[:, self.ix("jawOpen")])
        add_blinks(w, t, blink_times(rng, duration), self.ix)
        return Curves(np.clip(w, 0, 1).astype(np.float32), head_motion(rng, t, 3.0).astype(np.float32))

    def emotions(self, rng: np.random.Generator, duration: float = 18.0) -> Curves:
        t = self.times(duration)
        neutral = self.w({})
        order = ["smile", "frown", "surprise", "sad", "laugh", "disgust"]
        keys: list[tuple[float, np.ndarray]] = [(0.0, neutral), (0.8, neutral)]
        span = (duration - 1.6) / len(order)
        for i, name in enumerate(order):
            start = 0.8 + i * span
            target = self.w(NAMED_EXPRESSIONS[name]) * rng.uniform(0.85, 1.0)
            onset = rng.uniform(0.35, 0.6)
            keys += [(start + 0.2, neutral), (start + 0.2 + onset, target),
                     (start + span - 0.7, target * rng.uniform(0.85, 1.0)), (start + span - 0.1, neutral)]
        keys.append((duration, neutral))
        w = keyframes(t, keys)
        blinks = [(s, d) for s, d in blink_times(rng, duration) if w[min(int(s * self.fps), len(t) - 1),
                                                                      self.ix("eyeWide_L")] < 0.2]
        add_blinks(w, t, blinks, self.ix)
        return Curves(np.clip(w, 0, 1).astype(np.float32), head_motion(rng, t, 2.0).astype(np.float32))

    def gaze_weights(self, yaw: float, pitch: float) -> np.ndarray:
        """Both eyes turned: yaw > 0 towards the subject's left, pitch > 0 up (weights in [0, 1])."""
        spec: dict[str, float] = {}
        if yaw > 0:
            spec.update(eyeLookOut_L=yaw, eyeLookIn_R=yaw)
        else:
            spec.update(eyeLookIn_L=-yaw, eyeLookOut_R=-yaw)
        spec["eyeLookUp_LR" if pitch > 0 else "eyeLookDown_LR"] = abs(pitch)
        return self.w(spec)

    def blinks_gaze(self, rng: np.random.Generator, duration: float = 15.0) -> Curves:
        t = self.times(duration)
        keys: list[tuple[float, np.ndarray]] = [(0.0, self.gaze_weights(0.0, 0.0))]
        blinks = blink_times(rng, duration)
        now = 0.5
        while now < duration - 0.5:
            target = self.gaze_weights(rng.uniform(-0.8, 0.8), rng.uniform(-0.6, 0.5))
            if rng.random() < 0.15:  # a slow pursuit
                keys.append((now + rng.uniform(0.8, 1.5), target))
            else:  # a saccade of 40-80 ms
                keys += [(now, keys[-1][1]), (now + rng.uniform(0.04, 0.08), target)]
                if rng.random() < 0.3:
                    blinks.append((now - 0.02, rng.uniform(0.15, 0.22)))
            now = keys[-1][0] + rng.uniform(0.6, 2.5)
        keys.append((duration, keys[-1][1]))
        w = keyframes(t, keys)
        kept: list[tuple[float, float]] = []
        for b in sorted(blinks):  # no blink within 0.5 s after another
            if not kept or b[0] - kept[-1][0] > 0.5:
                kept.append(b)
        mid = duration * 0.6
        kept = [b for b in kept if abs(b[0] - mid) > 0.6] + [(mid, 0.16), (mid + 0.24, 0.18)]  # a double blink
        add_blinks(w, t, kept, self.ix)
        # the lids follow the gaze a little
        up, down = w[:, self.ix("eyeLookUp_L")], w[:, self.ix("eyeLookDown_L")]
        for side in ("_L", "_R"):
            w[:, self.ix("eyeWide" + side)] = np.maximum(w[:, self.ix("eyeWide" + side)], 0.25 * up)
            w[:, self.ix("eyeSquint" + side)] = np.maximum(w[:, self.ix("eyeSquint" + side)], 0.15 * down)
        return Curves(np.clip(w, 0, 1).astype(np.float32))


def build_sequences(emap: ExpressionMap, seed: int, fps: float = FPS) -> dict[str, ExpressionSequence]:
    """The demo sequences (deterministic from the seed), as expression codes z = M w + b."""
    builder = SequenceBuilder(emap.names, fps)
    out = {}
    for i, name in enumerate(("talking", "emotions", "blinks_gaze")):
        rng = np.random.default_rng(np.random.SeedSequence([seed, 0x5E0, i]))
        curves: Curves = getattr(builder, name)(rng)
        out[name] = ExpressionSequence(emap.encode(curves.weights), fps=fps, name=name, rotation=curves.rotation)
    return out
