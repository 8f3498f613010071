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

A ``set`` value is a number, or the name of a kernel parameter: then each recording
gets that parameter's value from its own set (e.g. a load cell's rest position = the
recording's clamp position ``fixed_position_m``). ``rod_modes`` limits a plant effect to
recordings whose rod is in one of those modes (``fixed``, ``free``, ``spring``): its set
and fitted values reach only those recordings (:func:`.calibrate.dataset_overrides`).
``refit_base`` names base parameters that the effect makes observable (e.g. piston
friction in the force of a compliant load cell); they are refitted with it and count as
its extra parameters.

Adding an effect = adding an entry to the YAML (and, for a plant effect, its row to the
kernel); nothing here changes.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.signal import lfilter

from pneumatic_env.params import ConfigError
from pneumatic_env.physics.layout import PARAMETER_NAMES
from pneumatic_env.recording import PISTON_MODES

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
_CANDIDATE_KEYS = {
    "kind",
    "description",
    "parameters",
    "set",
    "requires_motion",
    "requires_any_channel",
    "rod_modes",
    "refit_base",
}


@dataclass(frozen=True)
class Candidate:
    """One candidate effect (see the module docstring)."""

    name: str
    kind: str
    description: str
    parameters: tuple[FitParameter, ...]
    set: Mapping[str, float | str] = field(default_factory=dict)
    requires_motion: bool = False
    requires_any_channel: tuple[str, ...] = ()
    rod_modes: tuple[str, ...] = ()
    refit_base: tuple[FitParameter, ...] = ()

    @property
    def parameter_names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.parameters)

    @property
    def available(self) -> bool:
        """Whether the kernel (plant) or the sensor model knows every parameter."""
        names = (
            list(self.parameter_names)
            + list(self.set)
            + [v for v in self.set.values() if isinstance(v, str)]
        )
        if self.kind == "sensor":
            return all(n in SENSOR_NEUTRAL for n in self.parameter_names)
        return all(n in PARAMETER_NAMES for n in names)

    def scopes(self) -> dict[str, tuple[str, ...]]:
        """Effect parameter -> the rod modes of the recordings it applies to (empty: all)."""
        if not self.rod_modes:
            return {}
        return dict.fromkeys(self.parameter_names, self.rod_modes)

    def scoped_set(self) -> dict[str, float | str]:
        """``set`` as override keys: with ``rod_modes``, each a scoped key ``name@modes``
        (:func:`.datasets.kernel_name`), so a base parameter it sets (the piston's
        friction) keeps its own value on the other recordings."""
        if not self.rod_modes:
            return dict(self.set)
        suffix = "@" + "|".join(self.rod_modes)
        return {k + suffix: v for k, v in self.set.items()}

    def neutral(self) -> dict[str, float | None]:
        """Parameter values that switch the effect off (None: a switched effect's parameter
        with no "off" value)."""
        return {p.name: p.neutral for p in self.parameters}


def candidate_table(config: IdentificationConfig | None = None) -> dict[str, Candidate]:
    """Every candidate declared in the config, available or not, by name."""
    config = config or load_config()
    out = {}
    where = f"{config.path}: candidates"
    for name, entry in config.raw["candidates"].items():
        out[name] = _parse_candidate(where, name, entry, config)
    return out


def _parse_candidate(where: str, name: str, entry: Any, config: IdentificationConfig) -> Candidate:
    """One candidate's config entry, checked."""
    if not isinstance(entry, Mapping):
        raise ConfigError(f"{where}.{name} must be a mapping")
    extra = sorted(set(entry) - _CANDIDATE_KEYS)
    if extra:
        raise ConfigError(
            f"{where}.{name} has unknown key {extra[0]!r}; allowed keys: "
            f"{', '.join(sorted(_CANDIDATE_KEYS))}"
        )
    kind = entry.get("kind")
    if kind not in _KINDS:
        raise ConfigError(
            f"{where}.{name}.kind = {kind!r} is not allowed: must be one of {list(_KINDS)}"
        )
    params = entry.get("parameters")
    if not isinstance(params, Mapping) or not params:
        raise ConfigError(f"{where}.{name}.parameters must be a non-empty mapping")
    fitted = tuple(
        _parse_parameter(f"{where}.{name}.parameters", p, e, kind, True) for p, e in params.items()
    )
    if kind == "sensor":
        for p in fitted:
            if p.name not in SENSOR_NEUTRAL:
                raise ConfigError(
                    f"{where}.{name}: sensor parameter {p.name!r} is not "
                    f"known; known: {', '.join(SENSOR_PARAMETERS)}"
                )
    set_values = _set_values(f"{where}.{name}.set", entry.get("set") or {})
    channels = tuple(entry.get("requires_any_channel") or ())
    rod_modes = entry.get("rod_modes") or []
    if not isinstance(rod_modes, list) or any(m not in PISTON_MODES for m in rod_modes):
        raise ConfigError(
            f"{where}.{name}.rod_modes = {rod_modes!r} is not allowed: must "
            f"be a list of {list(PISTON_MODES)}"
        )
    if rod_modes and kind != "plant":
        raise ConfigError(f"{where}.{name}.rod_modes is only allowed for kind 'plant'")
    refit_base = entry.get("refit_base") or []
    if not isinstance(refit_base, list):
        raise ConfigError(f"{where}.{name}.refit_base must be a list of base parameter names")
    for b in refit_base:
        if b not in config.base_parameters:
            raise ConfigError(
                f"{where}.{name}.refit_base names {b!r}, which has no entry "
                f"under base_parameters; allowed: "
                f"{', '.join(config.base_parameters)}"
            )
    return Candidate(
        name=name,
        kind=kind,
        description=str(entry.get("description", "")),
        parameters=fitted,
        set=set_values,
        requires_motion=bool(entry.get("requires_motion", False)),
        requires_any_channel=channels,
        rod_modes=tuple(rod_modes),
        refit_base=tuple(config.base_parameters[b] for b in refit_base),
    )


def _set_values(where: str, fixed: Any) -> dict[str, float | str]:
    """A candidate's ``set``: kernel parameter -> a number or another parameter's name."""
    if not isinstance(fixed, Mapping):
        raise ConfigError(
            f"{where} must be a mapping of kernel parameter -> number or kernel parameter name"
        )
    set_values: dict[str, float | str] = {}
    for key, v in fixed.items():
        if isinstance(v, str):
            if v not in PARAMETER_NAMES:
                raise ConfigError(
                    f"{where}.{key} = {v!r} is not allowed: a "
                    "text value must name a kernel parameter (its value in "
                    "each recording's set is used)"
                )
            set_values[key] = v
        elif isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v):
            set_values[key] = float(v)
        else:
            raise ConfigError(
                f"{where}.{key} = {v!r} is not allowed: must be a "
                "finite number or the name of a kernel parameter"
            )
    return set_values


def available_candidates(
    names: Iterable[str] | None = None, config: IdentificationConfig | None = None
) -> list[Candidate]:
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
            raise ConfigError(
                f"candidate {name!r} is not declared in configs/identification.yaml;"
                f" declared: {', '.join(table)}"
            )
        if not table[name].available:
            raise ConfigError(
                f"candidate {name!r} needs kernel parameter(s) "
                f"{[n for n in table[name].parameter_names if n not in PARAMETER_NAMES]}"
                " that this version of the kernel does not have"
            )
        out.append(table[name])
    return out


def applicable(
    candidate: Candidate, channels: Iterable[str], moving: bool, rod_modes: Iterable[str] = ()
) -> str | None:
    """None if the data can show ``candidate``; else the reason it is skipped.

    ``rod_modes``: the rod modes of the recordings (``fixed``, ``free``, ``spring``).
    """
    channels = set(channels)
    if candidate.requires_motion and not moving:
        return "needs a recording with a moving piston and a measured position x"
    if candidate.rod_modes and not set(rod_modes) & set(candidate.rod_modes):
        return f"needs a recording with the rod in mode {' or '.join(candidate.rod_modes)}"
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


def apply_sensor_model(
    channels: Mapping[str, np.ndarray], values: Sequence[Mapping[str, float]], dt_s: float
) -> dict[str, np.ndarray]:
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
