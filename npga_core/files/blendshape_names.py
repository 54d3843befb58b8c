"""Matching blendshape names between capture sources and an avatar's basis: the one place spellings are known.

Sources spell Apple ARKit's 52 face blendshapes differently: ARKit and MediaPipe in camelCase
(``eyeBlinkLeft``; MediaPipe adds a ``_neutral`` category), Live Link Face in PascalCase (``EyeBlinkLeft``),
ICT-FaceKit (the demo) with ``_L``/``_R`` suffixes (``eyeBlink_L``) and split halves of ARKit's symmetric
``browInnerUp`` and ``cheekPuff``. Names are compared by a key: lower case, ``_L``/``_R``/``Left``/``Right``
folded to one side marker, underscores dropped. The match is a matrix S (target x source) so that
``target_weights = S @ source_weights``: a shape the target splits (``browInnerUp`` -> ``browInnerUp_L`` and
``_R``) drives both halves; two halves the target has as one shape are averaged. Source shapes the target
lacks (``tongueOut`` for the demo) are listed in `NameMatch.missing`, never dropped silently.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

#: Apple ARKit's 52 blendshape locations (ARFaceAnchor.BlendShapeLocation), in Live Link Face's packet order.
ARKIT_52: tuple[str, ...] = (
    "eyeBlinkLeft", "eyeLookDownLeft", "eyeLookInLeft", "eyeLookOutLeft", "eyeLookUpLeft", "eyeSquintLeft",
    "eyeWideLeft", "eyeBlinkRight", "eyeLookDownRight", "eyeLookInRight", "eyeLookOutRight", "eyeLookUpRight",
    "eyeSquintRight", "eyeWideRight", "jawForward", "jawLeft", "jawRight", "jawOpen", "mouthClose",
    "mouthFunnel", "mouthPucker", "mouthLeft", "mouthRight", "mouthSmileLeft", "mouthSmileRight",
    "mouthFrownLeft", "mouthFrownRight", "mouthDimpleLeft", "mouthDimpleRight", "mouthStretchLeft",
    "mouthStretchRight", "mouthRollLower", "mouthRollUpper", "mouthShrugLower", "mouthShrugUpper",
    "mouthPressLeft", "mouthPressRight", "mouthLowerDownLeft", "mouthLowerDownRight", "mouthUpperUpLeft",
    "mouthUpperUpRight", "browDownLeft", "browDownRight", "browInnerUp", "browOuterUpLeft", "browOuterUpRight",
    "cheekPuff", "cheekSquintLeft", "cheekSquintRight", "noseSneerLeft", "noseSneerRight", "tongueOut",
)
#: Head and eye rotation channels some sources send next to the shapes (Live Link Face: 9 after the 52).
ANGLE_NAMES: tuple[str, ...] = ("HeadYaw", "HeadPitch", "HeadRoll", "LeftEyeYaw", "LeftEyePitch", "LeftEyeRoll",
                                "RightEyeYaw", "RightEyePitch", "RightEyeRoll")
#: Categories that are no blendshape (MediaPipe's face landmarker reports ``_neutral`` first).
IGNORED = ("_neutral", "neutral")

# jawLeft / mouthLeft are directions, not sides: they keep their own names (no side marker).
_DIRECTIONAL = {"jawleft", "jawright", "mouthleft", "mouthright"}
_SIDE = re.compile(r"^(.*?)(?:_?(left|right)|_(l|r))$")


def name_key(name: str) -> str:
    """The comparison key of a blendshape name: ``eyeBlinkLeft``, ``EyeBlinkLeft``, ``eyeBlink_L`` and
    ``eye_blink_left`` all give ``eyeblink|l``; ``jawLeft`` (a direction) gives ``jawleft``."""
    low = name.strip().lower()
    flat = low.replace("_", "").replace("-", "").replace(" ", "")
    if flat in _DIRECTIONAL:
        return flat
    m = _SIDE.match(low)
    if m is None or not m.group(1):
        return flat
    side = (m.group(2) or m.group(3))[0]
    base = m.group(1).replace("_", "").replace("-", "").replace(" ", "")
    return f"{base}|{side}"


def canonical_arkit(name: str) -> str | None:
    """ARKit's own spelling of `name` (any of the spellings above), None if it is no ARKit shape."""
    return _ARKIT_BY_KEY.get(name_key(name))


_ARKIT_BY_KEY = {name_key(n): n for n in ARKIT_52}


@dataclass
class NameMatch:
    """Source names matched to target names: ``target = matrix @ source`` (matrix (n_target, n_source))."""

    matrix: np.ndarray
    source: tuple[str, ...]
    target: tuple[str, ...]
    missing: tuple[str, ...] = ()  # source shapes the target lacks (their weights have no effect)
    ignored: tuple[str, ...] = ()  # source channels that are no shapes (``_neutral``, head/eye angles)
    unset: tuple[str, ...] = field(default=())  # target shapes no source name drives (held at 0)

    def apply(self, weights: np.ndarray) -> np.ndarray:
        """Target weights (..., n_target) of source weights (..., n_source)."""
        return np.asarray(weights, np.float64) @ self.matrix.T

    def report(self) -> str:
        """One line naming what did not match (empty when everything did)."""
        def names(items: tuple[str, ...]) -> str:
            more = f" and {len(items) - 8} more" if len(items) > 8 else ""
            return ", ".join(items[:8]) + more

        parts = []
        if self.missing:
            parts.append(f"the avatar has no {names(self.missing)} (ignored)")
        if self.unset:
            parts.append(f"nothing drives {names(self.unset)}")
        return "; ".join(parts)


def match_names(source: list[str] | tuple[str, ...], target: list[str] | tuple[str, ...]) -> NameMatch:
    """Match `source` names (a capture's columns) to `target` names (an avatar basis's shapes).

    Raises ValueError when two source names mean the same shape or `source` has no name in common with
    `target` (a file with the wrong columns should not play as a neutral face).
    """
    src, tgt = tuple(str(s) for s in source), tuple(str(t) for t in target)
    tkeys: dict[str, int] = {}
    for j, t in enumerate(tgt):
        tkeys.setdefault(name_key(t), j)
    m = np.zeros((len(tgt), len(src)), np.float64)
    seen: dict[str, str] = {}
    missing, ignored = [], []
    for i, s in enumerate(src):
        if s.strip().lower() in IGNORED or name_key(s) in _ANGLE_KEYS:
            ignored.append(s)
            continue
        k = name_key(s)
        if k in seen:
            raise ValueError(f"names {seen[k]!r} and {s!r} are the same blendshape")
        seen[k] = s
        if k in tkeys:
            m[tkeys[k], i] = 1.0
        elif f"{k}|l" in tkeys and f"{k}|r" in tkeys:  # a symmetric shape the target splits into halves
            m[tkeys[f"{k}|l"], i] = m[tkeys[f"{k}|r"], i] = 1.0
        elif "|" in k and k.split("|")[0] in tkeys:  # one half of a shape the target has whole: average
            m[tkeys[k.split("|")[0]], i] = 0.5
        else:
            missing.append(s)
    if not (m != 0).any() and src:
        raise ValueError(f"no blendshape name in common with the avatar's ({', '.join(src[:4])}, ...)")
    unset = tuple(t for j, t in enumerate(tgt) if not (m[j] != 0).any())
    return NameMatch(m, src, tgt, tuple(missing), tuple(ignored), unset)


_ANGLE_KEYS = {name_key(n) for n in ANGLE_NAMES}
