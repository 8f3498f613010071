"""The sensors' white noise, estimated from the recordings alone (no model).

At 1 kHz the measured signals are smooth between a few sharp corners (steps, stick-slip),
so their third difference ``y[k+2] - 3 y[k+1] + 3 y[k] - y[k-1]`` is the noise's
(variance ``20 sigma^2`` for white noise) except at those corners. (The second difference
keeps a moving rod's acceleration: on a spring rod it read 1.8 x the position noise.) The
estimate: a robust scale of the third difference (median absolute deviation), the samples
beyond ``OUTLIER_FACTOR`` of it dropped as corners, the standard deviation of the rest over
sqrt(20); per channel, the median over the recordings that have it. An ADC's quantisation
is white to this estimate and counts as noise (``q / sqrt(12)``).

``train --rig`` and ``bench --rig`` give the fitted rig this noise
(``agents.rig.FittedRig.env_options``): a controller trained without it can amplify the
rig's sensor noise into valve chatter.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from pneumatic_env.recording import Recording
from pneumatic_env.recording_format import OUTPUT_COLUMNS

__all__ = ["OUTLIER_FACTOR", "noise_std", "sensor_noise"]

#: third differences beyond this many robust standard deviations are corners, not noise
OUTLIER_FACTOR = 5.0
_MAD_TO_STD = 1.4826  # the standard deviation of a Gaussian over its median abs. deviation
_MIN_SAMPLES = 20


def noise_std(y: np.ndarray) -> float:
    """The white-noise standard deviation of the uniformly sampled signal ``y`` (its
    unit), from its third difference (module docstring)."""
    y = np.asarray(y, dtype=float)
    if y.ndim != 1 or len(y) < _MIN_SAMPLES:
        raise ValueError(
            f"noise_std: y has shape {y.shape}: must be 1-D with at least {_MIN_SAMPLES} samples"
        )
    if not np.all(np.isfinite(y)):
        raise ValueError("noise_std: y has non-finite values: must be finite")
    d3 = np.diff(y, 3)
    centre = np.median(d3)
    scale = _MAD_TO_STD * np.median(np.abs(d3 - centre))
    if scale == 0.0:  # over half the samples lie on a parabola: noise below the ADC step
        return float(np.std(d3) / np.sqrt(20.0))
    kept = d3[np.abs(d3 - centre) <= OUTLIER_FACTOR * scale]
    return float(np.std(kept) / np.sqrt(20.0))


def sensor_noise(recordings: Sequence[Recording]) -> dict[str, float]:
    """{channel: noise standard deviation (SI)} of each measured output (p1, p2, x, f)
    some recording has: the median over those recordings of :func:`noise_std`."""
    out = {}
    for channel in OUTPUT_COLUMNS:
        values = [noise_std(r.channels[channel]) for r in recordings if r.has(channel)]
        if values:
            out[channel] = float(np.median(values))
    return out
