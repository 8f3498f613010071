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
import os
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .recording_checks import _channel_warnings, physical_limit
from .recording_format import (
    CLIP_MIN_RUN,
    COLUMNS,
    CYLINDERS,
    FORMAT_NAME,
    FORMAT_VERSION,
    JITTER_TOLERANCE,
    OUTPUT_COLUMNS,
    PISTON_MODES,
    PRESSURE_COLUMNS,
    REQUIRED_COLUMNS,
    RecordingError,
    RecordingWarning,
    _read_sidecar,
    _read_text,
    canonical_cylinder,
    rig_to_parameter_overrides,
    validate_rig,
)
from .text_format import jsonable
from .text_format import number_text as _fmt  # exact float text

# A plain decimal number: optional sign, digits with an optional '.', optional exponent.
_NUMBER = r"[ \t]*[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?[ \t]*"
_NUMBER_RE = re.compile(_NUMBER)
_ODD_CHAR_RE = re.compile(r"[^0-9.eE+\- \t]")
_ODD_BODY_RE = re.compile(r"[^0-9.eE+\- \t,\n]")
_NONFINITE_WORDS = {"nan", "inf", "infinity"}

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
    "physical_limit",
    "CLIP_MIN_RUN",
]

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


# --------------------------------------------------------------------------- reader


def _read_csv(csv_path: Path) -> tuple[np.ndarray, dict[str, np.ndarray], list[str]]:
    """(t, channels, warnings) of a recording's CSV file; raises on a broken one."""
    name = csv_path.name
    if not csv_path.is_file():
        raise RecordingError(f"{name}: file not found: {csv_path}", file=name)
    text = _read_text(csv_path)
    lines = text.split("\n")
    lines = [ln[:-1] if ln.endswith("\r") else ln for ln in lines]
    while lines and lines[-1].strip() == "":  # final newline / trailing blank lines
        lines.pop()
    if not lines:
        raise RecordingError(f"{name}: empty file (the first line must be the header)", file=name)
    header, warn = _csv_header(name, lines[0])
    if len(lines) >= 3 and all(h in COLUMNS for h in header):
        fast = _clean_table(lines[1:], header)
        if fast is not None:
            return _finish_csv(name, fast, warn)
    return _finish_csv(name, _csv_rows(name, lines[1:], header), warn)


def _csv_error(name: str, line: int, message: str, column=None) -> RecordingError:
    """The :class:`RecordingError` of ``line`` (and ``column``) of CSV file ``name``."""
    where = f"{name} line {line}" + (f", column {column!r}" if column is not None else "")
    return RecordingError(f"{where}: {message}", file=name, line=line, column=column)


def _csv_header(name: str, first_line: str) -> tuple[list[str], list[str]]:
    """The header's column names, checked, and a warning per unknown column."""
    header = [h.strip() for h in next(csv.reader([first_line]))]
    if not any(header):
        raise _csv_error(name, 1, "empty line: the first line must be the header (column names)")
    if len(header) == 1 and (";" in header[0] or "\t" in header[0]):
        raise _csv_error(
            name, 1, f"the header {first_line!r} has a single column: the separator must be ','"
        )
    if all(_NUMBER_RE.fullmatch(h) for h in header):
        raise _csv_error(
            name,
            1,
            f"the first line must be the header (column names), found numbers {first_line!r}",
        )
    for j, h in enumerate(header):
        if h == "":
            raise _csv_error(name, 1, f"empty column name (column {j + 1} of the header)")
    seen = set()
    for h in header:
        if h in seen:
            raise _csv_error(name, 1, f"duplicate column {h!r}", column=h)
        seen.add(h)
    for req in REQUIRED_COLUMNS:
        if req not in seen:
            raise _csv_error(name, 1, f"missing required column {req!r}", column=req)
    if not any(c in seen for c in OUTPUT_COLUMNS):
        raise _csv_error(name, 1, "needs at least one of the columns 'p1', 'p2', 'x', 'f'")
    warn = []
    for h in header:
        if h not in COLUMNS:
            hint = f" (did you mean {h.lower()!r}?)" if h.lower() in COLUMNS else ""
            warn.append(
                f"{name}: unknown column {h!r} ignored{hint}; known columns: " + ", ".join(COLUMNS)
            )
    return header, warn


def _clean_table(body: list[str], header: list[str]) -> dict[str, np.ndarray] | None:
    """Fast path for clean files: numpy's C parser on plain numeric text. Any
    irregularity (blank line, quote, odd character, bad cell) gives None: the row-by-row
    reader (:func:`_csv_rows`) locates it exactly."""
    if _ODD_BODY_RE.search("\n".join(body)):
        return None
    try:
        table = np.loadtxt(body, delimiter=",", dtype=np.float64, comments=None, ndmin=2)
    except ValueError:
        return None
    if table.shape == (len(body), len(header)) and np.all(np.isfinite(table)):
        return {h: np.ascontiguousarray(table[:, j]) for j, h in enumerate(header)}
    return None


def _csv_rows(name: str, body: list[str], header: list[str]) -> dict[str, np.ndarray]:
    """The known columns of the data rows ``body``, row by row; raises at the first
    broken row or cell."""
    ncol = len(header)
    rows = list(csv.reader(body))
    for k, row in enumerate(rows):
        if len(row) != ncol:
            if not row or (len(row) == 1 and row[0].strip() == ""):
                raise _csv_error(name, k + 2, "empty line (every row must hold one sample)")
            raise _csv_error(name, k + 2, f"{len(row)} cells, the header has {ncol} columns")
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
                raise _csv_error(name, k + 2, _cell_problem(c), column=h)
        raise AssertionError(
            f"{name}: column {h!r} failed to parse but no bad cell found"
        )  # pragma: no cover
    return data


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
    t = np.asarray(t, dtype=float)
    cols = _checked_columns(csv_path.name, t, channels)
    json_text = _sidecar_text(rig, json_path.name)
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


def _checked_columns(cname: str, t: np.ndarray, channels: dict) -> dict[str, np.ndarray]:
    """``channels`` as float arrays in the spec's column order, each checked against
    the format and ``t`` (``cname``: the CSV file's name, for the errors)."""
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
    return cols


def _sidecar_text(rig: dict, jname: str) -> str:
    """The sidecar's JSON text with ``format`` and ``version`` filled in, validated
    (its plausibility warnings issued to :func:`write_recording`'s caller)."""
    rig = jsonable(dict(rig))
    for key, value in (("format", FORMAT_NAME), ("version", FORMAT_VERSION)):
        if rig.get(key, value) != value:
            raise RecordingError(
                f"{jname}: key {key!r} is {rig[key]!r}, must be {value!r}",
                file=jname,
                column=key,
            )
    sidecar = {"format": FORMAT_NAME, "version": FORMAT_VERSION}
    sidecar.update((k, v) for k, v in rig.items() if k not in sidecar)
    for message in validate_rig(sidecar, jname):
        warnings.warn(message, RecordingWarning, stacklevel=3)
    return json.dumps(sidecar, indent=2, allow_nan=False) + "\n"
