"""Inspection modes (npga_core.inspection.inspector) against their definitions on small avatars."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import torch

from npga_core.camera.cameras import look_at
from npga_core.inspection.colouring import FeaturePCA, colour_map, robust_range
from npga_core.inspection.graph import knn, laplacian_terms
from npga_core.inspection.inspector import InspectInfo, Inspector, InspectSettings, offset_values, parse_mode
from npga_core.inspection.measures import (
    clip_box,
    clip_plane,
    count_gaussians,
    histogram,
    in_frustum,
    in_range,
    recolour,
)
from npga_core.model.avatar import Avatar
from npga_core.model.gaussians import SH_C0, GaussianCloud, logit, rgb_to_sh0
from npga_core.model.synthetic import make_synthetic_avatar


@pytest.fixture(scope="module")
def avatar() -> Avatar:
    """Small networks keep the tests fast; latent features so that h and G's latent block exist."""
    return make_synthetic_avatar(1500, latent_dim=5, hidden=48, depth=3, code_dim=20, n_components=8, seed=4)


@pytest.fixture(scope="module")
def inspector(avatar) -> Inspector:
    return Inspector(avatar)


def cloud_at(points: np.ndarray, features: np.ndarray | None = None, opacity: float = 0.9,
             scale: float = 0.01) -> GaussianCloud:
    n = len(points)
    return GaussianCloud(
        means=np.asarray(points, np.float32),
        quats=np.tile(np.float32([1, 0, 0, 0]), (n, 1)),
        log_scales=np.full((n, 3), np.log(scale), np.float32),
        opacity_logits=np.full(n, logit(np.float32(opacity)), np.float32),
        sh=rgb_to_sh0(np.full((n, 1, 3), 0.5, np.float32)),
        features=np.zeros((n, 0), np.float32) if features is None else np.asarray(features, np.float32),
    )


def colour_of(settings: InspectSettings, inspector: Inspector, posed, code=None, camera=None):
    return inspector.colouring(settings, posed, code, camera)


# --- colour maps and ranges ------------------------------------------------------------------------------
def test_colour_maps() -> None:
    viridis = colour_map(np.array([0.0, 0.5, 1.0]), "viridis")  # matplotlib: #440154, #21918c, #fde725
    np.testing.assert_allclose(viridis, [[0.267, 0.004, 0.329], [0.129, 0.569, 0.549], [0.992, 0.906, 0.145]],
                               atol=0.015)
    turbo = colour_map(np.array([0.0, 0.25, 0.5, 0.75, 1.0]), "turbo")  # dark, blue, green, orange, dark red
    assert [int(c.argmax()) for c in turbo[1:]] == [2, 1, 0, 0] and turbo[[0, 4]].sum(axis=1).max() < 0.7
    coolwarm = colour_map(np.array([0.0, 0.5, 1.0]), "coolwarm")
    assert coolwarm[0].argmax() == 2 and np.ptp(coolwarm[1]) < 1e-6 and coolwarm[2].argmax() == 0
    np.testing.assert_array_equal(colour_map(np.array([0.2]), "viridis_r"), colour_map(np.array([0.8]), "viridis"))
    assert np.all(colour_map(np.array([np.nan]), "turbo") == 0.5)
    np.testing.assert_array_equal(colour_map(np.array([-3.0, 7.0])), colour_map(np.array([0.0, 1.0])))
    with pytest.raises(ValueError):
        colour_map(np.zeros(1), "jet")


def test_robust_range_ignores_outliers() -> None:
    v = np.concatenate([np.linspace(0.0, 1.0, 1000), [1e6, np.nan]])
    lo, hi = robust_range(v)
    assert 0.0 <= lo < 0.02 and 0.98 < hi <= 1.0
    lo, hi = robust_range(np.array([-3.0, 2.0, 1.0]), percentiles=(0, 100), symmetric=True)
    assert (lo, hi) == (-3.0, 3.0)


# --- features, latent --------------------------------------------------------------------------------------
def test_feature_pca_recovers_known_axes() -> None:
    rng = np.random.default_rng(0)
    basis = np.linalg.qr(rng.normal(size=(6, 6)))[0][:, :3].T  # three orthonormal directions in R^6
    raw = rng.normal(size=(4000, 3))
    q = np.linalg.qr(raw - raw.mean(axis=0))[0]  # zero-mean, exactly uncorrelated columns
    coords = q * np.sqrt(3999.0) * [5.0, 2.0, 0.5]  # standard deviations 5, 2, 0.5
    pca = FeaturePCA.fit(coords @ basis + 3.0)
    np.testing.assert_allclose(np.abs(pca.axes @ basis.T), np.eye(3), atol=1e-6)
    np.testing.assert_allclose(pca.explained, np.array([25.0, 4.0, 0.25]) / 29.25, atol=0.01)
    proj = pca.project(coords @ basis + 3.0)
    np.testing.assert_allclose(np.abs(proj), np.abs(coords), atol=1e-5)  # each projection is +- the coordinate
    rgb = pca.colours(coords @ basis + 3.0)
    assert rgb.min() == 0.0 and rgb.max() == 1.0
    assert 0.005 < (rgb[:, 0] == 1.0).mean() < 0.015  # clipped above the 99th percentile


def test_features_mode_is_the_canonical_pca_and_stable_between_codes(avatar, inspector) -> None:
    s = InspectSettings(mode="features")
    ex = avatar.expression
    a = colour_of(s, inspector, avatar.pose(ex.mean), ex.mean)
    z = ex.from_sliders(np.full(3, 2.0, np.float32))
    b = colour_of(s, inspector, avatar.pose(z), z)
    np.testing.assert_array_equal(a.rgb, b.rgb)
    np.testing.assert_array_equal(a.rgb, FeaturePCA.fit(avatar.cloud.features).colours(avatar.cloud.features))
    assert a.cmap is None and "PC 1" in a.notes[0]


def test_feature_channel_mode(avatar, inspector) -> None:
    posed = avatar.pose()
    c = colour_of(InspectSettings(mode="feature:3"), inspector, posed)
    f3 = avatar.cloud.features[:, 3]
    np.testing.assert_array_equal(c.values, f3)
    assert c.lo == -c.hi  # the channel takes both signs: symmetric diverging map
    np.testing.assert_allclose(c.rgb, colour_map((f3 - c.lo) / (c.hi - c.lo), c.cmap), atol=1e-6)
    with pytest.raises(ValueError, match="channel 99"):
        colour_of(InspectSettings(mode="feature:99"), inspector, posed)


def test_latent_modes_use_the_posed_h(avatar, inspector) -> None:
    z = avatar.expression.from_sliders(np.array([1.5, -1.0], np.float32))
    posed = avatar.pose(z)
    assert not np.allclose(posed.latent, avatar.cloud.latent)  # G moves h
    c = colour_of(InspectSettings(mode="latent"), inspector, posed, z)
    np.testing.assert_allclose(c.rgb, FeaturePCA.fit(avatar.cloud.latent).colours(posed.latent), atol=1e-6)
    c2 = colour_of(InspectSettings(mode="latent:2"), inspector, posed, z)
    np.testing.assert_array_equal(c2.values, posed.latent[:, 2])


# --- offsets ------------------------------------------------------------------------------------------------
def test_offset_modes_match_the_reference_offsets(avatar, inspector) -> None:
    z = avatar.expression.from_sliders(np.array([2.0, 1.0, -1.0], np.float32))
    posed = avatar.pose(z)
    ref = avatar.offsets_reference(z)
    f, g = ref.f_position.numpy(), {k: v.numpy() for k, v in ref.g.items()}

    def values(attr: str, source: str = "sum") -> np.ndarray:
        s = InspectSettings(mode="offset", offset_attr=attr, offset_source=source)
        return colour_of(s, inspector, posed, z).values

    np.testing.assert_allclose(values("position", "sum"), np.linalg.norm(f + g["position"], axis=1), rtol=1e-4,
                               atol=1e-9)
    np.testing.assert_allclose(values("position", "F"), np.linalg.norm(f, axis=1), rtol=1e-4, atol=1e-9)
    np.testing.assert_allclose(values("position", "G"), np.linalg.norm(g["position"], axis=1), rtol=1e-4, atol=1e-9)
    np.testing.assert_allclose(values("opacity"), g["opacity"][:, 0], rtol=1e-4, atol=1e-7)
    np.testing.assert_allclose(values("scale"), np.linalg.norm(g["scale"], axis=1), rtol=1e-4, atol=1e-7)
    np.testing.assert_allclose(values("colour"), np.linalg.norm(SH_C0 * g["sh"][:, :3], axis=1), rtol=1e-4,
                               atol=1e-7)
    opacity = colour_of(InspectSettings(mode="offset", offset_attr="opacity"), inspector, posed, z)
    assert opacity.cmap == "coolwarm" and opacity.lo == -opacity.hi
    with pytest.raises(ValueError, match="only offsets positions"):
        values("scale", "F")


def test_rotation_offset_is_the_angle_of_the_rotation() -> None:
    theta = np.radians([0.0, 10.0, 90.0])
    d = np.stack([np.cos(theta / 2) - 1.0, np.sin(theta / 2), 0 * theta, 0 * theta], axis=1)
    np.testing.assert_allclose(offset_values({"rotation": d}, "rotation", "G"), [0.0, 10.0, 90.0], atol=1e-3)


# --- laplacian ----------------------------------------------------------------------------------------------
def test_laplacian_mode_on_a_chain_with_a_known_residual() -> None:
    # points 0..9 on a line, k = 2: an interior point's neighbours are i - 1 and i + 1. For f = i^2 the residual
    # is ((i-1)^2 + (i+1)^2) / 2 - i^2 = 1; point 0 has neighbours 1, 2: (1 + 4) / 2 - 0 = 2.5, R_lap = 6.25;
    # point 9 has 8, 7: (64 + 49) / 2 - 81 = -24.5, R_lap = 600.25.
    i = np.arange(10.0)
    cloud = cloud_at(np.stack([i, 0 * i, 0 * i], 1), features=(i ** 2)[:, None])
    insp = Inspector(Avatar(cloud))
    c = insp.colouring(InspectSettings(mode="laplacian", knn_k=2), cloud.posed_static())
    expected = np.ones(10)
    expected[0], expected[9] = 6.25, 600.25
    np.testing.assert_allclose(c.values, expected)
    assert c.lo == 0.0 and "R_lap" in c.label


def test_laplacian_of_g_offsets(avatar, inspector) -> None:
    z = avatar.expression.from_sliders(np.array([1.0], np.float32))
    posed = avatar.pose(z)
    nbrs = knn(avatar.cloud.means, 6)
    ref = {k: v.numpy() for k, v in avatar.offsets_reference(z).g.items()}
    all_g = colour_of(InspectSettings(mode="laplacian", laplacian_of="G", knn_k=6), inspector, posed, z)
    blocks = [laplacian_terms(v, nbrs) for v in ref.values()]
    np.testing.assert_allclose(all_g.values, sum(blocks), rtol=1e-3, atol=1e-12)  # concatenation = sum of blocks
    scale = colour_of(InspectSettings(mode="laplacian", laplacian_of="scale", knn_k=6), inspector, posed, z)
    np.testing.assert_allclose(scale.values, laplacian_terms(ref["scale"], nbrs), rtol=1e-3, atol=1e-12)
    with pytest.raises(ValueError, match="no 'rgb' offset"):
        colour_of(InspectSettings(mode="laplacian", laplacian_of="rgb"), inspector, posed, z)


# --- sensitivity --------------------------------------------------------------------------------------------
def test_sensitivity_matches_finite_differences(avatar, inspector) -> None:
    ex = avatar.expression
    z = ex.from_sliders(np.array([0.5, -0.5], np.float32))
    k = 2
    c = colour_of(InspectSettings(mode="sensitivity", direction=k), inspector, avatar.pose(z), z)

    dyn = copy.deepcopy(avatar.dynamics).double()  # float64 finite differences with a tiny step
    mu = torch.from_numpy(avatar.cloud.means.astype(np.float64))
    f = torch.from_numpy(avatar.cloud.features.astype(np.float64))

    def position_offset(code: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            off = dyn.offsets(mu, f, torch.from_numpy(code))
        return (off.f_position + off.g["position"]).numpy()

    eps = 1e-5  # standard deviations
    step = eps * ex.std[k].astype(np.float64) * ex.basis[k].astype(np.float64)
    fd = (position_offset(z + step) - position_offset(z - step)) / (2 * eps)
    expected = np.linalg.norm(fd, axis=1)
    np.testing.assert_allclose(c.values, expected, rtol=1e-3, atol=1e-4 * expected.max())
    assert expected.max() > 0 and "PC 3" in c.label


# --- opacity, scale, depth -----------------------------------------------------------------------------------
def test_opacity_scale_and_depth_modes(avatar, inspector) -> None:
    posed = avatar.pose()
    op = colour_of(InspectSettings(mode="opacity"), inspector, posed)
    np.testing.assert_array_equal(op.values, posed.opacities)
    assert (op.lo, op.hi) == (0.0, 1.0)
    np.testing.assert_allclose(op.rgb, colour_map(posed.opacities), atol=1e-6)
    size = colour_of(InspectSettings(mode="scale"), inspector, posed)
    np.testing.assert_allclose(size.values, posed.scales.max(axis=1))
    aniso = colour_of(InspectSettings(mode="scale", scale_measure="anisotropy"), inspector, posed)
    np.testing.assert_allclose(aniso.values, posed.scales.max(axis=1) / posed.scales.min(axis=1), rtol=1e-6)
    assert aniso.lo >= 1.0 and (aniso.lo, aniso.hi) == robust_range(aniso.values)
    cam = look_at((0.0, 0.0, 0.6), (0.0, 0.0, 0.0))
    depth = colour_of(InspectSettings(mode="depth"), inspector, posed, camera=cam)
    np.testing.assert_allclose(depth.values, 0.6 - posed.means[:, 2], atol=1e-6)
    near = np.argmin(depth.values)
    np.testing.assert_allclose(depth.rgb[near], colour_map(np.zeros(1), "turbo_r")[0], atol=0.05)
    with pytest.raises(ValueError, match="camera"):
        colour_of(InspectSettings(mode="depth"), inspector, posed)


def test_fixed_value_range_and_cmap(avatar, inspector) -> None:
    posed = avatar.pose()
    c = colour_of(InspectSettings(mode="opacity", cmap="grey", value_range=(0.5, 1.0)), inspector, posed)
    np.testing.assert_allclose(c.rgb[:, 0], np.clip((posed.opacities - 0.5) / 0.5, 0, 1), atol=1e-6)


def test_parse_mode() -> None:
    assert parse_mode("feature:3") == ("feature", 3)
    assert parse_mode("latent") == ("latent", None)
    for bad in ("feature:x", "opacity:2", "nope"):
        with pytest.raises(ValueError):
            parse_mode(bad)


# --- counts ---------------------------------------------------------------------------------------------------
def test_counts_on_a_camera_that_sees_a_known_subset() -> None:
    cam = look_at((0.0, 0.0, 5.0), (0.0, 0.0, 0.0), fov_y_deg=40.0, width=200, height=100)
    # half width of the view at z = 0: 5 * tan(20 deg) * 2 = 3.64 (x), 1.82 (y)
    pts = np.array([
        [0.0, 0.0, 0.0], [1.0, 1.0, 0.0], [-3.0, 0.5, 0.0],  # inside
        [3.0, 1.95, 0.0],  # above the top edge
        [5.0, 0.0, 0.0],  # right of the image
        [0.0, 0.0, 6.0],  # behind the camera
        [0.0, 0.0, 4.995],  # in front of the camera but closer than the near plane
    ])
    parts = np.array([0, 0, 1, 1, 1, -1, 0], np.int16)
    c = count_gaussians(cam, pts, parts, ["face", "hair"], drawn=np.array([1, 1, 0, 1, 0, 0, 0], bool))
    np.testing.assert_array_equal(in_frustum(cam, pts), [True, True, True, False, False, False, False])
    assert (c.total, c.in_frustum, c.drawn) == (7, 3, 3)
    assert c.parts == [("face", 3, 2, 2), ("hair", 3, 1, 1), ("(no part)", 1, 0, 0)]
    assert count_gaussians(cam, pts, drawn=5).drawn == 5 and count_gaussians(cam, pts).drawn is None


# --- histograms, filters, clipping -----------------------------------------------------------------------------
def test_histogram_range_filter_and_highlight(avatar, inspector) -> None:
    posed = avatar.pose()
    counts, edges = histogram(posed.opacities, bins=10, value_range=(0.0, 1.0))
    assert counts.sum() == len(posed) and edges[0] == 0.0 and edges[-1] == 1.0
    inside = in_range(posed.opacities, 0.9, 0.7)
    assert inside.sum() == ((posed.opacities >= 0.7) & (posed.opacities <= 0.9)).sum() > 0
    s = InspectSettings(mode="opacity", hist_attr="opacity", hist_range=(0.7, 0.9), hist_action="filter")
    frame = inspector.frame(s, posed)
    np.testing.assert_array_equal(frame.posed.opacities > 0, inside)
    np.testing.assert_array_equal(frame.posed.opacities[inside], posed.opacities[inside])
    assert frame.posed.sh.shape == (len(posed), 1, 3)
    s.hist_action = "highlight"
    frame = inspector.frame(s, posed)
    np.testing.assert_allclose(frame.posed.opacities[~inside], posed.opacities[~inside] * 0.15, rtol=1e-6)
    colours = frame.posed.sh[:, 0] * SH_C0 + 0.5
    assert np.allclose(colours[~inside], colours[~inside][:, :1])  # grey outside the range
    np.testing.assert_allclose(colours[inside], frame.colouring.rgb[inside], atol=1e-6)


def test_histogram_attributes(avatar, inspector) -> None:
    posed = avatar.pose()
    for name in inspector.attribute_names():
        v = inspector.attribute_values(name, posed)
        assert v.shape == (len(posed),) and np.all(np.isfinite(v)), name
    np.testing.assert_array_equal(inspector.attribute_values("feature:2", posed), avatar.cloud.features[:, 2])
    with pytest.raises(ValueError):
        inspector.attribute_values("feature:77", posed)


def test_clip_box_and_plane(avatar, inspector) -> None:
    pts = np.array([[0.0, 0.0, 0.0], [0.5, 0.5, 0.5], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [-0.1, 0.2, 0.2]])
    np.testing.assert_array_equal(clip_box(pts, (1, 1, 1), (0, 0, 0)), [True, True, True, False, False])
    np.testing.assert_array_equal(clip_plane(pts, (1.0, 0, 0), (-1.0, 0, 0)), [True, True, True, False, True])
    with pytest.raises(ValueError):
        clip_plane(pts, (0, 0, 0), (0, 0, 0))
    posed = avatar.pose()
    s = InspectSettings(clip="plane", clip_point=(0.0, 0.0, 0.0), clip_normal=(0.0, 0.0, 1.0))
    frame = inspector.frame(s, posed)
    np.testing.assert_array_equal(frame.posed.opacities > 0, posed.means[:, 2] >= 0)
    np.testing.assert_array_equal(frame.posed.sh, posed.sh)  # rgb mode keeps the SH


def test_recolour_without_changes_keeps_everything(avatar) -> None:
    posed = avatar.pose()
    out = recolour(posed)
    np.testing.assert_array_equal(out.sh, posed.sh)
    np.testing.assert_array_equal(out.opacities, posed.opacities)


# --- the inspector's record of one Gaussian --------------------------------------------------------------------
def test_record_of_a_gaussian(avatar, inspector) -> None:
    z = avatar.expression.from_sliders(np.array([1.0, 1.0], np.float32))
    posed = avatar.pose(z)
    rec = inspector.record(17, posed, z, k=5)
    c = avatar.cloud
    np.testing.assert_array_equal(rec["canonical"]["position"], c.means[17])
    np.testing.assert_array_equal(rec["posed"]["position"], posed.means[17])
    np.testing.assert_array_equal(rec["features"], c.features[17])
    np.testing.assert_array_equal(rec["posed_latent"], posed.latent[17])
    off = avatar.offsets_reference(z)
    np.testing.assert_allclose(rec["offsets"]["F position"], off.f_position[17].numpy(), rtol=1e-4, atol=1e-9)
    np.testing.assert_allclose(rec["canonical"]["position"] + rec["offsets"]["F position"]
                               + rec["offsets"]["G position"], posed.means[17], atol=1e-6)
    assert rec["part"] in c.part_names
    assert [j for j, _ in rec["neighbours"]] == list(knn(c.means, 5)[17])
    assert all(d > 0 for _, d in rec["neighbours"])
    with pytest.raises(ValueError):
        inspector.record(len(c), posed)


def test_static_avatar_modes_that_need_dynamics_fail_clearly() -> None:
    cloud = cloud_at(np.random.default_rng(0).normal(size=(50, 3)), features=np.ones((50, 2)))
    insp = Inspector(Avatar(cloud))
    with pytest.raises(ValueError, match="no dynamics"):
        insp.colouring(InspectSettings(mode="offset"), cloud.posed_static())
    with pytest.raises(ValueError, match="latent"):
        insp.colouring(InspectSettings(mode="latent"), cloud.posed_static())


def test_offsets_are_cached_per_code(avatar) -> None:
    insp = Inspector(avatar)
    calls = []
    original = avatar.offsets

    def counting(z, *a, **kw):
        calls.append(1)
        return original(z, *a, **kw)

    avatar.offsets = counting
    try:
        z = avatar.neutral_code()
        insp.offsets(z)
        insp.offsets(z.copy())
        assert len(calls) == 1
        insp.offsets(z + 0.1)
        assert len(calls) == 2
    finally:
        del avatar.offsets


# --- the Inspect panel, driven headless through imgui input events -------------------------------------------
@pytest.fixture
def panel_frame():
    imgui = pytest.importorskip("imgui_bundle").imgui
    context = imgui.create_context()
    io = imgui.get_io()
    io.set_ini_filename(None)
    io.display_size = imgui.ImVec2(520, 2400)
    io.backend_flags |= imgui.BackendFlags_.renderer_has_textures  # no renderer: imgui keeps the atlas to itself

    def frame(body) -> None:
        io.delta_time = 1 / 60
        imgui.new_frame()
        imgui.set_next_window_pos(imgui.ImVec2(0, 0))
        imgui.set_next_window_size(imgui.ImVec2(520, 2400))
        imgui.begin("side")
        imgui.set_next_item_open(True)  # the panel's collapsing header
        body()
        imgui.end()
        imgui.render()

    yield frame, io
    imgui.destroy_context(context)


def test_inspect_panel_draws_every_mode_and_writes_settings(avatar, inspector, panel_frame) -> None:
    from npga_view import actions as A
    from npga_view.panels.info import AppInfo
    from npga_view.panels.inspect import InspectPanel
    from npga_view.state import ViewerState

    panel = InspectPanel()

    frame, io = panel_frame
    state, info = ViewerState(), AppInfo(avatar=avatar)
    state.inspect = InspectSettings(picked=3)
    cam = look_at((0.0, 0.0, 0.6), (0.0, 0.0, 0.0))
    posed = avatar.pose()

    def refresh() -> None:
        colouring = inspector.colouring(state.inspect, posed, camera=cam)
        info.inspect = inspector.info(state.inspect, posed, None, colouring, cam, len(posed))

    def click(name: str) -> None:
        x0, y0, x1, y1 = info.rects[name]
        io.add_mouse_pos_event((x0 + x1) / 2, (y0 + y1) / 2)
        frame(lambda: panel.draw(state, info))
        io.add_mouse_button_event(0, True)
        frame(lambda: panel.draw(state, info))
        io.add_mouse_button_event(0, False)
        frame(lambda: panel.draw(state, info))

    refresh()
    frame(lambda: panel.draw(state, info))
    for node in ("histogram", "clipping", "knn", "picked"):
        click(f"inspect_node_{node}")
    assert {"inspect_hist_filter", "inspect_focus", "inspect_pick_on_click"} <= set(info.rects)
    click("inspect_hist_filter")
    assert state.inspect.hist_action == "filter" and state.inspect.hist_range is not None
    click("inspect_focus")
    assert state.actions == [A.FocusGaussian(3)]
    click("inspect_pick_on_click")
    assert state.inspect.pick_on_click
    modes = ["rgb", "features", "feature:1", "latent", "latent:2", "offset", "laplacian", "sensitivity", "opacity",
             "scale", "depth"]
    for mode in modes:
        state.inspect.mode = mode
        refresh()
        frame(lambda: panel.draw(state, info))
        assert state.inspect.mode == mode  # drawing alone changes nothing
    state.inspect.clip = "plane"
    frame(lambda: panel.draw(state, info))
    info.inspect = InspectInfo(error="something went wrong")
    frame(lambda: panel.draw(state, info))


@pytest.mark.filterwarnings("ignore::DeprecationWarning")  # torch.func.jvp's own one-time scripting
@pytest.mark.parametrize("activation, skips", [("relu", []), ("silu", [2]), ("tanh", [1, 3])])
def test_mlp_jvp_matches_autodiff_with_skips_and_activations(activation, skips) -> None:
    from npga_core.inspection.sensitivity import mlp_jvp
    from npga_core.model.dynamics import ConditionedMLP, MLPConfig

    torch.manual_seed(0)
    net = ConditionedMLP(MLPConfig(4, 6, [("rotation", 4), ("position", 3)], hidden=16, depth=4,
                                   activation=activation, pos_freqs=2, skips=skips))
    with torch.no_grad():
        net.input_scale.uniform_(0.5, 2.0)
        net.input_shift.uniform_(-0.1, 0.1)
    mu, f = torch.randn(300, 3), torch.randn(300, 4)
    z, v = torch.randn(6), torch.randn(6)
    _, expected = torch.func.jvp(lambda code: net(mu, f, code)[:, 4:7], (z,), (v,))
    got = mlp_jvp(net, net.precompute(mu, f), z, v, slice(4, 7), (mu, f), chunk=128)
    np.testing.assert_allclose(got.numpy(), expected.detach().numpy(), rtol=1e-4, atol=1e-6)
