"""Bad-data checks before a fit: refuse what would give a silently wrong answer.

The reader (:func:`pneumatic_env.recording.read_recording`) already raises on broken
files (gaps, NaN, unsorted time, missing required columns) and warns on values that look
wrong. Here its warnings are classified and a few fit-specific checks are added:

=================  ========  =============================================================
code               severity  what
=================  ========  =============================================================
``units``          error     a channel or sidecar value looks like bar, kPa, gauge pressure,
                             millimetres or degrees Celsius (the reader's warning; gauge
                             data are told by negative values, samples held near 0 Pa or a
                             median far below ambient, never by a sub-ambient dip alone)
``clipped``        warning   a channel sits at its extreme for a long run that is not a
                             chamber at supply or ambient pressure: left out of the fit
``constant``       warning   a channel never changes: it is left out of the fit
``no_output``      error     no usable output channel (e.g. only ``x`` with the rod clamped)
``no_position``    warning   the piston moves but ``x`` is not measured: friction not fitted
``no_excitation``  error     the coil current never leaves the valve's dead band
``too_short``      error     fewer samples than ``checks.min_samples`` (identification.yaml)
``format``         warning   anything else the reader warned about (unknown column, ...)
=================  ========  =============================================================
"""

from __future__ import annotations

import warnings
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from pneumatic_env.physics.derived import valve_currents_a
from pneumatic_env.recording import (
    CLIP_MIN_RUN,
    OUTPUT_COLUMNS,
    Recording,
    RecordingWarning,
    physical_limit,
    read_recording,
)

from .config import IdentificationConfig, load_config

__all__ = [
    "BadDataError",
    "DataIssue",
    "check_recording",
    "check_recordings",
    "read_checked",
    "usable_masks",
    "FITTED_CHANNELS",
]

#: Measured channels a fit can use (outputs plus the optional v and x_s).
FITTED_CHANNELS = (*OUTPUT_COLUMNS, "v", "x_s")
_UNIT_PHRASES = (
    "looks like bar",
    "looks like kpa",
    "looks like gauge",
    "looks like millimetres",
    "looks like degrees celsius",
    "is not above ambient",
)


@dataclass(frozen=True)
class DataIssue:
    """One problem found in a recording."""

    severity: str  # "error" or "warning"
    code: str
    recording: str
    message: str
    channel: str | None = None

    def __str__(self) -> str:
        return f"{self.severity}: [{self.code}] {self.message}"


class BadDataError(ValueError):
    """The recordings cannot be fitted; ``issues`` lists every error found."""

    def __init__(self, issues: Sequence[DataIssue]):
        self.issues = list(issues)
        lines = [str(i) for i in self.issues]
        super().__init__("refusing to fit:\n  " + "\n  ".join(lines))


def read_checked(path) -> Recording:
    """Read a recording; the reader's warnings are kept in ``Recording.warnings`` only."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RecordingWarning)
        return read_recording(path)


def _name(rec: Recording) -> str:
    return rec.path.name if rec.path is not None else "recording"


def _channel_in(message: str, rec: Recording) -> str | None:
    for ch in rec.channels:
        if f": {ch} " in message:
            return ch
    return None


def _extreme_runs(y: np.ndarray, value: float, min_run: int) -> np.ndarray:
    """Mask of samples equal to ``value`` in runs of at least ``min_run`` (not a leading run)."""
    eq = np.concatenate(([False], y == value, [False]))
    edges = np.flatnonzero(np.diff(eq.astype(np.int8)))
    mask = np.zeros(len(y), dtype=bool)
    for start, end in zip(edges[0::2], edges[1::2]):
        if end - start >= min_run and start > 0:
            mask[start:end] = True
    return mask


def usable_masks(
    rec: Recording, channels: Iterable[str], min_run: int = CLIP_MIN_RUN
) -> dict[str, np.ndarray]:
    """Per channel, the samples a fit may use: all but the clipped runs at the extremes.

    A run is clipped with the reader's rule (``recording.CLIP_MIN_RUN`` equal samples at
    the channel's minimum or maximum, not counting a leading run), unless it is a
    chamber at the supply or ambient pressure (``recording.physical_limit``: saturation,
    which the model predicts and the fit keeps).
    """
    out = {}
    for ch in channels:
        y = rec.channels[ch]
        clipped = np.zeros(len(y), dtype=bool)
        for value in (float(y.min()), float(y.max())):
            if physical_limit(ch, value, y, rec.rig, rec.channels) is None:
                clipped |= _extreme_runs(y, value, min_run)
        out[ch] = ~clipped
    return out


def dead_band_current(values: Mapping[str, float]) -> float:
    """Coil current at which the valve starts to open (Eqs. 43, 46; physics.derived)."""
    dead_band_a, _ = valve_currents_a(
        values["spool_half_width_m"],
        values["hole_radius_m"],
        values["spool_spring_n_per_m"],
        max(values["coil_force_n_per_a"], 1e-12),
    )
    return float(dead_band_a)


def check_recording(
    rec: Recording, params: dict | None = None, config: IdentificationConfig | None = None
) -> list[DataIssue]:
    """Issues of one recording. ``params`` (its parameter set) enables the dead-band check."""
    config = config or load_config()
    min_samples = int(config.number("checks", "min_samples", minimum=2))
    name = _name(rec)
    issues = [_reader_issue(message, rec, name) for message in rec.warnings]
    if rec.n_samples < min_samples:
        issues.append(
            DataIssue(
                "error",
                "too_short",
                name,
                f"{name}: {rec.n_samples} samples; a fit needs at least "
                f"{min_samples} (checks.min_samples)",
            )
        )
    issues += _output_issues(rec, name, {i.channel for i in issues if i.code == "constant"})
    if params is not None:
        dead_band_a = dead_band_current(params)
        peak = float(np.max(np.abs(rec.i_c)))
        if peak <= dead_band_a:
            issues.append(
                DataIssue(
                    "error",
                    "no_excitation",
                    name,
                    f"{name}: |i_c| never exceeds {peak:.4g} A, inside the valve's "
                    f"dead band (+-{dead_band_a:.4g} A by Eqs. 43, 46): the valve "
                    "never opens, nothing to fit",
                )
            )
    return issues


def _reader_issue(message: str, rec: Recording, name: str) -> DataIssue:
    """One of the reader's warnings classified (units, clipped, constant or format)."""
    low = message.lower()
    channel = _channel_in(message, rec)
    if any(p in low for p in _UNIT_PHRASES):
        return DataIssue(
            "error", "units", name, f"{message} (convert to SI/absolute before fitting)", channel
        )
    if "looks clipped" in low:
        return DataIssue(
            "warning",
            "clipped",
            name,
            f"{message}; the clipped samples are left out of the fit",
            channel,
        )
    if "is constant" in low:
        return DataIssue(
            "warning", "constant", name, f"{message}; the channel is left out of the fit", channel
        )
    return DataIssue("warning", "format", name, message, channel)


def _output_issues(rec: Recording, name: str, constant: set) -> list[DataIssue]:
    """No usable output channel (``constant``: channels that never change), or a moving
    piston whose position is not measured."""
    issues = []
    mode = rec.rig.get("piston", {}).get("mode")
    usable = [
        c
        for c in FITTED_CHANNELS
        if c in rec.channels and c not in constant and not (c == "x" and mode == "fixed")
    ]
    if not usable:
        issues.append(
            DataIssue(
                "error",
                "no_output",
                name,
                f"{name}: no usable output channel (present: "
                f"{', '.join(rec.channels)}; rod mode {mode!r}); need p1, p2, f, "
                "or x with a moving piston",
            )
        )
    if mode in ("free", "spring") and "x" not in rec.channels:
        issues.append(
            DataIssue(
                "warning",
                "no_position",
                name,
                f"{name}: the piston moves (mode {mode!r}) but x is not measured; "
                "the friction parameters are not fitted",
            )
        )
    return issues


def check_recordings(
    recs: Sequence[Recording],
    params: Sequence[dict] | None = None,
    raise_on_error: bool = True,
    config: IdentificationConfig | None = None,
) -> list[DataIssue]:
    """Issues of every recording; raises :class:`BadDataError` listing all errors."""
    issues: list[DataIssue] = []
    for k, rec in enumerate(recs):
        issues.extend(check_recording(rec, None if params is None else params[k], config))
    errors = [i for i in issues if i.severity == "error"]
    if errors and raise_on_error:
        raise BadDataError(errors)
    return issues
