"""Scoring of candidate effects: refit on the training data, score on the held-out data.

A candidate's parameters are refitted together with the current model's (:func:`score`);
its score is the relative drop of the mean held-out NRMSE, per held-out recording too,
and the change of an information criterion (BIC with the effective sample size of the
autocorrelated residual). :func:`score_many` runs independent refits in parallel
processes (the numba-compiled kernel is inherited by ``fork``).
"""

from __future__ import annotations

import logging
import math
import multiprocessing
import sys
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor, wait
from dataclasses import dataclass, field

import numpy as np

from . import progress
from .calibrate import FitResult, diagnosis_fit_stops, run_fit
from .candidates import Candidate
from .config import FitParameter, IdentificationConfig
from .holdout import Holdout
from .results import WIDE_INTERVAL

__all__ = [
    "CandidateScore",
    "conflicts",
    "heldout_improvement",
    "acceptance",
    "improvement_is_the_basin",
    "mean_nrmse",
    "refit_with_restart",
    "score",
    "score_many",
]

log = logging.getLogger("pneumatic_env.identification")


def mean_nrmse(d: Mapping[str, float]) -> float:
    """Mean over channels (finite values only)."""
    vals = [v for v in d.values() if v is not None and math.isfinite(v)]
    return float(np.mean(vals)) if vals else math.nan


def heldout_improvement(
    per_recording: Mapping[str, float],
    pooled: float,
    cfg: IdentificationConfig,
    acted_on: set[str] | None = None,
) -> tuple[float, str]:
    """The held-out improvement a candidate is judged by, and how it was taken.

    With at least ``diagnosis.median_from_recordings`` held-out recordings: the median of
    the per-recording relative improvements over the recordings the effect acts on
    (``acted_on``, :meth:`.Holdout.acted_on`: a friction law is judged where the rod
    moves, a load cell's compliance where it is clamped), so that one experiment whose
    held-out part a refit extrapolates badly (a free rod's stick-slip end) cannot veto an
    effect the other experiments show, nor carry one alone, and an experiment that cannot
    show the effect does not dilute it. With fewer: the pooled improvement (mean NRMSE
    over every held-out sample)."""
    values = {k: v for k, v in per_recording.items() if math.isfinite(v)}
    if len(values) >= int(cfg.diagnosis("median_from_recordings")):
        if acted_on is not None and 0 < len(acted_on & set(values)) < len(values):
            mine = [values[k] for k in sorted(acted_on & set(values))]
            return (
                float(np.median(mine)),
                f"median of the {len(mine)} of {len(values)} held-out recordings it acts on",
            )
        return float(np.median(list(values.values()))), (
            f"median of {len(values)} held-out recordings"
        )
    return pooled, "pooled held-out"


def unique(params: Sequence[FitParameter]) -> list[FitParameter]:
    """``params`` without repeated names (first occurrence kept)."""
    first: dict[str, FitParameter] = {}
    for p in params:
        first.setdefault(p.name, p)
    return list(first.values())


@dataclass
class CandidateScore:
    """A candidate refitted on the training data and scored on the held-out data."""

    candidate: Candidate
    round: int
    fit: FitResult | None
    heldout_nrmse: dict[str, float]
    heldout_mean: float
    relative_improvement: float
    delta_ic: float
    plausible: bool
    identified: bool
    accepted: bool
    reasons: list[str] = field(default_factory=list)
    per_recording: dict[str, float] = field(default_factory=dict)  # held-out improvement
    per_recording_nrmse: dict[str, float] = field(default_factory=dict)  # held-out NRMSE
    screening: dict | None = None  # the screening's prediction (see .screening)
    refitted: bool = True  # False: screened out, the score is the screening's prediction
    restarted: bool = False  # refitted again from the screening's step (refit_with_restart)
    notes: list[str] = field(default_factory=list)  # checks it passed, with their figures
    flags: list[str] = field(default_factory=list)  # accepted despite these (see score)

    @property
    def name(self) -> str:
        return self.candidate.name

    def to_dict(self) -> dict:
        params = {}
        for p in self.candidate.parameters:
            if self.fit is None:
                continue
            lo, hi = self.fit.ci[p.name]
            params[p.name] = {
                "value": self.fit.values[p.name],
                "unit": p.unit,
                "ci": [_num(lo), _num(hi)],
                "neutral": None if p.neutral is None else _num(p.neutral),
                "identified": self.fit.identified[p.name],
                "plausible": self.fit.plausible[p.name],
                "flags": self.fit.flags[p.name],
            }
        return {
            "name": self.name,
            "kind": self.candidate.kind,
            "description": self.candidate.description,
            "round": self.round,
            "parameters": params,
            "refitted_base": (
                {
                    p.name: self.fit.values[p.name]
                    for p in self.fit.parameters
                    if p.name not in params
                }
                if self.fit
                else {}
            ),
            "heldout_nrmse": self.heldout_nrmse,
            "heldout_nrmse_mean": self.heldout_mean,
            "score": self.relative_improvement,
            "relative_improvement": self.relative_improvement,
            "delta_ic": self.delta_ic,
            "plausible": self.plausible,
            "identified": self.identified,
            "accepted": self.accepted,
            "reasons": self.reasons,
            "refitted": self.refitted,
            "restarted_from_screening_step": self.restarted,
            "notes": self.notes,
            "flagged": self.flags,
            "heldout_improvement_per_recording": dict(self.per_recording),
            "heldout_nrmse_per_recording": dict(self.per_recording_nrmse),
            "screening": self.screening,
        }


def _num(x: float):
    return float(x) if math.isfinite(x) else None


def _ic(rss: float, n: int, n_eff: float, k: int) -> float:
    """BIC with the effective sample size: ``N_eff ln(RSS/N) + k ln(N_eff)``."""
    return n_eff * math.log(max(rss, 1e-300) / n) + k * math.log(max(n_eff, 2.0))


def conflicts(cand: Candidate, selected: Sequence[Candidate]) -> bool:
    """Whether ``cand`` fixes a parameter a selected effect fits, or fits one it fixes (e.g.
    the transmission line holds the tube's air, so it excludes a tube storage volume), or
    both fit the same parameter (LuGre friction has the Stribeck curve already)."""
    return any(
        set(cand.set) & set(other.parameter_names)
        or set(other.set) & set(cand.parameter_names)
        or set(cand.parameter_names) & set(other.parameter_names)
        for other in selected
    )


def improvement_is_the_basin(
    score: CandidateScore,
    current: FitResult,
    min_rel: float,
    split: Holdout,
    cfg: IdentificationConfig,
) -> bool:
    """True (and ``score`` refused) when the current model at the candidate's fitted values,
    the candidate's effect switched off, is within ``min_rel`` of the candidate's held-out
    error: then the improvement came from where the candidate's refit moved the base
    parameters (for a sliding piston, which stick events it makes), not from the effect.
    Unless the base parameters need the effect: switched off, the training cost rises by
    at least ``min_rel`` of the current model's, to above the current model's, and the
    held-out error does not fall. Then the base parameters are where they are because the
    effect takes up its part of the data (an exhaust muffler that biased the calibrated
    discharge coefficient), and the improvement is the effect's."""
    assert score.fit is not None  # a refitted score
    values = score.fit.all_values()
    fixed = {**current.fixed, **{p.name: values[p.name] for p in current.parameters}}
    problem = split.training_problem(
        [], fixed, f"the fit with {score.name}, the effect off", current.scopes
    )
    try:
        off = run_fit(problem)
    except (ValueError, FloatingPointError):
        return False
    off_nrmse, off_preds = split.heldout_nrmse(off)
    off_mean = mean_nrmse(off_nrmse)
    pooled = (off_mean - score.heldout_mean) / off_mean if off_mean > 0 else 0.0
    with_effect = score.per_recording_nrmse  # from score(): no second simulation
    per = {}
    for name, channels in split.per_recording(off_preds).items():
        ref = mean_nrmse(channels)
        per[name] = (ref - with_effect.get(name, math.nan)) / ref if ref > 0 else math.nan
    rel, how = heldout_improvement(per, pooled, cfg, split.acted_on(score.candidate))
    if rel >= min_rel:
        return False
    carried = (off.cost - score.fit.cost) / current.cost if current.cost > 0 else 0.0
    switched_off = (
        f"with {score.name} switched off at its fitted values the held-out NRMSE is "
        f"{off_mean:.4g} (with it {score.heldout_mean:.4g}"
    )
    # the base needs the effect: without it, the refit's base parameters fit the training
    # data worse than the current model does, and the effect does not raise the held-out error
    if carried >= min_rel and off.cost > current.cost and off_mean >= score.heldout_mean:
        score.notes.append(
            f"{switched_off}), but the training cost rises "
            f"from {score.fit.cost:.4g} to {off.cost:.4g} ({100 * carried:.0f} % of the "
            f"current model's {current.cost:.4g}): the base parameters need the effect"
        )
        return False
    score.accepted = False
    score.reasons.append(
        f"{switched_off}; {how}: {100 * rel:.1f} % better < "
        f"{100 * min_rel:.0f} %) and the training cost {off.cost:.4g} (with it "
        f"{score.fit.cost:.4g}, the current model {current.cost:.4g}; the base needs the "
        "effect only if this rises by the same share, to above the current model's, and "
        "the held-out error does not fall): the improvement is where the refit moved the "
        "base parameters, not the effect"
    )
    return True


def refit_with_restart(
    run: Callable[[Mapping[str, float]], FitResult],
    start: Mapping[str, float],
    step: Mapping[str, float],
    predicted_train: float,
    current_rss: float,
    cfg: IdentificationConfig,
    name: str = "",
) -> tuple[FitResult, bool]:
    """``run(start)``; again from ``start`` updated by the screening's ``step`` when that
    fell short (it lowered the training RSS below ``current_rss`` by less than
    ``screening.restart_shortfall`` of ``predicted_train``, the screening's prediction,
    which is at least ``screening.min_predicted_improvement``). The lower cost wins; the
    flag says whether the second fit ran."""
    fit = run(start)
    shortfall = cfg.number("screening", "restart_shortfall", minimum=0.0)
    worth = cfg.number("screening", "min_predicted_improvement", minimum=0.0)
    gained = (current_rss - fit.rss) / current_rss if current_rss > 0 else 0.0
    step_start = {k: v for k, v in step.items() if math.isfinite(v)}
    if not (step_start and predicted_train >= worth and gained < shortfall * predicted_train):
        return fit, False
    log.info(
        "%s: the refit lowered the training error by %.1f %%, the screening predicted "
        "%.1f %%: refitting from the screening's step",
        name,
        100 * gained,
        100 * predicted_train,
    )
    try:
        again = run({**start, **step_start})
    except (ValueError, FloatingPointError) as exc:  # a start the kernel rejects
        log.info("%s: the refit from the screening's step failed (%s)", name, exc)
        return fit, True
    return (again if again.cost < fit.cost else fit), True


def score(
    cand: Candidate,
    rnd: int,
    current: FitResult,
    current_mean: float,
    refit: Sequence[FitParameter],
    selected: Sequence[Candidate],
    split: Holdout,
    n_res: int,
    n_eff: float,
    min_rel: float,
    min_ic: float,
    nfev: int,
    cfg: IdentificationConfig,
    current_per: Mapping[str, float] | None = None,
    step: Mapping[str, float] | None = None,
    predicted_train: float = math.nan,
) -> CandidateScore:
    """Refit ``cand`` on top of ``current`` (training data) and score it held out.

    ``current_per``: the current model's mean held-out NRMSE per held-out recording; the
    score's ``per_recording`` is the candidate's relative improvement on each. The refit
    starts from the config's warm start, and from the screening's ``step`` as well when
    it falls short of ``predicted_train`` (:func:`refit_with_restart`). The verdict is
    :func:`acceptance`'s."""
    # parameters the candidate adds to the current model (its own and the base parameters
    # it makes observable that the current model did not fit)
    current_free = {p.name for p in current.parameters}
    n_extra = len(cand.parameters) + sum(p.name not in current_free for p in cand.refit_base)
    try:
        fit, restarted = _refit(
            cand, rnd, current, refit, selected, split, nfev, cfg, step, predicted_train
        )
    except _FitFailed as exc:
        return CandidateScore(
            cand,
            rnd,
            None,
            {},
            math.inf,
            -math.inf,
            math.inf,
            False,
            False,
            False,
            [f"fit failed: {exc}"],
        )
    nrmse, preds = split.heldout_nrmse(fit)
    mean = mean_nrmse(nrmse)
    per, per_nrmse = {}, {}
    for name, ch in split.per_recording(preds).items():
        ref = (current_per or {}).get(name, math.nan)
        per_nrmse[name] = mean_nrmse(ch)
        per[name] = (ref - per_nrmse[name]) / ref if ref > 0 else math.nan
    pooled = (current_mean - mean) / current_mean if current_mean > 0 else 0.0
    rel, how = heldout_improvement(per, pooled, cfg, split.acted_on(cand))
    # BIC(candidate) - BIC(current): N_eff ln(RSS_c / RSS_m) + (extra parameters) ln(N_eff)
    delta_ic = _ic(fit.rss, n_res, n_eff, n_extra) - _ic(current.rss, n_res, n_eff, 0)
    plausible, identified, reasons, outside, loose = _parameter_verdict(cand, fit)
    accepted, more, flags = acceptance(
        rel, how, delta_ic, identified, outside, min_rel, min_ic, cfg, loose
    )
    reasons = [] if accepted else reasons + more
    return CandidateScore(
        cand,
        rnd,
        fit,
        nrmse,
        mean,
        rel,
        delta_ic,
        plausible,
        identified and not loose,
        accepted,
        reasons,
        per_recording=per,
        per_recording_nrmse=per_nrmse,
        restarted=restarted,
        flags=flags,
    )


def acceptance(
    rel: float,
    how: str,
    delta_ic: float,
    identified: bool,
    outside: Sequence[str],
    min_rel: float,
    min_ic: float,
    cfg: IdentificationConfig,
    loose: Sequence[str] = (),
) -> tuple[bool, list[str], list[str]]:
    """Whether a refit is accepted, the reasons against and the flags it is accepted with.

    Accepted when the held-out improvement ``rel`` (taken as ``how``) is at least
    ``min_rel``, the BIC change ``delta_ic`` at most ``-min_ic``, the effect's parameters
    are ``identified`` (apart from the ``loose`` ones) and none is ``loose`` or
    ``outside`` its plausible range (each with its value). A strong effect is still that
    effect: with an improvement of at least ``diagnosis.min_improvement_when_implausible``
    it is accepted flagged with its ``loose`` parameters (a confidence interval wider than
    the plausible range, the effect's off value outside it: the data show the effect, not
    its strength) and those ``outside``. A weaker one is refused."""
    min_strong = cfg.diagnosis("min_improvement_when_implausible")
    strong = rel >= min_strong
    reasons = []
    if rel < min_rel:
        reasons.append(f"held-out improvement ({how}) {100 * rel:.1f} % < {100 * min_rel:.0f} %")
    if delta_ic > -min_ic:
        reasons.append(f"BIC change {delta_ic:.1f} > -{min_ic:g}")
    passes = rel >= min_rel and delta_ic <= -min_ic and identified
    waived = [f"strength not pinned down: {w}" for w in loose]
    waived += [f"fitted value outside the plausible range: {o}" for o in outside]
    if passes and (strong or not waived):  # a strong effect is still that effect: flagged
        return True, reasons, waived
    if identified and loose and not strong and rel >= min_rel:
        reasons.append(
            _needs_strong("a confidence interval wider than the plausible range", rel, min_strong)
        )
    reasons += outside
    if outside and rel >= min_rel:
        reasons.append(_needs_strong("a value outside the plausible range", rel, min_strong))
    return False, reasons, []


def _needs_strong(what: str, rel: float, min_strong: float) -> str:
    return (
        f"{what} needs a held-out improvement of at least {100 * min_strong:.0f} % "
        f"(diagnosis.min_improvement_when_implausible), this one is {100 * rel:.1f} %"
    )


def _refit(
    cand: Candidate,
    rnd: int,
    current: FitResult,
    refit: Sequence[FitParameter],
    selected: Sequence[Candidate],
    split: Holdout,
    nfev: int,
    cfg: IdentificationConfig,
    step: Mapping[str, float] | None,
    predicted_train: float,
) -> tuple[FitResult, bool]:
    """``cand``'s parameters refitted with ``current``'s on the training data, and whether
    the refit was repeated from the screening's step (:func:`refit_with_restart`)."""
    free = unique(
        list(refit)
        + [p for c in selected for p in (*c.refit_base, *c.parameters)]
        + list(cand.refit_base)
        + list(cand.parameters)
    )
    fixed = {k: v for k, v in current.all_values().items() if k not in {p.name for p in free}}
    fixed.update(cand.scoped_set())
    values = current.all_values()
    start = {p.name: float(values[p.name]) for p in free if p.name in values}
    problem = split.training_problem(
        free, fixed, f"{cand.name} (round {rnd})", {**current.scopes, **cand.scopes()}
    )
    # a candidate that changes the piston's friction law moves the static friction's
    # stick-event basins: it gets the restarts the base calibration had; the others
    # start from the calibrated base's basin
    stops = diagnosis_fit_stops(cfg)

    def run(u: Mapping[str, float]) -> FitResult:
        return run_fit(
            problem,
            start=u,
            max_nfev=nfev,
            friction_restarts=cand.requires_motion,
            **stops,
            basin_search=cand.parameter_names if cand.requires_motion else (),
        )

    try:
        return refit_with_restart(
            run, start, step or {}, predicted_train, current.rss, cfg, cand.name
        )
    except (ValueError, FloatingPointError) as exc:  # e.g. a parameter set the kernel rejects
        raise _FitFailed(str(exc)) from exc


class _FitFailed(Exception):
    """A candidate's refit failed (its message says why)."""


def _parameter_verdict(
    cand: Candidate, fit: FitResult
) -> tuple[bool, bool, list[str], list[str], list[str]]:
    """Whether ``cand``'s fitted parameters are plausible and identified (confidence
    interval excluding the neutral value) apart from the ``loose`` ones, why not
    identified, each parameter outside its plausible range with its value, and each one
    whose only shortfall is a confidence interval wider than the plausible range
    (``loose``: sensitive, not collinear, the neutral value outside its interval; its
    strength is not pinned down)."""
    plausible = all(fit.plausible[p.name] for p in cand.parameters)
    identified = True
    reasons, outside, loose = [], [], []
    for p in cand.parameters:
        lo, hi = fit.ci[p.name]
        off_inside = p.neutral is not None and lo <= p.neutral <= hi
        if not fit.identified[p.name]:
            reasons.append(f"{p.name} not identified ({'; '.join(fit.flags[p.name])})")
            if fit.flags[p.name] != [WIDE_INTERVAL] or off_inside:
                identified = False
            else:
                loose.append(
                    f"{p.name} = {fit.values[p.name]:.4g} {p.unit}, confidence interval "
                    f"[{lo:.3g}, {hi:.3g}] wider than the plausible range "
                    f"[{p.plausible_min:g}, {p.plausible_max:g}]"
                )
        elif off_inside:
            identified = False
            reasons.append(
                f"{p.name}: its confidence interval [{lo:.3g}, {hi:.3g}] contains the "
                f"neutral value {p.neutral:g} (effect off)"
            )
        if not fit.plausible[p.name]:
            outside.append(
                f"{p.name} = {fit.values[p.name]:.4g} {p.unit} is outside the plausible "
                f"range [{p.plausible_min:g}, {p.plausible_max:g}]"
            )
    return plausible, identified, reasons, outside, loose


def score_many(jobs_args: Sequence[tuple], jobs: int, poll_s: float = 1.0) -> list[CandidateScore]:
    """:func:`score` of every argument tuple, in up to ``jobs`` processes (``fork``: the
    children inherit the compiled kernel) when there are two or more; in order. The
    workers' simulated work reaches :mod:`.progress` through a shared counter, read every
    ``poll_s`` seconds."""
    jobs_args = list(jobs_args)
    if jobs <= 1 or len(jobs_args) < 2 or sys.platform == "win32":
        return [score(*args) for args in jobs_args]
    ctx = multiprocessing.get_context("fork")
    counter = ctx.Value("d", 0.0)
    shown = 0.0
    with ProcessPoolExecutor(
        max_workers=min(jobs, len(jobs_args)),
        mp_context=ctx,
        initializer=progress.report_to,
        initargs=(counter,),
    ) as pool:
        futures = [pool.submit(score, *args) for args in jobs_args]
        pending = set(futures)
        while pending:
            _, pending = wait(pending, timeout=poll_s)
            with counter.get_lock():
                now = counter.value
            progress.advance(now - shown)
            shown = now
        return [f.result() for f in futures]
