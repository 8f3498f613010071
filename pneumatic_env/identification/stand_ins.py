"""After the greedy rounds: drop an effect a later one made redundant (a stand-in).

The rounds add effects one at a time and never take one back. On a rig with several
effects, round 1 may accept a candidate that only stands in for an effect the base model
cannot yet take up in a plausible form: on a 2 m rig with wall heat transfer and spool
friction, round 1 accepted a larger exhaust discharge (27 % better on held-out data, the
heat-transfer refit implausible then), and round 3 heat transfer itself (67 % better).
With heat transfer in the model, the exhaust discharge may explain nothing more.

:func:`drop_stand_ins` is backward elimination, the second half of stepwise selection:
with two or more effects selected, the model is refitted without each effect selected
before the last round (base parameters and the other effects free, from the final fit,
with a candidate refit's budget ``fit.diagnosis_max_nfev``),
and the effect whose removal costs the least held-out accuracy is dropped when the
full model is less than ``diagnosis.min_relative_improvement`` better than the model
without it, judged as a candidate is (:func:`.scoring.heldout_improvement`, on the
held-out recordings it acts on). Repeated until every effect left earns its place. The
last round's effect was accepted against all the others already and is not retried.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass

from . import progress
from .calibrate import FitResult, run_fit
from .candidates import Candidate
from .scoring import heldout_improvement, mean_nrmse, unique

__all__ = ["Removal", "drop_stand_ins", "removal_trial"]

log = logging.getLogger("pneumatic_env.identification")


@dataclass
class Removal:
    """The model refitted without one selected effect, and what the effect is worth."""

    name: str
    fit: FitResult
    heldout_mean: float  # mean held-out NRMSE without the effect
    per_recording: dict[str, float]  # mean held-out NRMSE per held-out recording, without
    improvement: float  # the full model's held-out improvement over this one
    how: str  # how the improvement was taken (heldout_improvement)

    def to_dict(self, dropped: bool) -> dict:
        return {
            "name": self.name,
            "heldout_nrmse_mean_without": self.heldout_mean,
            "improvement_with": self.improvement,
            "judged_by": self.how,
            "dropped": dropped,
        }


def removal_trial(ctx, state, effect: Candidate) -> Removal:
    """The model of ``state`` (a ``selection.Selection``) without ``effect``: the base
    parameters (``ctx.refit``) and the other selected effects refitted from the final fit,
    everything else as the base fit has it (the effect off)."""
    rest = [c for c in state.selected if c is not effect]
    free = unique(list(ctx.refit) + [p for c in rest for p in (*c.refit_base, *c.parameters)])
    names = {p.name for p in free}
    fixed = {k: v for k, v in ctx.base.all_values().items() if k not in names}
    scopes = dict(ctx.base.scopes)
    for c in rest:
        fixed.update(c.scoped_set())
        scopes.update(c.scopes())
    values = state.current.all_values()
    start = {p.name: float(values[p.name]) for p in free if p.name in values}
    label = f"model without {effect.name}: " + (", ".join(c.name for c in rest) or "base")
    problem = ctx.split.training_problem(free, fixed, label, scopes)
    fit = run_fit(
        problem,
        start=start,
        max_nfev=ctx.settings.nfev,  # a candidate refit's budget: it starts converged
        **ctx.settings.fit_stops,
        friction_restarts=any(c.requires_motion for c in rest),
    )
    nrmse, preds = ctx.split.heldout_nrmse(fit)
    without = mean_nrmse(nrmse)
    per_without = {k: mean_nrmse(v) for k, v in ctx.split.per_recording(preds).items()}
    per = {
        k: (ref - state.current_per.get(k, math.nan)) / ref if ref > 0 else math.nan
        for k, ref in per_without.items()
    }
    pooled = (without - state.current_mean) / without if without > 0 else 0.0
    rel, how = heldout_improvement(per, pooled, ctx.cfg, ctx.split.acted_on(effect))
    return Removal(effect.name, fit, without, per_without, rel, how)


def drop_stand_ins(ctx, state) -> list[dict]:
    """Backward elimination over ``state.selected`` (module docstring); drops the stand-ins
    from ``state`` (its model, the selected list and their confidence entries, the
    accepted score marked refused with the reason) and returns every removal tried."""
    tried: list[dict] = []
    t0 = time.monotonic()
    while len(state.selected) >= 2:
        earlier = state.selected[:-1]
        what = f"checking {len(earlier)} earlier effect(s) for stand-ins"
        progress.stage(what, len(earlier) * ctx.plan.refit)
        trials = [removal_trial(ctx, state, c) for c in earlier]
        weakest = min(trials, key=lambda t: t.improvement)
        worth = weakest.improvement >= ctx.settings.min_rel
        tried += [t.to_dict(dropped=t is weakest and not worth) for t in trials]
        if worth:
            break
        _drop(ctx, state, weakest)
    ctx.timings["stand_in_check"] = time.monotonic() - t0
    return tried


def _drop(ctx, state, removal: Removal) -> None:
    """Take ``removal``'s effect out of ``state``: its model becomes the current one."""
    index = next(i for i, c in enumerate(state.selected) if c.name == removal.name)
    later = ", ".join(c.name for c in state.selected[index + 1 :])
    state.selected.pop(index)
    state.confidence.pop(index)
    state.current = removal.fit
    state.current_mean = removal.heldout_mean
    state.current_per = dict(removal.per_recording)
    reason = (
        f"dropped after the rounds: with {later} in the model it is "
        f"{100 * removal.improvement:.1f} % better on held-out data "
        f"({removal.how}) < {100 * ctx.settings.min_rel:.0f} %: a stand-in"
    )
    for score in state.scores:
        if score.name == removal.name and score.accepted:
            score.accepted = False
            score.reasons.append(reason)
    log.info("diagnosis: %s %s", removal.name, reason)
