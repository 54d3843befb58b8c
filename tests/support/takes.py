"""ARKit takes written as the apps write them: Live Link Face CSVs in the app's column order (the LiveLinkFace
Blender add-on's LIVE_LINK_FACE_HEADER), for the reader, timing and window tests."""

from __future__ import annotations

from npga_core.files.blendshape_names import ANGLE_NAMES, ARKIT_52

# The app's CSV column order (Blender add-on LIVE_LINK_FACE_HEADER), not the packet order.
CSV_SHAPES = [
    "EyeBlinkLeft", "EyeLookDownLeft", "EyeLookInLeft", "EyeLookOutLeft", "EyeLookUpLeft", "EyeSquintLeft",
    "EyeWideLeft", "EyeBlinkRight", "EyeLookDownRight", "EyeLookInRight", "EyeLookOutRight", "EyeLookUpRight",
    "EyeSquintRight", "EyeWideRight", "JawForward", "JawRight", "JawLeft", "JawOpen", "MouthClose",
    "MouthFunnel", "MouthPucker", "MouthRight", "MouthLeft", "MouthSmileLeft", "MouthSmileRight",
    "MouthFrownLeft", "MouthFrownRight", "MouthDimpleLeft", "MouthDimpleRight", "MouthStretchLeft",
    "MouthStretchRight", "MouthRollLower", "MouthRollUpper", "MouthShrugLower", "MouthShrugUpper",
    "MouthPressLeft", "MouthPressRight", "MouthLowerDownLeft", "MouthLowerDownRight", "MouthUpperUpLeft",
    "MouthUpperUpRight", "BrowDownLeft", "BrowDownRight", "BrowInnerUp", "BrowOuterUpLeft", "BrowOuterUpRight",
    "CheekPuff", "CheekSquintLeft", "CheekSquintRight", "NoseSneerLeft", "NoseSneerRight", "TongueOut",
]


def write_csv(path, rows: list[tuple[str, dict[str, float]]], head: bool = False) -> None:
    """A CSV in the app's layout; `rows` are (timecode, {shape or angle: value})."""
    cols = CSV_SHAPES + list(ANGLE_NAMES)
    lines = [",".join(["Timecode", "BlendShapeCount", *cols])]
    for tc, vals in rows:
        lines.append(",".join([tc, "61", *(f"{vals.get(c, 0.0):.6f}" for c in cols)]))
    path.write_text("\n".join(lines) + "\n")


# ------------------------------------------------------------------------------------------ names
def write_one_channel_take(path, rows: int, channel: str) -> None:
    """A Live Link Face CSV (its header: Timecode, BlendShapeCount, the 52 shapes, the 9 angles) moving one
    channel from 0 to 1 over the rows, at 30 Hz on a 60-count timecode as the app writes."""
    names = [n[0].upper() + n[1:] for n in ARKIT_52] + ["HeadYaw", "HeadPitch", "HeadRoll", "LeftEyeYaw",
                                                        "LeftEyePitch", "LeftEyeRoll", "RightEyeYaw",
                                                        "RightEyePitch", "RightEyeRoll"]
    lines = ["Timecode,BlendShapeCount," + ",".join(names)]
    col = ARKIT_52.index(channel)
    for r in range(rows):
        v = ["0"] * len(names)
        v[col] = f"{r / (rows - 1):.4f}"
        lines.append(f"10:00:{r // 30:02d}:{(2 * r) % 60:02d}.000,61," + ",".join(v))
    path.write_text("\n".join(lines) + "\n")
