"""Measurement recordings: reader, writer and plausibility checks.

A recording is ``NAME.csv`` (time series) plus ``NAME.json`` (the rig sidecar), as
specified in ``docs/measurement-format.md`` (format ``"pneumatic-measurement"``,
version 1). The reader is strict: anything that breaks the format raises
:class:`RecordingError` with a message naming the file, the line (1-based, as an editor
shows it) and the column or key. Data that is valid but looks wrong (gauge pressure,
bar, millimetres, a clipped or constant channel, an unknown column or key) gives a
:class:`RecordingWarning` and is listed in :attr:`Recording.warnings`.

Nothing here ever modifies a file it reads; the writer refuses to overwrite unless
asked to.
"""

from __future__ import annotations

import csv
import json
import math
import numbers
import os
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pneumatic_env import ids

__all__ = [
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "CYLINDERS",
    "COLUMNS",
    "REQUIRED_COLUMNS",
    "OUTPUT_COLUMNS",
    "PRESSURE_COLUMNS",
    "PISTON_MODES",
    "RecordingError",
    "RecordingWarning",
    "Recording",
    "read_recording",
    "write_recording",
    "validate_rig",
    "canonical_cylinder",
    "rig_to_parameter_overrides",
    "recording_paths",
]

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
_INITIAL_KEYS = ("p1", "p2", "x", "v", "x_s")

DEFAULT_AMBIENT_PA = 101325.0
JITTER_TOLERANCE = 1e-6
CLIP_FRACTION = 0.02
CLIP_MIN_RUN = 5

# A plain decimal number: optional sign, digits with an optional '.', optional exponent.
_NUMBER = r"[ \t]*[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?[ \t]*"
_NUMBER_RE = re.compile(_NUMBER)
_ODD_CHAR_RE = re.compile(r"[^0-9.eE+\- \t]")
_ODD_BODY_RE = re.compile(r"[^0-9.eE+\- \t,\n]")
_NONFINITE_WORDS = {"nan", "inf", "infinity"}


class RecordingError(ValueError):
    """A recording breaks the format. ``file``, ``line`` and ``column`` locate it."""

    def __init__(self, message, *, file=None, line=None, column=None):
        super().__init__(message)
        self.file = file
        self.line = line
        self.column = column


class RecordingWarning(UserWarning):
    """A recording is valid but something in it looks wrong (units, clipping, ...)."""


# --------------------------------------------------------------------------- Recording


@dataclass
class Recording:
    """One measurement: sample times, channels (``i_c`` and the measured ones), the rig.

    ``rig`` is the sidecar exactly as the file states it (package defaults are not
    filled in). ``warnings`` lists the plausibility warnings the reader issued.
    """

    t: np.ndarray
    channels: dict[str, np.ndarray]
    rig: dict
    path: Path | None = None
    warnings: list[str] = field(default_factory=list)

    def __post_init__(self):
        self.t = np.asarray(self.t, dtype=float)
        self.channels = {k: np.asarray(v, dtype=float) for k, v in self.channels.items()}

    @property
    def dt(self) -> float:
        """Sample step in s (mean step, exact for uniform sampling)."""
        return float((self.t[-1] - self.t[0]) / (len(self.t) - 1))

    @property
    def i_c(self) -> np.ndarray:
        """Valve coil current command in A (zero-order hold between samples)."""
        return self.channels["i_c"]

    def has(self, name: str) -> bool:
        """Whether the recording has channel ``name`` (``"t"`` always)."""
        return name == "t" or name in self.channels

    @property
    def measured_outputs(self) -> tuple[str, ...]:
        """The measured outputs present, among ``p1, p2, x, f``, in that order."""
        return tuple(name for name in OUTPUT_COLUMNS if name in self.channels)

    @property
    def duration(self) -> float:
        """``t[-1] - t[0]`` in s (the last command is held one more step beyond)."""
        return float(self.t[-1] - self.t[0])

    @property
    def n_samples(self) -> int:
        return len(self.t)


# --------------------------------------------------------------------------- paths


def recording_paths(path) -> tuple[Path, Path]:
    """``(NAME.csv, NAME.json)`` for ``path`` given as the .csv, the .json or the stem."""
    path = Path(path)
    if path.suffix.lower() in (".csv", ".json"):
        stem = path.with_suffix("")
    else:
        stem = path
    return stem.parent / (stem.name + ".csv"), stem.parent / (stem.name + ".json")


# --------------------------------------------------------------------------- helpers


def _is_number(value) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))


def _fmt(value) -> str:
    """Short, exact float text for messages."""
    return repr(float(value))


def _cell_problem(cell: str) -> str:
    """Why ``cell`` (from a known column) is not an acceptable number."""
    stripped = cell.strip()
    if stripped == "":
        return "empty cell"
    if stripped.lstrip("+-").lower() in _NONFINITE_WORDS:
        return f"{cell!r} is not allowed: NaN and inf are not allowed"
    if _NUMBER_RE.fullmatch(cell):
        return f"{cell!r} is not a finite number"  # overflows to inf
    if re.fullmatch(r"[ \t]*[+-]?\d+,\d+[ \t]*", cell):
        return f"{cell!r} is not a number (the decimal mark must be '.')"
    return f"{cell!r} is not a number"


def _check_time(t: np.ndarray, where) -> None:
    """Strictly increasing, uniform ``t``; ``where(k)`` prefixes messages about sample k."""
    if not np.all(np.isfinite(t)):
        k = int(np.flatnonzero(~np.isfinite(t))[0])
        raise RecordingError(
            f"{where(k, 't')}: {_fmt(t[k])} is not allowed: NaN and inf are not allowed"
        )
    d = np.diff(t)
    bad = np.flatnonzero(d <= 0.0)
    if bad.size:
        k = int(bad[0]) + 1
        raise RecordingError(
            f"{where(k, 't')}: time {_fmt(t[k])} is not after the previous sample's "
            f"{_fmt(t[k - 1])} (t must be strictly increasing)"
        )
    step = float(np.median(d))
    rel = np.abs(d - step) / step
    bad = np.flatnonzero(rel > JITTER_TOLERANCE)
    if bad.size:
        k = int(bad[0]) + 1
        what = "a gap in time: " if d[k - 1] > 1.5 * step else ""
        raise RecordingError(
            f"{where(k, 't')}: non-uniform sampling: {what}step {d[k - 1]:.10g} s found "
            f"(from t={_fmt(t[k - 1])} to t={_fmt(t[k])}), {step:.10g} s expected "
            f"(relative deviation {rel[k - 1]:.3g}, allowed {JITTER_TOLERANCE:g})"
        )


# --------------------------------------------------------------------------- sidecar


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
    out: list[str] = []

    def fail(key, text):
        raise RecordingError(f"{source}: key {key!r} {text}", file=source, column=key)

    def number(key, value, *, positive=False, nonnegative=False):
        if not _is_number(value) or not math.isfinite(value):
            kind = "a positive number" if positive else "a finite number"
            fail(key, f"must be {kind}, found {value!r}")
        if positive and not value > 0:
            fail(key, f"must be a positive number, found {value!r}")
        if nonnegative and value < 0:
            fail(key, f"must be a non-negative number, found {value!r}")
        return float(value)

    if not isinstance(rig, dict):
        raise RecordingError(
            f"{source}: the sidecar must be a JSON object, found {type(rig).__name__}", file=source
        )
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
        fail("format", f'is {rig["format"]!r}, must be "{FORMAT_NAME}"')
    version = rig["version"]
    if not (
        _is_number(version) and isinstance(version, numbers.Integral) and version == FORMAT_VERSION
    ):
        fail(
            "version",
            f"is {version!r}, must be {FORMAT_VERSION} (the only version this package reads)",
        )
    cyl = rig["cylinder"]
    if not (isinstance(cyl, str) and cyl.strip().lower() in _CYLINDER_ALIASES):
        fail("cylinder", f"is {cyl!r}, allowed: {_allowed_cylinders()}")
    tube_length = number("tube_length_m", rig["tube_length_m"], positive=True)
    if tube_length > 50:
        out.append(
            f"{source}: tube_length_m {_fmt(tube_length)} looks like millimetres; "
            "the format wants metres"
        )

    for key in _OPTIONAL_POSITIVE_KEYS:
        if key in rig:
            number(key, rig[key], positive=True)
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

    piston = rig["piston"]
    if not isinstance(piston, dict):
        fail(
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
        fail("piston.mode", f'is {mode!r}, allowed: "fixed", "free", "spring"')
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
        number(f"piston.{key}", piston[key], nonnegative=key in _NONNEGATIVE_PISTON_KEYS)
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

    if "initial" in rig:
        initial = rig["initial"]
        if not isinstance(initial, dict):
            fail(
                "initial",
                f"must be an object with keys among {', '.join(_INITIAL_KEYS)}, found {initial!r}",
            )
        for key, value in initial.items():
            if key not in _INITIAL_KEYS:
                fail(f"initial.{key}", f"is not allowed; allowed: {', '.join(_INITIAL_KEYS)}")
            number(f"initial.{key}", value)
    if "notes" in rig and not isinstance(rig["notes"], str):
        fail("notes", f"must be a string, found {rig['notes']!r}")
    for key in rig:
        if key not in _KNOWN_TOP_KEYS:
            out.append(
                f"{source}: unknown key {key!r} ignored (known: "
                + ", ".join([*_REQUIRED_TOP_KEYS, *_OPTIONAL_POSITIVE_KEYS, "initial", "notes"])
                + ")"
            )
    return out


def _read_sidecar(json_path: Path) -> dict:
    name = json_path.name
    if not json_path.is_file():
        raise RecordingError(
            f"{name}: sidecar not found (a recording is NAME.csv plus NAME.json): {json_path}",
            file=name,
        )
    try:
        text = json_path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as exc:
        raise RecordingError(
            f"{name}: not UTF-8 text ({exc.reason} at byte {exc.start})", file=name
        ) from None

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


# --------------------------------------------------------------------------- plausibility


def _pressure_value_warnings(label: str, value: float, ambient: float) -> list[str]:
    if abs(value) < 20:
        return [f"{label} {_fmt(value)} looks like bar; the format wants absolute Pa"]
    if abs(value) < 2e3:
        return [f"{label} {_fmt(value)} looks like kPa; the format wants absolute Pa"]
    return []


#: Gauge data (0 Pa at ambient) at rest sit within this fraction of ambient around 0 Pa,
#: where an absolute pressure cannot stay: a sealed chamber expanding against a spring
#: falls below ambient (44-90 kPa measured, issue 20), not to a few kPa for long.
GAUGE_ZERO_BAND = 0.05
#: A chamber's absolute pressure spends most of a recording at or above ambient: a median
#: below this fraction of ambient is gauge data (or a wrong ambient in the sidecar).
GAUGE_MEDIAN_FRACTION = 0.5
#: A flat run within this of the ambient pressure (Pa), or within this fraction of the
#: span above the stated supply, is the chamber at the pressure of the line it is open
#: to (physical saturation), not a sensor at its range: transducer noise and offset
#: (0.5 % of a 1 MPa span) and the regulator's setting (the stated supply is nominal).
SATURATION_TOLERANCE_PA = 5e3
SATURATION_SUPPLY_FRACTION = 0.1


def _gauge_pressure_warnings(label: str, y: np.ndarray, ambient: float) -> list[str]:
    """Warnings when a pressure channel looks like gauge data, judged by what gauge data
    look like, not by a value below ambient (which a sealed chamber expanding against a
    spring reaches physically): negative values, samples held near 0 Pa, or a median
    far below ambient."""
    lo = float(y.min())
    if lo < 0.0:
        return [
            f"{label} looks like gauge pressure: values below ambient (min {lo:.6g} Pa); "
            "the format wants absolute Pa"
        ]
    near_zero = float(np.mean(np.abs(y) < GAUGE_ZERO_BAND * ambient))
    if near_zero > CLIP_FRACTION:
        return [
            f"{label} looks like gauge pressure: {100.0 * near_zero:.1f}% of the samples "
            f"within {GAUGE_ZERO_BAND * ambient:.6g} Pa of 0 Pa, where an absolute "
            "pressure cannot stay; the format wants absolute Pa"
        ]
    median = float(np.median(y))
    if median < GAUGE_MEDIAN_FRACTION * ambient:
        return [
            f"{label} looks like gauge pressure: median {median:.6g} Pa is below "
            f"{GAUGE_MEDIAN_FRACTION:g} x ambient ({ambient:.6g} Pa); the format wants "
            "absolute Pa"
        ]
    return []


def physical_limit(
    name: str, value: float, y: np.ndarray, rig: dict, channels: dict | None = None
) -> str | None:
    """``"supply"`` or ``"ambient"`` when a pressure channel's flat ``value`` is the
    pressure a chamber saturates at (the sidecar's supply or ambient pressure, within
    ``SATURATION_TOLERANCE_PA`` plus five times the channel's noise, and for the supply
    within ``SATURATION_SUPPLY_FRACTION`` of the span), else None. A value another
    chamber's pressure in ``channels`` exceeds by more than that tolerance is not the
    supply (a sensor at its range below the supply). The force ``f`` of a clamped rod is
    flat where both chambers are: ``"saturated chambers"`` when p1 and p2 sit at their
    extremes on nine in ten of the samples at ``value`` (whether those are physical is
    the pressure channels' own check)."""
    if not isinstance(rig, dict):
        return None
    if name == "f" and channels is not None and "p1" in channels and "p2" in channels:
        at_value = y == value
        saturated = np.ones(len(y), dtype=bool)
        for c in ("p1", "p2"):
            p = channels[c]
            saturated &= (p == p.min()) | (p == p.max())
        if at_value.any() and np.mean(saturated[at_value]) >= 0.9:
            return "saturated chambers"
        return None
    if name not in PRESSURE_COLUMNS:
        return None
    ambient = rig.get("ambient_pressure_pa", DEFAULT_AMBIENT_PA)
    ambient = float(ambient) if _is_number(ambient) else DEFAULT_AMBIENT_PA
    steps = np.abs(np.diff(y))
    steps = steps[steps > 0]
    noise = 1.4826 * float(np.median(steps)) / math.sqrt(2.0) if steps.size else 0.0
    tolerance = SATURATION_TOLERANCE_PA + 5.0 * noise
    if abs(value - ambient) <= tolerance:
        return "ambient"
    raw_supply = rig.get("supply_pressure_pa")
    if raw_supply is None or not _is_number(raw_supply):
        return None
    supply = float(raw_supply)
    if not (
        supply > ambient
        and abs(value - supply) <= max(tolerance, SATURATION_SUPPLY_FRACTION * (supply - ambient))
    ):
        return None
    chambers = channels or {}
    others = [c for c in ("p1", "p2") if c != name and c in chambers]
    if any(float(np.max(chambers[c])) > value + tolerance for c in others):
        return None
    return "supply"


def _extreme_run_fraction(y: np.ndarray, value: float) -> tuple[int, int]:
    """Samples equal to ``value`` that lie in runs of >= CLIP_MIN_RUN, skipping a leading run.

    Returns ``(count, longest_run)``. A recording that starts at rest (the first samples
    all equal) is normal and is not counted.
    """
    eq = np.concatenate(([False], y == value, [False]))
    edges = np.flatnonzero(np.diff(eq.astype(np.int8)))
    starts, ends = edges[0::2], edges[1::2]
    lengths = ends - starts
    keep = (lengths >= CLIP_MIN_RUN) & (starts > 0)
    if not keep.any():
        return 0, 0
    return int(lengths[keep].sum()), int(lengths[keep].max())


def _channel_warnings(name: str, channels: dict, rig: dict, source: str) -> list[str]:
    out: list[str] = []
    y = channels[name]
    lo, hi = float(y.min()), float(y.max())
    ambient = rig.get("ambient_pressure_pa", DEFAULT_AMBIENT_PA)
    ambient = float(ambient) if _is_number(ambient) else DEFAULT_AMBIENT_PA
    if name in PRESSURE_COLUMNS:
        if max(abs(lo), abs(hi)) < 20:
            out.append(
                f"{source}: {name} looks like bar (max {_fmt(hi)}); the format wants absolute Pa"
            )
        elif max(abs(lo), abs(hi)) < 2e4:
            out.append(
                f"{source}: {name} looks like kPa (max {_fmt(hi)}); the format wants absolute Pa"
            )
        else:
            out.extend(_gauge_pressure_warnings(f"{source}: {name}", y, ambient))
    if name == "x" and max(abs(lo), abs(hi)) > 0.5:
        out.append(
            f"{source}: x looks like millimetres (max |x| {max(abs(lo), abs(hi)):.6g}); "
            "the format wants metres"
        )
    if name == "x_s" and max(abs(lo), abs(hi)) > 0.01:
        out.append(
            f"{source}: x_s looks like millimetres (max |x_s| {max(abs(lo), abs(hi)):.6g}); "
            "the format wants metres"
        )
    piston = rig.get("piston")
    fixed = isinstance(piston, dict) and piston.get("mode") == "fixed"
    if lo == hi:
        if not (name == "x" and fixed):
            out.append(f"{source}: {name} is constant ({_fmt(lo)}) over the whole recording")
        return out
    if name == "i_c":  # a command sitting at its limit is normal
        return out
    n = len(y)
    for label, value in (("minimum", lo), ("maximum", hi)):
        if physical_limit(name, value, y, rig, channels) is not None:
            continue  # a chamber at supply or ambient pressure: saturation, not clipping
        count, longest = _extreme_run_fraction(y, value)
        if count > CLIP_FRACTION * n:
            note = " or the piston at an end stop" if name == "x" else ""
            out.append(
                f"{source}: {name} looks clipped: it sits at its {label} {_fmt(value)} for "
                f"{100.0 * count / n:.1f}% of the samples (longest run {longest} samples); "
                f"a saturated sensor or range{note}?"
            )
    return out


# --------------------------------------------------------------------------- reader


def _read_csv(csv_path: Path) -> tuple[np.ndarray, dict[str, np.ndarray], list[str]]:
    name = csv_path.name
    if not csv_path.is_file():
        raise RecordingError(f"{name}: file not found: {csv_path}", file=name)
    try:
        text = csv_path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as exc:
        raise RecordingError(
            f"{name}: not UTF-8 text ({exc.reason} at byte {exc.start})", file=name
        ) from None
    lines = text.split("\n")
    lines = [ln[:-1] if ln.endswith("\r") else ln for ln in lines]
    while lines and lines[-1].strip() == "":  # final newline / trailing blank lines
        lines.pop()
    if not lines:
        raise RecordingError(f"{name}: empty file (the first line must be the header)", file=name)
    warn: list[str] = []

    def err(line, message, column=None):
        where = f"{name} line {line}" + (f", column {column!r}" if column is not None else "")
        return RecordingError(f"{where}: {message}", file=name, line=line, column=column)

    header = [h.strip() for h in next(csv.reader([lines[0]]))]
    if not any(header):
        raise err(1, "empty line: the first line must be the header (column names)")
    if len(header) == 1 and (";" in header[0] or "\t" in header[0]):
        raise err(1, f"the header {lines[0]!r} has a single column: the separator must be ','")
    if all(_NUMBER_RE.fullmatch(h) for h in header):
        raise err(
            1, f"the first line must be the header (column names), found numbers {lines[0]!r}"
        )
    for j, h in enumerate(header):
        if h == "":
            raise err(1, f"empty column name (column {j + 1} of the header)")
    seen = set()
    for h in header:
        if h in seen:
            raise err(1, f"duplicate column {h!r}", column=h)
        seen.add(h)
    for req in REQUIRED_COLUMNS:
        if req not in seen:
            raise err(1, f"missing required column {req!r}", column=req)
    if not any(c in seen for c in OUTPUT_COLUMNS):
        raise err(1, "needs at least one of the columns 'p1', 'p2', 'x', 'f'")
    for h in header:
        if h not in COLUMNS:
            hint = f" (did you mean {h.lower()!r}?)" if h.lower() in COLUMNS else ""
            warn.append(
                f"{name}: unknown column {h!r} ignored{hint}; known columns: " + ", ".join(COLUMNS)
            )

    ncol = len(header)
    if len(lines) >= 3 and all(h in COLUMNS for h in header):
        # Fast path for clean files: numpy's C parser on plain numeric text. Any
        # irregularity (blank line, quote, odd character, bad cell) falls through to
        # the row-by-row reader below, which locates it exactly.
        body = lines[1:]
        if not _ODD_BODY_RE.search("\n".join(body)):
            try:
                table = np.loadtxt(body, delimiter=",", dtype=np.float64, comments=None, ndmin=2)
            except ValueError:
                table = None
            if (
                table is not None
                and table.shape == (len(body), ncol)
                and np.all(np.isfinite(table))
            ):
                fast = {h: np.ascontiguousarray(table[:, j]) for j, h in enumerate(header)}
                return _finish_csv(name, fast, warn)
    rows = list(csv.reader(lines[1:]))
    for k, row in enumerate(rows):
        if len(row) != ncol:
            if not row or (len(row) == 1 and row[0].strip() == ""):
                raise err(k + 2, "empty line (every row must hold one sample)")
            raise err(k + 2, f"{len(row)} cells, the header has {ncol} columns")
    if len(rows) < 2:
        raise RecordingError(
            f"{name}: {len(rows)} data row{'s' if len(rows) != 1 else ''}; "
            "a recording needs at least 2",
            file=name,
        )

    data: dict[str, np.ndarray] = {}
    columns = list(zip(*rows))
    for j, h in enumerate(header):
        if h not in COLUMNS:
            continue
        cells = columns[j]
        # Fast path: only digits, '.', exponent, sign and blanks, then numpy's parser
        # (Python float syntax). Anything odd falls to the cell-by-cell check below.
        if not _ODD_CHAR_RE.search("".join(cells)):
            try:
                values = np.array(cells).astype(np.float64)
            except ValueError:
                values = None
            if values is not None and np.all(np.isfinite(values)):
                data[h] = values
                continue
        for k, c in enumerate(cells):  # slow path: find the first bad cell
            if not _NUMBER_RE.fullmatch(c) or not math.isfinite(float(c)):
                raise err(k + 2, _cell_problem(c), column=h)
        raise AssertionError(
            f"{name}: column {h!r} failed to parse but no bad cell found"
        )  # pragma: no cover

    return _finish_csv(name, data, warn)


def _finish_csv(name, data, warn):
    t = data.pop("t")
    _check_time(t, lambda k, col: f"{name} line {k + 2}, column {col!r}")
    channels = {h: data[h] for h in COLUMNS if h in data}
    return t, channels, warn


def read_recording(path) -> Recording:
    """Read ``NAME.csv`` and ``NAME.json``; ``path`` is the .csv, the .json or the stem.

    Raises :class:`RecordingError` for anything that breaks the format; issues a
    :class:`RecordingWarning` for each plausibility problem (also kept in
    ``Recording.warnings``). The files are only read.
    """
    csv_path, json_path = recording_paths(path)
    t, channels, warn = _read_csv(csv_path)
    rig = _read_sidecar(json_path)
    warn = validate_rig(rig, json_path.name) + warn
    for name in channels:
        warn.extend(_channel_warnings(name, channels, rig, csv_path.name))
    for message in warn:
        warnings.warn(message, RecordingWarning, stacklevel=2)
    return Recording(t=t, channels=channels, rig=rig, path=csv_path, warnings=warn)


# --------------------------------------------------------------------------- writer


def _jsonable(value):
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    return value


def write_recording(path, t, channels: dict, rig: dict, *, overwrite: bool = False) -> Path:
    """Write ``NAME.csv`` and ``NAME.json``; ``path`` is the stem, the .csv or the .json.

    ``channels`` maps column names to arrays as long as ``t``: ``i_c`` and at least one
    of ``p1, p2, x, f`` are required, ``v, x_s, p_s`` optional, nothing else. Columns are
    written as ``t, i_c`` then the spec's order, floats as their exact ``repr``. ``rig``
    is the sidecar; ``format`` and ``version`` are filled in. Everything is validated
    before anything is written; existing files are kept unless ``overwrite=True``.
    Returns the path of the CSV file.
    """
    csv_path, json_path = recording_paths(path)
    cname = csv_path.name
    t = np.asarray(t, dtype=float)
    if t.ndim != 1:
        raise RecordingError(
            f"{cname}: t must be one-dimensional, has shape {t.shape}", file=cname, column="t"
        )
    if len(t) < 2:
        raise RecordingError(f"{cname}: {len(t)} samples; a recording needs at least 2", file=cname)
    for name in channels:
        if name not in COLUMNS or name == "t":
            raise RecordingError(
                f"{cname}: unknown channel {name!r}; allowed: " + ", ".join(COLUMNS[1:]),
                file=cname,
                column=name,
            )
    if "i_c" not in channels:
        raise RecordingError(f"{cname}: missing required channel 'i_c'", file=cname, column="i_c")
    if not any(c in channels for c in OUTPUT_COLUMNS):
        raise RecordingError(
            f"{cname}: needs at least one of the channels 'p1', 'p2', 'x', 'f'", file=cname
        )
    cols = {}
    for name in COLUMNS[1:]:
        if name not in channels:
            continue
        y = np.asarray(channels[name], dtype=float)
        if y.shape != t.shape:
            raise RecordingError(
                f"{cname}: channel {name!r} has shape {y.shape}, t has {t.shape}",
                file=cname,
                column=name,
            )
        bad = np.flatnonzero(~np.isfinite(y))
        if bad.size:
            k = int(bad[0])
            raise RecordingError(
                f"{cname}: channel {name!r} sample {k}: {_fmt(y[k])} is not allowed: "
                "NaN and inf are not allowed",
                file=cname,
                column=name,
            )
        cols[name] = y
    _check_time(t, lambda k, col: f"{cname}: channel {col!r} sample {k}")

    rig = _jsonable(dict(rig))
    for key, value in (("format", FORMAT_NAME), ("version", FORMAT_VERSION)):
        if rig.get(key, value) != value:
            raise RecordingError(
                f"{json_path.name}: key {key!r} is {rig[key]!r}, must be {value!r}",
                file=json_path.name,
                column=key,
            )
    sidecar = {"format": FORMAT_NAME, "version": FORMAT_VERSION}
    sidecar.update((k, v) for k, v in rig.items() if k not in sidecar)
    for message in validate_rig(sidecar, json_path.name):
        warnings.warn(message, RecordingWarning, stacklevel=2)
    json_text = json.dumps(sidecar, indent=2, allow_nan=False) + "\n"

    if not overwrite:
        for p in (csv_path, json_path):
            if p.exists():
                raise FileExistsError(f"{p} exists; pass overwrite=True to replace it")

    names = ["t", *cols]
    columns = [list(map(repr, c.tolist())) for c in (t, *cols.values())]
    csv_text = ",".join(names) + "\n" + "\n".join(map(",".join, zip(*columns))) + "\n"

    for p, content in ((csv_path, csv_text), (json_path, json_text)):
        tmp = p.parent / f".{p.name}.tmp{os.getpid()}"
        try:
            with open(tmp, "w", encoding="utf-8", newline="\n") as fh:
                fh.write(content)
            os.replace(tmp, p)
        finally:
            if tmp.exists():
                tmp.unlink()
    return csv_path


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
