"""Seed statistics for learned-control claims (pneumatic_env.agents.stats)."""

import numpy as np
import pytest

from pneumatic_env.agents import stats


def test_iqm_is_the_mean_of_the_middle_half():
    scores = np.arange(1.0, 17.0).reshape(4, 4)  # 16 values: the middle 8 are 5..12
    assert stats.iqm(scores) == pytest.approx(np.mean(np.arange(5.0, 13.0)))
    outlier = scores.copy()
    outlier[3, 3] = 1e6  # the largest score made an outlier: the IQM does not move
    assert stats.iqm(outlier) == pytest.approx(stats.iqm(scores))


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_iqm_interval_covers_the_true_iqm(seed):
    """Over 200 experiments of 10 runs x 9 tasks from a known distribution, the 95 % interval
    covers the population's IQM in 85-100 % of them (threshold set before running)."""
    rng = np.random.default_rng(seed)
    true_iqm = stats.iqm(rng.lognormal(0.0, 0.3, size=(200_000, 1)))
    hits = 0
    for _ in range(200):
        est = stats.iqm_estimate(
            rng.lognormal(0.0, 0.3, size=(10, 9)), reps=300, seed=int(rng.integers(1 << 30))
        )
        assert est.low <= est.value <= est.high
        hits += est.low <= true_iqm <= est.high
    assert 0.85 <= hits / 200 <= 1.0


def test_probability_of_improvement_counts_lower_errors():
    low, high = np.full((5, 3), 1.0), np.full((4, 3), 2.0)
    assert stats.probability_of_improvement(low, high) == 1.0
    assert stats.probability_of_improvement(high, low) == 0.0
    assert stats.probability_of_improvement(low, low) == 0.5
    rng = np.random.default_rng(0)
    x, y = rng.normal(size=(6, 4)), rng.normal(size=(7, 4))
    assert stats.probability_of_improvement(x, y) == pytest.approx(
        1 - stats.probability_of_improvement(y, x)
    )


def test_paired_ratio_and_beats():
    baseline = np.array([[2.0, 4.0, 8.0]])
    better = np.tile(0.5 * baseline, (6, 1)) * np.linspace(0.9, 1.1, 6)[:, None]
    summary = stats.summarize(better, baseline, reps=500)
    assert summary["paired_ratio"]["value"] == pytest.approx(0.5)
    assert summary["paired_ratio"]["high"] < 1.0 and summary["beats"]
    assert summary["probability_of_improvement"]["value"] == 1.0
    worse = stats.summarize(np.tile(1.2 * baseline, (6, 1)), baseline, reps=500)
    assert not worse["beats"] and worse["paired_ratio"]["low"] > 1.0


def test_bad_scores_name_the_field_and_value():
    with pytest.raises(ValueError, match=r"scores contains nan: .*finite"):
        stats.iqm([[1.0, np.nan]])
    with pytest.raises(ValueError, match=r"baseline has 2 tasks and x 3"):
        stats.paired_ratio_estimate(np.ones((2, 3)), np.ones((1, 2)))
    with pytest.raises(ValueError, match=r"baseline contains 0.0: .*> 0"):
        stats.paired_ratio_estimate(np.ones((2, 2)), np.array([[1.0, 0.0]]))
