"""The shipped learned controllers as candidates for a rig (``train --rig``, issue 35).

A shipped actor (``agents/policies``, trained on the package's model of its variant, some
over randomised plants) may track a fitted rig better than the residual the short
training on that rig gives. So ``train --rig`` scores the shipped actors of the rig's
variant on the fitted rig beside the classical controllers
(``rig_base.shipped_candidates``), and writes the best of them as ``OUT/controller.npz``
if it cuts the trained controller's error there by ``rig_base.min_shipped_gain`` within
the chatter and air limits (``best_shipped``, ``adopt_shipped``); the trained one stays in
``OUT/training/controller_trained.npz``. The margin is wide because the fitted rig is not
the rig: on the cross-piston leak + coil lag evaluation rig the shipped ``ppo_adaptive``
beat the trained controller by 2.8 % on the fitted rig and lost to it by a third on the
rig's plant.
"""

from __future__ import annotations

import math
import shutil
from pathlib import Path

from .base import ControllerContext
from .learned import LearnedActor, shipped_policies, shipped_policy_path, write_self_contained
from .registry import classical_gains

__all__ = ["SHIPPED_SUFFIX", "shipped_for", "shipped_base", "best_shipped", "adopt_shipped"]

#: the suffix of a shipped actor's row in ``train --rig``'s figures
SHIPPED_SUFFIX = " (shipped)"


def shipped_for(names: list[str], variant: str) -> list[str]:
    """Those of the shipped policies ``names`` with an actor for ``variant`` (a generalist's
    one actor serves all); a name that is not a shipped policy is an error."""
    known = shipped_policies()
    unknown = [n for n in names if n not in known]
    if unknown:
        raise ValueError(
            f"rig_base.shipped_candidates = {unknown} is not allowed: the shipped policies "
            f"are {sorted(known)}"
        )
    out = []
    for name in names:
        try:
            shipped_policy_path(name, variant)
        except ValueError:
            continue  # no actor for this variant
        out.append(name)
    return out


def shipped_base(name: str, variant: str) -> tuple[str, dict] | None:
    """(kind, gains) of the base a shipped residual actor runs on the variant (the gains
    its residual config names, else the benchmark's of ``variant``); None for a pure one."""
    residual = LearnedActor(shipped_policy_path(name, variant)).residual_config
    if residual is None:
        return None
    kind, gains = residual.base, residual.gains
    return kind, dict(gains) if gains is not None else classical_gains(kind, variant)


def best_shipped(
    trained: dict,
    shipped: list[dict],
    chatter_limit_a: float,
    min_gain: float = 0.0,
    air_limit_mg: float = math.inf,
) -> dict | None:
    """The row of ``shipped`` (figures on the fitted rig) with the lowest mean RMS error,
    if it cuts ``trained``'s by more than the fraction ``min_gain``
    (``rig_base.min_shipped_gain``) and its chatter and air are within ``chatter_limit_a``
    and ``air_limit_mg``; else None."""
    quiet = [
        f for f in shipped if f["chatter_rms_a"] <= chatter_limit_a and f["air_mg"] <= air_limit_mg
    ]
    best = min(quiet, key=lambda f: f["rms_error_pct"], default=None)
    if best is None or best["rms_error_pct"] >= trained["rms_error_pct"] * (1.0 - min_gain):
        return None
    return best


def adopt_shipped(name: str, variant: str, context: ControllerContext, path: Path) -> Path:
    """Write the shipped actor ``name`` of ``variant`` self-contained (the fitted rig's
    model ``context``, its base and gains) to ``path``, the trained controller there moved
    to ``training/controller_trained.npz`` beside it. Returns the moved file."""
    kept = path.parent / "training" / "controller_trained.npz"
    kept.parent.mkdir(parents=True, exist_ok=True)
    shutil.move(path, kept)
    write_self_contained(
        shipped_policy_path(name, variant),
        path,
        context,
        shipped_base(name, variant),
        name=name,
        source=f"shipped {name}, chosen by train --rig on the fitted rig",
    )
    return kept
