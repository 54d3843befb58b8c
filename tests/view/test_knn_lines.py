"""The kNN graph as the viewer shows it: cached graph, edge lists, the line pass, and `render --mode` pictures."""

from __future__ import annotations

import json

import numpy as np
import pytest

from npga_core.camera.cameras import look_at
from npga_core.inspection.graph import edge_lengths, edges_touching, knn, knn_cached, knn_edges
from npga_core.inspection.inspector import PICK_COLOUR, Inspector, InspectSettings
from npga_core.model.avatar import Avatar
from npga_core.model.gaussians import GaussianCloud, PosedGaussians, logit, rgb_to_sh0
from npga_view.rendering.lines import pack_rgba8

W, H = 96, 80


# --- graph utilities ------------------------------------------------------------------------------------------
def test_knn_edges_are_the_undirected_pairs_once() -> None:
    pts = np.random.default_rng(0).normal(size=(120, 3))
    nbrs = knn(pts, 5)
    edges = knn_edges(nbrs)
    expected = {(min(i, int(j)), max(i, int(j))) for i in range(120) for j in nbrs[i]}
    assert edges.dtype == np.int32 and len(edges) == len(expected)
    assert {tuple(e) for e in edges.tolist()} == expected
    assert np.all(edges[:, 0] < edges[:, 1])
    assert np.all(np.diff(edges[:, 0].astype(np.int64) * 120 + edges[:, 1]) > 0)  # sorted, no duplicates


def test_edges_touching_and_lengths() -> None:
    pts = np.array([[0, 0, 0], [3, 4, 0], [0, 0, 1], [9, 9, 9]], np.float32)
    edges = np.array([[0, 1], [0, 2], [2, 3]], np.int32)
    np.testing.assert_allclose(edge_lengths(pts, edges), [5.0, 1.0, np.sqrt(81 + 81 + 64)], rtol=1e-6)
    np.testing.assert_array_equal(edges_touching(edges, np.array([0, 0, 0, 1], bool)), [[2, 3]])
    np.testing.assert_array_equal(edges_touching(edges, np.array([1, 0, 0, 0], bool)), [[0, 1], [0, 2]])


def test_knn_cached_reuses_the_graph_for_the_same_points() -> None:
    pts = np.random.default_rng(1).normal(size=(300, 3)).astype(np.float32)
    a = knn_cached(pts, 6)
    assert knn_cached(pts.copy(), 6) is a and not a.flags.writeable
    np.testing.assert_array_equal(a, knn(pts, 6))
    assert knn_cached(pts, 4).shape == (300, 4)
    moved = pts.copy()
    moved[0] += 10.0
    b = knn_cached(moved, 6)
    assert b is not a and not np.array_equal(b, a)


# --- Inspector.lines ------------------------------------------------------------------------------------------
def grid_avatar() -> Avatar:
    g = np.stack(np.meshgrid(np.arange(6.0), np.arange(5.0), [0.0], indexing="ij"), -1).reshape(-1, 3) * 0.1
    n = len(g)
    feats = np.stack([g[:, 0], g[:, 1] ** 2], 1)
    cloud = GaussianCloud(g.astype(np.float32), np.tile(np.float32([1, 0, 0, 0]), (n, 1)),
                          np.full((n, 3), np.log(0.01), np.float32), np.full(n, logit(np.float32(0.9))),
                          rgb_to_sh0(np.full((n, 1, 3), 0.5, np.float32)), feats.astype(np.float32))
    return Avatar(cloud)


def test_lines_all_picked_and_selection() -> None:
    avatar = grid_avatar()
    insp = Inspector(avatar)
    posed = avatar.cloud.posed_static()
    nbrs = knn(avatar.cloud.means, 4)
    all_lines = insp.lines(InspectSettings(knn_show="all", knn_k=4), posed)
    np.testing.assert_array_equal(all_lines.edges, knn_edges(nbrs))
    np.testing.assert_array_equal(all_lines.positions, posed.means)
    lengths = edge_lengths(posed.means, all_lines.edges)
    longest, shortest = np.argmax(lengths), np.argmin(lengths)
    assert all_lines.colours[longest, 0] > all_lines.colours[shortest, 0]  # viridis: long edges yellow
    by_feature = insp.lines(InspectSettings(knn_show="all", knn_k=4, knn_colour="feature"), posed)
    assert not np.array_equal(by_feature.colours, all_lines.colours)

    picked = insp.lines(InspectSettings(knn_k=4, picked=7), posed)  # only the picked Gaussian's neighbours
    n = len(posed)
    np.testing.assert_array_equal(picked.edges[:4], np.stack([np.full(4, 7), nbrs[7]], 1))
    assert len(picked.edges) == 4 + 3 and np.all(picked.edges[4:] >= n)  # plus a 3-segment cross
    np.testing.assert_allclose(picked.positions[n:].mean(axis=0), posed.means[7], atol=1e-6)
    np.testing.assert_allclose(picked.colours[:, :3], np.tile(PICK_COLOUR, (7, 1)))

    sel = np.zeros(n, bool)
    sel[[0, 29]] = True
    lines = insp.lines(InspectSettings(knn_show="selection", knn_k=4), posed, sel)
    np.testing.assert_array_equal(lines.edges, edges_touching(knn_edges(nbrs), sel))
    assert insp.lines(InspectSettings(), posed) is None
    assert insp.lines(InspectSettings(knn_show="picked"), posed) is None  # nothing picked
    assert insp.lines(InspectSettings(knn_show="selection"), posed) is None  # no selection


def test_stretch_colours_follow_the_posed_lengths() -> None:
    avatar = grid_avatar()
    insp = Inspector(avatar)
    posed = avatar.cloud.posed_static()
    stretched = PosedGaussians(posed.means * np.float32([1.5, 1.0, 1.0]), posed.quats, posed.scales,
                               posed.opacities, posed.sh)
    edges = knn_edges(knn(avatar.cloud.means, 4))
    c = insp.edge_colouring("stretch", edges, stretched.means)
    expected = edge_lengths(stretched.means, edges) / edge_lengths(avatar.cloud.means, edges)
    np.testing.assert_allclose(c.values, expected, rtol=1e-5)
    assert c.lo < 1.0 < c.hi and c.cmap == "coolwarm"


# --- the line pass --------------------------------------------------------------------------------------------
def test_pack_rgba8_byte_order() -> None:
    packed = pack_rgba8(np.array([[1.0, 0.0, 0.5, 1.0], [0.0, 1.0, 0.0, 0.0]]))
    assert packed.dtype == np.uint32
    assert packed[0] == 0xFF8000FF and packed[1] == 0x0000FF00
    assert pack_rgba8(np.array([[0.0, 0.0, 1.0]]))[0] == 0xFFFF0000  # alpha 1 added


@pytest.fixture
def renderer(make_renderer):
    r = make_renderer(W, H)
    yield r
    r.release()


def test_lines_are_drawn_between_the_projected_points(renderer) -> None:
    cam = look_at((0.0, 0.0, 3.0), (0.0, 0.0, 0.0), fov_y_deg=40.0, width=W, height=H)
    renderer.set_gaussians(PosedGaussians(np.zeros((0, 3), np.float32), np.zeros((0, 4), np.float32),
                                          np.zeros((0, 3), np.float32), np.zeros(0, np.float32),
                                          np.zeros((0, 1, 3), np.float32)))
    ends = np.array([[-0.6, 0.3, 0.0], [0.6, 0.3, 0.0], [0.0, -0.5, 0.0], [0.0, 0.5, 0.5]], np.float32)
    renderer.set_lines(ends, np.array([[0, 1], [2, 3]]), np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]))
    image = renderer.render(cam)
    uv = cam.project(ends)
    red = (image[..., 0] > 0.99) & (image[..., 1] < 0.01)
    rows = np.flatnonzero(red.any(axis=1))
    assert len(rows) == 1 and abs(rows[0] + 0.5 - uv[0, 1]) <= 1.0  # a horizontal 1-pixel line at v
    cols = np.flatnonzero(red[rows[0]])
    assert abs(cols.min() - uv[0, 0]) <= 1.5 and abs(cols.max() + 1 - uv[1, 0]) <= 1.5
    green = image[..., 1] > 0.99
    ys, xs = np.nonzero(green)
    t = (ys + 0.5 - uv[2, 1]) / (uv[3, 1] - uv[2, 1])  # every green pixel lies on the projected segment
    assert green.sum() > 20 and np.all(np.abs(uv[2, 0] + t * (uv[3, 0] - uv[2, 0]) - (xs + 0.5)) <= 1.0)
    assert renderer.render(cam, mode="alpha").max() == 0.0  # lines only in the colour image
    assert renderer.line_count == 2
    renderer.clear_lines()
    assert renderer.render(cam).max() == 0.0
    with pytest.raises(ValueError):
        renderer.set_lines(ends, np.array([[0, 4]]), np.zeros((1, 3)))


def test_lines_lie_over_the_splats(renderer) -> None:
    avatar = grid_avatar()
    cam = look_at((0.25, 0.2, 1.5), (0.25, 0.2, 0.0), fov_y_deg=40.0, width=W, height=H)
    posed = avatar.cloud.posed_static()
    renderer.set_gaussians(posed)
    plain = renderer.render(cam)
    frame = Inspector(avatar).frame(InspectSettings(knn_show="all", knn_k=4), posed)
    renderer.set_lines(frame.lines.positions, frame.lines.edges, frame.lines.colours)
    with_lines = renderer.render(cam)
    changed = np.any(np.abs(with_lines - plain) > 1e-3, axis=2)
    assert changed.mean() > 0.02
    colours = frame.lines.colours[:, :3]
    hit = with_lines[changed]  # the changed pixels carry an edge colour, drawn opaquely on top
    dist = np.min(np.linalg.norm(hit[:, None, :] - colours[None], axis=2), axis=1)
    assert np.median(dist) < 0.01


# --- the render command ---------------------------------------------------------------------------------------
MODES = ["features", "feature:2", "latent", "latent:1", "offset", "laplacian", "sensitivity", "opacity", "scale",
         "depth", "points", "ellipsoids", "knn"]


@pytest.mark.slow
def test_render_modes_write_pictures_with_a_legend(small_npga, tmp_path, capsys) -> None:
    cv2 = pytest.importorskip("cv2")
    from npga_core.inspection.legend import LEGEND_HEIGHT
    from npga_view.cli.main import main

    size = ["--width", "48", "--height", "64"]
    pictures = {}
    for mode in MODES:
        out = tmp_path / f"{mode.replace(':', '_')}.png"
        assert main(["render", str(small_npga), "--out", str(out), "--mode", mode, *size]) == 0, mode
        img = cv2.imread(str(out))
        assert img.shape == (64 + LEGEND_HEIGHT, 48, 3), mode
        assert img[:64].max() > 40, mode  # something drawn
        pictures[mode] = img
    assert len({p[:64].tobytes() for p in pictures.values()}) == len(MODES)  # every mode looks different
    assert main(["render", str(small_npga), "--out", str(tmp_path / "o.png"), "--mode", "offset", "--offset-attr",
                 "opacity", "--no-legend", *size]) == 0
    assert cv2.imread(str(tmp_path / "o.png")).shape == (64, 48, 3)
    assert main(["render", str(small_npga), "--out", str(tmp_path / "f.npy"), "--mode", "features", *size]) == 0
    assert np.load(tmp_path / "f.npy").shape == (64, 48, 3)
    capsys.readouterr()
    assert main(["render", str(small_npga), "--out", str(tmp_path / "c.png"), "--counts", *size]) == 0
    counts = json.loads(capsys.readouterr().out)
    assert counts["total"] == 600 and counts["drawn"] <= counts["total"]
    assert sum(p["total"] for p in counts["parts"].values()) == 600
    out = tmp_path / "hidden.png"
    assert main(["render", str(small_npga), "--out", str(out), "--filter", "opacity=2,3", "--no-legend", *size]) == 0
    assert cv2.imread(str(out)).max() == 0  # no opacity in 2..3: everything hidden
    capsys.readouterr()
    assert main(["render", str(small_npga), "--out", str(out), "--clip-plane", "0,0,0,0,0,1", "--counts", *size]) == 0
    clipped = json.loads(capsys.readouterr().out)
    assert 0 < clipped["drawn"] < counts["drawn"]
    for bad in (["--clip-box", "0,0,0,1"], ["--highlight", "opacity"], ["--filter", "nope=0,1"]):
        assert main(["render", str(small_npga), "--out", str(out), *bad, *size]) == 2, bad
    capsys.readouterr()
    for bad in (["--mode", "feature:99"], ["--mode", "offset", "--offset-source", "F", "--offset-attr", "scale"],
                ["--mode", "sensitivity", "--direction", "0"], ["--mode", "opacity", "--range", "1,0"]):
        assert main(["render", str(small_npga), "--out", str(tmp_path / "e.png"), *bad, *size]) == 2, bad
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 4 and all("Traceback" not in line for line in err)
