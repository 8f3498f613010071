"""The greedy selection of :func:`.diagnose.diagnose` (its steps 3 to 5): each round
screens the eligible candidates, refits the most promising few, accepts the best that
passes the rules, and re-converges the model with it; then round 1's winner, its
runner-up and an experiment to separate them."""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field

from . import progress
from .calibrate import Dataset, FitResult, run_fit
from .candidates import Candidate, candidate_table, separating_experiment
from .config import ConfigError, IdentificationConfig
from .drift import base_drifts, suggested_effects
from .holdout import Holdout
from .later_effects import fit_freer_form, freer_form_check, second_effect_support
from .scoring import (
    CandidateScore,
    conflicts,
    improvement_is_the_basin,
    mean_nrmse,
    score_many,
    unique,
)
from .screening import screen_candidates

__all__ = [
    "RoundContext",
    "Selection",
    "Settings",
    "WorkPlan",
    "best_first",
    "eligible",
    "screening_columns",
    "selection_round",
    "winner_and_runner_up",
    "work_after_refits",
]

log = logging.getLogger("pneumatic_env.identification")


@dataclass(frozen=True)
class Settings:
    """The diagnosis's thresholds and budgets, read once from the config."""

    min_rel: float  # least relative held-out improvement to accept an effect
    min_ic: float  # least BIC drop to accept an effect
    max_effects: int
    nfev: int  # function evaluations per refit
    top_k: int  # refits per round (the screening's best)
    min_pred: float
    jobs: int  # processes for the refits
    fit_stops: dict  # run_fit keywords of the base fit and of each selected model's polish
    thresholds: dict  # as reported in ``diagnosis.json``


@dataclass(frozen=True)
class WorkPlan:
    """The work ahead, in simulated samples x substeps x parameter columns (for progress
    and the size notice)."""

    base: float  # the base fit
    round: float  # round 1: its screening and its refits
    refit: float  # one refit
    column: float = 0.0  # one simulation of all the data (a screening column)
    after_first: float = 0.0  # what round 1 would start by accepting an effect

    def screening(self, pool: Sequence[Candidate], n_refit: int) -> float:
        """The work of screening ``pool`` (:func:`screening_columns`)."""
        return self.column * screening_columns(pool, n_refit)


def screening_columns(pool: Sequence[Candidate], n_refit: int) -> int:
    """Simulations of all the data a screening of ``pool`` runs: the current model and
    its ``n_refit`` columns, and each plant candidate's start and columns."""
    return n_refit + 1 + sum(1 + len(c.parameters) for c in pool if c.kind == "plant")


@dataclass
class RoundContext:
    """What every selection round reads: the data, the config and the base model."""

    cfg: IdentificationConfig
    settings: Settings
    datasets: Sequence[Dataset]
    split: Holdout
    base_params: Sequence
    refit: Sequence  # base parameters refitted with each candidate
    plan: WorkPlan
    quick: bool
    base: FitResult  # the calibrated base model (its residual count and effective samples)
    timings: dict  # seconds per stage, filled in by the rounds
    # called after each screening, before its refits (diagnose: finish a base fit that
    # was stopped early for the first screening)
    after_screening: Callable[[RoundContext, Selection, Sequence], None] | None = None
    # the work planned after the current round's screening (its refits, and what an
    # accepted effect would start: :func:`work_after_refits`), for the progress display
    work_after_screening: float = 0.0
    # the kernel's lane-substeps per second on one core (.stage_costs), for the report
    kernel_substeps_per_s: float = 0.0

    @property
    def moving(self) -> bool:
        """A piston moves in some recording."""
        return any(ds.moving for ds in self.datasets)


@dataclass
class Selection:
    """The greedy selection so far: the current model and what each round found."""

    current: FitResult
    current_mean: float
    current_per: dict
    selected: list = field(default_factory=list)  # Candidate, in the order accepted
    scores: list = field(default_factory=list)
    screening: list = field(default_factory=list)
    confidence: list = field(default_factory=list)
    freer_forms: list = field(default_factory=list)
    over_freer: dict = field(default_factory=dict)
    stand_ins: list = field(default_factory=list)  # the removals tried (.stand_ins)


def eligible(pool: Sequence[Candidate], selected: Sequence[Candidate]) -> list[Candidate]:
    """The candidates of ``pool`` a round screens: not selected, not in conflict with one."""
    return [c for c in pool if c not in selected and not conflicts(c, selected)]


def work_after_refits(
    plan: WorkPlan,
    settings: Settings,
    n_refit: int,
    candidates: Sequence[Candidate],
    rnd: int,
    quick: bool,
) -> float:
    """The work round ``rnd``'s refits would start by accepting an effect: re-converging
    the model with it, then the next round's screening (of one candidate fewer, with
    ``n_refit`` base columns) and refits. Counted before it is known whether it will run,
    so the display never nears 100 % while another round may follow; a round that
    accepts nothing ends the run sooner than shown."""
    rest = candidates[1:]
    if quick or rnd >= settings.max_effects or not rest:
        return 0.0
    next_refits = min(settings.top_k, len(rest)) + 1  # + its freer-form refit
    return plan.refit * (1 + next_refits) + plan.screening(rest, n_refit)


def selection_round(
    ctx: RoundContext, state: Selection, pool: Sequence[Candidate], rnd: int
) -> bool:
    """One greedy round: screen, refit the best few, accept the best; False when done."""
    candidates = eligible(pool, state.selected)
    if not candidates:
        return False
    t_round = time.monotonic()
    n_refits = 0 if ctx.quick else min(ctx.settings.top_k, len(candidates))
    after = work_after_refits(ctx.plan, ctx.settings, len(ctx.refit), candidates, rnd, ctx.quick)
    ctx.work_after_screening = n_refits * ctx.plan.refit + after
    progress.stage(
        f"screening {len(candidates)} candidates (round {rnd})",
        ctx.plan.screening(candidates, len(ctx.refit)),
        later=ctx.work_after_screening,
    )
    screens = screen_candidates(
        candidates,
        state.current,
        list(state.current.parameters),
        ctx.datasets,
        ctx.split.train,
        ctx.split.train_n,
        ctx.split.held,
        ctx.split.held_masks,
        ctx.cfg,
        training_only=ctx.quick,
    )
    state.screening.append({"round": rnd, "ranking": [s.to_dict() for s in screens]})
    ctx.timings[f"screening_round_{rnd}"] = time.monotonic() - t_round
    if ctx.after_screening is not None:
        ctx.after_screening(ctx, state, screens)
    round_scores = _refit_round(ctx, state, screens, rnd, after)
    state.scores.extend(round_scores)
    accepted = _accepted(ctx, state, round_scores, rnd, after)
    if not accepted:
        return False
    _adopt(ctx, state, accepted[0], round_scores, max(after - ctx.plan.refit, 0.0))
    return True


def _refit_round(
    ctx: RoundContext, state: Selection, screens: Sequence, rnd: int, later: float
) -> list:
    """Refit the screening's best few (in parallel); the rest keep the screening's score."""
    top_k = ctx.settings.top_k
    top = [] if ctx.quick else [*screens[:top_k], *drift_picks(ctx, state, screens[top_k:])]
    if not ctx.quick:
        top += form_picks(ctx.cfg, screens[top_k:], top)
        top += rival_picks(ctx.cfg, screens[top_k:], top)
    if top:  # --quick refits none: no stage to show
        progress.stage(
            f"refitting {len(top)} candidates (round {rnd})", len(top) * ctx.plan.refit, later
        )
    t_refit = time.monotonic()
    # a refit starts from the config's warm start (starting from the screening's step
    # alone was tried: it left a heat-transfer refit at its bound, 10 W/K, and a coil
    # lag's shape unidentified, where the warm start found both); from the step as well
    # only when the first refit falls short of the screening's prediction
    s_ = ctx.settings
    args = [
        (
            s.candidate,
            rnd,
            state.current,
            state.current_mean,
            ctx.refit,
            state.selected,
            ctx.split,
            ctx.base.n_residuals,
            ctx.base.n_eff,
            s_.min_rel,
            s_.min_ic,
            s_.nfev,
            ctx.cfg,
            state.current_per,
            s.values,
            s.predicted_train,
        )
        for s in top
    ]
    round_scores = score_many(args, s_.jobs)
    for sc, s in zip(round_scores, top):
        sc.screening = s.to_dict()
    for s in screens:
        if all(s is not t for t in top):
            round_scores.append(_screened_only(s, rnd, ctx.quick, top_k))
    ctx.timings[f"refits_round_{rnd}"] = time.monotonic() - t_refit
    return round_scores


def drift_picks(ctx: RoundContext, state: Selection, rest: Sequence) -> list:
    """The screens of ``rest`` (below the screening's top) whose candidate the current
    fit's implausible base parameters point at (:func:`.drift.base_drifts`), the farthest
    drift's first, at most ``screening.drift_refits``: refitted beside the top."""
    n_max = int(ctx.cfg.number("screening", "drift_refits", minimum=0))
    suggested = suggested_effects(base_drifts(state.current, ctx.datasets, ctx.cfg))
    by_name = {s.name: s for s in rest}
    picks = [by_name[name] for name in suggested if name in by_name][:n_max]
    for s in picks:
        log.info("%s: refitted too, as the base fit's drifts point at it", s.name)
    return picks


def form_picks(cfg: IdentificationConfig, rest: Sequence, taken: Sequence) -> list:
    """The screens of ``rest`` (below the screening's top) whose candidate
    ``screening.always_refit`` names and ``taken`` does not hold: effects that change the
    model's form, which a one-step prediction misjudges, refitted whatever their rank."""
    names = cfg.names("screening", "always_refit")
    known = candidate_table(cfg)
    unknown = [n for n in names if n not in known]
    if unknown:
        raise ConfigError(
            f"{cfg.path}: screening.always_refit names {unknown!r}, which are not "
            f"candidates: allowed are {sorted(known)}"
        )
    picks = [s for s in rest if s.name in names and all(s is not t for t in taken)]
    for s in picks:
        log.info("%s: refitted too, whatever its screening (screening.always_refit)", s.name)
    return picks


def rival_picks(cfg: IdentificationConfig, rest: Sequence, taken: Sequence) -> list:
    """The screens of ``rest`` (below the screening's top) that are the rival of a refitted
    one in a separating experiment's pair (``separating_experiments``: effects the usual
    data confuse) and whose predicted BIC drop is at least ``screening.rival_refit_ratio``
    of that one's: the screening's one-step prediction cannot tell such a pair apart,
    the refits' held-out errors can (a cross-piston leak 4th at -42 behind the valve's
    null leak at -51, then refitted: held out 0.0097 against 0.0100)."""
    ratio = cfg.number("screening", "rival_refit_ratio", minimum=0.0, maximum=1.0)
    min_ic = cfg.diagnosis("min_ic_drop")
    rivals = {pair for pair, _ in cfg.separating_experiments()}
    picks = []
    for s in rest:
        if any(s is t for t in taken):  # a drift or form pick already
            continue
        for t in taken:
            pair = frozenset((s.name, t.name))
            drop = -t.predicted_delta_ic
            if pair in rivals and drop >= min_ic and -s.predicted_delta_ic >= ratio * drop:
                log.info("%s: refitted too, close to its rival %s in the screening", s.name, t.name)
                picks.append(s)
                break
    return picks


def _screened_only(s, rnd: int, quick: bool, top_k: int) -> CandidateScore:
    """The score of a candidate that was screened but not refitted (``s``: its screening)."""
    why = (
        "quick mode: screening only"
        if quick
        else f"not refitted: below the screening's top {top_k} (predicted BIC "
        f"change {s.predicted_delta_ic:.1f}, training error "
        f"{100 * s.predicted_train:.1f} % lower)"
    )
    return CandidateScore(
        s.candidate,
        rnd,
        None,
        {},
        math.nan,
        s.predicted_heldout,
        math.nan,
        False,
        False,
        False,
        [why],
        per_recording=dict(s.per_recording),
        screening=s.to_dict(),
        refitted=False,
    )


def _accepted(
    ctx: RoundContext, state: Selection, round_scores: Sequence, rnd: int, later: float
) -> list:
    """The round's accepted scores, best first (:func:`best_first`), after the basin and
    later-effect checks (``later``: the work planned after them, for the progress display)."""
    min_rel, split = ctx.settings.min_rel, ctx.split
    accepted = best_first(s for s in round_scores if s.accepted)
    if ctx.moving:  # stick-event basins: the effect itself must make the improvement
        for sc in accepted:
            if not improvement_is_the_basin(sc, state.current, min_rel, split, ctx.cfg):
                break
        accepted = [s for s in accepted if s.accepted]
    if rnd > 1:  # supported on held-out data the effects before did not explain
        band = ctx.cfg.number("diagnosis", "refit_noise_band", minimum=0.0)
        for sc in accepted:
            second_effect_support(sc, min_rel, split.acted_on(sc.candidate), band)
        accepted = [s for s in accepted if s.accepted]
        if accepted:  # ... and not the effects before in a freer form (.later_effects)
            t_freer = time.monotonic()
            what = f"refitting the selected effects per experiment (round {rnd})"
            progress.stage(what, ctx.plan.refit, later)
            freer = fit_freer_form(
                state.selected, state.current, ctx.refit, split, ctx.settings.nfev, ctx.cfg
            )
            ctx.timings[f"freer_form_round_{rnd}"] = time.monotonic() - t_freer
            if freer is not None:
                state.freer_forms.append({"round": rnd, **freer.to_dict()})
                for sc in accepted:
                    state.over_freer[sc.name] = freer_form_check(
                        sc, freer, state.current_per, min_rel, split.acted_on(sc.candidate), band
                    )
                accepted = [s for s in accepted if s.accepted]
    return accepted


def best_first(accepted: Iterable[CandidateScore]) -> list[CandidateScore]:
    """Accepted scores, the one whose model predicts the held-out data best first (the
    lowest held-out NRMSE, the report's headline figure), then by score. Acceptance takes
    the median over the held-out recordings, which a candidate can pass while it predicts
    one of them much worse: on a 2 m rig with tube waves the exhaust discharge (median 56 %
    better, one recording 22 % worse, NRMSE 0.112) outscored the tube's waves (51 %, every
    recording better, 0.076) and was adopted in their place (issue 34)."""
    return sorted(accepted, key=lambda s: (s.heldout_mean, -s.relative_improvement))


def _adopt(
    ctx: RoundContext,
    state: Selection,
    best: CandidateScore,
    round_scores: Sequence,
    later: float,
) -> None:
    """Add ``best`` to the model and re-converge base + selected effects with the full
    budget, so the next round compares against a converged model (not against a refit
    stopped by its budget)."""
    split = ctx.split
    state.selected.append(best.candidate)
    state.confidence.append(
        _confidence(best, round_scores, ctx.settings.min_rel, split.acted_on(best.candidate))
    )
    state.confidence[-1]["margin_over_freer_form"] = state.over_freer.get(best.name)
    before, _ = split.heldout_nrmse(state.current)
    state.confidence[-1]["explains_channels"] = channel_drops(before, best.heldout_nrmse)
    selected = state.selected
    assert best.fit is not None  # an accepted candidate was refitted
    progress.stage(f"re-converging the model with {best.name}", ctx.plan.refit, later)
    free = unique(
        list(ctx.base_params) + [p for c in selected for p in (*c.refit_base, *c.parameters)]
    )
    fixed = {k: v for k, v in best.fit.all_values().items() if k not in {p.name for p in free}}
    polish = split.training_problem(
        free, fixed, f"model with {', '.join(c.name for c in selected)}", best.fit.scopes
    )
    state.current = run_fit(
        polish,
        start=best.fit.all_values(),
        **ctx.settings.fit_stops,
        friction_restarts=any(c.requires_motion for c in selected),
    )
    nrmse_now, preds_now = split.heldout_nrmse(state.current)
    state.current_mean = mean_nrmse(nrmse_now)
    state.current_per = {k: mean_nrmse(v) for k, v in split.per_recording(preds_now).items()}
    log.info(
        "diagnosis: accepted %s (held-out NRMSE %.4g, %.1f %% better)",
        best.name,
        best.heldout_mean,
        100 * best.relative_improvement,
    )


def winner_and_runner_up(
    state: Selection, cfg: IdentificationConfig, min_rel: float, quick: bool
) -> tuple[str | None, str | None, str | None]:
    """Round 1's winner, its runner-up, and an experiment to separate them when close."""
    # refitted candidates first: a screened-out one carries only the screening's linear
    # prediction, which is no score to compare with
    first = sorted(
        (s for s in state.scores if s.round == 1),
        key=lambda s: (not s.refitted, -s.relative_improvement),
    )
    winner = state.selected[0].name if state.selected else None
    runner_up, suggestion = None, None
    if first:
        others = [s for s in first if s.name != winner]
        if others:
            runner_up = others[0].name
        w = next((s for s in first if s.name == winner), None)
        if w is not None and others:
            r = others[0]
            if (
                r.relative_improvement
                >= cfg.diagnosis("runner_up_close_ratio") * w.relative_improvement
                and r.relative_improvement > 0
            ):
                suggestion = separating_experiment(w.name, r.name, cfg)
        elif not winner and not quick and first[0].relative_improvement >= min_rel:
            suggestion = (
                "the best candidate (" + first[0].name + ") improves the held-out "
                "error but is not accepted ("
                + "; ".join(first[0].reasons)
                + "): "
                + cfg.default_experiment()
            )
    return winner, runner_up, suggestion


def channel_drops(before: dict[str, float], after: dict[str, float]) -> dict[str, float]:
    """Per held-out channel, the relative drop of the NRMSE from ``before`` to ``after``
    (what an effect explains, channel by channel)."""
    return {
        c: 1.0 - after[c] / before[c]
        for c in before
        if c in after and before[c] > 0 and math.isfinite(after[c])
    }


def _confidence(
    best: CandidateScore,
    round_scores: Sequence[CandidateScore],
    min_rel: float,
    acts_on: set[str],
) -> dict:
    """How sure the selection is of ``best``: its margin over the round's runner-up and
    over no effect, which held-out recordings support it, and whether it holds on every
    one of them and on every one it can act on (``acts_on``, :meth:`.Holdout.acted_on`)."""
    others = sorted(
        (s for s in round_scores if s is not best),
        key=lambda s: (not s.refitted, -s.relative_improvement),
    )
    runner = others[0] if others else None
    per = {k: v for k, v in best.per_recording.items() if math.isfinite(v)}
    where = sorted(acts_on & set(per))
    return {
        "effect": best.name,
        "round": best.round,
        "heldout_improvement": best.relative_improvement,
        "margin_over_none": best.relative_improvement,
        "delta_ic": best.delta_ic,
        "runner_up": runner.name if runner else None,
        "runner_up_improvement": runner.relative_improvement if runner else None,
        "runner_up_refitted": runner.refitted if runner else None,
        "margin_over_runner_up": (
            best.relative_improvement - runner.relative_improvement if runner else None
        ),
        "heldout_improvement_per_recording": per,
        "supported_by": [k for k, v in per.items() if v >= min_rel],
        "holds_on_every_heldout_recording": bool(per) and all(v > 0 for v in per.values()),
        "acts_on": where,
        "holds_where_it_acts": bool(where) and all(per[k] > 0 for k in where),
        "flagged": list(best.flags),
    }
