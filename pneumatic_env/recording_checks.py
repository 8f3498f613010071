"""Plausibility of a recording's channels: units, gauge pressure and clipping, told
apart from what the physics does (a chamber below ambient while it expands, a chamber
at supply or ambient pressure). Each check returns warning texts; the reader
(:func:`pneumatic_env.recording.read_recording`) issues them."""

from __future__ import annotations

import math

import numpy as np

from .recording_format import (
    CLIP_FRACTION,
    CLIP_MIN_RUN,
    DEFAULT_AMBIENT_PA,
    PRESSURE_COLUMNS,
)
from .text_format import is_number as _is_number
from .text_format import number_text as _fmt  # exact float text

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
