"""The measurement format's names and errors, and the rig sidecar's validation.

``NAME.json`` beside each recording's ``NAME.csv`` (``docs/measurement-format.md``,
format ``"pneumatic-measurement"``, version 1): its keys, :func:`validate_rig` (raises
:class:`RecordingError` naming the file and the key) and its mapping to the physics
core's parameter names. The reader and writer are in :mod:`pneumatic_env.recording`.
"""

from __future__ import annotations

import json
import math
import numbers
from pathlib import Path

import pneumatic_env.ids as ids
from pneumatic_env.simulator import INITIAL_STATE_KEYS  # the sidecar's "initial" keys
from pneumatic_env.text_format import is_number as _is_number
from pneumatic_env.text_format import number_text as _fmt  # exact float text

FORMAT_NAME = "pneumatic-measurement"
FORMAT_VERSION = 1

#: Known CSV columns, in the spec's order (also the order the writer uses).
COLUMNS = ("t", "i_c", "p1", "p2", "x", "f", "v", "x_s", "p_s")
REQUIRED_COLUMNS = ("t", "i_c")
#: Measured outputs; a recording needs at least one of them.
OUTPUT_COLUMNS = ("p1", "p2", "x", "f")
PRESSURE_COLUMNS = ("p1", "p2", "p_s")

#: Canonical cylinder names and their case-insensitive aliases (pneumatic_env.ids).
CYLINDERS = tuple(ids.CYLINDERS)
_CYLINDER_ALIASES = ids.CYLINDER_ALIASES

#: Piston modes, their physics-core code (ids.PISTON_MODE_CODES) and their required keys.
PISTON_MODES = {
    "fixed": (ids.MODE_FIXED, ("position_m",)),
    "free": (ids.MODE_FREE, ("load_mass_kg", "load_force_n")),
    "spring": (ids.MODE_SPRING, ("stiffness_n_per_m", "rest_position_m", "load_mass_kg")),
}
_PISTON_KEYS = {
    "mode",
    "position_m",
    "load_mass_kg",
    "load_force_n",
    "stiffness_n_per_m",
    "rest_position_m",
}
_NONNEGATIVE_PISTON_KEYS = {"load_mass_kg", "stiffness_n_per_m"}

_REQUIRED_TOP_KEYS = ("format", "version", "cylinder", "tube_length_m", "piston")
_OPTIONAL_POSITIVE_KEYS = (
    "tube_inner_diameter_m",
    "supply_pressure_pa",
    "ambient_pressure_pa",
    "temperature_k",
)
_KNOWN_TOP_KEYS = set(_REQUIRED_TOP_KEYS) | set(_OPTIONAL_POSITIVE_KEYS) | {"initial", "notes"}

DEFAULT_AMBIENT_PA = 101325.0
JITTER_TOLERANCE = 1e-6
CLIP_FRACTION = 0.02
CLIP_MIN_RUN = 5


class RecordingError(ValueError):
    """A recording breaks the format. ``file``, ``line`` and ``column`` locate it."""

    def __init__(self, message, *, file=None, line=None, column=None):
        super().__init__(message)
        self.file = file
        self.line = line
        self.column = column


class RecordingWarning(UserWarning):
    """A recording is valid but something in it looks wrong (units, clipping, ...)."""


# --------------------------------------------------------------------------- sidecar


def _pressure_value_warnings(label: str, value: float, ambient: float) -> list[str]:
    if abs(value) < 20:
        return [f"{label} {_fmt(value)} looks like bar; the format wants absolute Pa"]
    if abs(value) < 2e3:
        return [f"{label} {_fmt(value)} looks like kPa; the format wants absolute Pa"]
    return []


def canonical_cylinder(name: str) -> str:
    """Canonical cylinder name for ``name`` (case-insensitive, aliases accepted)."""
    if isinstance(name, str) and name.strip().lower() in _CYLINDER_ALIASES:
        return _CYLINDER_ALIASES[name.strip().lower()]
    raise RecordingError(
        f"cylinder {name!r} is unknown; allowed: {_allowed_cylinders()}", column="cylinder"
    )


def _allowed_cylinders() -> str:
    aliases = ", ".join(f'"{a}"' for names in ids.CYLINDERS.values() for a in names)
    return ", ".join(f'"{c}"' for c in CYLINDERS) + f" (or the aliases {aliases})"


def validate_rig(rig, source: str = "rig") -> list[str]:
    """Check a sidecar dict against the format; return plausibility warnings.

    Raises :class:`RecordingError` naming ``source`` (the JSON file) and the key.
    Does not emit the warnings: the caller does.
    """
    if not isinstance(rig, dict):
        raise RecordingError(
            f"{source}: the sidecar must be a JSON object, found {type(rig).__name__}", file=source
        )
    out = _rig_top_warnings(rig, source)
    out += _rig_value_warnings(rig, source)
    out += _piston_warnings(rig["piston"], source)
    if "initial" in rig:
        initial = rig["initial"]
        if not isinstance(initial, dict):
            _fail(
                source,
                "initial",
                f"must be an object with keys among {', '.join(INITIAL_STATE_KEYS)}, "
                f"found {initial!r}",
            )
        for key, value in initial.items():
            if key not in INITIAL_STATE_KEYS:
                _fail(
                    source,
                    f"initial.{key}",
                    f"is not allowed; allowed: {', '.join(INITIAL_STATE_KEYS)}",
                )
            _number(source, f"initial.{key}", value)
    if "notes" in rig and not isinstance(rig["notes"], str):
        _fail(source, "notes", f"must be a string, found {rig['notes']!r}")
    for key in rig:
        if key not in _KNOWN_TOP_KEYS:
            out.append(
                f"{source}: unknown key {key!r} ignored (known: "
                + ", ".join([*_REQUIRED_TOP_KEYS, *_OPTIONAL_POSITIVE_KEYS, "initial", "notes"])
                + ")"
            )
    return out


def _fail(source: str, key: str, text: str) -> None:
    """Raise (always) the :class:`RecordingError` of sidecar ``source``'s ``key``."""
    raise RecordingError(f"{source}: key {key!r} {text}", file=source, column=key)


def _number(source: str, key: str, value, *, positive=False, nonnegative=False) -> float:
    """``value`` of sidecar key ``key`` as a float, refused unless finite (and positive
    or non-negative when asked)."""
    if not _is_number(value) or not math.isfinite(value):
        kind = "a positive number" if positive else "a finite number"
        _fail(source, key, f"must be {kind}, found {value!r}")
    if positive and not value > 0:
        _fail(source, key, f"must be a positive number, found {value!r}")
    if nonnegative and value < 0:
        _fail(source, key, f"must be a non-negative number, found {value!r}")
    return float(value)


def _rig_top_warnings(rig: dict, source: str) -> list[str]:
    """The required top-level keys checked: format, version, cylinder, tube length."""
    hints = {
        "format": f'(must be "{FORMAT_NAME}")',
        "version": f"(must be {FORMAT_VERSION})",
        "cylinder": f"(allowed: {_allowed_cylinders()})",
        "tube_length_m": "(a positive number, in m)",
        "piston": '(an object with "mode": "fixed", "free" or "spring")',
    }
    for key in _REQUIRED_TOP_KEYS:
        if key not in rig:
            raise RecordingError(
                f"{source}: missing required key {key!r} {hints[key]}", file=source, column=key
            )
    if rig["format"] != FORMAT_NAME:
        _fail(source, "format", f'is {rig["format"]!r}, must be "{FORMAT_NAME}"')
    version = rig["version"]
    if not (
        _is_number(version) and isinstance(version, numbers.Integral) and version == FORMAT_VERSION
    ):
        _fail(
            source,
            "version",
            f"is {version!r}, must be {FORMAT_VERSION} (the only version this package reads)",
        )
    cyl = rig["cylinder"]
    if not (isinstance(cyl, str) and cyl.strip().lower() in _CYLINDER_ALIASES):
        _fail(source, "cylinder", f"is {cyl!r}, allowed: {_allowed_cylinders()}")
    tube_length = _number(source, "tube_length_m", rig["tube_length_m"], positive=True)
    if tube_length > 50:
        return [
            f"{source}: tube_length_m {_fmt(tube_length)} looks like millimetres; "
            "the format wants metres"
        ]
    return []


def _rig_value_warnings(rig: dict, source: str) -> list[str]:
    """The optional positive keys checked; values that look like the wrong unit."""
    out: list[str] = []
    for key in _OPTIONAL_POSITIVE_KEYS:
        if key in rig:
            _number(source, key, rig[key], positive=True)
    ambient = float(rig.get("ambient_pressure_pa", DEFAULT_AMBIENT_PA))
    for key in ("supply_pressure_pa", "ambient_pressure_pa"):
        if key in rig:
            out.extend(_pressure_value_warnings(f"{source}: {key}", float(rig[key]), ambient))
    if "supply_pressure_pa" in rig and 2e4 <= rig["supply_pressure_pa"] <= ambient:
        out.append(
            f"{source}: supply_pressure_pa {_fmt(rig['supply_pressure_pa'])} is not above "
            f"ambient ({_fmt(ambient)} Pa); the format wants absolute Pa"
        )
    if "temperature_k" in rig and rig["temperature_k"] < 150:
        out.append(
            f"{source}: temperature_k {_fmt(rig['temperature_k'])} looks like degrees Celsius; "
            "the format wants kelvin"
        )
    if "tube_inner_diameter_m" in rig and rig["tube_inner_diameter_m"] > 0.05:
        out.append(
            f"{source}: tube_inner_diameter_m {_fmt(rig['tube_inner_diameter_m'])} looks like "
            "millimetres; the format wants metres"
        )
    return out


def _piston_warnings(piston, source: str) -> list[str]:
    """The ``piston`` object checked: its mode and the keys the mode needs."""
    out: list[str] = []
    if not isinstance(piston, dict):
        _fail(
            source,
            "piston",
            f'must be an object with "mode": "fixed", "free" or "spring", found {piston!r}',
        )
    if "mode" not in piston:
        raise RecordingError(
            f'{source}: missing required key \'piston.mode\' (allowed: "fixed", "free", "spring")',
            file=source,
            column="piston.mode",
        )
    mode = piston["mode"]
    if mode not in PISTON_MODES:
        _fail(source, "piston.mode", f'is {mode!r}, allowed: "fixed", "free", "spring"')
    required = PISTON_MODES[mode][1]
    for key in required:
        if key not in piston:
            raise RecordingError(
                f"{source}: missing required key 'piston.{key}' (mode {mode!r} needs "
                + ", ".join(required)
                + ")",
                file=source,
                column=f"piston.{key}",
            )
        _number(source, f"piston.{key}", piston[key], nonnegative=key in _NONNEGATIVE_PISTON_KEYS)
    for key in piston:
        if key == "mode" or key in required:
            continue
        if key in _PISTON_KEYS:
            out.append(f"{source}: key 'piston.{key}' is not used in mode {mode!r}; ignored")
        else:
            out.append(
                f"{source}: unknown key 'piston.{key}' ignored (mode {mode!r} uses "
                + ", ".join(required)
                + ")"
            )
    for key in ("position_m", "rest_position_m"):
        if key in required and abs(piston[key]) > 0.5:
            out.append(
                f"{source}: piston.{key} {_fmt(piston[key])} looks like millimetres; "
                "the format wants metres"
            )
    return out


def _read_text(path: Path) -> str:
    """The file's text (UTF-8, a byte-order mark dropped); a clear error if it is not."""
    try:
        return path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as exc:
        raise RecordingError(
            f"{path.name}: not UTF-8 text ({exc.reason} at byte {exc.start})", file=path.name
        ) from None


def _read_sidecar(json_path: Path) -> dict:
    name = json_path.name
    if not json_path.is_file():
        raise RecordingError(
            f"{name}: sidecar not found (a recording is NAME.csv plus NAME.json): {json_path}",
            file=name,
        )
    text = _read_text(json_path)

    def pairs(items):
        obj = {}
        for key, value in items:
            if key in obj:
                raise RecordingError(f"{name}: duplicate key {key!r}", file=name, column=key)
            obj[key] = value
        return obj

    def constant(word):
        raise RecordingError(f"{name}: {word} is not allowed (numbers must be finite)", file=name)

    try:
        return json.loads(text, object_pairs_hook=pairs, parse_constant=constant)
    except json.JSONDecodeError as exc:
        raise RecordingError(
            f"{name} line {exc.lineno}, column {exc.colno}: invalid JSON: {exc.msg}",
            file=name,
            line=exc.lineno,
        ) from None


# --------------------------------------------------------------------------- physics mapping


def rig_to_parameter_overrides(rig: dict) -> dict:
    """Map a sidecar to physics-core parameter names (see ``physics/layout.py``).

    Returns only what the sidecar states: ``cylinder`` (canonical name, to pick the
    cylinder's defaults), ``tube_length_m``, ``tube_inner_diameter_m``,
    ``supply_pressure_pa``, ``ambient_pressure_pa``, ``temperature_k``, ``piston_mode``
    (0 fixed, 1 free, 2 spring) and the mode's ``fixed_position_m`` / ``load_mass_kg``,
    ``load_force_n`` / ``spring_stiffness_n_per_m``, ``spring_rest_position_m``,
    ``load_mass_kg``. ``initial`` is a state, not a parameter, and is not mapped.
    Raises :class:`RecordingError` if the sidecar is invalid.
    """
    rig = {"format": FORMAT_NAME, "version": FORMAT_VERSION, **rig}
    validate_rig(rig, "rig")
    out: dict = {"cylinder": canonical_cylinder(rig["cylinder"])}
    for key in ("tube_length_m", *_OPTIONAL_POSITIVE_KEYS):
        if key in rig:
            out[key] = float(rig[key])
    piston = rig["piston"]
    mode = piston["mode"]
    out["piston_mode"] = PISTON_MODES[mode][0]
    names = {
        "fixed": {"position_m": "fixed_position_m"},
        "free": {"load_mass_kg": "load_mass_kg", "load_force_n": "load_force_n"},
        "spring": {
            "stiffness_n_per_m": "spring_stiffness_n_per_m",
            "rest_position_m": "spring_rest_position_m",
            "load_mass_kg": "load_mass_kg",
        },
    }[mode]
    for key, param in names.items():
        out[param] = float(piston[key])
    return out
