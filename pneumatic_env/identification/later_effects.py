"""When is a second (or later) effect really there, and not the first one's form?

An effect the data show is rarely exactly the candidate's form: a rig's heat transfer or
supply line has its own law. Fitted in the candidate's form, the first effect leaves a
structured residual that varies between experiments, and any second candidate that bends
the model the right way explains part of it. Two checks keep such a second effect out:

1. :func:`second_effect_support`: it must lower the held-out error of every held-out
   recording it can act on (every experiment type that can show it) by
   ``diagnosis.min_relative_improvement`` over the model with the effects before it,
   and raise none. A first effect is judged by the median over the recordings; a later
   one carries the burden of a second explanation, the first effect's form error, which
   shows on some experiments and not on others. A recording whose error the refit
   changes by less than ``diagnosis.refit_noise_band`` either way (what refits that add
   nothing do) did not show the effect: it neither supports nor refuses it.
2. :func:`freer_form_check`: it must also beat a freer form of the effects already
   selected: their plant parameters refitted per experiment type (rod clamped, on a
   spring, free; a value per rod mode of the training data). A form error of the first
   effect shows as parameters that differ between experiments, which the freer form
   takes up; a second effect the rig really has does not vary with the experiment, so
   the freer form cannot take it up. The second effect must lower the held-out error of
   every recording it acts on by the same threshold below the freer form too.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from .calibrate import FitResult, diagnosis_fit_stops, run_fit
from .candidates import Candidate
from .config import FitParameter, IdentificationConfig
from .holdout import Holdout
from .scoring import CandidateScore, mean_nrmse, unique

__all__ = [
    "FreerForm",
    "fit_freer_form",
    "freer_form_check",
    "second_effect_support",
    "shown",
]

log = logging.getLogger("pneumatic_env.identification")


def _acting(per: Mapping[str, float], acts_on: set[str]) -> list[str]:
    """The recordings of ``per`` among those ``acts_on`` (all of them when it names none)."""
    return [k for k in per if k in acts_on] or list(per)


def _figures(per: Mapping[str, float]) -> str:
    return ", ".join(f"{k} {100 * v:+.1f} %" for k, v in per.items())


def shown(per: Mapping[str, float], acts_on: set[str], band: float) -> list[str]:
    """The recordings of ``per`` (held-out improvements) it acts on (:func:`_acting`) whose
    error changed by ``band`` or more either way: those that showed the effect or not."""
    return [k for k in _acting(per, acts_on) if not abs(per[k]) < band]


def second_effect_support(
    sc: CandidateScore, min_rel: float, acts_on: set[str], band: float = 0.0
) -> None:
    """Refuse a later-round effect (``sc.accepted`` False, with the reason) unless it lowers
    the held-out error of every held-out recording it can act on (``acts_on``,
    :meth:`.Holdout.acted_on`) by ``min_rel`` over the model with the effects before it,
    and raises that of none; a recording whose error changed by less than ``band``
    either way (``diagnosis.refit_noise_band``) counts for neither, and one must
    remain."""
    per = {k: v for k, v in sc.per_recording.items() if math.isfinite(v)}
    showing = shown(per, acts_on, band)
    short = [k for k in showing if not per[k] >= min_rel]
    worse = [k for k, v in per.items() if v < -band]
    if showing and not short and not worse:
        return
    sc.accepted = False
    if short or not showing:
        unshown = "" if showing else f"; none changed by {100 * band:.0f} % or more"
        sc.reasons.append(
            f"not {100 * min_rel:.0f} % better on every held-out recording it acts on "
            f"than the effects already selected ({_figures(per)}{unshown})"
        )
    if worse:
        sc.reasons.append(
            "held-out recording(s) worse with it: "
            + ", ".join(f"{k} {100 * per[k]:+.1f} %" for k in worse)
        )


@dataclass
class FreerForm:
    """The selected effects refitted with their plant parameters per rod mode."""

    fit: FitResult
    per_recording_nrmse: dict[str, float]  # mean held-out NRMSE per held-out recording
    parameters: list[str]  # the per-mode copies, ``name@mode``

    def to_dict(self) -> dict:
        return {
            "parameters": {k: self.fit.values[k] for k in self.parameters},
            "heldout_nrmse_per_recording": dict(self.per_recording_nrmse),
        }


def per_mode_parameters(selected: Sequence[Candidate], modes: Sequence[str]) -> list[FitParameter]:
    """A copy ``name@mode`` of each selected plant effect's parameter for every rod mode
    in ``modes`` it acts in (its ``rod_modes``; a friction law not on a clamped rod);
    none where it acts in fewer than two of them (no freer form to fit)."""
    out: list[FitParameter] = []
    for cand in selected:
        if cand.kind != "plant":
            continue
        acts = [
            m
            for m in modes
            if (not cand.rod_modes or m in cand.rod_modes)
            and not (cand.requires_motion and m == "fixed")
        ]
        if len(acts) < 2:
            continue
        for p in cand.parameters:
            out.extend(dataclasses.replace(p, name=f"{p.name}@{m}") for m in acts)
    return out


def fit_freer_form(
    selected: Sequence[Candidate],
    current: FitResult,
    refit: Sequence[FitParameter],
    split: Holdout,
    nfev: int,
    cfg: IdentificationConfig,
) -> FreerForm | None:
    """Refit ``current`` (base and ``selected``) on the training data with the selected
    effects' plant parameters free per rod mode (:func:`per_mode_parameters`), from the
    current values; None when there is no freer form or its fit fails."""
    modes = sorted({ds.rod_mode for ds in split.train})
    copies = per_mode_parameters(selected, modes)
    if not copies:
        return None
    values = current.all_values()
    shared = [p for c in selected for p in c.refit_base]
    free = unique(list(refit) + shared + copies)
    fixed = {k: v for k, v in values.items() if k not in {p.name for p in free}}
    start = {
        p.name: float(values[p.name]) for p in unique(list(refit) + shared) if p.name in values
    }
    start.update((p.name, float(values[p.name.partition("@")[0]])) for p in copies)
    problem = split.training_problem(
        free, fixed, "selected effects per experiment type", current.scopes
    )
    try:
        fit = run_fit(
            problem,
            start=start,
            max_nfev=nfev,
            friction_restarts=any(c.requires_motion for c in selected),
            **diagnosis_fit_stops(cfg),
        )
    except (ValueError, FloatingPointError) as exc:  # a start the kernel rejects
        log.info("freer form of %s failed: %s", ", ".join(c.name for c in selected), exc)
        return None
    _, preds = split.heldout_nrmse(fit)
    per = {k: mean_nrmse(v) for k, v in split.per_recording(preds).items()}
    return FreerForm(fit, per, [p.name for p in copies])


def freer_form_check(
    sc: CandidateScore,
    freer: FreerForm,
    current_per: Mapping[str, float],
    min_rel: float,
    acts_on: set[str],
    band: float = 0.0,
) -> float:
    """Refuse ``sc`` (``accepted`` False, with the reason) unless it lowers the held-out
    error of every held-out recording it acts on by ``min_rel`` below the freer form of
    the effects before it, each against the lower of the freer form's and the current
    model's error (a freer form that extrapolates worse sets no bar); the recordings
    that did not show it (:func:`shown`, ``band``) are left out. Returns the smallest of
    those improvements (the margin)."""
    per = {}
    for name, nrmse in sc.per_recording_nrmse.items():
        ref = min(freer.per_recording_nrmse.get(name, math.inf), current_per.get(name, math.inf))
        if math.isfinite(ref) and ref > 0 and math.isfinite(nrmse):
            per[name] = (ref - nrmse) / ref
    showing = shown(sc.per_recording, acts_on, band)
    margin = min((per[k] for k in showing if k in per), default=-math.inf)
    figures = _figures(per)
    if margin >= min_rel:
        sc.notes.append(
            "beats the freer form of the effects before it (their parameters per "
            f"experiment type) on every held-out recording it acts on ({figures})"
        )
        return margin
    sc.accepted = False
    sc.reasons.append(
        f"not {100 * min_rel:.0f} % better on every held-out recording it acts on than the "
        f"effects before it with their parameters per experiment type ({figures}): the "
        "improvement may be the first effect's form varying between experiments"
    )
    return margin
