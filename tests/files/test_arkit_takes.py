"""ARKit takes: name matching, the blendshape basis, Live Link Face CSV and ARKit JSON readers, and the demo.

Layouts are taken from their authors' code and real files:
- Live Link Face CSV header: the LiveLinkFace Blender add-on's ``LIVE_LINK_FACE_HEADER`` (Timecode,
  BlendShapeCount, EyeBlinkLeft, ..., JawForward, JawRight, JawLeft, ..., MouthRight, MouthLeft, ...,
  HeadYaw, HeadPitch, HeadRoll, LeftEyeYaw, ...): the app's CSV order, which differs from the packet order of
  PyLiveLinkFace (JimWest/PyLiveLinkFace, pylivelinkface/pylivelinkface.py lines 12-73: JawLeft = 15,
  JawRight = 16, MouthLeft = 21, MouthRight = 22); timecodes like ``14:03:52:28.207``.
- LAM Audio2Expression (aigc3d/LAM_Audio2Expression, models/utils.py lines 344-361): ``{"names": [...],
  "metadata": {"fps", "frame_count", "blendshape_names"}, "frames": [{"weights", "time", "rotation"}]}``.
- MediaPipe face landmarker: per face a list of categories (``index``, ``score``, ``categoryName``,
  ``displayName``; Python ``category_name``), the first being ``_neutral``.
"""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

from npga_core.errors import AvatarFileError
from npga_core.files.arkit_takes import (
    Take,
    read_arkit_json,
    read_livelink_csv,
    read_take,
    take_sequence,
    write_livelink_csv,
)
from npga_core.files.blendshape_names import ARKIT_52, canonical_arkit, match_names, name_key
from npga_core.files.loading import DEMO_AVATAR, load_sequence
from npga_core.model.blendshapes import BlendshapeBasis, fit
from tests.support.takes import CSV_SHAPES, write_csv

ICT_53 = ["browDown_L", "browDown_R", "browInnerUp_L", "browInnerUp_R", "browOuterUp_L", "browOuterUp_R",
          "cheekPuff_L", "cheekPuff_R", "cheekSquint_L", "cheekSquint_R", "eyeBlink_L", "eyeBlink_R",
          "eyeLookDown_L", "eyeLookDown_R", "eyeLookIn_L", "eyeLookIn_R", "eyeLookOut_L", "eyeLookOut_R",
          "eyeLookUp_L", "eyeLookUp_R", "eyeSquint_L", "eyeSquint_R", "eyeWide_L", "eyeWide_R", "jawForward",
          "jawLeft", "jawOpen", "jawRight", "mouthClose", "mouthDimple_L", "mouthDimple_R", "mouthFrown_L",
          "mouthFrown_R", "mouthFunnel", "mouthLeft", "mouthLowerDown_L", "mouthLowerDown_R", "mouthPress_L",
          "mouthPress_R", "mouthPucker", "mouthRight", "mouthRollLower", "mouthRollUpper", "mouthShrugLower",
          "mouthShrugUpper", "mouthSmile_L", "mouthSmile_R", "mouthStretch_L", "mouthStretch_R",
          "mouthUpperUp_L", "mouthUpperUp_R", "noseSneer_L", "noseSneer_R"]


def ict_basis(dim: int = 12, seed: int = 0) -> BlendshapeBasis:
    rng = np.random.default_rng(seed)
    return BlendshapeBasis(tuple(ICT_53), rng.standard_normal((dim, 53)), rng.standard_normal(dim), "test")


def test_every_spelling_of_an_arkit_name_has_one_key():
    for n in ("eyeBlinkLeft", "EyeBlinkLeft", "eyeBlink_L", "eye_blink_left", "EYEBLINKLEFT"):
        assert name_key(n) == name_key("eyeBlinkLeft"), n
        assert canonical_arkit(n) == "eyeBlinkLeft"
    assert name_key("jawLeft") != name_key("jaw_L")  # a direction, not a side
    assert canonical_arkit("JawLeft") == "jawLeft" and canonical_arkit("MouthRight") == "mouthRight"
    assert canonical_arkit("_neutral") is None and canonical_arkit("HeadYaw") is None
    assert sorted({canonical_arkit(n) for n in CSV_SHAPES}) == sorted(ARKIT_52)


def test_arkit_to_ict_splits_symmetric_shapes_and_reports_what_the_demo_lacks():
    m = match_names(["_neutral", *ARKIT_52], ICT_53)
    w = np.zeros(53)
    src = ["_neutral", *ARKIT_52]
    w[src.index("browInnerUp")] = 0.7
    w[src.index("cheekPuff")] = 0.4
    w[src.index("eyeBlinkLeft")] = 1.0
    w[src.index("jawLeft")] = 0.3
    out = dict(zip(ICT_53, m.apply(w), strict=True))
    assert out["browInnerUp_L"] == out["browInnerUp_R"] == 0.7
    assert out["cheekPuff_L"] == out["cheekPuff_R"] == 0.4
    assert out["eyeBlink_L"] == 1.0 and out["eyeBlink_R"] == 0.0
    assert out["jawLeft"] == 0.3 and out["jawRight"] == 0.0
    assert m.missing == ("tongueOut",) and m.ignored == ("_neutral",) and m.unset == ()
    assert "tongueOut" in m.report()


def test_name_matching_refuses_duplicates_and_no_overlap():
    with pytest.raises(ValueError, match="same blendshape"):
        match_names(["eyeBlinkLeft", "EyeBlink_L"], ICT_53)
    with pytest.raises(ValueError, match="no blendshape name in common"):
        match_names(["foo", "bar"], ICT_53)


# ------------------------------------------------------------------------------------------ basis


def test_basis_round_trips_through_arrays_and_fits_exact_pairs():
    b = ict_basis()
    again = BlendshapeBasis.from_arrays(b.header(), b.to_arrays())
    assert again.names == b.names and np.array_equal(again.matrix, b.matrix)
    w = np.random.default_rng(1).uniform(0, 1, (200, 53))
    f = fit(b.names, w, b.codes(w))
    assert f.rms < 1e-4 and f.relative < 1e-4
    np.testing.assert_allclose(f.basis.matrix, b.matrix, atol=1e-3)
    with pytest.raises(ValueError):
        BlendshapeBasis.from_arrays({"names": ["a"]}, {})


@pytest.mark.skipif(not DEMO_AVATAR.is_file(), reason="demo not built")
def test_demo_basis_is_the_map_it_is_built_with():
    from npga_core.demo.basis import basis_from_provenance, bundled_basis
    from npga_core.files.loading import load_avatar

    a = bundled_basis()
    b = basis_from_provenance(load_avatar("demo").provenance)
    assert a.names == b.names == tuple(ICT_53)
    np.testing.assert_array_equal(a.matrix, b.matrix)
    np.testing.assert_array_equal(a.offset, b.offset)
    # the avatar's named codes were encoded with the build's map (npga_core/demo/build.py: space.named)
    from npga_core.demo.expressions import named_weights

    named = load_avatar("demo").expression.named
    for key, w in named_weights(ICT_53).items():
        np.testing.assert_allclose(a.codes(w), named[key], atol=1e-5, err_msg=key)


# ------------------------------------------------------------------------------------------ CSV


def test_livelink_csv_columns_by_name_timecodes_rate_and_head(tmp_path):
    p = tmp_path / "take.csv"
    rows = [(f"14:03:52:{58 + k:02d}.207" if k < 2 else f"14:03:53:{k - 2:02d}.207",
             {"JawLeft": 0.1 * k, "EyeBlinkLeft": 0.9, "HeadYaw": 0.1, "HeadPitch": -0.05})
            for k in range(5)]
    write_csv(p, rows)
    t = read_livelink_csv(p)
    assert t.fps == 60.0  # FF reaches 59
    np.testing.assert_allclose(t.times, np.arange(5) / 60.0, atol=1e-9)
    col = dict(zip(t.names, t.weights.T, strict=True))
    np.testing.assert_allclose(col["JawLeft"], 0.1 * np.arange(5), atol=1e-6)
    assert np.all(col["JawRight"] == 0)  # the column next to it in the file, JawRight, stays 0
    assert t.head is not None and t.eyes is None  # eye angles all zero: not recorded
    seq, report = take_sequence(t, ict_basis(), p)
    assert "tongueOut".lower() in report.lower()
    assert seq.pose is not None and len(seq) == 5
    r = seq.pose[0, :3, :3]
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-9)


def test_dropped_frames_are_timed_by_their_timecodes(tmp_path):
    p = tmp_path / "gap.csv"
    # 30 fps, frames 0, 1, 3 (2 dropped): frame 2 is interpolated; the take ends at frame 0 of the next second
    rows = [(f"00:00:01:{f:02d}.000", {"JawOpen": f / 10}) for f in (0, 1, 3, 29)]
    write_csv(p, [*rows, ("00:00:02:00.000", {"JawOpen": 3.0})])
    t = read_livelink_csv(p)
    assert t.fps == 30.0
    seq = load_sequence(p, basis=BlendshapeBasis(("jawOpen",), np.eye(1), np.zeros(1)))
    assert len(seq) == 31 and seq.fps == 30.0
    np.testing.assert_allclose(seq.codes[:4, 0], [0.0, 0.1, 0.2, 0.3], atol=1e-6)


def test_sub_frame_jitter_keeps_one_row_per_frame(tmp_path):
    p = tmp_path / "jitter.csv"
    # real takes carry a varying sub-frame (".207", ".911"): still one frame each, nothing interpolated
    write_csv(p, [("00:00:01:58.207", {"JawOpen": 0.58}), ("00:00:01:59.911", {"JawOpen": 0.59}),
                  ("00:00:02:00.005", {"JawOpen": 0.6})])
    seq = load_sequence(p, basis=BlendshapeBasis(("jawOpen",), np.eye(1), np.zeros(1)))
    np.testing.assert_allclose(seq.codes[:, 0], [0.58, 0.59, 0.6], atol=1e-6)


def test_rate_within_one_second_is_live_link_faces_60():
    from npga_core.files.arkit_takes import timecode_rate

    assert timecode_rate(np.array([5.0, 5.0]), np.array([3.0, 4.0])) == 60.0
    assert timecode_rate(np.array([5.0, 6.0]), np.array([24.0, 0.0])) == 25.0
    assert timecode_rate(np.array([5.0, 6.0]), np.array([59.0, 0.0])) == 60.0


def test_recorded_take_reopens(tmp_path):
    rng = np.random.default_rng(3)
    take = Take(rng.uniform(0, 1, (7, 52)).astype(np.float32), ARKIT_52, np.arange(7) / 60.0, 60.0,
                head=rng.uniform(-0.2, 0.2, (7, 3)))
    p = tmp_path / "rec.csv"
    write_livelink_csv(p, take, start=3600.0 * 23 + 59 * 60 + 59.9)  # across midnight
    back = read_take(p)
    assert back.fps == 60.0 and back.names == ARKIT_52
    np.testing.assert_allclose(back.weights, take.weights, atol=1e-6)
    np.testing.assert_allclose(back.times, take.times, atol=1e-3)
    np.testing.assert_allclose(back.head, take.head, atol=1e-9)


@pytest.mark.parametrize("text, match", [
    ("", "empty"),
    ("a,b\n1,2\n", "Timecode"),
    ("Timecode,EyeBlinkLeft\n00:00:00:00.000,nan\n", "NaN"),
    ("Timecode,EyeBlinkLeft\n00:00:00:00.000,0.1\n00:00:00:01.000\n", "fields"),
    ("Timecode,EyeBlinkLeft\nbogus,0.1\n", "timecode"),
    ("Timecode,EyeBlinkLeft\n00:00:00:01.000,0.1\n00:00:00:00.000,0.1\n", "increase"),
    ("Timecode,EyeBlinkLeft\n00:00:00:00.000,1e300\n", "weights reach"),
    ("Timecode,Foo,Bar\n00:00:00:00.000,0.1,0.2\n", "in common"),
    ("Timecode,EyeBlinkLeft,eyeblinkleft\n00:00:00:00.000,0.1,0.2\n", "repeated"),
])
def test_bad_csv_is_one_line_naming_the_file(tmp_path, text, match):
    p = tmp_path / "bad.csv"
    p.write_text(text)
    with pytest.raises(AvatarFileError, match=match) as e:
        load_sequence(p, basis=ict_basis())
    assert str(p) in str(e.value) and "\n" not in str(e.value)


# ------------------------------------------------------------------------------------------ JSON


def test_lam_json(tmp_path):
    w = np.random.default_rng(2).uniform(0, 1, (4, 52))
    doc = {"names": list(ARKIT_52), "metadata": {"fps": 30, "frame_count": 4, "blendshape_names": list(ARKIT_52)},
           "frames": [{"weights": w[i].tolist(), "time": i / 30, "rotation": []} for i in range(4)]}
    p = tmp_path / "lam.json"
    p.write_text(json.dumps(doc))
    t = read_arkit_json(p)
    assert t.fps == 30.0 and t.names == ARKIT_52
    np.testing.assert_allclose(t.weights, w, atol=1e-6)
    b = ict_basis()
    seq = load_sequence(p, basis=b)
    m = match_names(ARKIT_52, ICT_53)
    np.testing.assert_allclose(seq.codes, b.codes(m.apply(w)), atol=1e-5)


def test_mediapipe_category_lists_and_plain_series(tmp_path):
    cats = [[{"index": 0, "score": 0.9, "categoryName": "_neutral", "displayName": ""},
             {"index": 1, "score": 0.2 * i, "categoryName": "eyeBlinkLeft", "displayName": ""}]
            for i in range(3)]
    p = tmp_path / "mp.json"
    p.write_text(json.dumps({"fps": 25, "frames": [{"faceBlendshapes": [{"categories": c}]} for c in cats]}))
    t = read_arkit_json(p)
    assert t.fps == 25 and t.names == ("_neutral", "eyeBlinkLeft")
    seq = load_sequence(p, basis=BlendshapeBasis(("eyeBlink_L",), np.eye(1), np.zeros(1)))
    np.testing.assert_allclose(seq.codes[:, 0], [0.0, 0.2, 0.4], atol=1e-6)
    q = tmp_path / "py.json"
    q.write_text(json.dumps([[{"category_name": "jawOpen", "score": 0.5}]]))
    assert read_arkit_json(q).weights.tolist() == [[0.5]]
    r = tmp_path / "plain.json"
    r.write_text(json.dumps({"fps": 50, "jawOpen": [0.0, 0.5], "eyeBlinkLeft": [1.0, 0.0]}))
    t = read_arkit_json(r)
    assert t.fps == 50 and t.weights.shape == (2, 2)


@pytest.mark.parametrize("doc, match", [
    ({"names": ["jawOpen"], "frames": [{"weights": [0.1, 0.2]}]}, "weights"),
    ({"jawOpen": [0.1], "eyeBlinkLeft": [0.1, 0.2]}, "lengths"),
    ([[{"categoryName": "jawOpen", "score": "x"}]], "number"),
    ({"names": ["jawOpen"], "frames": [{"weights": [0.1], "time": 1}, {"weights": [0.1], "time": 1}]}, "increase"),
    (42, "no ARKit take"),
    ({"names": ["jawOpen"], "frames": []}, "no frames"),
])
def test_bad_json_is_one_line_naming_the_file(tmp_path, doc, match):
    p = tmp_path / "bad.json"
    p.write_text(json.dumps(doc))
    with pytest.raises(AvatarFileError, match=match) as e:
        load_sequence(p, basis=ict_basis())
    assert str(p) in str(e.value)


# ------------------------------------------------------------------------------------------ the demo


@pytest.mark.slow
@pytest.mark.skipif(not DEMO_AVATAR.is_file(), reason="demo not built")
def test_export_of_a_take_frame_equals_export_of_its_code(tmp_path):
    from npga_core.demo.basis import bundled_basis
    from npga_view.cli.main import main

    p = tmp_path / "take.csv"
    write_csv(p, [("10:00:00:00.000", {}), ("10:00:00:01.000", {"EyeBlinkLeft": 1.0, "BrowInnerUp": 0.5})])
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # what did not match is a note of the sequence, not a Python warning
        seq = load_sequence(p)
    assert len(seq.notes) == 1 and "no tongueOut" in seq.notes[0].replace("TongueOut", "tongueOut") \
        and str(p) in seq.notes[0]
    b = bundled_basis()
    w = np.zeros(53)
    w[ICT_53.index("eyeBlink_L")] = 1.0
    w[ICT_53.index("browInnerUp_L")] = w[ICT_53.index("browInnerUp_R")] = 0.5
    np.testing.assert_allclose(seq.codes[1], b.codes(w), atol=1e-6)
    z = tmp_path / "z.npy"
    np.save(z, b.codes(w))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(["export", "demo", "--out", str(tmp_path / "a.ply"), "--sequence", str(p), "--frame", "1"]) == 0
    assert main(["export", "demo", "--out", str(tmp_path / "b.ply"), "--expr", str(z)]) == 0
    from npga_core.files.ply import read_ply

    a, c = read_ply(tmp_path / "a.ply"), read_ply(tmp_path / "b.ply")
    np.testing.assert_allclose(a.means, c.means, atol=1e-5)


@pytest.mark.slow
@pytest.mark.skipif(not DEMO_AVATAR.is_file(), reason="demo not built")
def test_eye_blink_left_closes_the_demos_left_eye(tmp_path):
    from npga_core.files.loading import load_avatar

    p = tmp_path / "blink.csv"
    write_csv(p, [("10:00:00:00.000", {}), ("10:00:00:01.000", {"EyeBlinkLeft": 1.0})])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        seq = load_sequence(p)
    avatar = load_avatar("demo")
    rest, blink = avatar.pose(seq.codes[0]).means, avatar.pose(seq.codes[1]).means
    moved = np.linalg.norm(blink - rest, axis=1) > 0.002  # 2 mm
    assert moved.sum() > 50
    assert (rest[moved, 0] > 0).mean() > 0.95  # +x is the subject's left (npga_core/demo/ict.py GazeModel)


def _take_files(tmp_path, w: np.ndarray) -> dict[str, object]:
    """The same T x 52 weights (over ARKIT_52) as a Live Link Face CSV in the app's column order, one in the
    packet order (PyLiveLinkFace, pylivelinkface.py lines 12-73: JawLeft before JawRight), and a LAM JSON."""
    paths = {}
    by_name = [dict(zip(ARKIT_52, row, strict=True)) for row in w]
    for name, cols in (("app_order", CSV_SHAPES), ("packet_order", [n[0].upper() + n[1:] for n in ARKIT_52])):
        lines = [",".join(["Timecode", "BlendShapeCount", *cols])]
        for k, vals in enumerate(by_name):
            lines.append(",".join([f"10:00:00:{k:02d}.000", "61",
                                   *(f"{vals[canonical_arkit(c)]:.9g}" for c in cols)]))
        p = tmp_path / f"{name}.csv"
        p.write_text("\n".join(lines) + "\n")
        paths[name] = p
    doc = {"names": list(ARKIT_52), "metadata": {"fps": 60, "frame_count": len(w)},
           "frames": [{"weights": row.tolist(), "time": k / 60, "rotation": []} for k, row in enumerate(w)]}
    paths["lam_json"] = tmp_path / "lam.json"
    paths["lam_json"].write_text(json.dumps(doc))
    return paths


@pytest.mark.skipif(not DEMO_AVATAR.is_file(), reason="demo not built")
def test_the_demo_file_carries_its_basis():
    """The bundled .npga stores the map it is built with (format version 3), equal to the one derived from the
    build's seed; `info` shows it."""
    from npga_core.demo.basis import basis_from_provenance
    from npga_core.files.checkpoint import read_header
    from npga_core.files.loading import load_avatar

    avatar = load_avatar("demo")
    b = avatar.blendshapes
    assert b is not None and list(b.names) == ICT_53 and b.code_dim == avatar.code_dim
    ref = basis_from_provenance(avatar.provenance)
    np.testing.assert_allclose(b.matrix, ref.matrix, atol=1e-7)
    np.testing.assert_allclose(b.offset, ref.offset, atol=1e-7)
    assert read_header(DEMO_AVATAR)[0]["format_version"] == 3


@pytest.mark.slow
@pytest.mark.skipif(not DEMO_AVATAR.is_file(), reason="demo not built")
def test_every_frame_of_each_take_layout_poses_the_demo_as_its_weights_say(tmp_path, capsys):
    """Both CSV column orders and a JSON take: every frame's code is the demo's map of its weights, and `export
    --sequence TAKE --frame K` writes the same Gaussians as `export --expr z` (the avatar's own basis, no flag)."""
    from npga_core.files.loading import load_avatar
    from npga_core.files.ply import read_ply
    from npga_view.cli.main import main

    basis = load_avatar("demo").blendshapes
    rng = np.random.default_rng(7)
    w = rng.uniform(0, 1, (4, 52)) * (rng.uniform(0, 1, (4, 52)) < 0.3)
    w[:, ARKIT_52.index("tongueOut")] = 0.0  # the demo has no tongueOut
    want = basis.codes(match_names(ARKIT_52, basis.names).apply(w))
    assert main(["info", "demo"]) == 0
    assert "blendshapes: 53 -> 100-D codes" in capsys.readouterr().out
    for name, path in _take_files(tmp_path, w).items():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            seq = load_sequence(path, basis=basis)
        assert len(seq) == 4, name
        np.testing.assert_allclose(seq.codes, want, atol=1e-6, err_msg=name)
        k = 2
        z = tmp_path / "z.npy"
        np.save(z, want[k])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            assert main(["export", "demo", "--out", str(tmp_path / "a.ply"), "--sequence", str(path),
                         "--frame", str(k)]) == 0
        assert main(["export", "demo", "--out", str(tmp_path / "b.ply"), "--expr", str(z)]) == 0
        a, c = read_ply(tmp_path / "a.ply"), read_ply(tmp_path / "b.ply")
        np.testing.assert_allclose(a.means, c.means, atol=1e-6, err_msg=name)
        np.testing.assert_allclose(a.sh, c.sh, atol=1e-6, err_msg=name)


def test_export_uses_the_avatars_own_basis(tmp_path):
    """A take opened on an avatar whose file carries a basis goes through that basis, not the demo's."""
    from npga_core.files.checkpoint import save_avatar
    from npga_core.model.synthetic import make_synthetic_avatar
    from npga_view.cli.export import expression_code
    from npga_view.cli.main import build_parser

    avatar = make_synthetic_avatar(20, code_dim=6, hidden=8, depth=2, n_components=3)
    avatar.blendshapes = BlendshapeBasis(("jawOpen", "eyeBlinkLeft"), np.arange(12.0).reshape(6, 2),
                                         np.full(6, 0.5), "test")
    path = tmp_path / "own.npga"
    save_avatar(avatar, path)
    take = tmp_path / "t.csv"
    write_csv(take, [("10:00:00:00.000", {"JawOpen": 0.25, "EyeBlinkLeft": 1.0})])
    from npga_core.files.loading import load_avatar

    loaded = load_avatar(path)
    args = build_parser().parse_args(["export", str(path), "--out", str(tmp_path / "o.ply"), "--sequence",
                                      str(take), "--frame", "0"])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        z, _ = expression_code(args, loaded)
    np.testing.assert_allclose(z, avatar.blendshapes.codes(np.array([0.25, 1.0])), atol=1e-6)
