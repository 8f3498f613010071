"""The drift notice: base parameters fitted outside their plausible range.

A model that lacks an effect bends its base parameters to take up the effect's part of
the data (on a tube-wave rig the discharge coefficient fell from 0.25 to 0.095 and a dead
volume rose six-fold). Each base parameter fitted outside ``plausible_min`` ..
``plausible_max`` (``base_parameters`` in ``configs/identification.yaml``) is reported
with its nominal and fitted values, the factor outside the range, and the effects it may
stand for (``base_drift`` in the config, with the physical reasoning). A parameter whose
smallest simulated value is the plausible edge itself (``simulated_min``, the dead
volumes: a smaller chamber makes the kernel split its substeps) cannot leave the range;
held on that edge, it is reported as a drift with a factor of 1 (at least: the data pull
it further).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from pneumatic_env.params import ConfigError

from .config import IdentificationConfig
from .datasets import Dataset
from .results import FitResult

__all__ = ["Drift", "base_drifts", "drift_table", "suggested_effects"]


@dataclass(frozen=True)
class Drift:
    """One base parameter fitted outside its plausible range."""

    name: str
    unit: str
    nominal: float  # the warm start: the config's initial, else the data's value
    fitted: float  # in the calibrated base model
    plausible_min: float
    plausible_max: float
    direction: str  # "above" or "below" the plausible range
    factor: float  # how far outside: fitted / max above, min / fitted below (>= 1)
    effects: tuple[str, ...]  # what it may stand for (config base_drift)
    explanation: str
    final: float | None = None  # in the model with the selected effects, if refitted
    held_at_bound: bool = False  # on the plausible edge, its floor (factor >= 1)

    def to_dict(self) -> dict:
        return {
            "parameter": self.name,
            "unit": self.unit,
            "nominal": self.nominal,
            "fitted": self.fitted,
            "plausible_range": [self.plausible_min, self.plausible_max],
            "direction": self.direction,
            "factor_outside": self.factor if math.isfinite(self.factor) else None,
            "may_stand_for": list(self.effects),
            "explanation": self.explanation,
            "final": self.final,
            "held_at_bound": self.held_at_bound,
        }


def drift_table(cfg: IdentificationConfig) -> dict[str, dict[str, tuple[tuple[str, ...], str]]]:
    """``base_drift`` of the config: parameter -> direction -> (effects, explanation)."""
    raw = cfg.raw.get("base_drift") or {}
    out: dict[str, dict[str, tuple[tuple[str, ...], str]]] = {}
    for name, sides in raw.items():
        if name not in cfg.base_parameters or not isinstance(sides, Mapping):
            raise ConfigError(f"{cfg.path}: base_drift.{name} must name a base parameter")
        out[name] = {}
        for side, entry in sides.items():
            effects = entry.get("effects") if isinstance(entry, Mapping) else None
            source = entry.get("source") if isinstance(entry, Mapping) else None
            if side not in ("above", "below") or not isinstance(effects, list):
                raise ConfigError(
                    f"{cfg.path}: base_drift.{name}.{side} must be 'above' or 'below' "
                    "with a list 'effects' and a text 'source'"
                )
            if not isinstance(source, str):
                raise ConfigError(f"{cfg.path}: base_drift.{name}.{side} needs a 'source'")
            out[name][side] = (tuple(str(e) for e in effects), source)
    return out


#: A fitted value within this relative distance of its floor is held there.
BOUND_RTOL = 1e-3


def _side(p, value: float) -> tuple[str, float, bool] | None:
    """(direction, factor outside, held at the floor) of a value outside ``p``'s plausible
    range or held on its ``simulated_min`` where that is the plausible edge; None inside."""
    if value > p.plausible_max:
        return "above", value / p.plausible_max if p.plausible_max > 0 else math.inf, False
    if value < p.plausible_min:
        return "below", p.plausible_min / value if value > 0 else math.inf, False
    floor = p.simulated_min
    if floor is not None and floor >= p.plausible_min and value <= floor * (1.0 + BOUND_RTOL):
        return "below", 1.0, True
    return None


def base_drifts(
    base: FitResult,
    datasets: Sequence[Dataset],
    cfg: IdentificationConfig,
    final: FitResult | None = None,
) -> list[Drift]:
    """The base parameters of ``base`` fitted outside their plausible range (or held on
    its edge by their floor, ``_side``), farthest first; ``final``: the model with the
    selected effects (its value of each, if fitted)."""
    table = drift_table(cfg)
    out = []
    for p in base.parameters:
        value = base.values[p.name]
        where = _side(p, value)
        if where is None:
            continue
        side, factor, held = where
        effects, why = table.get(p.name, {}).get(side, ((), "no known stand-in"))
        nominal = p.initial if p.initial is not None else datasets[0].values[p.name]
        out.append(
            Drift(
                p.name,
                p.unit,
                float(nominal),
                float(value),
                p.plausible_min,
                p.plausible_max,
                side,
                float(factor),
                effects,
                why,
                None if final is None else final.values.get(p.name),
                held,
            )
        )
    return sorted(out, key=lambda d: -d.factor)


def suggested_effects(drifts: Sequence[Drift]) -> list[str]:
    """The effects the drifts point at, those of the farthest drift first, once each."""
    out: list[str] = []
    for d in drifts:
        out += [e for e in d.effects if e not in out]
    return out
