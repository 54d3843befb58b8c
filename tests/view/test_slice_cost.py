"""`SliceCost`: slices sized by their splats' predicted cost stay near the budget where the rate along the sorted
order changes (the rule it replaced, the last slice's rate, overshot 2-3x there)."""

from __future__ import annotations

import numpy as np

from npga_view.rendering.slice_cost import MIN_SLICE, SliceCost, footprints


def _true_ms(pixels: np.ndarray, first: int, count: int) -> float:
    return 1.5e-3 * count + 12.0 * float(pixels[first : first + count].sum()) / 1e6


def test_slices_fit_the_budget_where_splats_grow():
    rng = np.random.default_rng(0)
    n = 60_000
    # small background splats, then 10k large ones (a head's shoulders and hair), then small facial ones
    pixels = np.concatenate([rng.uniform(5, 50, 20_000), rng.uniform(300, 3000, 10_000), rng.uniform(5, 80, 30_000)])
    cost = SliceCost()
    worst, last_rule_worst = [], []
    for _image in range(4):
        cost.begin(pixels)
        first, last_count, last_ms = 0, 8192, 0.0
        while first < n:
            budget = 12.0
            count = cost.count(first, n, budget)
            ms = _true_ms(pixels, first, count)
            cost.record(first, count, ms)
            worst.append(ms / budget)
            # the earlier rule: the next slice scaled by the last one's rate
            grow = min(4.0, max(0.25, budget / max(last_ms, 1e-3))) if last_ms else 1.0
            last_count = int(max(1024, last_count * grow))
            last_ms = _true_ms(pixels, first, min(last_count, n - first))
            last_rule_worst.append(last_ms / budget)
            first += count
    assert np.percentile(worst[8:], 95) < 1.3  # once the model has seen an image
    assert max(last_rule_worst) > 2.0  # (what the earlier rule did on the same order)
    assert 1e-3 < cost.coef[0] < 2e-3 and 10.0 < cost.coef[1] < 14.0


def test_counts_without_footprints_and_bounds():
    cost = SliceCost()
    cost.begin(None)
    assert MIN_SLICE <= cost.count(0, 100_000, 10.0) <= 100_000
    assert cost.count(99_900, 100_000, 1e9) == 100
    cost.begin(np.full(1000, 10.0))
    assert cost.count(0, 999, 5.0) >= MIN_SLICE or cost.count(0, 999, 5.0) == 999  # a stale length falls back


def test_footprints_are_clipped_to_the_image():
    z = np.array([1.0, 0.001, 10.0, -1.0])
    r = np.array([0.01, 1.0, 0.01, 0.01])
    px = footprints(z, r, 1000.0, 1000.0, 640, 480)
    assert px[0] == (0.01 * 1000 * 6 + 1) ** 2 and px[1] == 640 * 480 and px[2] < px[0]
    assert np.all(px >= 1.0) and np.all(px <= 640 * 480)
