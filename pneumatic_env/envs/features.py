"""Observation features for a delayed plant, computed from the base observation.

The 2 m tube and the spool hide several control periods of commands that were sent but
not yet felt, so ``[p1, p2, x, f, ref(k), preview...]`` is not a Markov state; appending
the last k actions restores it for a constant input delay (Katsikopoulos & Engelbrecht,
IEEE TAC 2003). The env options below append these features after the base layout
(``TaskCore`` when any is on), and a controller rebuilds the same numbers from the base
observation in SI units and the currents it applied (:class:`FeatureState` on its own
rows), so a learned policy runs from the sensors alone.

Blocks, in this order (all O(1), whatever ``normalize_observation`` says; ``y`` is the
tracked channel: f for ForceTrack, x for PositionTrack; ``y_n = y / reference_scale``):

* ``action_history = K``: the last K applied coil currents ``u(k-1) .. u(k-K)`` in A
  (zeros before the episode's first step). Columns ``u-1 .. u-K``.
* ``measurement_history = M``: per measured channel c in (p1, p2, x, f), its changes
  ``10 (c_n(k) - c_n(k-j))`` for j = 1..M, with ``c_n`` normalised as the observation
  (``(p - P_a)/(P_s - P_a)``, ``x/(L/2)``, ``f/force_scale``); the past before the
  episode's start equals its first frame. Columns ``dp1-1 .. dp1-M``, ``dp2-*``,
  ``dx-*``, ``df-*``.
* ``tracking_error``: ``e_n = y_n - r_n(k)`` and ``10 I`` with
  ``I(k) = (1 - dt/tau) I(k-1) + (dt/tau) e_n(k)`` (leaky: a low-pass of e_n with time
  constant ``tau = error_integral_tau_s``) or ``I(k) = I(k-1) + (dt/tau) e_n(k)``
  (``error_integral_leaky=False``: the plain integral in units of tau), I = 0 before the
  episode. Columns ``e``, ``e_int``.
* ``relative_preview``: the preview as differences from the measured tracked channel,
  ``r_n(k+j) - y_n(k)`` for j = 0..H. Columns ``rel_ref+0 .. rel_ref+H``.

The base layout's columns are named ``p1, p2, x, f, ref+0 .. ref+H``
(:func:`observation_columns`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields

import numpy as np

from .observation import OBS_F, OBS_P1, OBS_P2, OBS_REF, OBS_X, OBSERVED_CHANNELS, ObservationScales

__all__ = [
    "FeatureConfig",
    "FeatureState",
    "FEATURE_OPTIONS",
    "observation_columns",
    "normalize_base_observation",
    "HISTORY_SCALE",
    "INTEGRAL_SCALE",
]

HISTORY_SCALE = 10.0  # measured changes over a few ms are ~0.1 of a channel's unit
INTEGRAL_SCALE = 10.0  # the (leaky) error integral is ~0.1 of the scale in steady tracking


@dataclass(frozen=True)
class FeatureConfig:
    """The feature options of a tracking env (keyword arguments of ``gym.make``)."""

    action_history: int = 0  # K last applied currents
    measurement_history: int = 0  # M frames of changes of the measured channels
    tracking_error: bool = False  # e_n and its (leaky) integral
    error_integral_tau_s: float = 0.2  # the integral's time constant (s)
    error_integral_leaky: bool = True  # leaky (low-pass) or plain integral
    relative_preview: bool = False  # r_n(k+j) - y_n(k), j = 0..H

    @classmethod
    def from_options(cls, options) -> FeatureConfig:
        """The feature options of an ``EnvOptions`` (or any object with these fields)."""
        return cls(**{f.name: getattr(options, f.name) for f in fields(cls)})

    def as_dict(self) -> dict:
        return asdict(self)

    @property
    def enabled(self) -> bool:
        return bool(
            self.action_history
            or self.measurement_history
            or self.tracking_error
            or self.relative_preview
        )

    def validate(self) -> None:
        for name in ("action_history", "measurement_history"):
            value = getattr(self, name)
            if isinstance(value, bool) or int(value) != value or value < 0:
                raise ValueError(f"{name} = {value!r} is not allowed: must be an integer >= 0")
        for name in ("tracking_error", "relative_preview", "error_integral_leaky"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise ValueError(
                    f"{name} = {getattr(self, name)!r} is not allowed: must be True or False"
                )
        tau = self.error_integral_tau_s
        if not (np.isfinite(tau) and tau > 0):
            raise ValueError(
                f"error_integral_tau_s = {tau!r} is not allowed: must be a finite number > 0"
            )

    def columns(self, preview_steps: int) -> list[str]:
        """Names of the feature columns (appended after the base layout)."""
        names = [f"u-{j}" for j in range(1, int(self.action_history) + 1)]
        for ch in OBSERVED_CHANNELS:
            names += [f"d{ch}-{j}" for j in range(1, int(self.measurement_history) + 1)]
        if self.tracking_error:
            names += ["e", "e_int"]
        if self.relative_preview:
            names += [f"rel_ref+{j}" for j in range(int(preview_steps) + 1)]
        return names

    def dim(self, preview_steps: int) -> int:
        return len(self.columns(preview_steps))


FEATURE_OPTIONS = tuple(f.name for f in fields(FeatureConfig))


def observation_columns(preview_steps: int, features: FeatureConfig | None = None) -> list[str]:
    """Column names of an observation row: the base layout, then the features."""
    base = list(OBSERVED_CHANNELS) + [f"ref+{j}" for j in range(int(preview_steps) + 1)]
    return base + (features.columns(preview_steps) if features is not None else [])


def _channels_n(obs: np.ndarray, scales: ObservationScales) -> np.ndarray:
    """(n, 4) measured channels normalised as the observation, float64, from SI rows."""
    span = scales.supply_pa - scales.ambient_pa
    return np.stack(
        [
            (obs[:, OBS_P1] - scales.ambient_pa) / span,
            (obs[:, OBS_P2] - scales.ambient_pa) / span,
            obs[:, OBS_X] / scales.half_stroke_m,
            obs[:, OBS_F] / scales.force_scale_n,
        ],
        axis=1,
    )


def normalize_base_observation(obs: np.ndarray, scales: ObservationScales) -> np.ndarray:
    """SI base rows -> the ``normalize_observation=True`` layout (float64): the numpy twin
    of ``observation.fill_observation_row`` for controllers that get SI observations."""
    o = np.asarray(obs, dtype=np.float64)
    out = np.empty_like(o)
    out[:, :OBS_REF] = _channels_n(o, scales)
    out[:, OBS_REF:] = o[:, OBS_REF:] / scales.reference_scale
    return out


class FeatureState:
    """The feature state of ``n`` rows (histories, integral) and its values.

    Env side and controller side alike: ``reset(rows, obs_si)`` starts episodes (their
    first observation), ``update(obs_si, applied_a)`` takes every row's next observation and
    the current applied before it. ``values`` (n, dim) float32 holds the features of the
    last observation. ``obs_si``: base rows ``[p1, p2, x, f, ref(k..k+H)]`` in SI units.
    """

    def __init__(
        self,
        config: FeatureConfig,
        n: int,
        preview_steps: int,
        scales: ObservationScales,
        dt_s: float,
        tracked: str = "f",
    ):
        config.validate()
        self.config = config
        self.n, self.preview = int(n), int(preview_steps)
        self.scales = scales
        self.dt_s = float(dt_s)
        self.tracked = {"f": OBS_F, "x": OBS_X}[tracked]
        self.K, self.M = int(config.action_history), int(config.measurement_history)
        self.dim = config.dim(self.preview)
        self.actions = np.zeros((self.n, self.K))
        self.history = np.zeros((self.n, len(OBSERVED_CHANNELS), self.M + 1))  # col 0 newest
        self.integral = np.zeros(self.n)
        self.values = np.zeros((self.n, self.dim), dtype=np.float32)

    def _assemble(self, obs, rows) -> np.ndarray:
        parts = []
        if self.K:
            parts.append(self.actions[rows])
        if self.M:
            h = self.history[rows]
            parts.append((HISTORY_SCALE * (h[:, :, :1] - h[:, :, 1:])).reshape(h.shape[0], -1))
        scale = self.scales.reference_scale
        y = obs[:, self.tracked] / scale
        if self.config.tracking_error:
            e = y - obs[:, OBS_REF] / scale
            parts += [e[:, None], INTEGRAL_SCALE * self.integral[rows][:, None]]
        if self.config.relative_preview:
            refs = obs[:, OBS_REF : OBS_REF + self.preview + 1] / scale
            parts.append(refs - y[:, None])
        if not parts:
            return np.zeros((obs.shape[0], 0), dtype=np.float32)
        return np.concatenate(parts, axis=1).astype(np.float32)

    def _integrate(self, obs, previous):
        scale = self.scales.reference_scale
        e = obs[:, self.tracked] / scale - obs[:, OBS_REF] / scale
        a = self.dt_s / self.config.error_integral_tau_s
        if self.config.error_integral_leaky:
            return (1 - a) * previous + a * e
        return previous + a * e

    def reset(self, rows, obs_si) -> None:
        """Start the episodes of ``rows`` at their first observation ``obs_si`` (len(rows)
        rows): no past actions, the past equal to the present, I = 0 before it."""
        rows = np.asarray(rows, dtype=np.int64)
        if rows.size == 0:
            return
        obs = np.asarray(obs_si, dtype=np.float64)
        self.actions[rows] = 0.0
        if self.M:
            self.history[rows] = _channels_n(obs, self.scales)[:, :, None]
        if self.config.tracking_error:
            self.integral[rows] = self._integrate(obs, np.zeros(rows.size))
        self.values[rows] = self._assemble(obs, rows)

    def update(self, obs_si, applied_a) -> np.ndarray:
        """Every row's next observation after applying ``applied_a`` (A, clipped); returns
        ``values``."""
        obs = np.asarray(obs_si, dtype=np.float64)
        if self.K:
            self.actions[:, 1:] = self.actions[:, :-1]
            self.actions[:, 0] = applied_a
        if self.M:
            self.history[:, :, 1:] = self.history[:, :, :-1]
            self.history[:, :, 0] = _channels_n(obs, self.scales)
        if self.config.tracking_error:
            self.integral = self._integrate(obs, self.integral)
        self.values[:] = self._assemble(obs, slice(None))
        return self.values
