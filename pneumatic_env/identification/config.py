"""Settings of the identification pipeline: ``configs/identification.yaml``.

Scalar settings are entries ``{value, unit, source}``; fitted parameters (base and
effect) are entries with ``unit, source, lower, upper, plausible_min, plausible_max,
scale`` and, for effects, ``initial`` and ``neutral``. :func:`load_config` reads and
checks the file once (cached until it changes) and :class:`IdentificationConfig` gives
typed access. Errors name the file, the entry and what is allowed.
"""

from __future__ import annotations

import math
import numbers
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pneumatic_env.config_files import (
    ConfigError,
    check_entry,
    config_dir,
    is_entry,
    read_yaml,
)
from pneumatic_env.text_format import is_number

__all__ = ["CONFIG_FILE", "FitParameter", "IdentificationConfig", "load_config"]

CONFIG_FILE = "identification.yaml"
_PARAM_KEYS = {
    "unit",
    "source",
    "initial",
    "lower",
    "upper",
    "plausible_min",
    "plausible_max",
    "scale",
    "neutral",
    "log",
    "fd_step",
    "simulated_min",
}
_PARAM_REQUIRED = ("unit", "source", "lower", "upper", "plausible_min", "plausible_max", "scale")


@dataclass(frozen=True)
class FitParameter:
    """One parameter the optimiser may move.

    ``kind`` is ``"plant"`` (a kernel parameter row) or ``"sensor"`` (applied to the
    simulated channels, see :mod:`.candidates`). ``initial`` None means "the value of the
    parameter set being fitted". The optimiser works in ``value / scale`` or, with
    ``log``, in ``log10(value / scale)``.
    """

    name: str
    kind: str
    unit: str
    source: str
    lower: float
    upper: float
    plausible_min: float
    plausible_max: float
    scale: float
    initial: float | None = None
    neutral: float | None = None
    log: bool = False
    fd_step: float | None = None  # forward-difference step in optimiser units (else the default)
    #: the smallest value simulated (None: no floor); a coordinate below maps to it, so the
    #: cost is flat there and a fit that stays above sees the model as without it
    simulated_min: float | None = None

    def to_u(self, value: float) -> float:
        """Physical value -> optimiser coordinate."""
        if self.log:
            return math.log10(max(value, 1e-300) / self.scale)
        return value / self.scale

    def from_u(self, u: float) -> float:
        """Optimiser coordinate -> physical value."""
        value = self.scale * 10.0 ** min(max(u, -300.0), 300.0) if self.log else u * self.scale
        return value if self.simulated_min is None else max(value, self.simulated_min)

    @property
    def bounds_u(self) -> tuple[float, float]:
        return self.to_u(self.lower), self.to_u(self.upper)


def _is_infinity(x: Any) -> bool:
    return isinstance(x, numbers.Real) and not isinstance(x, bool) and math.isinf(float(x))


def _parse_parameter(
    where: str, name: str, entry: Any, kind: str, need_initial: bool
) -> FitParameter:
    """One fitted parameter's entry, its keys and numbers checked."""
    required = _PARAM_REQUIRED + (("initial", "neutral") if need_initial else ())
    check_entry(f"{where}: entry {name!r}", entry, _PARAM_KEYS, required)
    nums = _entry_numbers(where, name, entry)
    log = entry.get("log", False)
    if not isinstance(log, bool):
        raise ConfigError(f"{where}: entry {name!r}: 'log' must be true or false")
    _check_entry_ranges(where, name, nums, log)
    return FitParameter(
        name=name,
        kind=kind,
        unit=entry["unit"].strip(),
        source=entry["source"],
        lower=nums["lower"],
        upper=nums["upper"],
        plausible_min=nums["plausible_min"],
        plausible_max=nums["plausible_max"],
        scale=nums["scale"],
        initial=nums.get("initial"),
        neutral=nums.get("neutral"),
        log=log,
        fd_step=nums.get("fd_step"),
        simulated_min=nums.get("simulated_min"),
    )


def _entry_numbers(where: str, name: str, entry: Mapping) -> dict[str, float]:
    """The entry's numeric keys as floats (a neutral value may be infinite or null)."""
    nums: dict[str, float] = {}
    for key in (
        "lower",
        "upper",
        "plausible_min",
        "plausible_max",
        "scale",
        "initial",
        "neutral",
        "fd_step",
        "simulated_min",
    ):
        if key in entry:
            if key == "neutral" and entry[key] is None:
                # a switched effect (``set``) with no value of this parameter that is "off"
                continue
            if key == "neutral" and _is_infinity(entry[key]):
                # an effect that vanishes only in a limit (a rigid load cell: k -> inf)
                nums[key] = float(entry[key])
                continue
            if not is_number(entry[key], finite=True):
                allowed = (
                    (
                        "a finite number, .inf / -.inf for an effect that vanishes only "
                        "in that limit, or null for none (an effect switched on by 'set')"
                    )
                    if key == "neutral"
                    else "a finite number"
                )
                raise ConfigError(
                    f"{where}: entry {name!r}: {key!r} = {entry[key]!r} is not "
                    f"allowed: must be {allowed}"
                )
            nums[key] = float(entry[key])
    return nums


def _check_entry_ranges(where: str, name: str, nums: Mapping[str, float], log: bool) -> None:
    """Bounds in order, positive scale and steps, the initial value within the bounds."""
    if not nums["lower"] < nums["upper"]:
        raise ConfigError(
            f"{where}: entry {name!r}: 'lower' {nums['lower']!r} must be less than "
            f"'upper' {nums['upper']!r}"
        )
    for key in ("scale", "fd_step"):
        if key in nums and not nums[key] > 0:
            raise ConfigError(f"{where}: entry {name!r}: {key!r} {nums[key]!r} must be > 0")
    if log and not nums["lower"] > 0:
        raise ConfigError(
            f"{where}: entry {name!r}: 'lower' {nums['lower']!r} must be > 0 with log: true"
        )
    if "simulated_min" in nums and not nums["lower"] <= nums["simulated_min"] < nums["upper"]:
        raise ConfigError(
            f"{where}: entry {name!r}: 'simulated_min' {nums['simulated_min']!r} must be in "
            f"[{nums['lower']!r}, {nums['upper']!r})"
        )
    if "initial" in nums and not nums["lower"] <= nums["initial"] <= nums["upper"]:
        raise ConfigError(
            f"{where}: entry {name!r}: 'initial' {nums['initial']!r} must be in "
            f"[{nums['lower']!r}, {nums['upper']!r}]"
        )
    if not nums["plausible_min"] <= nums["plausible_max"]:
        raise ConfigError(
            f"{where}: entry {name!r}: 'plausible_min' must not exceed 'plausible_max'"
        )


class IdentificationConfig:
    """Typed view of ``configs/identification.yaml`` (see the file for the meaning)."""

    def __init__(self, data: Mapping, path: str):
        self.path = path
        self.raw = data
        if not isinstance(data, Mapping):
            raise ConfigError(f"{path}: must be a mapping")
        for section in (
            "fit",
            "channel_scales",
            "base_fit",
            "base_parameters",
            "candidates",
            "diagnosis",
            "virtual_rig",
        ):
            if section not in data or not isinstance(data[section], Mapping):
                raise ConfigError(f"{path}: section {section!r} is missing or not a mapping")
        self.base_parameters = {
            name: _parse_parameter(f"{path}: base_parameters", name, entry, "plant", False)
            for name, entry in data["base_parameters"].items()
        }
        for key in ("fit_always", "fit_when_moving", "optional", "refit_in_diagnosis"):
            names = data["base_fit"].get(key)
            if key == "refit_in_diagnosis" and names == "all":
                continue
            if not isinstance(names, list):
                raise ConfigError(f"{path}: base_fit.{key} must be a list of parameter names")
            for name in names:
                if name not in self.base_parameters:
                    raise ConfigError(
                        f"{path}: base_fit.{key} names {name!r}, which has no "
                        "entry under base_parameters"
                    )

    # -- scalar settings ------------------------------------------------------------------
    def value(self, section: str, name: str, sub: str | None = None) -> Any:
        """``value`` of entry ``section.name`` (or ``section.name.sub``)."""
        node = self.raw.get(section, {})
        where = f"{section}.{name}" + (f".{sub}" if sub else "")
        entry = node.get(name) if isinstance(node, Mapping) else None
        if sub is not None:
            entry = entry.get(sub) if isinstance(entry, Mapping) else None
        if not is_entry(entry):
            raise ConfigError(f"{self.path}: entry {where} is missing (needs value, unit, source)")
        return check_entry(f"{self.path}: entry {where}", entry)["value"]

    def number(
        self,
        section: str,
        name: str,
        sub: str | None = None,
        *,
        positive=False,
        minimum: float | None = None,
        maximum: float | None = None,
    ) -> float:
        """A finite numeric setting, checked."""
        v = self.value(section, name, sub)
        where = f"{section}.{name}" + (f".{sub}" if sub else "")
        if not is_number(v, finite=True):
            raise ConfigError(
                f"{self.path}: {where} = {v!r} is not allowed: must be a finite number"
            )
        v = float(v)
        if positive and not v > 0:
            raise ConfigError(f"{self.path}: {where} = {v!r} is not allowed: must be > 0")
        if minimum is not None and v < minimum:
            raise ConfigError(
                f"{self.path}: {where} = {v!r} is not allowed: must be >= {minimum!r}"
            )
        if maximum is not None and v > maximum:
            raise ConfigError(
                f"{self.path}: {where} = {v!r} is not allowed: must be <= {maximum!r}"
            )
        return v

    def positive_numbers(self, section: str, name: str) -> list[float]:
        """A list of finite numbers > 0 (possibly empty), checked."""
        v = self.value(section, name)
        if not isinstance(v, list) or not all(is_number(x, finite=True) and x > 0 for x in v):
            raise ConfigError(
                f"{self.path}: {section}.{name} = {v!r} is not allowed: must be "
                "a list of finite numbers > 0"
            )
        return [float(x) for x in v]

    def fit(self, name: str) -> Any:
        return self.value("fit", name)

    def diagnosis(self, name: str) -> float:
        return self.number("diagnosis", name)

    # -- lists ----------------------------------------------------------------------------
    def names(self, section: str, name: str) -> list[str]:
        """A list of names (possibly empty), checked."""
        v = self.value(section, name)
        if not isinstance(v, list) or not all(isinstance(x, str) for x in v):
            raise ConfigError(
                f"{self.path}: {section}.{name} = {v!r} is not allowed: must be a list of names"
            )
        return list(v)

    def base_fit_names(self, key: str) -> list[str]:
        names = self.raw["base_fit"][key]
        return list(names) if names != "all" else ["all"]

    def separating_experiments(self) -> list[tuple[frozenset, str]]:
        out = []
        for i, item in enumerate(self.raw.get("separating_experiments", []) or []):
            pair = item.get("pair") if isinstance(item, Mapping) else None
            text = item.get("experiment") if isinstance(item, Mapping) else None
            if not (isinstance(pair, list) and len(pair) == 2 and isinstance(text, str)):
                raise ConfigError(
                    f"{self.path}: separating_experiments[{i}] must have 'pair' "
                    "(two effect names) and 'experiment' (text)"
                )
            out.append((frozenset(pair), text))
        return out

    def default_experiment(self) -> str:
        items = self.raw.get("default_experiment") or [""]
        return str(items[0])


def load_config(path: str | os.PathLike | None = None) -> IdentificationConfig:
    """The identification settings; ``path`` defaults to ``<config_dir>/identification.yaml``."""
    path = Path(path) if path is not None else config_dir() / CONFIG_FILE
    if not path.is_file():
        raise ConfigError(f"identification config {str(path)!r} does not exist")
    return _cached(*_stamp(path))


def _stamp(path: Path) -> tuple[str, int, int]:
    st = os.stat(path)
    return str(path), st.st_mtime_ns, st.st_size


_CACHE: dict = {}


def _cached(path: str, mtime_ns: int, size: int) -> IdentificationConfig:
    key = (path, mtime_ns, size)
    if key not in _CACHE:
        _CACHE.clear()
        _CACHE[key] = IdentificationConfig(read_yaml(Path(path)), path)
    return _CACHE[key]
