"""The one smoothing filter (npga_core/posing/smoothing.py) for sequences and streams: against a plain reference
of each method written from its definition (Casiez et al. 2012 for the 1-euro filter), a whole table equal to the
same rows streamed, uneven intervals, restarts, and the window's timeline settings read safely."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from npga_core.posing.smoothing import METHODS, Smoothing, SmoothingFilter, check_playback, jitter


def _reference(x: np.ndarray, dts: list[float], method: str, alpha=0.5, min_cutoff=1.0, beta=0.5, d_cutoff=1.0):
    """Each method by its definition, one scalar channel at a time (dts[t]: seconds before sample t)."""
    def smoothing_factor(cutoff: float, dt: float) -> float:
        r = 2 * math.pi * cutoff * dt
        return r / (r + 1)

    out = np.zeros_like(x, dtype=np.float64)
    for k in range(x.shape[1]):
        y_prev, dx_prev = float(x[0, k]), 0.0
        out[0, k] = y_prev
        for t in range(1, len(x)):
            v = float(x[t, k])
            if method == "none":
                y_prev = v
            elif method == "exponential":
                y_prev = alpha * v + (1 - alpha) * y_prev
            else:
                dx = (v - y_prev) / dts[t]
                a_d = smoothing_factor(d_cutoff, dts[t])
                dx_prev = a_d * dx + (1 - a_d) * dx_prev
                a = smoothing_factor(min_cutoff + beta * abs(dx_prev), dts[t])
                y_prev = a * v + (1 - a) * y_prev
            out[t, k] = y_prev
    return out


@pytest.fixture
def noisy() -> np.ndarray:
    rng = np.random.default_rng(5)
    t = np.linspace(0, 2, 90)[:, None]
    return (np.sin(3 * t + np.arange(4)) + 0.05 * rng.standard_normal((90, 4))).astype(np.float32)


@pytest.mark.parametrize("settings", [Smoothing("none"), Smoothing("exponential", alpha=0.3),
                                      Smoothing("one_euro", min_cutoff=0.8, beta=0.7)])
def test_a_table_is_smoothed_as_the_definitions_say(noisy, settings):
    out = SmoothingFilter(settings).run(noisy, 30.0)
    want = _reference(noisy, [1 / 30] * len(noisy), settings.method, settings.alpha, settings.min_cutoff,
                      settings.beta)
    assert out.dtype == np.float32 and out.shape == noisy.shape
    np.testing.assert_allclose(out, want, atol=1e-5)
    if settings.method != "none":
        assert jitter(out) < 0.8 * jitter(noisy)


def test_a_stream_at_uneven_intervals_and_the_table_at_its_rate_are_one_filter(noisy):
    euro = Smoothing("one_euro", min_cutoff=1.0, beta=0.5)
    dts = [0.0] + list(np.random.default_rng(6).uniform(0.01, 0.05, len(noisy) - 1))
    f = SmoothingFilter(euro)
    streamed = np.stack([f.step(x, dt) for x, dt in zip(noisy, dts, strict=True)])
    np.testing.assert_allclose(streamed, _reference(noisy, dts, "one_euro"), atol=1e-5)
    # at an even rate, sample by sample equals the whole table at once, bit for bit
    g = SmoothingFilter(euro)
    even = np.stack([g.step(x, 1 / 60) for x in noisy])
    np.testing.assert_array_equal(even, SmoothingFilter(euro).run(noisy, 60.0))


def test_a_restart_forgets_the_past(noisy):
    f = SmoothingFilter(Smoothing("exponential", alpha=0.2))
    for x in noisy[:10]:
        f.step(x, 1 / 30)
    np.testing.assert_array_equal(f.step(noisy[10], 0.0), noisy[10])  # dt 0: the stream restarted (a clock jump)
    f.step(noisy[11], 1 / 30)
    np.testing.assert_array_equal(f.step(noisy[:2, 0], 1 / 30), noisy[:2, 0])  # another shape: a new stream
    f.reset()
    np.testing.assert_array_equal(f.step(noisy[12], 1 / 30), noisy[12])


def test_settings_are_checked_and_the_timeline_is_read_clamped():
    for bad in (dict(method="cubic"), dict(alpha=0.0), dict(alpha=1.5), dict(min_cutoff=0.0), dict(beta=-1.0)):
        with pytest.raises(ValueError):
            Smoothing(**bad)
    tl = SimpleNamespace(smoothing="one_euro", smooth_alpha=0.0, euro_min_cutoff=-3.0, euro_beta=float("nan"))
    s = Smoothing.of(tl)  # typed into a slider: out of range, never an error in the frame loop
    assert s == Smoothing("one_euro", alpha=1e-3, min_cutoff=1e-6, beta=0.5)
    assert Smoothing.of(SimpleNamespace(smoothing="cubic")).method == "none"
    assert Smoothing.of(SimpleNamespace(smoothing="exponential", smooth_alpha=0.4)) == Smoothing("exponential", 0.4)
    assert len({Smoothing.of(tl), Smoothing.of(tl)}) == 1  # equal settings are one key
    with pytest.raises(ValueError, match="smoothing"):
        check_playback(SimpleNamespace(smoothing="cubic"))
    for m in METHODS:
        check_playback(SimpleNamespace(smoothing=m))


def test_no_smoothing_and_short_tables(noisy):
    np.testing.assert_array_equal(SmoothingFilter().run(noisy, 0.0), noisy)  # "none" needs no rate
    assert SmoothingFilter(Smoothing("one_euro")).run(noisy[:0], 30.0).shape == (0, 4)
    with pytest.raises(ValueError, match="fps"):
        SmoothingFilter(Smoothing("exponential")).run(noisy, 0.0)
