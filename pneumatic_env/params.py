"""Parameter sets: the YAML configs in ``configs/`` and their loader.

Every name of :data:`pneumatic_env.physics.layout.PARAMETER_NAMES` is defined in exactly
one config file (``air``, ``valve``, ``tube``, ``load``, ``numerics`` or a cylinder file
under ``cylinders/``) as an entry with a value, a unit, a source and its allowed range::

    supply_pressure_pa:
      value: 6.5e+5
      unit: Pa
      source: "assumed: ..."      # "paper ..." when stated in the paper or fixed by physics
      min: 1.0e+5                 # inclusive; min_exclusive/max_exclusive: true make it strict
      max: 2.0e+6                 # .inf / -.inf where unbounded
    tube_coupling:
      value: 0
      unit: "-"
      source: "..."
      allowed: [0, 1]             # discrete; names from layout.DISCRETE_PARAMETERS also accepted

A cylinder file holds the cylinder parameters and may override any other parameter.
``numerics.yaml`` also holds ``control_dt_s`` and ``substeps``, which are not kernel
parameter rows; :func:`load_numerics` returns them.

Numbers in the YAML files are read with YAML 1.2 rules, so ``1e-3`` and ``6.5e5`` are
floats (PyYAML alone would read them as strings).
"""

from __future__ import annotations

import difflib
import functools
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from pneumatic_env.config_files import (
    CONFIG_DIR_ENV,
    ENTRY_KEYS,
    ConfigError,
    _cylinder_path,
    _stamp,
    check_entry,
    config_dir,
    make_entry,
    read_yaml,
    resolve_cylinder,
)
from pneumatic_env.ids import CYLINDERS, DEFAULT_CYLINDER
from pneumatic_env.param_rules import _check_relations
from pneumatic_env.physics.layout import (
    CYLINDER_PARAMETERS,
    DISCRETE_PARAMETERS,
    N_PARAMS,
    PARAMETER_INDEX,
    PARAMETER_NAMES,
)
from pneumatic_env.text_format import is_number, value_text

__all__ = [
    "CONFIG_DIR_ENV",
    "CYLINDERS",
    "CYLINDER_PARAMETERS",
    "ConfigError",
    "DEFAULT_CYLINDER",
    "NUMERICS_NAMES",
    "config_dir",
    "load_numerics",
    "load_parameters",
    "parameter_array",
    "parameter_info",
    "resolve_cylinder",
    "read_yaml",
    "save_parameters",
]


# CYLINDERS (canonical names, the file stems under configs/cylinders/, and their short
# aliases) and DEFAULT_CYLINDER: pneumatic_env.ids

BASE_FILES = ("air.yaml", "valve.yaml", "tube.yaml", "load.yaml", "numerics.yaml", "effects.yaml")
# Numerics settings in numerics.yaml that are not kernel parameter rows.
NUMERICS_NAMES = ("control_dt_s", "substeps")

# keys of an entry in the config files and in a file of save_parameters
_CONFIG_ENTRY_KEYS = (
    *ENTRY_KEYS,
    "min",
    "max",
    "min_exclusive",
    "max_exclusive",
    "allowed",
    "integer",
)
_PARAMS_ENTRY_KEYS = (*ENTRY_KEYS, "uncertainty")

# How specific a value's origin is; a cross-field violation blames the more specific field.
_LEVEL_BASE, _LEVEL_CYLINDER, _LEVEL_PARAMS, _LEVEL_OVERRIDE = range(4)


# --------------------------------------------------------------------------- specs


@dataclass(frozen=True)
class _Spec:
    name: str
    value: float
    unit: str
    source: str
    min: float
    max: float
    min_exclusive: bool
    max_exclusive: bool
    allowed: tuple[int, ...] | None
    integer: bool
    file: str
    level: int


def _suggest(
    name: str,
    known: Sequence[str],
    fallback: str = "known names are pneumatic_env.physics.layout.PARAMETER_NAMES",
) -> str:
    close = difflib.get_close_matches(name, list(known), n=3, cutoff=0.6)
    if close:  # keep the matches about as close as the best one
        best = difflib.SequenceMatcher(None, name, close[0]).ratio()
        close = [c for c in close if difflib.SequenceMatcher(None, name, c).ratio() >= best - 0.1]
    else:
        close = [k for k in known if name and name.lower() in k][:3]
    if close:
        return "did you mean " + " or ".join(repr(c) for c in close) + "?"
    return fallback


def _unknown(source: str, name: Any, known: Sequence[str]) -> ConfigError:
    msg = f"{source} {name!r} is not a known parameter; "
    if name in NUMERICS_NAMES:
        return ConfigError(msg + "it is a numerics setting (see load_numerics)")
    return ConfigError(msg + _suggest(str(name), known))


def _range_text(spec: _Spec) -> str:
    lo = "(" if spec.min_exclusive else "["
    hi = ")" if spec.max_exclusive else "]"
    text = f"{lo}{float(spec.min)!r}, {float(spec.max)!r}{hi}"
    return text + _unit_suffix(spec.unit)


def _unit_suffix(unit: str) -> str:
    return "" if unit in ("-", "") else f" {unit}"


def _discrete_text(spec: _Spec) -> str:
    names = DISCRETE_PARAMETERS.get(spec.name, {})
    parts = [f"{c} ({names[c]!r})" if c in names else str(c) for c in spec.allowed or ()]
    return "one of " + ", ".join(parts)


def _coerce(spec: _Spec, value: Any, source: str) -> float:
    """Validate one value against its spec and return it as a float."""
    head = f"{source} {spec.name!r} = {value_text(value)} is not allowed: must be "
    if spec.allowed is not None:
        if isinstance(value, str):
            key = value.strip().lower()
            for code, label in DISCRETE_PARAMETERS.get(spec.name, {}).items():
                if label == key and code in spec.allowed:
                    return float(code)
        elif is_number(value):
            v = float(value)
            if v.is_integer() and int(v) in spec.allowed:
                return v
        raise ConfigError(head + _discrete_text(spec))
    if not is_number(value):
        raise ConfigError(head + "a number in " + _range_text(spec))
    v = float(value)
    if not math.isfinite(v):
        raise ConfigError(head + "a finite number in " + _range_text(spec))
    below = v <= spec.min if spec.min_exclusive else v < spec.min
    above = v >= spec.max if spec.max_exclusive else v > spec.max
    if below or above:
        raise ConfigError(head + "in " + _range_text(spec))
    if spec.integer and not v.is_integer():
        raise ConfigError(head + "a whole number in " + _range_text(spec))
    return v


def _parse_entry(path: str, name: str, entry: Any, level: int) -> _Spec:
    where = f"{path}: entry {name!r}"
    check_entry(where, entry, keys=_CONFIG_ENTRY_KEYS)
    flags = {}
    for key in ("min_exclusive", "max_exclusive", "integer"):
        flags[key] = entry.get(key, False)
        if not isinstance(flags[key], bool):
            raise ConfigError(f"{where}: {key!r} must be true or false")
    allowed = None
    if "allowed" in entry:
        if "min" in entry or "max" in entry:
            raise ConfigError(f"{where}: give either 'allowed' or 'min'/'max', not both")
        raw = entry["allowed"]
        if (
            not isinstance(raw, list)
            or not raw
            or not all(isinstance(a, int) and not isinstance(a, bool) for a in raw)
        ):
            raise ConfigError(f"{where}: 'allowed' must be a non-empty list of integers")
        allowed = tuple(raw)
        names = DISCRETE_PARAMETERS.get(name)
        if names is not None and set(allowed) - set(names):
            raise ConfigError(
                f"{where}: 'allowed' has codes {sorted(set(allowed) - set(names))} "
                f"that layout.DISCRETE_PARAMETERS does not name"
            )
        lo, hi = float(min(allowed)), float(max(allowed))
    else:
        for key in ("min", "max"):
            if key not in entry:
                raise ConfigError(f"{where} is missing key {key!r} (or 'allowed')")
            if not is_number(entry[key]) or math.isnan(float(entry[key])):
                raise ConfigError(
                    f"{where}: {key!r} must be a number or .inf/-.inf, got {value_text(entry[key])}"
                )
        lo, hi = float(entry["min"]), float(entry["max"])
        if lo > hi:
            raise ConfigError(f"{where}: 'min' {lo!r} is greater than 'max' {hi!r}")
    spec = _Spec(
        name=name,
        value=math.nan,
        unit=entry["unit"].strip(),
        source=entry["source"],
        min=lo,
        max=hi,
        min_exclusive=flags["min_exclusive"],
        max_exclusive=flags["max_exclusive"],
        allowed=allowed,
        integer=flags["integer"],
        file=path,
        level=level,
    )
    value = _coerce(spec, entry["value"], path)
    return replace(spec, value=value)


def _parse_file(path: Path, level: int) -> dict[str, _Spec]:
    data = read_yaml(path)
    if not isinstance(data, Mapping) or not data:
        raise ConfigError(f"{path}: must be a non-empty mapping of parameter entries")
    return {
        str(name): _parse_entry(str(path), str(name), entry, level) for name, entry in data.items()
    }


@dataclass(frozen=True)
class _Schema:
    params: dict[str, _Spec]  # PARAMETER_NAMES order
    numerics: dict[str, _Spec]  # NUMERICS_NAMES order


@functools.lru_cache(maxsize=32)
def _build_schema(cfg: str, cylinder_file: str, stamps: tuple) -> _Schema:
    # `stamps` (file mtimes and sizes) only keys the cache.
    cylinder_set = set(CYLINDER_PARAMETERS)
    base: dict[str, _Spec] = {}
    numerics: dict[str, _Spec] = {}
    for fname in BASE_FILES:
        path = Path(cfg) / fname
        known = PARAMETER_NAMES + (NUMERICS_NAMES if fname == "numerics.yaml" else ())
        for name, spec in _parse_file(path, _LEVEL_BASE).items():
            if name in cylinder_set:
                raise ConfigError(
                    f"{path}: {name!r} is a cylinder parameter; "
                    f"it belongs in the files under cylinders/"
                )
            if name not in known:
                raise _unknown(str(path) + ":", name, known)
            if name in base or name in numerics:
                other = (base.get(name) or numerics[name]).file
                raise ConfigError(f"{path}: {name!r} is already defined in {other}")
            (numerics if name in NUMERICS_NAMES else base)[name] = spec
    cyl_path = Path(cylinder_file)
    for name, spec in _parse_file(cyl_path, _LEVEL_CYLINDER).items():
        if name not in PARAMETER_NAMES:
            raise _unknown(str(cyl_path) + ":", name, PARAMETER_NAMES)
        if name in base and base[name].unit != spec.unit:
            raise ConfigError(
                f"{cyl_path}: entry {name!r} has unit {spec.unit!r}, "
                f"but {base[name].file} uses {base[name].unit!r}"
            )
        base[name] = spec
    for name in CYLINDER_PARAMETERS:
        if base.get(name, None) is None or base[name].level != _LEVEL_CYLINDER:
            raise ConfigError(f"{cyl_path}: cylinder parameter {name!r} is missing")
    for name in PARAMETER_NAMES:
        if name not in base:
            raise ConfigError(
                f"{cfg}: parameter {name!r} is not defined in any of {', '.join(BASE_FILES)}"
            )
    for name in NUMERICS_NAMES:
        if name not in numerics:
            raise ConfigError(f"{Path(cfg) / 'numerics.yaml'}: entry {name!r} is missing")
    schema = _Schema(
        params={n: base[n] for n in PARAMETER_NAMES},
        numerics={n: numerics[n] for n in NUMERICS_NAMES},
    )
    values = {n: s.value for n, s in schema.params.items()}
    _check_relations(
        values,
        {n: s.file for n, s in schema.params.items()},
        {n: s.level for n, s in schema.params.items()},
    )
    return schema


def _schema(cylinder: str | os.PathLike = DEFAULT_CYLINDER) -> _Schema:
    cfg = config_dir()
    cyl = _cylinder_path(cylinder, cfg)
    stamps = tuple(_stamp(p) for p in [cfg / f for f in BASE_FILES] + [cyl])
    return _build_schema(str(cfg), str(cyl), stamps)


# --------------------------------------------------------------------------- public API


def _params_items(params: Any, specs: Mapping[str, _Spec]) -> tuple[list, str]:
    """(name, raw value) pairs and a source label from a params file or mapping."""
    if isinstance(params, (str, os.PathLike)):
        source = str(params)
        data = read_yaml(Path(params).expanduser())
        if not isinstance(data, Mapping):
            raise ConfigError(f"{source}: must be a mapping of parameter names to values")
    elif isinstance(params, Mapping):
        source, data = "params", params
    else:
        raise ConfigError(f"params must be a path or a mapping, got {type(params).__name__}")
    items = []
    for name, entry in data.items():
        if name not in specs:
            raise _unknown(source, name, PARAMETER_NAMES)
        if isinstance(entry, Mapping):
            check_entry(f"{source}: entry {name!r}", entry, _PARAMS_ENTRY_KEYS, ("value",))
            unit = entry.get("unit")
            if unit is not None and str(unit).strip() != specs[name].unit:
                raise ConfigError(
                    f"{source}: entry {name!r} has unit {unit!r}; expected {specs[name].unit!r}"
                )
            entry = entry["value"]
        items.append((name, entry))
    return items, source


def load_parameters(
    cylinder: str | os.PathLike = DEFAULT_CYLINDER,
    tube_length_m: float | None = None,
    params: str | os.PathLike | Mapping[str, Any] | None = None,
    **overrides: Any,
) -> dict[str, float]:
    """A complete, validated parameter set, keys in ``PARAMETER_NAMES`` order.

    Layers, each on top of the previous: the config files (the cylinder's file on top of
    air/valve/tube/load/numerics), ``params`` (a file written by :func:`save_parameters`
    or a mapping of name -> value or name -> {value: ...}), then ``tube_length_m`` and
    ``overrides``. ``cylinder`` is a name or alias from :data:`CYLINDERS` (any case), a
    file stem under ``configs/cylinders/``, or a path to a cylinder YAML file. Discrete
    parameters accept their names (``tube_coupling="literal"``). Raises
    :class:`ConfigError` on an unknown name or a value that is not allowed.
    """
    schema = _schema(cylinder)
    specs = schema.params
    values = {n: s.value for n, s in specs.items()}
    origin = {n: s.file for n, s in specs.items()}
    level = {n: s.level for n, s in specs.items()}
    layers = []
    if params is not None:
        items, source = _params_items(params, specs)
        layers.append((items, source, _LEVEL_PARAMS))
    explicit = dict(overrides)
    if tube_length_m is not None:
        explicit["tube_length_m"] = tube_length_m
    if explicit:
        layers.append((list(explicit.items()), "override", _LEVEL_OVERRIDE))
    for items, source, lvl in layers:
        for name, raw in items:
            spec = specs.get(name)
            if spec is None:
                raise _unknown(source, name, PARAMETER_NAMES)
            values[name] = _coerce(spec, raw, source)
            origin[name], level[name] = source, lvl
    _check_relations(values, origin, level)
    return values


def parameter_array(param_dicts: Mapping[str, float] | Sequence[Mapping[str, float]]) -> np.ndarray:
    """Parameter dicts as the kernel's ``params[N_PARAMS, n_envs]`` array (float64, C order)."""
    dicts = [param_dicts] if isinstance(param_dicts, Mapping) else list(param_dicts)
    out = np.empty((N_PARAMS, len(dicts)), dtype=np.float64)
    for j, d in enumerate(dicts):
        if not isinstance(d, Mapping):
            raise ConfigError(f"parameter set {j} is a {type(d).__name__}, not a mapping")
        for name in d:
            if name not in PARAMETER_INDEX:
                raise _unknown(f"parameter set {j}:", name, PARAMETER_NAMES)
        for name, row in PARAMETER_INDEX.items():
            if name not in d:
                raise ConfigError(
                    f"parameter set {j}: {name!r} is missing "
                    f"(use load_parameters for a complete set)"
                )
            if not is_number(d[name]):
                raise ConfigError(
                    f"parameter set {j}: {name!r} = {value_text(d[name])} is not a "
                    f"number (use load_parameters to convert names)"
                )
            out[row, j] = d[name]
    return out


def parameter_info(name: str, cylinder: str | os.PathLike = DEFAULT_CYLINDER) -> dict:
    """Unit, source, bounds and default of a parameter (or a numerics setting).

    Keys: ``unit``, ``source``, ``min``, ``max``, ``min_exclusive``, ``max_exclusive``,
    ``allowed`` (codes of a discrete parameter, else None), ``names`` (code -> name of
    a discrete parameter, else None), ``default``, ``file``. Cylinder parameters are
    taken from ``cylinder``'s file.
    """
    schema = _schema(cylinder)
    spec = schema.params.get(name) or schema.numerics.get(name)
    if spec is None:
        raise _unknown("parameter_info:", name, PARAMETER_NAMES + NUMERICS_NAMES)
    return {
        "unit": spec.unit,
        "source": spec.source,
        "min": spec.min,
        "max": spec.max,
        "min_exclusive": spec.min_exclusive,
        "max_exclusive": spec.max_exclusive,
        "allowed": list(spec.allowed) if spec.allowed is not None else None,
        "names": dict(DISCRETE_PARAMETERS[name]) if name in DISCRETE_PARAMETERS else None,
        "default": int(spec.value) if spec.integer or spec.allowed else spec.value,
        "file": spec.file,
    }


def load_numerics(**overrides: Any) -> dict[str, float | int]:
    """The numerics settings that are not kernel parameters: ``control_dt_s``, ``substeps``."""
    specs = _schema().numerics
    out: dict[str, float | int] = {name: spec.value for name, spec in specs.items()}
    for name, raw in overrides.items():
        if name not in specs:
            raise ConfigError(
                f"override {name!r} is not a numerics setting; "
                + _suggest(name, NUMERICS_NAMES, f"known: {', '.join(NUMERICS_NAMES)}")
            )
        out[name] = _coerce(specs[name], raw, "override")
    out["substeps"] = int(out["substeps"])
    return out


def _reference_cylinder(values: Mapping[str, Any]) -> str:
    """The cylinder whose defaults match most of the cylinder parameters in ``values``."""
    best, best_score = DEFAULT_CYLINDER, -1
    for canonical in CYLINDERS:
        specs = _schema(canonical).params
        score = sum(
            1
            for n in CYLINDER_PARAMETERS
            if n in values and is_number(values[n]) and float(values[n]) == specs[n].value
        )
        if score > best_score:
            best, best_score = canonical, score
    return best


def save_parameters(
    path: str | os.PathLike,
    values: Mapping[str, Any],
    notes: str = "",
    uncertainties: Mapping[str, float] | None = None,
) -> None:
    """Write a parameter set that ``load_parameters(params=path)`` reads back exactly.

    Each entry carries its value, unit and source: the config's source where the value
    equals the default of the closest cylinder (see below), else ``"fitted: <notes>"``.
    ``uncertainties`` (name -> standard deviation, same unit) are written as an
    ``uncertainty`` key. ``values`` may be partial; loading then fills the rest from the
    configs. The closest cylinder is the one of :data:`CYLINDERS` whose defaults match
    most of the given cylinder parameters.
    """
    reference = _reference_cylinder(values)
    # Validates names, values and (with the reference defaults) the cross-field rules.
    checked = load_parameters(cylinder=reference, params=dict(values))
    specs = _schema(reference).params
    uncertainties = dict(uncertainties or {})
    for name, u in uncertainties.items():
        if name not in values:
            raise ConfigError(f"uncertainties: {name!r} is not in values")
        if not is_number(u) or not float(u) >= 0.0:
            raise ConfigError(
                f"uncertainties: {name!r} = {value_text(u)} is not allowed: must be a number >= 0"
            )
    one_line = " ".join(notes.split())
    fitted = f"fitted: {one_line}" if one_line else "fitted"
    doc: dict[str, dict] = {}
    for name in PARAMETER_NAMES:
        if name not in values:
            continue
        spec, v = specs[name], checked[name]
        more = {"uncertainty": float(uncertainties[name])} if name in uncertainties else {}
        doc[name] = make_entry(
            int(v) if spec.allowed is not None else v,
            spec.unit,
            spec.source if v == spec.value else fitted,
            **more,
        )
    header = [
        "# pneumatic_env parameter set (pneumatic_env.params.save_parameters)",
        f"# reference cylinder: {reference}",
    ]
    header += [f"# {line}".rstrip() for line in notes.splitlines()]
    text = (
        "\n".join(header)
        + "\n"
        + yaml.safe_dump(
            doc, sort_keys=False, default_flow_style=False, allow_unicode=True, width=1000
        )
    )
    Path(path).expanduser().write_text(text, encoding="utf-8")
