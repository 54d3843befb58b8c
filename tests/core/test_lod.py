"""Level-of-detail clouds (npga_core.model.lod): the 3x3 eigen-solver, the k-d grouping and the moment-matched
merge against dense formulas computed here, and a merged demo avatar against the full one on screen."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from npga_core.model import lod
from npga_core.model.gaussians import PosedGaussians, normalize_quats


def sym(c6: np.ndarray) -> np.ndarray:
    """(N, 3, 3) matrices from entries (xx, yy, zz, xy, xz, yz)."""
    xx, yy, zz, xy, xz, yz = np.asarray(c6, np.float64).T
    return np.stack([np.stack([xx, xy, xz], -1), np.stack([xy, yy, yz], -1), np.stack([xz, yz, zz], -1)], -2)


def entries(m: np.ndarray) -> np.ndarray:
    return np.stack([m[:, 0, 0], m[:, 1, 1], m[:, 2, 2], m[:, 0, 1], m[:, 0, 2], m[:, 1, 2]], axis=1)


def rotated(diag, n: int = 100, seed: int = 1) -> np.ndarray:
    """Entries of R diag(d) R^T for `n` random rotations R."""
    r = Rotation.random(n, random_state=seed).as_matrix()
    return entries(r @ (np.asarray(diag, np.float64)[None, :, None] * r.transpose(0, 2, 1)))


def covariances(quats: np.ndarray, scales: np.ndarray) -> np.ndarray:
    """R diag(s^2) R^T (N, 3, 3) from (w, x, y, z) quaternions, via scipy."""
    r = Rotation.from_quat(np.asarray(quats, np.float64)[:, [1, 2, 3, 0]]).as_matrix()
    return r @ (np.asarray(scales, np.float64)[:, :, None] ** 2 * r.transpose(0, 2, 1))


def random_cloud(n: int, seed: int = 0, latent_dim: int = 4) -> PosedGaussians:
    rng = np.random.default_rng(seed)
    return PosedGaussians(
        means=rng.uniform(-1.0, 1.0, (n, 3)).astype(np.float32),
        quats=normalize_quats(rng.normal(size=(n, 4))),
        scales=np.exp(rng.uniform(np.log(0.005), np.log(0.05), (n, 3))).astype(np.float32),
        opacities=rng.uniform(0.05, 1.0, n).astype(np.float32),
        sh=rng.normal(size=(n, 4, 3)).astype(np.float32),
        latent=rng.normal(size=(n, latent_dim)).astype(np.float32) if latent_dim else None)


def check_eigh(c6: np.ndarray, tol: float = 1e-9) -> tuple[np.ndarray, np.ndarray]:
    """eigh3 gives a proper rotation whose columns reconstruct the matrix; eigenvalues descending, as LAPACK's."""
    lam, rot = lod.eigh3(c6)
    m = sym(c6)
    size = np.abs(m).max(axis=(1, 2))[:, None, None] + 1e-300
    assert np.isfinite(lam).all() and np.isfinite(rot).all()
    assert np.all(np.abs(rot @ (lam[:, :, None] * rot.transpose(0, 2, 1)) - m) <= tol * size)
    assert np.allclose(rot.transpose(0, 2, 1) @ rot, np.eye(3), atol=1e-12)
    assert np.allclose(np.linalg.det(rot), 1.0, atol=1e-12)
    assert np.all(lam[:, :-1] >= lam[:, 1:] - 1e-12 * size[:, :, 0])  # descending (equal ones within rounding)
    assert np.all(np.abs(lam - np.linalg.eigvalsh(m)[:, ::-1]) <= tol * size[:, :, 0])
    return lam, rot


# --- eigh3 --------------------------------------------------------------------------------------------------
def test_eigh3_random_spd_matches_lapack():
    rng = np.random.default_rng(0)
    b = rng.normal(size=(2000, 3, 3))
    c6 = entries(b @ b.transpose(0, 2, 1) + 1e-3 * np.eye(3))
    lam, rot = check_eigh(c6)
    ref_lam, ref_vec = np.linalg.eigh(sym(c6))
    assert np.allclose(lam, ref_lam[:, ::-1], rtol=1e-9, atol=0)
    # well separated eigenvalues: the same eigenvectors up to sign
    dots = np.abs(np.einsum("nik,nik->nk", rot, ref_vec[:, :, ::-1]))
    assert np.allclose(dots, 1.0, atol=1e-6)


@pytest.mark.parametrize("name, c6", [
    ("isotropic", np.array([[2.5, 2.5, 2.5, 0, 0, 0], [1e-8, 1e-8, 1e-8, 0, 0, 0]])),
    ("zero", np.zeros((3, 6))),
    ("larger pair equal", rotated([2.0, 2.0, 1.0])),
    ("smaller pair equal", rotated([3.0, 1.0, 1.0])),
    ("diagonal distinct", np.array([[3, 1, 2, 0, 0, 0], [1, 2, 3, 0, 0, 0], [1e-3, 5, 1e3, 0, 0, 0.0]])),
    ("rank 1", rotated([1.0, 0.0, 0.0])),
    ("rank 2", rotated([1.0, 1.0, 0.0])),
    ("nearly repeated", rotated([1.0, 1.0 + 1e-10, 0.5])),
    ("tiny", rotated([3.0, 2.0, 1.0]) * 1e-16),
    ("tiny, repeated", rotated([3.0, 3.0, 1.0]) * 1e-16),
    ("large", rotated([3.0, 2.0, 1.0]) * 1e12),
])
def test_eigh3_degenerate(name, c6):
    # repeated eigenvalues cost the closed form's arccos about half the digits (~5e-9 measured), nothing more
    check_eigh(c6, tol=1e-7)


# --- kd_clusters --------------------------------------------------------------------------------------------
def test_kd_clusters_partition_compact_deterministic():
    pts = np.random.default_rng(2).random((5000, 3))
    labels = lod.kd_clusters(pts, 20)
    assert labels.shape == (5000,)
    k = labels.max() + 1
    sizes = np.bincount(labels)
    assert sizes.shape == (k,) and sizes.min() >= 1 and sizes.max() <= 20
    diag = [np.linalg.norm(np.ptp(pts[labels == c], axis=0)) for c in range(k)]
    assert np.mean(diag) < 0.2 * np.sqrt(3.0)  # ~250 compact cells of a unit cube
    assert np.array_equal(labels, lod.kd_clusters(pts.copy(), 20))


def test_kd_clusters_edges():
    pts = np.random.default_rng(3).random((50, 3))
    for bad in (0, -1):
        with pytest.raises(ValueError):
            lod.kd_clusters(pts, bad)
    assert np.all(lod.kd_clusters(pts, 50) == 0) and np.all(lod.kd_clusters(pts, 1000) == 0)
    assert np.array_equal(np.sort(lod.kd_clusters(pts, 1)), np.arange(50))
    assert np.all(np.bincount(lod.kd_clusters(np.zeros((40, 3)), 7)) <= 7)  # coincident points still split


# --- LevelOfDetail.merge ------------------------------------------------------------------------------------
def check_output(m: PosedGaussians, count: int) -> None:
    """Float32, C-ordered, finite, unit quaternions, positive scales, opacities in (0, 0.99]."""
    for a in vars(m).values():
        if a is not None:
            assert a.shape[0] == count and a.dtype == np.float32 and np.isfinite(a).all()
            assert a.flags.c_contiguous
    assert np.allclose(np.linalg.norm(m.quats, axis=1), 1.0, atol=1e-5)
    assert np.all(m.scales > 0) and np.all(m.opacities > 0) and np.all(m.opacities <= np.float32(0.99))


def test_one_gaussian_per_cluster_reproduces_cloud():
    g = random_cloud(300)
    g.opacities[:5] = 0.999  # above the 0.99 cap
    level = lod.LevelOfDetail(g.means, len(g))
    m = level.merge(g)
    assert level.clusters == len(g)
    check_output(m, len(g))
    order = np.lexsort(m.means.T), np.lexsort(g.means.T)  # the merged order may differ
    m, g = m.subset(order[0]), g.subset(order[1])
    assert np.array_equal(m.means, g.means)
    assert np.allclose(covariances(m.quats, m.scales), covariances(g.quats, g.scales), rtol=1e-4, atol=1e-9)
    assert np.allclose(m.sh, g.sh, atol=1e-6) and np.allclose(m.latent, g.latent, atol=1e-6)
    assert np.allclose(m.opacities, np.minimum(g.opacities, 0.99), rtol=1e-4)


def expected_merge(g: PosedGaussians) -> dict[str, np.ndarray | float]:
    """The module docstring's formulas for one cluster, densely in float64."""
    o, s = g.opacities.astype(np.float64), g.scales.astype(np.float64)
    area = np.prod(s, axis=1) ** (2 / 3)
    w = o * area
    mu = w @ g.means / w.sum()
    d = g.means - mu
    cov = np.einsum("n,nij->ij", w, covariances(g.quats, s) + lod.SPREAD * d[:, :, None] * d[:, None, :]) / w.sum()
    covered = (o * area).sum() / np.linalg.det(cov) ** (1 / 3)  # A = (s1 s2 s3)^(2/3) = det(Sigma)^(1/3)
    stacked = 1.0 - np.prod(1.0 - o)
    return {"mean": mu, "cov": cov, "sh": np.einsum("n,nkc->kc", w, g.sh) / w.sum(), "latent": w @ g.latent / w.sum(),
            "covered": covered, "stacked": stacked, "opacity": min(covered, stacked, 0.99)}


def test_two_clusters_match_formulas():
    rng = np.random.default_rng(4)
    spread = random_cloud(5, seed=5)  # spread out: the covered area decides the opacity
    spread.means[:] = rng.normal(0.0, 0.05, (5, 3)) + (-5.0, 0.0, 0.0)
    tight = random_cloud(6, seed=6)  # nearly on top of each other: stacking decides
    tight.means[:] = rng.normal(0.0, 0.001, (6, 3)) + (5.0, 0.3, 0.0)
    tight.scales[:] = rng.uniform(0.04, 0.05, (6, 3))
    tight.opacities[:] = rng.uniform(0.1, 0.2, 6)
    g = PosedGaussians(*(np.concatenate([getattr(spread, f), getattr(tight, f)]) for f in
                         ("means", "quats", "scales", "opacities", "sh", "latent")))
    level = lod.LevelOfDetail(g.means, 2)
    m = level.merge(g)
    assert level.clusters == 2
    check_output(m, 2)
    got = m.subset(np.argsort(m.means[:, 0]))
    for i, (part, winner) in enumerate(((spread, "covered"), (tight, "stacked"))):
        exp = expected_merge(part)
        assert exp[winner] < min(exp["covered"] + exp["stacked"] - exp[winner], 0.99)  # that term of the min wins
        assert np.allclose(got.means[i], exp["mean"], rtol=0, atol=1e-5)
        assert np.allclose(covariances(got.quats[i:i + 1], got.scales[i:i + 1])[0], exp["cov"], rtol=1e-4,
                           atol=1e-5 * np.abs(exp["cov"]).max())
        assert np.allclose(got.sh[i], exp["sh"], atol=1e-5) and np.allclose(got.latent[i], exp["latent"], atol=1e-5)
        assert got.opacities[i] == pytest.approx(exp["opacity"], rel=1e-4)


@pytest.mark.parametrize("o", [0.6, 0.95])
def test_identical_pair_stacks(o: float):
    g = random_cloud(1, seed=7)
    g = g.subset(np.array([0, 0]))
    g.opacities[:] = o
    m = lod.LevelOfDetail(g.means, 1).merge(g)
    check_output(m, 1)
    assert np.allclose(m.means, g.means[:1], atol=1e-7)
    assert np.allclose(covariances(m.quats, m.scales), covariances(g.quats[:1], g.scales[:1]), rtol=1e-4, atol=1e-10)
    stacked = 1.0 - (1.0 - o) ** 2  # < 2 o, the covered area's term
    assert m.opacities[0] == pytest.approx(min(stacked, 0.99), rel=1e-5)


@pytest.mark.parametrize("clusters", [1024, 4096, 1000, 3000])
def test_merged_count_and_output(clusters: int):
    """At most `clusters` Gaussians and more than half of it, for powers of two and others (a first version gave
    2**ceil(log2(clusters)): 1000 -> 1024, 3000 -> 3856 for N = 20000)."""
    g = random_cloud(20000, seed=8)
    level = lod.LevelOfDetail(g.means, clusters)
    m = level.merge(g)
    check_output(m, level.clusters)
    assert clusters / 2 <= level.clusters <= clusters


def test_merged_arrays_c_contiguous():
    """PosedGaussians promises C-contiguous arrays (a first version returned Fortran-ordered quats)."""
    g = random_cloud(500, seed=10)
    m = lod.LevelOfDetail(g.means, 32).merge(g)
    assert [k for k, a in vars(m).items() if not a.flags.c_contiguous] == []


def test_merge_without_latent_and_wrong_count():
    g = random_cloud(1000, seed=9, latent_dim=0)
    level = lod.LevelOfDetail(g.means, 64)
    m = level.merge(g)
    assert m.latent is None
    check_output(m, level.clusters)
    with pytest.raises(ValueError, match=r"1000.*999|999.*1000"):
        level.merge(g.subset(np.arange(999)))


def test_shifted_merge_follows_moved_centres():
    """`Merge.shifted`: a cloud moved rigidly by a translation gives exactly the merge of the moved cloud; a small
    smooth deformation moves each merged centre by its members' weighted mean move (checked against a plain
    weighted mean with the merge's own weights o_i A_i), shapes and colours kept."""
    g = random_cloud(4000, seed=11)
    level = lod.LevelOfDetail(g.means, 256)
    kept = level.merge_keeping(g)
    t = np.array([0.1, -0.2, 0.05], np.float32)
    moved = PosedGaussians(g.means + t, g.quats, g.scales, g.opacities, g.sh, g.latent)
    np.testing.assert_allclose(kept.shifted(moved.means).means, level.merge(moved).means, atol=2e-6)
    bent = g.means + 0.01 * np.sin(3.0 * g.means[:, [1, 2, 0]]).astype(np.float32)
    shifted = kept.shifted(bent)
    w = g.opacities * np.cbrt(np.prod(g.scales.astype(np.float64), axis=1)) ** 2
    labels = level.labels
    move = np.stack([np.bincount(labels, w * (bent - g.means)[:, k], level.clusters) for k in range(3)], 1)
    move /= np.bincount(labels, w, level.clusters)[:, None]
    np.testing.assert_allclose(shifted.means - kept.cloud.means, move, atol=1e-6)
    assert shifted.scales is kept.cloud.scales and shifted.sh is kept.cloud.sh
    # with the new SH: the base colour (DC) is the weighted mean of the members' (the merge's own, for fixed
    # weights), the view-dependent bands stay the merge's
    sh2 = g.sh.copy()
    sh2[:, 0, :] += np.sin(g.means).astype(np.float32)
    sh2[:, 1:, :] *= 2.0
    recoloured = kept.shifted(g.means, sh2)
    same_weights = PosedGaussians(g.means, g.quats, g.scales, g.opacities, sh2, g.latent)
    np.testing.assert_allclose(recoloured.sh[:, 0], level.merge(same_weights).sh[:, 0], atol=1e-5)
    np.testing.assert_array_equal(recoloured.sh[:, 1:], kept.cloud.sh[:, 1:])
    np.testing.assert_allclose(recoloured.means, kept.cloud.means, atol=1e-7)


# --- what the person sees -----------------------------------------------------------------------------------
@pytest.mark.slow
def test_merged_demo_looks_like_full(ctx, tmp_path):
    from npga_core.camera.cameras import frame_points
    from npga_core.files.loading import DEMO_AVATAR, load_avatar
    from npga_view.rendering.renderer import SplatRenderer

    if not DEMO_AVATAR.is_file():
        pytest.skip(f"demo avatar not built ({DEMO_AVATAR})")
    a = load_avatar("demo")
    p = a.pose(a.expression.mean)
    level = lod.LevelOfDetail(p.means, lod.CLUSTERS)
    merged = level.merge(p)
    subset = p.subset(np.sort(np.random.default_rng(0).choice(len(p), level.clusters, replace=False)))
    cam = frame_points(p.means, 240, 225)
    r = SplatRenderer(ctx, cam.width, cam.height)
    try:
        images = []
        for g in (p, merged, subset):
            r.set_gaussians(g)
            images.append(np.clip(r.render(cam, (0.5, 0.5, 0.5)), 0.0, 1.0))
    finally:
        r.release()
    import cv2

    cv2.imwrite(str(tmp_path / "lod_full_merged_random.png"),
                (np.concatenate(images, axis=1)[..., ::-1] * 255).round().astype(np.uint8))

    def psnr(x: np.ndarray) -> float:
        return float(10.0 * np.log10(1.0 / np.mean((x - images[0]) ** 2)))

    merged_db, subset_db = psnr(images[1]), psnr(images[2])  # measured 38.4 and 26.0 dB
    assert merged_db >= 35.0, f"merged {merged_db:.1f} dB"
    assert merged_db >= subset_db + 8.0, f"merged {merged_db:.1f} dB, random subset {subset_db:.1f} dB"
