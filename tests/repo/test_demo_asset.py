"""The shipped demo avatar (assets/demo): structure, expression space, sequences, and that it animates.

Skipped only when the asset has not been built (`python -m npga_core.demo.build`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from npga_core.demo.expression_map import ExpressionMap
from npga_core.files.loading import load_avatar, load_sequence
from npga_core.inspection.graph import knn
from npga_core.model.avatar import Avatar
from npga_core.model.gaussians import sigmoid

DEMO = Path(__file__).resolve().parents[2] / "assets" / "demo"
AVATAR = DEMO / "avatar.npga"
PARTS = {"face", "head_neck", "mouth_socket", "gums_tongue", "teeth", "sclera_l", "sclera_r", "iris_l", "iris_r"}
NAMED = {"neutral", "jaw_open", "smile", "blink", "brows_up", "frown", "surprise"}

pytestmark = [pytest.mark.slow, pytest.mark.skipif(not AVATAR.is_file(), reason="demo avatar not built")]


@pytest.fixture(scope="module")
def avatar() -> Avatar:
    return load_avatar(AVATAR)


@pytest.fixture(scope="module")
def neutral(avatar: Avatar):
    return avatar.pose(avatar.expression.named["neutral"])


def part_mask(avatar: Avatar, name: str) -> np.ndarray:
    return np.asarray(avatar.cloud.part_ids) == avatar.cloud.part_names.index(name)


def test_files_and_size() -> None:
    assert AVATAR.stat().st_size <= 40 * 2**20
    assert (DEMO / "LICENSE.ict-facekit").read_text().strip().startswith("MIT")  # the kit's licence travels
    assert (DEMO / "README.txt").is_file()
    assert len(list((DEMO / "sequences").glob("*.npzseq"))) >= 3


def test_cloud_structure(avatar: Avatar) -> None:
    c = avatar.cloud
    assert 50_000 <= len(c) <= 150_000
    assert avatar.units == "m"
    assert c.sh_degree == 1 and c.feature_dim == 8 and 4 <= c.latent_dim <= 8
    assert set(c.part_names) >= PARTS
    counts = np.bincount(np.asarray(c.part_ids), minlength=len(c.part_names))
    for name in PARTS:
        assert counts[c.part_names.index(name)] > 100, name
    for name, arr in c.arrays().items():
        if arr.dtype.kind == "f":
            assert np.isfinite(arr).all(), name
    assert np.median(sigmoid(c.opacity_logits)) > 0.9
    extent = np.ptp(np.asarray(c.means), axis=0)
    assert np.all((extent > 0.15) & (extent < 0.45)), extent  # a head in metres
    # flat discs: the thinnest axis is much thinner than the others
    s = np.sort(np.exp(np.asarray(c.log_scales)), axis=1)
    assert np.median(s[:, 0] / s[:, 1]) < 0.3
    # features vary over the surface but smoothly: kNN neighbours are far more alike than random pairs
    f = np.asarray(c.features)
    assert f.std(axis=0).min() > 1e-3
    rows = np.random.default_rng(0).choice(len(c), 5000, replace=False)
    nbrs = knn(np.asarray(c.means), 8)[rows]
    near = np.linalg.norm(f[nbrs] - f[rows, None], axis=2).mean()
    far = np.linalg.norm(f[np.random.default_rng(1).permutation(rows)] - f[rows], axis=1).mean()
    assert near < 0.3 * far


def test_dynamics_and_expression_space(avatar: Avatar) -> None:
    assert avatar.dynamics is not None and avatar.dynamics.F is not None and avatar.dynamics.G is not None
    assert avatar.code_dim == 100
    for net in avatar.dynamics.networks().values():
        assert net.config.depth == 6 and net.config.hidden == 256 and net.config.feature_dim == 8
    ex = avatar.expression
    ex.validate()
    assert ex.dim == 100
    assert 10 <= ex.n_components <= 53  # codes live in the 53-D image of the blendshape map
    assert set(ex.named) >= NAMED
    for code in ex.named.values():
        assert code.shape == (100,) and np.isfinite(code).all()


def test_neutral_code_leaves_the_canonical_cloud_in_place(avatar: Avatar, neutral) -> None:
    moved = np.linalg.norm(neutral.means - np.asarray(avatar.cloud.means), axis=1)
    assert np.percentile(moved, 99) < 0.5e-3  # metres


def test_jaw_open_moves_the_chin_down_and_not_the_back_of_the_head(avatar: Avatar, neutral) -> None:
    posed = avatar.pose(avatar.expression.named["jaw_open"])
    m = np.asarray(avatar.cloud.means)
    d = posed.means - neutral.means
    face = part_mask(avatar, "face")
    lip_marks_y = m[part_mask(avatar, "teeth"), 1].min()  # lowest tooth: below it lies the chin
    chin = face & (np.abs(m[:, 0]) < 0.015) & (m[:, 1] < lip_marks_y - 0.01) & (m[:, 1] > lip_marks_y - 0.04) \
        & (m[:, 2] > np.percentile(m[face, 2], 80))
    assert chin.sum() > 30
    down = -d[chin, 1]
    assert 0.008 < np.median(down) < 0.05, np.median(down)  # 8 mm .. 5 cm
    back = part_mask(avatar, "head_neck") & (m[:, 2] < np.percentile(m[:, 2], 10)) & (m[:, 1] > 0.0)
    assert back.sum() > 100
    assert np.percentile(np.linalg.norm(d[back], axis=1), 99) < 1e-3
    # the teeth of the lower jaw go down with it, the upper ones stay
    teeth = part_mask(avatar, "teeth")
    assert np.percentile(-d[teeth, 1], 90) > 0.008 and np.percentile(-d[teeth, 1], 10) < 0.002


def test_blink_closes_the_upper_eyelids(avatar: Avatar, neutral) -> None:
    posed = avatar.pose(avatar.expression.named["blink"])
    m = np.asarray(avatar.cloud.means)
    d = posed.means - neutral.means
    eyes = [np.asarray(avatar.cloud.means)[part_mask(avatar, n)].mean(axis=0) for n in ("iris_l", "iris_r")]
    for centre in eyes:
        near = (np.linalg.norm(m[:, :2] - centre[:2], axis=1) < 0.012) & part_mask(avatar, "face")
        upper = near & (m[:, 1] > centre[1] + 0.004)
        assert upper.sum() > 10
        assert np.percentile(-d[upper, 1], 90) > 0.004


def test_sequences(avatar: Avatar) -> None:
    names = set()
    for path in sorted((DEMO / "sequences").glob("*.npzseq")):
        seq = load_sequence(path)
        seq.check_dim(avatar.code_dim, path)
        assert seq.fps == 25.0
        assert 10.0 <= seq.duration <= 20.0
        assert np.isfinite(seq.codes).all()
        # codes stay where the avatar was trained: within a few standard deviations of the expression space
        s = avatar.expression.to_sliders(seq.codes)
        assert np.abs(s).max() < 10.0
        names.add(path.stem)
    assert {"talking", "emotions", "blinks_gaze"} <= names


def test_sequences_have_realistic_timing() -> None:
    """Decode the codes with the shipped expression map and check the blendshape curves themselves."""
    with np.load(DEMO / "expression_map.npz", allow_pickle=False) as f:
        emap = ExpressionMap(f["M"], f["b"], tuple(str(n) for n in f["names"]))
    assert np.allclose(emap.matrix.T @ emap.matrix, np.eye(len(emap.names)), atol=1e-5)

    def weights(name: str) -> np.ndarray:
        return emap.decode(load_sequence(DEMO / "sequences" / f"{name}.npzseq").codes)

    ix = emap.names.index
    w = weights("blinks_gaze")
    assert w.min() > -0.01 and w.max() < 1.01
    blink = w[:, ix("eyeBlink_L")]
    closed = blink > 0.05
    onsets = np.flatnonzero(closed[1:] & ~closed[:-1]) + 1
    ends = np.flatnonzero(closed[:-1] & ~closed[1:]) + 1
    assert len(onsets) >= 3
    durations = (ends[: len(onsets)] - onsets[: len(ends)]) / 25.0
    assert np.all((durations >= 0.08) & (durations <= 0.32)), durations
    assert np.diff(onsets).max() / 25.0 <= 6.5
    assert blink.max() > 0.9  # blinks close the eyes
    gaze = w[:, [ix(n) for n in emap.names if n.startswith("eyeLook")]]
    assert gaze.max() > 0.3 and np.abs(np.diff(gaze, axis=0)).max() > 0.2  # saccades
    talk = weights("talking")
    assert talk[:, ix("jawOpen")].std() > 0.05 and talk[:, ix("mouthPucker")].max() > 0.3
    emo = weights("emotions")
    assert emo[:, ix("mouthSmile_L")].max() > 0.7 and emo[:, ix("browInnerUp_L")].max() > 0.7


def test_latent_features_g_offsets_and_cnn(avatar: Avatar, neutral) -> None:
    """The refine stage's additions (npga_core/demo/refine_stage.py): h, G's latent block and a trained CNN."""
    h = np.asarray(avatar.cloud.latent)
    assert np.isfinite(h).all() and (h.std(axis=0) > 1e-3).all()
    g = avatar.dynamics.G
    assert [n for n, _ in g.config.outputs] == ["rotation", "scale", "sh", "latent"]
    assert dict(g.config.outputs)["latent"] == h.shape[1]
    cnn = avatar.cnn
    assert cnn is not None and cnn.config.residual and cnn.config.in_channels == 3 + h.shape[1]
    assert all(layer.kernel % 2 == 1 for layer in cnn.config.layers)
    # G moves h with the expression (the latent image is not the same at every expression)
    jaw = avatar.pose(avatar.expression.named["jaw_open"])
    moved = np.abs(jaw.latent - neutral.latent).max(axis=1)
    assert np.percentile(moved, 99) > 0.01
    # trained, not set by hand: the build recorded held-out metrics where the CNN beats the raw splats
    r = avatar.provenance["refine"]
    m = r["held_out"]
    assert m["crops"] >= 8
    assert m["cnn_psnr"] > m["raw_psnr"] and m["cnn_ssim"] > m["raw_ssim"]
    assert r["loss_first_last"][1] < r["loss_first_last"][0]


def test_cnn_refines_a_render_without_destroying_it(avatar: Avatar, neutral) -> None:
    """Through the numpy splat rasteriser (no GL here): the CNN changes the image where the head is, by a small
    amount (a refinement, not a new picture)."""
    import torch

    from npga_core.camera.cameras import frame_points
    from npga_core.demo.mesh_raster import crop_camera
    from npga_core.demo.splat_raster import rasterize_splats

    m = np.asarray(avatar.cloud.means)
    view = frame_points(m[m[:, 1] > np.percentile(m[:, 1], 12)], 550, 802, margin=1.02)
    cam = crop_camera(view, 140, 230, 280, 160)  # eyes and nose bridge
    img = rasterize_splats(neutral.means, neutral.quats, neutral.scales, neutral.opacities, neutral.sh, cam,
                           fov_camera=view)
    latent = img.composite(torch.from_numpy(neutral.latent)).numpy()
    raw = img.over((0.0, 0.0, 0.0))
    out = avatar.cnn.refine(np.concatenate([raw, latent], axis=2))
    diff = np.abs(out - np.clip(raw, 0, 1)).mean(axis=2)
    head = img.alpha > 0.99
    assert 0.002 < diff[head].mean() < 0.08
