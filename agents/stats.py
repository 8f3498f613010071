"""Statistics over training seeds for learned-control claims (Agarwal et al., NeurIPS 2021).

Scores are errors (lower is better) in an array ``(n_runs, n_tasks)``: one row per training
seed, one column per benchmark task. Computed with NumPy in the way rliable does (rliable
1.2 does not import beside pandas 3, whose ``arch`` dependency breaks):

* the interquartile mean (IQM): the mean of the middle 50 % of all run-task scores
  (``scipy.stats.trim_mean(..., 0.25)`` of the flattened array);
* 95 % stratified bootstrap confidence intervals: runs are resampled with replacement
  within each task;
* the probability of improvement ``P(X < Y)`` of runs X over runs Y (Mann-Whitney,
  ties count one half), averaged over tasks;
* the paired ratio: per run, the mean over tasks of ``X / Y`` (task by task, Y a
  deterministic baseline or the mean of its runs); "X beats Y" needs its interval below 1.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from scipy import stats

__all__ = [
    "Estimate",
    "iqm",
    "iqm_estimate",
    "paired_ratio_estimate",
    "probability_of_improvement",
    "improvement_estimate",
    "summarize",
]

DEFAULT_REPS = 2000
CONFIDENCE = 0.95


@dataclass(frozen=True)
class Estimate:
    """A point estimate with its bootstrap interval."""

    value: float
    low: float
    high: float
    n_runs: int

    def as_dict(self) -> dict:
        return asdict(self)

    def __str__(self) -> str:
        return f"{self.value:.3g} [{self.low:.3g}, {self.high:.3g}]"


def _scores(scores, name: str = "scores") -> np.ndarray:
    a = np.asarray(scores, dtype=float)
    if a.ndim == 1:
        a = a[:, None]
    if a.ndim != 2 or a.shape[0] < 1 or a.shape[1] < 1:
        raise ValueError(
            f"{name} has shape {a.shape}: expected (n_runs, n_tasks) with at least "
            "one run and one task"
        )
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} contains {a[~np.isfinite(a)][0]}: scores must be finite")
    return a


def iqm(scores) -> float:
    """Interquartile mean of all run-task scores."""
    return float(stats.trim_mean(_scores(scores).ravel(), 0.25))


def _stratified_resamples(n_runs: int, n_tasks: int, reps: int, rng) -> np.ndarray:
    """Run indices ``(reps, n_runs, n_tasks)``: each task's runs resampled independently."""
    return rng.integers(0, n_runs, size=(reps, n_runs, n_tasks))


def _interval(point: float, samples: np.ndarray, n_runs: int) -> Estimate:
    alpha = (1 - CONFIDENCE) / 2
    low, high = np.quantile(samples, [alpha, 1 - alpha])
    return Estimate(float(point), float(low), float(high), n_runs)


def iqm_estimate(scores, reps: int = DEFAULT_REPS, seed: int = 0) -> Estimate:
    """IQM with a 95 % stratified bootstrap interval."""
    a = _scores(scores)
    n_runs, n_tasks = a.shape
    idx = _stratified_resamples(n_runs, n_tasks, reps, np.random.default_rng(seed))
    resampled = np.take_along_axis(a[None], idx, axis=1).reshape(reps, -1)
    samples = stats.trim_mean(resampled, 0.25, axis=1)
    return _interval(iqm(a), samples, n_runs)


def probability_of_improvement(x, y) -> float:
    """``P(X < Y)`` (lower error is better), ties counting one half, averaged over tasks."""
    a, b = _scores(x, "x"), _scores(y, "y")
    if a.shape[1] != b.shape[1]:
        raise ValueError(f"x has {a.shape[1]} tasks and y {b.shape[1]}: they must be the same")
    less = (a[:, None, :] < b[None, :, :]).mean(axis=(0, 1))
    ties = (a[:, None, :] == b[None, :, :]).mean(axis=(0, 1))
    return float(np.mean(less + 0.5 * ties))


def improvement_estimate(x, y, reps: int = DEFAULT_REPS, seed: int = 0) -> Estimate:
    """``probability_of_improvement(x, y)`` with a stratified bootstrap over both run sets."""
    a, b = _scores(x, "x"), _scores(y, "y")
    rng = np.random.default_rng(seed)
    samples = np.empty(reps)
    for rep in range(reps):
        ia = rng.integers(0, a.shape[0], size=a.shape)
        ib = rng.integers(0, b.shape[0], size=b.shape)
        samples[rep] = probability_of_improvement(
            np.take_along_axis(a, ia, 0), np.take_along_axis(b, ib, 0)
        )
    return _interval(probability_of_improvement(a, b), samples, a.shape[0])


def paired_ratio_estimate(x, baseline, reps: int = DEFAULT_REPS, seed: int = 0) -> Estimate:
    """Mean over runs of each run's mean over tasks of ``x / baseline``, with a bootstrap
    interval over runs. ``baseline`` is one row per task (a deterministic controller) or
    ``(n_runs_b, n_tasks)``, whose mean over runs is used."""
    a = _scores(x, "x")
    b = _scores(baseline, "baseline")
    b = b.mean(axis=0) if b.shape[0] > 1 else b[0]
    if b.shape[0] != a.shape[1]:
        raise ValueError(
            f"baseline has {b.shape[0]} tasks and x {a.shape[1]}: they must be the same"
        )
    if np.any(b <= 0):
        raise ValueError(f"baseline contains {b[b <= 0][0]}: errors must be > 0 for a ratio")
    per_run = (a / b).mean(axis=1)
    rng = np.random.default_rng(seed)
    samples = per_run[rng.integers(0, per_run.size, size=(reps, per_run.size))].mean(axis=1)
    return _interval(float(per_run.mean()), samples, a.shape[0])


def summarize(x, baseline, reps: int = DEFAULT_REPS, seed: int = 0) -> dict:
    """IQM of ``x`` and of ``baseline``, the paired ratio and the probability of improvement,
    each with its 95 % interval, and whether x beats the baseline (ratio interval below 1)."""
    ratio = paired_ratio_estimate(x, baseline, reps, seed)
    return {
        "iqm": iqm_estimate(x, reps, seed).as_dict(),
        "baseline_iqm": iqm_estimate(baseline, reps, seed).as_dict(),
        "paired_ratio": ratio.as_dict(),
        "probability_of_improvement": improvement_estimate(x, baseline, reps, seed).as_dict(),
        "beats": bool(ratio.high < 1.0),
    }
