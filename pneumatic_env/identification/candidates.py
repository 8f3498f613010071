"""Candidate effects and the measurement-side (sensor) model.

A candidate effect is a declarative entry of ``configs/identification.yaml`` under
``candidates``: a name, a kind, the parameters to fit (bounds, warm start, plausible
range, neutral value), parameters to fix while it is on (``set``) and what data it needs.

- ``plant`` effects are kernel parameter rows (docs/effects.md; the cross-piston leak of
  Sec. 2.2). A plant effect whose parameter names are not in
  :data:`pneumatic_env.physics.layout.PARAMETER_NAMES` is skipped, so entries for effects
  still being added to the kernel plug in as soon as the rows exist.
- ``sensor`` effects act on the simulated channels (:func:`apply_sensor_model`): a
  constant offset of each pressure transducer, a first-order lag of the pressure
  transducers, and a time skew of all measured outputs against the coil current.

Adding an effect = adding an entry to the YAML (and, for a plant effect, its row to the
kernel); nothing here changes.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterable, Mapping, Sequence

import numpy as np
from scipy.signal import lfilter

from pneumatic_env.params import ConfigError
from pneumatic_env.physics.layout import PARAMETER_NAMES

from .config import FitParameter, IdentificationConfig, _parse_parameter, load_config

__all__ = [
    "Candidate",
    "SENSOR_NEUTRAL",
    "SENSOR_PARAMETERS",
    "apply_sensor_model",
    "applicable",
    "available_candidates",
    "candidate_table",
    "separating_experiment",
]

#: Sensor-side parameters and their neutral values (the sensor model is the identity).
SENSOR_NEUTRAL = {
    "pressure_offset_p1_pa": 0.0,
    "pressure_offset_p2_pa": 0.0,
    "pressure_sensor_time_constant_s": 0.0,
    "channel_skew_s": 0.0,
}
SENSOR_PARAMETERS = tuple(SENSOR_NEUTRAL)
_KINDS = ("plant", "sensor")
_CANDIDATE_KEYS = {"kind", "description", "parameters", "set", "requires_motion",
                   "requires_any_channel"}


@dataclass(frozen=True)
class Candidate:
    """One candidate effect (see the module docstring)."""

    name: str
    kind: str
    description: str
    parameters: tuple[FitParameter, ...]
    set: Mapping[str, float] = field(default_factory=dict)
    requires_motion: bool = False
    requires_any_channel: tuple[str, ...] = ()

    @property
    def parameter_names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.parameters)

    @property
    def available(self) -> bool:
        """Whether the kernel (plant) or the sensor model knows every parameter."""
        names = list(self.parameter_names) + list(self.set)
        if self.kind == "sensor":
            return all(n in SENSOR_NEUTRAL for n in self.parameter_names)
        return all(n in PARAMETER_NAMES for n in names)

    def neutral(self) -> dict[str, float]:
        """Parameter values that switch the effect off."""
        return {p.name: p.neutral for p in self.parameters}


def candidate_table(config: IdentificationConfig | None = None) -> dict[str, Candidate]:
    """Every candidate declared in the config, available or not, by name."""
    config = config or load_config()
    out = {}
    where = f"{config.path}: candidates"
    for name, entry in config.raw["candidates"].items():
        if not isinstance(entry, Mapping):
            raise ConfigError(f"{where}.{name} must be a mapping")
        extra = sorted(set(entry) - _CANDIDATE_KEYS)
        if extra:
            raise ConfigError(f"{where}.{name} has unknown key {extra[0]!r}; allowed keys: "
                              f"{', '.join(sorted(_CANDIDATE_KEYS))}")
        kind = entry.get("kind")
        if kind not in _KINDS:
            raise ConfigError(f"{where}.{name}.kind = {kind!r} is not allowed: must be one of "
                              f"{list(_KINDS)}")
        params = entry.get("parameters")
        if not isinstance(params, Mapping) or not params:
            raise ConfigError(f"{where}.{name}.parameters must be a non-empty mapping")
        fitted = tuple(_parse_parameter(f"{where}.{name}.parameters", p, e, kind, True)
                       for p, e in params.items())
        if kind == "sensor":
            for p in fitted:
                if p.name not in SENSOR_NEUTRAL:
                    raise ConfigError(f"{where}.{name}: sensor parameter {p.name!r} is not "
                                      f"known; known: {', '.join(SENSOR_PARAMETERS)}")
        fixed = dict(entry.get("set") or {})
        channels = tuple(entry.get("requires_any_channel") or ())
        out[name] = Candidate(name=name, kind=kind, description=str(entry.get("description", "")),
                              parameters=fitted, set={k: float(v) for k, v in fixed.items()},
                              requires_motion=bool(entry.get("requires_motion", False)),
                              requires_any_channel=channels)
    return out


def available_candidates(names: Iterable[str] | None = None,
                         config: IdentificationConfig | None = None) -> list[Candidate]:
    """The candidates the kernel and sensor model support, optionally only ``names``.

    Raises :class:`ConfigError` for a name that is not declared, or declared but not
    available in this kernel.
    """
    table = candidate_table(config)
    if names is None:
        return [c for c in table.values() if c.available]
    out = []
    for name in names:
        if name not in table:
            raise ConfigError(f"candidate {name!r} is not declared in configs/identification.yaml;"
                              f" declared: {', '.join(table)}")
        if not table[name].available:
            raise ConfigError(f"candidate {name!r} needs kernel parameter(s) "
                              f"{[n for n in table[name].parameter_names if n not in PARAMETER_NAMES]}"
                              " that this version of the kernel does not have")
        out.append(table[name])
    return out


def applicable(candidate: Candidate, channels: Iterable[str], moving: bool) -> str | None:
    """None if the data can show ``candidate``; else the reason it is skipped."""
    channels = set(channels)
    if candidate.requires_motion and not moving:
        return "needs a recording with a moving piston and a measured position x"
    if candidate.requires_any_channel and not channels & set(candidate.requires_any_channel):
        return f"needs one of the channels {list(candidate.requires_any_channel)}"
    return None


def separating_experiment(a: str, b: str, config: IdentificationConfig | None = None) -> str:
    """An experiment that tells effect ``a`` from effect ``b`` (static table in the config)."""
    config = config or load_config()
    key = frozenset((a, b))
    for pair, text in config.separating_experiments():
        if pair == key:
            return text
    return config.default_experiment()


# --------------------------------------------------------------------------- sensor model

def _shift(y: np.ndarray, delay_samples: float) -> np.ndarray:
    """``y`` delayed by a (fractional) number of samples; before the start it holds y[0]."""
    if delay_samples == 0.0:
        return y
    n = y.shape[0]
    pos = np.arange(n) - delay_samples
    pos = np.clip(pos, 0.0, n - 1.0)
    lo = np.floor(pos).astype(np.int64)
    hi = np.minimum(lo + 1, n - 1)
    w = (pos - lo).reshape((-1,) + (1,) * (y.ndim - 1))
    return y[lo] * (1.0 - w) + y[hi] * w


def _lag(y: np.ndarray, time_constant_s: float, dt_s: float) -> np.ndarray:
    """First-order lag, exact for a signal held between samples; starts at steady state."""
    if time_constant_s <= 0.0:
        return y
    a = float(np.exp(-dt_s / time_constant_s))
    zi = a * y[:1]  # steady state: output = input at the first sample
    out, _ = lfilter([1.0 - a], [1.0, -a], y, axis=0, zi=zi)
    return out


def apply_sensor_model(channels: Mapping[str, np.ndarray], values: Sequence[Mapping[str, float]],
                       dt_s: float) -> dict[str, np.ndarray]:
    """Simulated (true) channels -> what the sensors would record.

    ``channels[name]`` is ``(n_samples, n_columns)``; ``values[j]`` holds the sensor
    parameters of column ``j`` (missing ones are neutral). In order: every output channel
    is delayed by ``channel_skew_s`` (linear interpolation; negative = leads), the
    pressures pass a first-order lag ``pressure_sensor_time_constant_s`` and get their
    offsets ``pressure_offset_p1_pa`` / ``pressure_offset_p2_pa``.
    """
    out = {}
    for name, y in channels.items():
        y = np.asarray(y, dtype=float)
        cols = []
        for j in range(y.shape[1]):
            v = {**SENSOR_NEUTRAL, **values[j]}
            col = _shift(y[:, j], v["channel_skew_s"] / dt_s)
            if name in ("p1", "p2"):
                col = _lag(col, v["pressure_sensor_time_constant_s"], dt_s)
                col = col + v[f"pressure_offset_{name}_pa"]
            cols.append(col)
        out[name] = np.stack(cols, axis=1)
    return out
