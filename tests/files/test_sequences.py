"""Sequence files: the project's format, npz/npy, MonoNPHM tracking folders, dimension checks."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from npga_core.errors import AvatarFileError
from npga_core.files.loading import load_sequence
from npga_core.files.sequences import ExpressionSequence


def test_own_format_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    seq = ExpressionSequence(rng.standard_normal((30, 100)).astype(np.float32), 30.0, "talk",
                             rotation=rng.standard_normal((30, 3)).astype(np.float32),
                             translation=np.zeros((30, 3), np.float32), scale=np.ones(30, np.float32),
                             frame_names=[f"{i:05d}" for i in range(30)])
    seq.save(tmp_path / "s.npzseq")
    back = load_sequence(tmp_path / "s.npzseq")
    assert np.array_equal(back.codes, seq.codes) and back.fps == 30.0 and back.name == "talk"
    assert np.array_equal(back.pose, seq.pose) and back.frame_names == seq.frame_names
    assert back.pose.shape == (30, 4, 4)
    assert back.pose_source == seq.pose_source == "x_world = s R x + t (rotation axis-angle)"
    assert back.duration == pytest.approx(1.0)
    with np.load(tmp_path / "s.npzseq") as z:  # the 4x4 is what is written
        assert {"pose", "pose_source"} <= set(z.files) and not {"rotation", "translation", "scale"} & set(z.files)


@pytest.mark.parametrize("key", ["expression", "expr", "z_exp"])
def test_npz_common_keys(tmp_path, key):
    codes = np.arange(12, dtype=np.float32).reshape(4, 3)
    np.savez(tmp_path / "e.npz", **{key: codes})
    assert np.array_equal(load_sequence(tmp_path / "e.npz").codes, codes)


def test_plain_npy(tmp_path):
    codes = np.ones((5, 100), np.float64)
    np.save(tmp_path / "c.npy", codes)
    s = load_sequence(tmp_path / "c.npy", fps=50)
    assert s.codes.shape == (5, 100) and s.codes.dtype == np.float32 and s.fps == 50


def _mononphm(root, stage, t=4, d=100):
    """Frame folders as MonoNPHM's Tracker.rec_and_save writes them (src/mononphm/photometric_tracking/
    tracking.py L1236-1261): z_exp.npy the frame's (1, D) row in stage 1, the whole (T, D) table in stage 2
    (L1239); rot.npy so3_exp_map of an axis-angle, (1, 3, 3); trans.npy (1, 3); scale.npy (1,)."""
    table = np.random.default_rng(1).standard_normal((t, d)).astype(np.float32)
    for i in range(t):
        f = root / f"{i:05d}"
        f.mkdir(parents=True)
        np.save(f / "z_exp.npy", table[i : i + 1] if stage == 1 else table)
        np.save(f / "rot.npy", Rotation.from_rotvec([0.0, 0.1 * i, 0.0]).as_matrix()[None].astype(np.float32))
        np.save(f / "trans.npy", np.full((1, 3), 0.01 * i, np.float32))
        np.save(f / "scale.npy", np.full((1,), 1.1, np.float32))
    return table


@pytest.mark.parametrize("stage", [1, 2])
def test_mononphm_folders(tmp_path, stage):
    table = _mononphm(tmp_path / "track", stage)
    s = load_sequence(tmp_path / "track")
    assert np.array_equal(s.codes, table) and s.frame_names == ["00000", "00001", "00002", "00003"]
    assert s.pose.shape == (4, 4, 4) and s.pose_source.startswith("MonoNPHM")
    # the world -> NPHM pose inverted: frame i turns by -0.1 i about y, scaled by 1 / 1.1
    np.testing.assert_allclose(s.pose[:, :3, :3] * 1.1,
                               Rotation.from_rotvec(np.outer(-0.1 * np.arange(4), [0, 1, 0])).as_matrix(), atol=1e-6)


def test_bad_sequences(tmp_path):
    np.save(tmp_path / "nan.npy", np.full((3, 4), np.nan))
    np.savez(tmp_path / "nokey.npz", foo=np.zeros((2, 2)))
    np.save(tmp_path / "obj.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)
    (tmp_path / "trunc.npzseq").write_bytes(b"PK\x03\x04garbage")
    (tmp_path / "empty").mkdir()
    for name, msg in [("nan.npy", "NaN"), ("nokey.npz", "no expression array"), ("obj.npy", "npy"),
                      ("trunc.npzseq", "npz"), ("empty", "no frame folders"), ("missing.npy", "no such file")]:
        with pytest.raises(AvatarFileError, match=msg) as e:
            load_sequence(tmp_path / name)
        assert "\n" not in str(e.value)


def test_dimension_check_names_both_numbers():
    s = ExpressionSequence(np.zeros((2, 64), np.float32))
    with pytest.raises(AvatarFileError, match="64 dims, the avatar expects 100"):
        s.check_dim(100, "x.npy")


def test_mononphm_rotation_matrices_with_three_frames(tmp_path):
    import math

    for i in range(3):
        f = tmp_path / "t" / f"{i:05d}"
        f.mkdir(parents=True)
        np.save(f / "z_exp.npy", np.zeros((1, 5), np.float32))
        a = 0.1 * (i + 1)
        rot = np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]], np.float32)
        np.save(f / "rot.npy", rot)
    s = load_sequence(tmp_path / "t")  # (3, 3) matrices, no trans.npy or scale.npy: those are the identity
    np.testing.assert_allclose(Rotation.from_matrix(s.pose[:, :3, :3]).as_rotvec(),
                               [[-0.1, 0, 0], [-0.2, 0, 0], [-0.3, 0, 0]], atol=1e-6)
    np.testing.assert_allclose(s.pose[:, :3, 3], 0.0)


def test_npz_with_bad_fps_or_names_is_a_clean_error(tmp_path):
    np.savez(tmp_path / "a.npz", codes=np.zeros((3, 4)), fps=np.ones(3))
    np.savez(tmp_path / "b.npz", codes=np.zeros((3, 4)), frame_names=np.array(["x", "y"]))
    for name in ("a.npz", "b.npz"):
        with pytest.raises(AvatarFileError):
            load_sequence(tmp_path / name)
