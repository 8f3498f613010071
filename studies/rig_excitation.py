"""Excitation of the virtual rig: the coil-current signals of its experiments.

One segment kind (rest, steps of both signs, PRBS, multisine, chirp, slow triangle) or
the ``identification`` layout of ``virtual_rig.excitation.block_layout`` in
``configs/identification.yaml`` (two blocks, so a time split holds out every kind).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from pneumatic_env.identification.config import IdentificationConfig, load_config
from pneumatic_env.references import ChirpReference, MultisineReference

__all__ = ["EXCITATIONS", "USER_SIGNALS", "UserExcitation", "excitation"]

EXCITATIONS = ("identification", "steps", "prbs", "multisine", "chirp", "triangle")
_SEGMENTS = ("rest", "step_pos", "step_neg", "prbs", "multisine", "chirp", "triangle")


def _segment(
    kind: str, n: int, dt: float, rng: np.random.Generator, cfg: IdentificationConfig
) -> np.ndarray:
    ex = lambda name: cfg.value("virtual_rig", "excitation", name)  # noqa: E731
    if n <= 0:
        return np.zeros(0)
    if kind == "rest":
        return np.zeros(n)
    if kind in ("step_pos", "step_neg"):
        return np.full(n, float(ex("step_a")) * (1.0 if kind == "step_pos" else -1.0))
    if kind == "prbs":
        hold = max(1, int(round(float(ex("prbs_hold_s")) / dt)))
        levels = rng.choice([-1.0, 1.0], size=n // hold + 1)
        return float(ex("prbs_a")) * np.repeat(levels, hold)[:n]
    if kind == "multisine":
        f_lo, f_hi = (float(f) for f in ex("multisine_band_hz"))
        period = n * dt
        k = np.arange(max(1, math.ceil(f_lo * period)), max(2, math.floor(f_hi * period)) + 1)
        spec = MultisineReference(
            amplitude=float(ex("multisine_a")), frequencies_hz=tuple(k / period), phases="random"
        )
        return spec.generate(n, dt, rng)
    if kind == "chirp":
        f0, f1 = (float(f) for f in ex("chirp_band_hz"))
        return ChirpReference(
            amplitude=float(ex("chirp_a")), f0_hz=f0, f1_hz=f1, duration_s=n * dt
        ).generate(n, dt)
    if kind == "triangle":
        a = float(ex("triangle_a"))
        phase = np.arange(n) / n  # one period: 0 -> +a -> -a -> 0
        return a * np.where(
            phase < 0.25, 4 * phase, np.where(phase < 0.75, 2 - 4 * phase, 4 * phase - 4)
        )
    raise ValueError(f"excitation segment {kind!r} is not known; allowed: {', '.join(_SEGMENTS)}")


#: Signal kinds of a :class:`UserExcitation`.
USER_SIGNALS = ("random_steps", "multisine", "pulses", "sine")


class UserExcitation(NamedTuple):
    """An experiment's own signal, set by the user rather than the config's excitation.

    ``random_steps``: levels drawn uniformly in +-``amplitude_a``, each held ``hold_s``;
    ``multisine``: random phases on the FFT grid of the segment within ``band_hz``, peak
    ``amplitude_a``; ``pulses``: ``amplitude_a`` for ``hold_s`` at the start of every
    ``period_s``, 0 otherwise; ``sine``: ``amplitude_a sin(2 pi t / period_s)``.
    """

    signal: str
    amplitude_a: float
    hold_s: float = 0.0
    period_s: float = 0.0
    band_hz: tuple[float, float] = (0.0, 0.0)


def _user_signal(spec: UserExcitation, n: int, dt: float, rng: np.random.Generator) -> np.ndarray:
    t = dt * np.arange(n)
    a = float(spec.amplitude_a)
    if spec.signal == "random_steps":
        hold = max(1, int(round(spec.hold_s / dt)))
        return np.repeat(rng.uniform(-a, a, size=n // hold + 1), hold)[:n]
    if spec.signal == "multisine":
        period = n * dt
        f_lo, f_hi = spec.band_hz
        k = np.arange(max(1, math.ceil(f_lo * period)), max(2, math.floor(f_hi * period)) + 1)
        return MultisineReference(amplitude=a, frequencies_hz=tuple(k / period)).generate(
            n, dt, rng
        )
    if spec.signal == "pulses":
        return np.where(np.mod(t, spec.period_s) < spec.hold_s - 0.5 * dt, a, 0.0)
    if spec.signal == "sine":
        return a * np.sin(2.0 * math.pi * t / spec.period_s)
    raise ValueError(
        f"user signal {spec.signal!r} is not known; allowed: {', '.join(USER_SIGNALS)}"
    )


def excitation(
    kind: str | UserExcitation,
    n_samples: int,
    dt_s: float,
    rng: np.random.Generator,
    config: IdentificationConfig | None = None,
) -> np.ndarray:
    """Coil current (A) for identification, ``n_samples`` at ``dt_s``.

    ``identification``: two blocks of ``virtual_rig.excitation.block_layout`` (rest
    periods, steps of both signs, PRBS, multisine, chirp, slow triangle) sized
    ``train_fraction`` and the rest of the recording, so a time split holds out the same
    kinds of segment. The other kinds are one segment type over the whole recording
    (``steps`` alternates +/- steps with rests). A :class:`UserExcitation` is its own signal.
    """
    if isinstance(kind, UserExcitation):
        return _user_signal(kind, n_samples, dt_s, rng)
    cfg = config or load_config()
    if kind not in EXCITATIONS:
        raise ValueError(f"excitation {kind!r} is not known; allowed: {', '.join(EXCITATIONS)}")
    if kind == "identification":
        split = int(round(cfg.number("fit", "train_fraction") * n_samples))
        layout = cfg.value("virtual_rig", "excitation", "block_layout")
        parts = []
        for n_block in (split, n_samples - split):
            shares = np.array([float(s) for _, s in layout])
            bounds = np.round(np.concatenate([[0], np.cumsum(shares) / shares.sum()]) * n_block)
            for (seg, _), a, b in zip(layout, bounds[:-1], bounds[1:]):
                parts.append(_segment(seg, int(b - a), dt_s, rng, cfg))
        return np.concatenate(parts)
    if kind == "steps":
        quarter = n_samples // 4
        out = np.concatenate(
            [_segment(s, quarter, dt_s, rng, cfg) for s in ("step_pos", "rest", "step_neg", "rest")]
        )
        return np.concatenate([out, np.zeros(n_samples - out.size)])
    return _segment(kind, n_samples, dt_s, rng, cfg)
