"""Residual diagnosis: which effect beyond the calibrated model do the data show?

1. Calibrate the base model on the training data (:mod:`.holdout`: the start of each
   recording, whole held-out recordings, or per experiment type for a campaign).
2. Analyse the residual on the held-out data per channel and per phase (valve open,
   after the flow stops, rest, current reversals): NRMSE, bias, whiteness (normalised
   autocorrelation, Ljung-Box) and cross-correlation with the coil current
   (:mod:`.residuals`).
3. Screen the whole catalogue (:mod:`.screening`: one Gauss-Newton step per candidate
   from one batch simulation) and refit only the most promising few, in parallel
   processes (:mod:`.scoring`): each refit's parameters together with the base's, scored
   on the held-out data (relative drop of the mean held-out NRMSE, overall and per
   held-out recording) and by an information criterion (BIC) with the effective sample
   size ``N (1 - rho) / (1 + rho)`` of the autocorrelated residual.
4. Accept an effect only when the held-out improvement and the BIC drop pass the
   thresholds of ``configs/identification.yaml`` (fixed before any test data existed),
   and its parameters are identified (confidence interval narrower than the plausible
   range and excluding the neutral value) and plausible, or the improvement is strong
   (``diagnosis.min_improvement_when_implausible``: then it is accepted flagged with the
   value outside the plausible range, or with the interval wider than the plausible range
   when that is its only shortfall). A second or later effect must
   also be supported on held-out data the effects before it did not explain: it must
   lower the error of every held-out recording it can act on by the threshold, raise
   none, and beat the effects before it refitted per experiment type
   (:mod:`.later_effects`).
   Select greedily (the accepted best joins the model, the rest are screened again);
   then drop an effect a later one made redundant (:mod:`.stand_ins`, backward
   elimination). Report the winner, the runner-up, or "none", and each selected
   effect's margins.
5. Suggest an experiment that separates the winner from a close runner-up.

Nothing here reads how the data were made: only the recordings' samples and the rig
facts of their sidecars (never the notes).
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from pneumatic_env.recording import Recording

from . import progress
from .calibrate import (
    Dataset,
    FitResult,
    base_fit_parameters,
    diagnosis_fit_stops,
    prepare_datasets,
    run_fit,
)
from .candidates import (
    Candidate,
    applicable,
    available_candidates,
    candidate_table,
)
from .checks import dead_band_current
from .config import IdentificationConfig, load_config
from .drift import base_drifts, suggested_effects
from .holdout import Holdout
from .noise import sensor_noise
from .problem import FitProblem, simulation_threads
from .residuals import PHASES, phase_masks, residual_analysis
from .scoring import (
    CandidateScore,
    conflicts,
    improvement_is_the_basin,
    mean_nrmse,
    score,
    unique,
)
from .screening import coarse_dataset
from .selection import (
    RoundContext,
    Selection,
    Settings,
    WorkPlan,
    eligible,
    screening_columns,
    selection_round,
    winner_and_runner_up,
    work_after_refits,
)
from .stage_costs import kernel_substeps_per_s, stage_costs
from .stand_ins import drop_stand_ins

__all__ = [
    "PHASES",
    "CandidateScore",
    "Diagnosis",
    "dead_band_current",
    "diagnose",
    "phase_masks",
    "residual_analysis",
]

log = logging.getLogger("pneumatic_env.identification")
# names of the previous single module, kept for callers
_Split = Holdout
_mean = mean_nrmse
_conflicts = conflicts
_improvement_is_the_basin = improvement_is_the_basin
_score = score
_unique = unique


@dataclass
class Diagnosis:
    """Everything :func:`diagnose` found; :meth:`to_json` gives ``diagnosis.json``."""

    datasets: list[Dataset]
    holdout: dict
    issues: list
    base: FitResult
    baseline_nrmse: dict[str, float]
    baseline_residuals: dict
    scores: list[CandidateScore]
    skipped: dict[str, str]
    selected: list[str]
    final: FitResult
    after_nrmse: dict[str, float]
    after_residuals: dict
    winner: str | None
    runner_up: str | None
    suggestion: str | None
    thresholds: dict
    predictions: dict = field(default_factory=dict)  # "before"/"after": per dataset channels
    screening: list = field(default_factory=list)  # per round: the screening's ranking
    confidence: list = field(default_factory=list)  # per selected effect (see diagnose)
    per_recording: dict = field(default_factory=dict)  # held-out NRMSE before/after per recording
    quick: bool = False  # screening only, nothing refitted
    freer_forms: list = field(default_factory=list)  # per later round (.later_effects)
    timings: dict = field(default_factory=dict)  # seconds per stage
    stage_costs: list = field(default_factory=list)  # .stage_costs: each stage vs the kernel
    kernel_substeps_per_s: float = 0.0  # the kernel's lane-substeps per second, one core
    status: str = "complete"  # or "running, round N" (a report written during the run)
    still_checking: str | None = None  # what the running round checks
    drift: list = field(default_factory=list)  # .drift.Drift: base parameters implausible
    stand_ins: list = field(default_factory=list)  # removals tried after the rounds

    @functools.cached_property
    def sensor_noise(self) -> dict[str, float]:
        """{channel: white-noise std (SI)} of the recordings (``.noise.sensor_noise``),
        once however often the report is written."""
        return sensor_noise([ds.recording for ds in self.datasets])

    def ranked(self) -> list[CandidateScore]:
        """Round 1 by score (refitted candidates first), then each later round."""
        return sorted(self.scores, key=lambda s: (s.round, not s.refitted, -s.relative_improvement))

    def to_json(self) -> dict:
        return {
            "recordings": [ds.name for ds in self.datasets],
            # each recording's sidecar as stated: the rig (agents.rig reads it back)
            "rigs": {ds.name: ds.recording.rig for ds in self.datasets},
            # the sensors' white noise from the recordings alone (agents.rig reads it back)
            "sensor_noise": self.sensor_noise,
            "holdout": self.holdout,
            "issues": [str(i) for i in self.issues],
            "thresholds": self.thresholds,
            "calibration": self.base.to_dict(),
            "baseline_nrmse": self.baseline_nrmse,
            "baseline_nrmse_mean": mean_nrmse(self.baseline_nrmse),
            "baseline_residuals": self.baseline_residuals,
            "candidates": [s.to_dict() for s in self.ranked()],
            "skipped": self.skipped,
            "selected": list(self.selected),
            "winner": self.winner,
            "runner_up": self.runner_up,
            "suggested_experiment": self.suggestion,
            "after_nrmse": self.after_nrmse,
            "after_nrmse_mean": mean_nrmse(self.after_nrmse),
            "after_residuals": self.after_residuals,
            "final_fit": self.final.to_dict(),
            "confidence": self.confidence,
            "per_recording": self.per_recording,
            "screening": self.screening,
            "freer_forms": self.freer_forms,
            "stand_in_check": self.stand_ins,
            "quick": self.quick,
            "timings_s": self.timings,
            "stage_costs": self.stage_costs,
            "kernel_lane_substeps_per_s": self.kernel_substeps_per_s,
            "simulation_threads": simulation_threads(),
            "status": self.status,
            "still_checking": self.still_checking,
            "base_drift": [d.to_dict() for d in self.drift],
            "suggested_by_drift": suggested_effects(self.drift),
            "note": "NRMSE = RMSE / channel scale (supply - ambient for pressures, that times the "
            "cap area for the force, half the stroke for x), on held-out data",
        }


def _work(datasets: Sequence[Dataset], n_samples: Sequence[int] | None = None) -> float:
    """Simulation work of one parameter column over ``datasets`` (samples x substeps)."""
    n_samples = n_samples or [ds.n_samples for ds in datasets]
    return float(sum(n * ds.substeps for ds, n in zip(datasets, n_samples)))


def _size_issue(
    datasets: Sequence[Dataset],
    cfg: IdentificationConfig,
    seconds_per_column: float,
    n_columns: float,
):
    """A warning when the data are longer than the tool is tuned for, with what it does."""
    from .checks import DataIssue

    total_s = sum(ds.n_samples * ds.dt_s for ds in datasets)
    expected = cfg.number("screening", "expected_total_duration_s", positive=True)
    if total_s <= expected:
        return None
    minutes = seconds_per_column * n_columns / 60.0
    return DataIssue(
        "warning",
        "size",
        "all",
        f"the {len(datasets)} recordings hold {total_s:.1f} s of data, more than the "
        f"{expected:g} s this tool is tuned for "
        "(screening.expected_total_duration_s): "
        f"every fit simulates all of it, so the run takes about {minutes:.0f} min "
        "(it grows in proportion to the data); all samples are used. For an answer "
        "in seconds run with --quick (screening only), or pass fewer or shorter "
        "recordings",
    )


def _settings(cfg: IdentificationConfig, max_effects: int | None, jobs: int | None) -> Settings:
    """:class:`Settings` from ``cfg``, ``max_effects`` and ``jobs`` overriding it."""
    min_rel = cfg.diagnosis("min_relative_improvement")
    min_ic = cfg.diagnosis("min_ic_drop")
    max_effects = int(max_effects if max_effects is not None else cfg.diagnosis("max_effects"))
    nfev = int(cfg.number("fit", "diagnosis_max_nfev", positive=True))
    top_k = int(cfg.number("screening", "refit_top", positive=True))
    min_pred = cfg.number("screening", "min_predicted_improvement", minimum=0.0)
    jobs = int(jobs if jobs is not None else cfg.number("screening", "jobs", positive=True))
    thresholds = {
        "min_relative_improvement": min_rel,
        "min_ic_drop": min_ic,
        "median_from_recordings": int(cfg.diagnosis("median_from_recordings")),
        "max_effects": max_effects,
        "refit_top": top_k,
        "min_predicted_improvement": min_pred,
        "min_improvement_when_implausible": cfg.diagnosis("min_improvement_when_implausible"),
    }
    stops = diagnosis_fit_stops(cfg)
    return Settings(min_rel, min_ic, max_effects, nfev, top_k, min_pred, jobs, stops, thresholds)


def _candidate_pool(
    datasets: Sequence[Dataset], candidates: Sequence[str] | None, cfg: IdentificationConfig
) -> tuple[list[Candidate], dict[str, str]]:
    """The candidates the data can show, and why each other one is skipped."""
    channels = {c for ds in datasets for c in ds.channels}
    moving = any(ds.moving for ds in datasets)
    rod_modes = {ds.rod_mode for ds in datasets}
    pool, skipped = [], {}
    for cand in available_candidates(candidates, cfg):
        why = applicable(cand, channels, moving, rod_modes)
        if why:
            skipped[cand.name] = why
        else:
            pool.append(cand)
    if candidates is None:
        for name, cand in candidate_table(cfg).items():
            if not cand.available:
                skipped[name] = "its kernel parameters are not in this version of the kernel"
    return pool, skipped


def _plan_work(
    datasets: Sequence[Dataset],
    split: Holdout,
    base_params: Sequence,
    refit: Sequence,
    pool: Sequence[Candidate],
    cfg: IdentificationConfig,
    settings: Settings,
    quick: bool,
    issues: list,
) -> WorkPlan:
    """Estimate the work, time one simulation of the data, and add the size notice."""
    w_train, w_all = _work(split.train, split.train_n), _work(datasets)
    n_screen = screening_columns(pool, len(refit))
    plan_base = w_train * (len(base_params) + 1) * 0.8 * cfg.number("fit", "max_nfev")
    refit_work = w_train * (len(refit) + 3) * 12  # about 12 Jacobians per refit
    plan_round = w_all * n_screen + (0 if quick else settings.top_k * refit_work)
    progress.stage("timing a simulation of the data", w_all, later=plan_base + plan_round)
    t_probe = time.monotonic()
    FitProblem(datasets, [], config=cfg, label="probe").residual(np.empty(0))
    per_column = (time.monotonic() - t_probe) / max(w_all, 1.0)
    issue = _size_issue(datasets, cfg, per_column, plan_base + plan_round)
    if issue is not None:
        issues.append(issue)
        log.warning("%s", issue.message)
    progress.restart_clock()  # the first simulation may have compiled the kernel
    plan = WorkPlan(plan_base, plan_round, refit_work, w_all)
    after = work_after_refits(plan, settings, len(refit), pool, 1, quick)
    return dataclasses.replace(plan, after_first=after)


def diagnose(
    recordings: Sequence[Recording],
    params=None,
    candidates: Sequence[str] | None = None,
    base_fit: Sequence[str] | None = None,
    holdout: str = "auto",
    config: IdentificationConfig | None = None,
    max_effects: int | None = None,
    quick: bool = False,
    jobs: int | None = None,
    on_round: Callable[[Diagnosis], object] | None = None,
) -> Diagnosis:
    """Calibrate, screen the candidates, refit the promising ones, select effects.

    ``candidates``: names (default: every available candidate). ``base_fit``: base
    parameters to calibrate (default from the config). ``holdout``: see :mod:`.holdout`.
    ``quick``: stop after the screening (nothing is refitted or selected; the ranking is
    in ``screening``). ``jobs``: processes for the refits (default ``screening.jobs``).
    ``on_round``: called with the diagnosis so far (status "running, round N") before
    each round, e.g. to write the report then, so a run stopped early still tells what
    it found.
    """
    t0 = time.monotonic()
    progress.ledger(start=True)
    cfg = config or load_config()
    datasets, issues = prepare_datasets(recordings, params, cfg)
    split = Holdout(datasets, holdout, cfg)
    base_params = base_fit_parameters(datasets, base_fit, cfg)
    refit_names = cfg.base_fit_names("refit_in_diagnosis")
    refit = (
        base_params if refit_names == ["all"] else [p for p in base_params if p.name in refit_names]
    )
    settings = _settings(cfg, max_effects, jobs)
    pool, skipped = _candidate_pool(datasets, candidates, cfg)
    plan = _plan_work(datasets, split, base_params, refit, pool, cfg, settings, quick, issues)
    clamped = [ds for ds in split.train if not ds.moving] or list(split.train)
    kernel_rate = kernel_substeps_per_s(clamped[0])  # after the plan's probe compiled it
    base = _fit_base(split, base_params, cfg, settings, plan, early=True)
    timings = {"base_fit": time.monotonic() - t0}
    ctx = RoundContext(
        cfg, settings, datasets, split, base_params, refit, plan, quick, base, timings
    )
    ctx.kernel_substeps_per_s = kernel_rate
    ctx.after_screening = None if quick else _finish_base
    state = Selection(base, *_heldout_means(split, base))
    before = _Before(t0, issues, skipped)
    for rnd in range(1, settings.max_effects + 1):
        if on_round is not None:  # the report so far, before each round
            on_round(_assemble(ctx, state, before, pool, rnd))
        if not selection_round(ctx, state, pool, rnd):
            break
    if not quick and len(state.selected) >= 2:
        state.stand_ins = drop_stand_ins(ctx, state)
    diag = _assemble(ctx, state, before, pool)
    progress.finish()
    return diag


@dataclass
class _Before:
    """What :func:`diagnose` knows before the rounds: the start time, the data issues and
    the skipped candidates (the base model's held-out error is taken at each assembly:
    a base fit stopped early for the screening is finished after it)."""

    t0: float
    issues: list
    skipped: dict


def _assemble(
    ctx: RoundContext,
    state: Selection,
    before: _Before,
    pool: Sequence[Candidate],
    running_round: int | None = None,
) -> Diagnosis:
    """The :class:`Diagnosis` of the selection so far: complete, or (``running_round``)
    while that round is still to run (no predictions for plots then)."""
    split, base, cfg = ctx.split, ctx.base, ctx.cfg
    winner, runner_up, suggestion = winner_and_runner_up(
        state, cfg, ctx.settings.min_rel, ctx.quick
    )
    baseline_nrmse, base_preds = split.heldout_nrmse(base)
    base_per = split.per_recording(base_preds)
    after_nrmse, after_preds = split.heldout_nrmse(state.current)
    after_per = split.per_recording(after_preds)
    ledger = progress.ledger()  # the stages up to now, as the total below
    ctx.timings["total"] = time.monotonic() - before.t0
    status, checking = "complete", None
    if running_round is not None:
        status = f"running, round {running_round}"
        checking = _still_checking(state, pool, running_round)
    return Diagnosis(
        datasets=list(ctx.datasets),
        holdout=split.info,
        issues=before.issues,
        base=base,
        baseline_nrmse=baseline_nrmse,
        baseline_residuals=_heldout_residuals(split, base, base_preds, cfg),
        scores=list(state.scores),
        skipped=before.skipped,
        selected=[c.name for c in state.selected],
        final=state.current,
        after_nrmse=after_nrmse,
        after_residuals=_heldout_residuals(split, state.current, after_preds, cfg),
        winner=winner,
        runner_up=runner_up,
        suggestion=suggestion,
        thresholds=ctx.settings.thresholds,
        predictions=(
            {}
            if running_round is not None
            else {
                "before": split.predict(base, ctx.datasets),
                "after": split.predict(state.current, ctx.datasets),
            }
        ),
        screening=list(state.screening),
        confidence=list(state.confidence),
        freer_forms=list(state.freer_forms),
        stand_ins=list(state.stand_ins),
        per_recording=_per_recording_before_after(base_per, after_per),
        quick=ctx.quick,
        timings=dict(ctx.timings),
        stage_costs=stage_costs(ledger, ctx.kernel_substeps_per_s, simulation_threads()),
        kernel_substeps_per_s=ctx.kernel_substeps_per_s,
        status=status,
        still_checking=checking,
        drift=base_drifts(base, ctx.datasets, cfg, state.current),
    )


def _still_checking(state: Selection, pool: Sequence[Candidate], rnd: int) -> str:
    """What round ``rnd`` checks, in words."""
    names = [c.name for c in eligible(pool, state.selected)]
    found = ", ".join(c.name for c in state.selected)
    question = f"is there an effect beyond {found}?" if found else "which effect, if any?"
    return f"round {rnd}: {question} Screening {len(names)} candidates: {', '.join(names)}"


def _fit_base(
    split: Holdout,
    base_params: Sequence,
    cfg: IdentificationConfig,
    settings: Settings,
    plan: WorkPlan,
    early: bool = False,
    start: FitResult | None = None,
    later: float | None = None,
) -> FitResult:
    """Calibrate the base model on the training data (from ``start``'s values if given;
    ``later``: the work planned after it, default round 1's).

    ``early``: at the screening's coarser substep of a moving rod
    (:func:`.screening.coarse_dataset`), and stop where the cost has stopped falling fast
    (``screening.early_relative_decrease`` after ``screening.early_min_jacobians``), for
    the screening; the fit's ``message`` then starts with "stopped early"
    (:func:`_finish_base` fits on at the fine substep)."""
    progress.stage(
        "base fit" if start is None else "finishing the base fit",
        plan.base,
        later=plan.round + plan.after_first if later is None else later,
    )
    log.info(
        "diagnosis: %s the base model (%s) on the training data",
        "calibrating" if start is None else "finishing the fit of",
        ", ".join(p.name for p in base_params),
    )
    decrease = cfg.number("screening", "early_relative_decrease", minimum=0.0)
    n_min = int(cfg.number("screening", "early_min_jacobians", positive=True))
    early = early and decrease > 0  # 0: one fit at the fine substep, as before
    train = [coarse_dataset(ds, cfg) for ds in split.train] if early else split.train
    base_problem = FitProblem(train, base_params, n_samples=split.train_n, config=cfg, label="base")
    if start is not None:  # the coarse answer checked against the fine model
        fine = base_problem.robust_cost(base_problem.residual(base_problem.initial_u(start.values)))
        log.info(
            "diagnosis: the base fit's cost at its early point: %.6g at the coarse substep, "
            "%.6g at the fine one (%+.2f %%)",
            start.cost_history[-1],
            fine,
            100 * (fine / start.cost_history[-1] - 1),
        )
    return run_fit(
        base_problem,
        start=None if start is None else start.values,
        **settings.fit_stops,
        early_stop=(decrease, n_min) if early else None,
    )


def stopped_early(fit: FitResult) -> bool:
    """The fit was stopped for the screening before it converged (:func:`_fit_base`)."""
    return fit.message.startswith("stopped early")


def _heldout_means(split: Holdout, fit: FitResult) -> tuple[float, dict]:
    """``fit``'s mean held-out NRMSE, overall and per held-out recording."""
    nrmse, preds = split.heldout_nrmse(fit)
    return mean_nrmse(nrmse), {k: mean_nrmse(v) for k, v in split.per_recording(preds).items()}


def _finish_base(ctx: RoundContext, state: Selection, screens: Sequence) -> None:
    """After the first screening, finish a base fit stopped early for it: fit on from its
    point, and make the result the base and the current model the refits are held
    against (a no-op once finished, or when an effect has been adopted). The screens'
    predicted training drops are restated against the finished base."""
    if not stopped_early(ctx.base) or state.current is not ctx.base:
        return
    t0 = time.monotonic()
    early = ctx.base
    base = _fit_base(
        ctx.split,
        ctx.base_params,
        ctx.cfg,
        ctx.settings,
        ctx.plan,
        start=early,
        later=ctx.work_after_screening,
    )
    for s in screens:
        s.predicted_train = 1.0 - (1.0 - s.predicted_train) * early.rss / base.rss
    ctx.base = base
    state.current = base
    state.current_mean, state.current_per = _heldout_means(ctx.split, base)
    ctx.timings["base_fit_finish"] = time.monotonic() - t0


def _heldout_residuals(split: Holdout, fit: FitResult, preds, cfg: IdentificationConfig) -> dict:
    """:func:`.residual_analysis` of ``fit``'s predictions on the held-out data."""
    values = [fit.dataset_values(ds) for ds in split.held]
    return residual_analysis(split.held, preds, split.held_masks, values, cfg)


def _per_recording_before_after(base_per: dict, after_per: dict) -> dict:
    """Held-out NRMSE per recording and channel before and after, with their means."""
    return {
        name: {
            "before": base_per[name],
            "after": after_per[name],
            "before_mean": mean_nrmse(base_per[name]),
            "after_mean": mean_nrmse(after_per[name]),
        }
        for name in base_per
    }
