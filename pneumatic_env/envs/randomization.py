"""Domain randomisation: the plant parameters drawn per episode (env option
``domain_randomization``).

The option is ``{name: (low, high)}`` in the parameter's SI unit or ``{name: r}`` for
+-r relative to the plant's value, each drawn uniformly per episode. The key ``one_of``
adds alternatives drawn per episode: ``[{"probability": p, "ranges": {name: ...}}, ...]``
with probabilities summing to 1; one alternative is chosen and its ranges are drawn as
well. A switch (e.g. ``tube_waves``) is thus on with probability p, and an effect that
excludes another (the transmission line holds the tube's air itself, so it excludes
``tube_volume_fraction``) takes its own alternative.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

import pneumatic_env.params as P

ONE_OF = "one_of"
_SUM_TOLERANCE = 1e-9  # of the alternatives' probabilities against 1


@dataclass(frozen=True)
class Randomization:
    """Checked ranges ``{name: (low, high)}`` and alternatives ``((probability, ranges),
    ...)``."""

    ranges: dict
    alternatives: tuple = ()

    def __bool__(self) -> bool:
        return bool(self.ranges or self.alternatives)

    def draw(self, rng: np.random.Generator) -> dict:
        """One episode's parameters ``{name: value}`` from the env's own generator: the
        ranges in order, then (with alternatives) a uniform number choosing one and its
        ranges. Without alternatives the draws are the ranges' alone."""
        drawn = {n: rng.uniform(lo, hi) for n, (lo, hi) in self.ranges.items()}
        if self.alternatives:
            cumulative = np.cumsum([p for p, _ in self.alternatives])
            chosen = min(
                int(np.searchsorted(cumulative, rng.random(), side="right")),
                len(self.alternatives) - 1,
            )
            ranges = self.alternatives[chosen][1]
            drawn.update({n: rng.uniform(lo, hi) for n, (lo, hi) in ranges.items()})
        return drawn


def _check_range(name: str, rng: Any, base: dict) -> tuple[float, float]:
    """(low, high) of one entry, both valid values of the parameter."""
    if name not in base:
        P.load_parameters(**{name: 0.0})  # raises the loader's "unknown field" error
    if np.isscalar(rng):
        if not (np.isfinite(rng) and 0 <= rng < 1):
            raise ValueError(
                f"domain_randomization['{name}'] = {rng!r} is not allowed: "
                "a relative half-width must be in [0, 1)"
            )
        low, high = base[name] * (1 - rng), base[name] * (1 + rng)
    else:
        low, high = (float(v) for v in rng)
    if not (np.isfinite(low) and np.isfinite(high) and low <= high):
        raise ValueError(
            f"domain_randomization['{name}'] = {rng!r} is not allowed: "
            "must be (low, high) with low <= high, finite"
        )
    for value in (low, high):  # both ends must be valid parameter values
        P.load_parameters(params=base, **{name: value})
    return (min(low, high), max(low, high))


def _check_alternatives(spec, base: dict) -> tuple:
    """((probability, ranges), ...) of the ``one_of`` entry."""
    bad = f"domain_randomization['{ONE_OF}'] = {spec!r} is not allowed: "
    if not isinstance(spec, (list, tuple)) or not spec:
        raise ValueError(bad + "must be a non-empty list of {probability, ranges}")
    out = []
    for alternative in spec:
        if not isinstance(alternative, Mapping) or set(alternative) != {"probability", "ranges"}:
            raise ValueError(bad + "each alternative must have exactly probability and ranges")
        p: Any = alternative["probability"]
        if not (np.isscalar(p) and np.isfinite(p) and 0 <= p <= 1):
            raise ValueError(bad + f"probability {p!r} must be in [0, 1]")
        ranges = {n: _check_range(n, r, base) for n, r in alternative["ranges"].items()}
        out.append((float(p), ranges))
    if abs(sum(p for p, _ in out) - 1.0) > _SUM_TOLERANCE:
        raise ValueError(bad + "the probabilities must sum to 1")
    return tuple(out)


def check_randomization(spec, base: dict, cylinder: str) -> Randomization:
    """The option checked against the plant's parameters ``base``: each range's ends are
    valid values; with alternatives, so are the low and the high ends of all ranges
    together with each alternative's (conflicting effects are refused here, not at an
    episode's start)."""
    if not spec:
        return Randomization({})
    ranges = {n: _check_range(n, r, base) for n, r in spec.items() if n != ONE_OF}
    alternatives = _check_alternatives(spec[ONE_OF], base) if ONE_OF in spec else ()
    for _, extra in alternatives:
        both = {**ranges, **extra}
        for end in (0, 1):
            try:
                P.load_parameters(cylinder, params=base, **{n: r[end] for n, r in both.items()})
            except ValueError as exc:
                raise ValueError(
                    f"domain_randomization = {spec!r} is not allowed: the "
                    f"{('low', 'high')[end]} ends of {sorted(both)} together: {exc}"
                ) from None
    return Randomization(ranges, alternatives)
