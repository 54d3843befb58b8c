"""Two images composed for comparison (npga_core/evaluation/compare.py): every mode checked pixel by pixel."""

from __future__ import annotations

import numpy as np
import pytest

from npga_core.evaluation.compare import CompareSettings, compose, divider_column, error_map, heatmap

# matplotlib's inferno at 0 and 1 (matplotlib `_cm_listed.py`, `_inferno_data` first and last rows)
INFERNO_LOW = np.array([0.001462, 0.000466, 0.013866])
INFERNO_HIGH = np.array([0.988362, 0.998364, 0.644924])


def _pair(h=60, w=80):
    rng = np.random.default_rng(1)
    return rng.random((h, w, 3)).astype(np.float32), rng.random((h, w, 3)).astype(np.float32)


def test_single_side_and_blend():
    a, b = _pair()
    assert np.array_equal(compose(a, b, CompareSettings("a")), a)
    assert np.array_equal(compose(a, b, CompareSettings("b")), b)
    side = compose(a, b, CompareSettings("side"))
    assert side.shape == (60, 160, 3) and np.array_equal(side[:, :80], a) and np.array_equal(side[:, 80:], b)
    np.testing.assert_allclose(compose(a, b, CompareSettings("blend", t=0.25)), 0.75 * a + 0.25 * b, atol=1e-6)


@pytest.mark.parametrize("t", [0.0, 0.3, 0.5, 1.0])
def test_wipe_shows_a_left_of_the_divider_and_b_right(t):
    a, b = _pair()
    out = compose(a, b, CompareSettings("wipe", t=t))
    x = divider_column(80, t)
    assert x == round(80 * t)
    left, right = max(x - 1, 0), min(x + 1, 80) if 0 < x < 80 else x
    assert np.array_equal(out[:, :left], a[:, :left])
    assert np.array_equal(out[:, right:], b[:, right:])
    if 0 < x < 80:
        assert np.all(out[:, x - 1:x + 1] == 1.0)  # the divider line


def test_difference_heatmap_scale_and_colour_bar():
    a = np.zeros((150, 200, 3), np.float32)
    b = a.copy()
    b[:, :100] = 0.5  # error 0.5 >= vmax on the left half, 0 on the right
    out = compose(a, b, CompareSettings("difference", vmax=0.25))
    np.testing.assert_allclose(out[75, 190], INFERNO_LOW, atol=2 / 255)
    np.testing.assert_allclose(out[75, 80], INFERNO_HIGH, atol=2 / 255)
    bar_x = 2 + int(200 * 0.06) // 2
    top, bottom = out[10, bar_x], out[138, bar_x]
    assert top.sum() > bottom.sum() + 1.0  # bright at the top (vmax), dark at the bottom (0)
    plain = heatmap(error_map(a, b), 0.25, bar=False)
    np.testing.assert_allclose(plain[75, bar_x], INFERNO_HIGH, atol=2 / 255)
    small = compose(b[:90, :120], b[:90, :120], CompareSettings("difference", vmax=0.25))
    np.testing.assert_allclose(small, np.broadcast_to(INFERNO_LOW, (90, 120, 3)), atol=2 / 255)  # no bar


def test_error_map_is_the_mean_absolute_channel_error():
    a, b = _pair(8, 9)
    np.testing.assert_allclose(error_map(a, b), np.abs(a - b).mean(axis=2), atol=1e-6)


@pytest.mark.parametrize("kw", [{"mode": "swirl"}, {"t": 1.5}, {"t": float("nan")}, {"vmax": 0.0}])
def test_bad_settings_are_refused(kw):
    with pytest.raises(ValueError):
        CompareSettings(**kw)


def test_images_of_different_sizes_are_refused():
    with pytest.raises(ValueError, match="one size"):
        compose(np.zeros((4, 4, 3)), np.zeros((4, 5, 3)))
