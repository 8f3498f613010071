"""Residual diagnosis: which effect beyond the calibrated model do the data show?

1. Calibrate the base model on the training data (the start of each recording, or all
   recordings but the held-out ones).
2. Analyse the residual on the held-out data per channel and per phase (valve open,
   after the flow stops, rest, current reversals): NRMSE, bias, whiteness (normalised
   autocorrelation, Ljung-Box) and cross-correlation with the coil current.
3. For each candidate effect (:mod:`.candidates`), refit its parameters together with a
   subset of the base parameters, and score it on the held-out data: the relative drop
   of the mean held-out NRMSE, and an information criterion (BIC) computed with the
   effective sample size ``N (1 - rho) / (1 + rho)`` of the autocorrelated residual.
4. Accept an effect only when the held-out improvement and the BIC drop pass the
   thresholds of ``configs/identification.yaml`` (fixed before any test data existed),
   and its parameters are plausible and identified (confidence interval narrower than
   the plausible range and excluding the neutral value). Rank, select greedily (forward
   selection: the accepted best joins the model, the rest are tried again), report the
   winner, the runner-up, or "none".
5. Suggest an experiment that separates the winner from a close runner-up.

Nothing here reads how the data were made: only the recordings' samples and the rig
facts of their sidecars (never the notes).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.stats import chi2, norm

from pneumatic_env.physics.derived import valve_currents_a
from pneumatic_env.recording import Recording

from .calibrate import (
    Dataset,
    FitProblem,
    FitResult,
    base_fit_parameters,
    channel_nrmse,
    prepare_datasets,
    run_fit,
)
from .candidates import (
    Candidate,
    applicable,
    available_candidates,
    candidate_table,
    separating_experiment,
)
from .config import FitParameter, IdentificationConfig, load_config

__all__ = ["CandidateScore", "Diagnosis", "diagnose", "phase_masks", "residual_analysis"]

log = logging.getLogger("pneumatic_env.identification")
PHASES = ("flow", "after_flow", "rest", "reversal")


# --------------------------------------------------------------------------- residual analysis


def dead_band_current(values: Mapping[str, float]) -> float:
    """Coil current at which the valve starts to open (Eqs. 43, 46; physics.derived)."""
    dead_band_a, _ = valve_currents_a(
        values["spool_half_width_m"],
        values["hole_radius_m"],
        values["spool_spring_n_per_m"],
        max(values["coil_force_n_per_a"], 1e-12),
    )
    return float(dead_band_a)


def phase_masks(
    i_c: np.ndarray, dt_s: float, values: Mapping[str, float], config: IdentificationConfig
) -> dict[str, np.ndarray]:
    """Per phase, the samples in it (phases may overlap: a reversal is also flow).

    ``flow``: |i_c| beyond the dead band; ``after_flow``: valve closed, within
    ``diagnosis.after_flow_window_s`` of the last open sample; ``rest``: closed longer (or
    never opened); ``reversal``: within ``diagnosis.reversal_window_s`` after the opening
    direction changes sign.
    """
    db = dead_band_current(values)
    sign = np.where(i_c > db, 1, np.where(i_c < -db, -1, 0))
    flow = sign != 0
    n = len(i_c)
    idx = np.arange(n)
    last_open = np.where(flow, idx, -1)
    last_open = np.maximum.accumulate(last_open)
    since = np.where(last_open >= 0, (idx - last_open) * dt_s, np.inf)
    window = config.diagnosis("after_flow_window_s")
    after = ~flow & (since <= window)
    rest = ~flow & ~after
    reversal = np.zeros(n, dtype=bool)
    nz = np.flatnonzero(sign)
    if nz.size > 1:
        changes = nz[1:][sign[nz[1:]] != sign[nz[:-1]]]
        width = max(1, int(round(config.diagnosis("reversal_window_s") / dt_s)))
        for k in changes:
            reversal[k : k + width] = True
    return {"flow": flow, "after_flow": after, "rest": rest, "reversal": reversal}


def _whiteness(e: np.ndarray, max_lag: int, alpha: float) -> dict:
    n = e.size
    m = int(min(max_lag, n // 4))
    x = e - e.mean()
    den = float(x @ x)
    if den == 0 or m < 1:
        return {"autocorrelation": [], "ljung_box_q": 0.0, "p_value": 1.0, "white": True}
    r = np.array([float(x[k:] @ x[:-k]) / den for k in range(1, m + 1)])
    q = float(n * (n + 2) * np.sum(r**2 / (n - np.arange(1, m + 1))))
    p = float(chi2.sf(q, m))
    return {
        "autocorrelation": r[:10].tolist(),
        "lags": m,
        "ljung_box_q": q,
        "p_value": p,
        "white": p > alpha,
    }


def _input_correlation(e: np.ndarray, u: np.ndarray, max_lag: int, alpha: float) -> dict:
    """Largest |cross-correlation| of the residual with the input at lags 0..m, against
    the white-noise bound at level ``alpha`` Bonferroni-corrected over the m + 1 lags."""
    n = e.size
    x, v = e - e.mean(), u - u.mean()
    den = math.sqrt(float(x @ x) * float(v @ v))
    m = int(min(max_lag, n // 4))
    bound = float(norm.ppf(1.0 - alpha / (2.0 * (m + 1)))) / math.sqrt(max(n, 1))
    if den == 0:
        return {"max_abs": 0.0, "at_lag": 0, "bound": bound, "significant": False}
    rho = [float(x[k:] @ v[: n - k]) / den for k in range(m + 1)]  # residual after input
    k = int(np.argmax(np.abs(rho)))
    return {"max_abs": abs(rho[k]), "at_lag": k, "bound": bound, "significant": abs(rho[k]) > bound}


def residual_analysis(
    datasets: Sequence[Dataset],
    preds: Sequence[Mapping[str, np.ndarray]],
    masks: Sequence[Mapping[str, np.ndarray]],
    values: Sequence[Mapping[str, float]],
    config: IdentificationConfig,
) -> dict:
    """Per channel (pooled over datasets): NRMSE, bias, per-phase statistics, whiteness and
    the largest cross-correlation with the coil current. Residuals are normalised by the
    channel scale; ``masks`` select the analysed samples (e.g. the held-out part). The
    tests use ``diagnosis.whiteness_alpha`` divided by the number of channels."""
    max_lag = int(config.diagnosis("max_lag"))
    alpha = config.diagnosis("whiteness_alpha")
    out: dict[str, dict] = {}
    per_channel: dict[str, dict[str, list]] = {}
    for ds, pred, mask, vals in zip(datasets, preds, masks, values):
        phases = phase_masks(ds.recording.i_c, ds.dt_s, vals, config)
        for c in ds.channels:
            m = mask[c] & ds.usable[c]
            e = (pred[c] - ds.measured(c)) / ds.scales[c]
            acc = per_channel.setdefault(c, {"e": [], "u": [], **{ph: [] for ph in PHASES}})
            acc["e"].append(e[m])
            acc["u"].append(ds.recording.i_c[m])
            for ph in PHASES:
                acc[ph].append(e[m & phases[ph]])
    alpha = alpha / max(len(per_channel), 1)  # Bonferroni over the channels
    for c, acc in per_channel.items():
        e = np.concatenate(acc["e"])
        u = np.concatenate(acc["u"])
        phases = {}
        for ph in PHASES:
            x = np.concatenate(acc[ph])
            phases[ph] = {
                "n": int(x.size),
                "nrmse": float(np.sqrt(np.mean(x**2))) if x.size else None,
                "bias": float(np.mean(x)) if x.size else None,
            }
        out[c] = {
            "nrmse": float(np.sqrt(np.mean(e**2))) if e.size else None,
            "bias": float(np.mean(e)) if e.size else None,
            "n": int(e.size),
            "phases": phases,
            "whiteness": _whiteness(e, max_lag, alpha),
            "input_correlation": _input_correlation(e, u, max_lag, alpha),
        }
    return out


# --------------------------------------------------------------------------- scoring


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
        }


def _num(x: float):
    return float(x) if math.isfinite(x) else None


def _ic(rss: float, n: int, n_eff: float, k: int) -> float:
    """BIC with the effective sample size: ``N_eff ln(RSS/N) + k ln(N_eff)``."""
    return n_eff * math.log(max(rss, 1e-300) / n) + k * math.log(max(n_eff, 2.0))


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

    def ranked(self) -> list[CandidateScore]:
        """Round 1 by score, then each later round by score."""
        return sorted(self.scores, key=lambda s: (s.round, -s.relative_improvement))

    def to_json(self) -> dict:
        return {
            "recordings": [ds.name for ds in self.datasets],
            "holdout": self.holdout,
            "issues": [str(i) for i in self.issues],
            "thresholds": self.thresholds,
            "calibration": self.base.to_dict(),
            "baseline_nrmse": self.baseline_nrmse,
            "baseline_nrmse_mean": _mean(self.baseline_nrmse),
            "baseline_residuals": self.baseline_residuals,
            "candidates": [s.to_dict() for s in self.ranked()],
            "skipped": self.skipped,
            "selected": list(self.selected),
            "winner": self.winner,
            "runner_up": self.runner_up,
            "suggested_experiment": self.suggestion,
            "after_nrmse": self.after_nrmse,
            "after_nrmse_mean": _mean(self.after_nrmse),
            "after_residuals": self.after_residuals,
            "final_fit": self.final.to_dict(),
            "note": "NRMSE = RMSE / channel scale (supply - ambient for pressures, that times the "
            "cap area for the force, half the stroke for x), on held-out data",
        }


def _mean(d: Mapping[str, float]) -> float:
    vals = [v for v in d.values() if v is not None and math.isfinite(v)]
    return float(np.mean(vals)) if vals else math.nan


# --------------------------------------------------------------------------- diagnose


class _Split:
    """Training and held-out parts of the datasets."""

    def __init__(self, datasets: Sequence[Dataset], mode: str, config: IdentificationConfig):
        self.config = config
        self.datasets = list(datasets)
        n = len(self.datasets)
        if mode == "auto":  # a time split keeps every recording (e.g. both tube lengths) in the fit
            mode = "recordings" if n >= 3 else "time"
        if mode == "time":
            frac = config.number("fit", "train_fraction", positive=True)
            if not frac < 1:
                raise ValueError(f"fit.train_fraction = {frac!r} must be < 1 for a time split")
            self.train = self.datasets
            self.train_n = [max(2, int(round(frac * ds.n_samples))) for ds in self.datasets]
            self.held = self.datasets
            self.held_masks = []
            for ds, k in zip(self.datasets, self.train_n):
                m = np.zeros(ds.n_samples, dtype=bool)
                m[k:] = True
                self.held_masks.append(dict.fromkeys(ds.channels, m))
            self.info = {"mode": "time", "train_fraction": frac}
        elif mode == "recordings":
            if n < 2:
                raise ValueError("holdout mode 'recordings' needs at least 2 recordings")
            self.train = self.datasets[:-1]
            self.train_n = [ds.n_samples for ds in self.train]
            self.held = self.datasets[-1:]
            self.held_masks = [
                {c: np.ones(ds.n_samples, bool) for c in ds.channels} for ds in self.held
            ]
            self.info = {"mode": "recordings", "held_out": [ds.name for ds in self.held]}
        else:
            raise ValueError(
                f"holdout = {mode!r} is not allowed: must be 'auto', 'time' or 'recordings'"
            )
        self.mode = mode

    def predict(self, fit: FitResult, datasets=None) -> list[dict[str, np.ndarray]]:
        """Whole-recording predictions of ``datasets`` (default: the held-out ones)."""
        datasets = self.held if datasets is None else datasets
        problem = FitProblem(
            datasets,
            [],
            fixed=fit.all_values(),
            config=self.config,
            label="predict",
            scopes=fit.scopes,
        )
        return problem.predict(np.zeros(0), [ds.n_samples for ds in datasets])

    def heldout_nrmse(self, fit: FitResult) -> tuple[dict, list]:
        preds = self.predict(fit)
        return channel_nrmse(self.held, preds, self.held_masks), preds


def _unique(params: Sequence[FitParameter]) -> list[FitParameter]:
    """``params`` without repeated names (first occurrence kept)."""
    seen: set[str] = set()
    return [p for p in params if not (p.name in seen or seen.add(p.name))]


def _values_per_dataset(datasets: Sequence[Dataset], fit: FitResult) -> list[dict]:
    return [fit.dataset_values(ds) for ds in datasets]


def diagnose(
    recordings: Sequence[Recording],
    params=None,
    candidates: Sequence[str] | None = None,
    base_fit: Sequence[str] | None = None,
    holdout: str = "auto",
    config: IdentificationConfig | None = None,
    max_effects: int | None = None,
) -> Diagnosis:
    """Calibrate, diagnose the residual against the candidates, select effects.

    ``candidates``: names (default: every available candidate). ``base_fit``: base
    parameters to calibrate (default from the config). ``holdout``: ``"time"`` (fit on
    the start of every recording, score on the rest), ``"recordings"`` (fit on all but
    the last recording, score on it) or ``"auto"`` (recordings from three recordings on,
    else time).
    """
    cfg = config or load_config()
    datasets, issues = prepare_datasets(recordings, params, cfg)
    split = _Split(datasets, holdout, cfg)
    base_params = base_fit_parameters(datasets, base_fit, cfg)
    refit_names = cfg.base_fit_names("refit_in_diagnosis")
    refit = (
        base_params if refit_names == ["all"] else [p for p in base_params if p.name in refit_names]
    )
    min_rel = cfg.diagnosis("min_relative_improvement")
    min_ic = cfg.diagnosis("min_ic_drop")
    max_effects = int(max_effects if max_effects is not None else cfg.diagnosis("max_effects"))
    nfev = int(cfg.number("fit", "diagnosis_max_nfev", positive=True))
    thresholds = {
        "min_relative_improvement": min_rel,
        "min_ic_drop": min_ic,
        "max_effects": max_effects,
    }

    log.info(
        "diagnosis: calibrating the base model (%s) on the training data",
        ", ".join(p.name for p in base_params),
    )
    base_problem = FitProblem(
        split.train, base_params, n_samples=split.train_n, config=cfg, label="base"
    )
    base = run_fit(base_problem)
    baseline_nrmse, base_preds = split.heldout_nrmse(base)
    baseline_res = residual_analysis(
        split.held, base_preds, split.held_masks, _values_per_dataset(split.held, base), cfg
    )
    n_res, n_eff = base.n_residuals, base.n_eff

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

    current, current_mean = base, _mean(baseline_nrmse)
    selected: list[Candidate] = []
    scores: list[CandidateScore] = []
    for rnd in range(1, max_effects + 1):
        round_scores = []
        for cand in pool:
            if cand in selected or _conflicts(cand, selected):
                continue
            log.info("diagnosis round %d: candidate %s", rnd, cand.name)
            round_scores.append(
                _score(
                    cand,
                    rnd,
                    current,
                    current_mean,
                    refit,
                    selected,
                    split,
                    n_res,
                    n_eff,
                    min_rel,
                    min_ic,
                    nfev,
                    cfg,
                )
            )
        scores.extend(round_scores)
        accepted = sorted(
            (s for s in round_scores if s.accepted), key=lambda s: -s.relative_improvement
        )
        if moving:  # stick-event basins: the effect itself must make the improvement
            for score in accepted:
                if not _improvement_is_the_basin(score, current, min_rel, split, cfg):
                    break
            accepted = [s for s in accepted if s.accepted]
        if not accepted:
            break
        best = accepted[0]
        selected.append(best.candidate)
        # Re-converge base + selected effects with the full budget, so the next round
        # compares against a converged model (not against a refit stopped by its budget).
        free = _unique(
            list(base_params) + [p for c in selected for p in (*c.refit_base, *c.parameters)]
        )
        fixed = {k: v for k, v in best.fit.all_values().items() if k not in {p.name for p in free}}
        polish = FitProblem(
            split.train,
            free,
            fixed=fixed,
            n_samples=split.train_n,
            config=cfg,
            label=f"model with {', '.join(c.name for c in selected)}",
            scopes=best.fit.scopes,
        )
        current = run_fit(
            polish,
            start=best.fit.all_values(),
            friction_restarts=any(c.requires_motion for c in selected),
        )
        current_mean = _mean(split.heldout_nrmse(current)[0])
        log.info(
            "diagnosis: accepted %s (held-out NRMSE %.4g, %.1f %% better)",
            best.name,
            best.heldout_mean,
            100 * best.relative_improvement,
        )

    first = sorted((s for s in scores if s.round == 1), key=lambda s: -s.relative_improvement)
    winner = selected[0].name if selected else None
    runner_up, suggestion = None, None
    if first:
        others = [s for s in first if s.name != winner]
        if others:
            runner_up = others[0].name
        if winner and others:
            w = next(s for s in first if s.name == winner)
            r = others[0]
            if (
                r.relative_improvement
                >= cfg.diagnosis("runner_up_close_ratio") * w.relative_improvement
                and r.relative_improvement > 0
            ):
                suggestion = separating_experiment(winner, r.name, cfg)
        elif not winner and first[0].relative_improvement >= min_rel:
            suggestion = (
                "the best candidate (" + first[0].name + ") improves the held-out error but "
                "is not accepted (" + "; ".join(first[0].reasons) + "): " + cfg.default_experiment()
            )
    after_nrmse, after_preds = split.heldout_nrmse(current)
    after_res = residual_analysis(
        split.held, after_preds, split.held_masks, _values_per_dataset(split.held, current), cfg
    )
    predictions = {
        "before": split.predict(base, datasets),
        "after": split.predict(current, datasets),
    }
    return Diagnosis(
        datasets=datasets,
        holdout=split.info,
        issues=issues,
        base=base,
        baseline_nrmse=baseline_nrmse,
        baseline_residuals=baseline_res,
        scores=scores,
        skipped=skipped,
        selected=[c.name for c in selected],
        final=current,
        after_nrmse=after_nrmse,
        after_residuals=after_res,
        winner=winner,
        runner_up=runner_up,
        suggestion=suggestion,
        thresholds=thresholds,
        predictions=predictions,
    )


def _conflicts(cand: Candidate, selected: Sequence[Candidate]) -> bool:
    """Whether ``cand`` fixes a parameter a selected effect fits, or fits one it fixes (e.g.
    the transmission line holds the tube's air, so it excludes a tube storage volume), or
    both fit the same parameter (LuGre friction has the Stribeck curve already)."""
    return any(
        set(cand.set) & set(other.parameter_names)
        or set(other.set) & set(cand.parameter_names)
        or set(cand.parameter_names) & set(other.parameter_names)
        for other in selected
    )


def _improvement_is_the_basin(
    score: CandidateScore,
    current: FitResult,
    min_rel: float,
    split: _Split,
    cfg: IdentificationConfig,
) -> bool:
    """True (and ``score`` refused) when the current model at the candidate's fitted values,
    the candidate's effect switched off, is within ``min_rel`` of the candidate's held-out
    error: then the improvement came from where the candidate's refit moved the base
    parameters (for a sliding piston, which stick events it makes), not from the effect."""
    values = score.fit.all_values()
    fixed = {**current.fixed, **{p.name: values[p.name] for p in current.parameters}}
    problem = FitProblem(
        split.train,
        [],
        fixed=fixed,
        n_samples=split.train_n,
        config=cfg,
        label=f"the fit with {score.name}, the effect off",
        scopes=current.scopes,
    )
    try:
        off = run_fit(problem)
    except (ValueError, FloatingPointError):
        return False
    off_mean = _mean(split.heldout_nrmse(off)[0])
    rel = (off_mean - score.heldout_mean) / off_mean if off_mean > 0 else 0.0
    if rel >= min_rel:
        return False
    score.accepted = False
    score.reasons.append(
        f"with {score.name} switched off at its fitted values the held-out NRMSE is "
        f"{off_mean:.4g} (with it {score.heldout_mean:.4g}, {100 * rel:.1f} % better < "
        f"{100 * min_rel:.0f} %): the improvement is where the refit moved the base "
        "parameters, not the effect"
    )
    return True


def _score(
    cand: Candidate,
    rnd: int,
    current: FitResult,
    current_mean: float,
    refit: Sequence[FitParameter],
    selected: Sequence[Candidate],
    split: _Split,
    n_res: int,
    n_eff: float,
    min_rel: float,
    min_ic: float,
    nfev: int,
    cfg: IdentificationConfig,
) -> CandidateScore:
    free = _unique(
        list(refit)
        + [p for c in selected for p in (*c.refit_base, *c.parameters)]
        + list(cand.refit_base)
        + list(cand.parameters)
    )
    fixed = {k: v for k, v in current.all_values().items() if k not in {p.name for p in free}}
    fixed.update(cand.set)
    start = {p.name: current.all_values()[p.name] for p in free if p.name in current.all_values()}
    problem = FitProblem(
        split.train,
        free,
        fixed=fixed,
        n_samples=split.train_n,
        config=cfg,
        label=f"{cand.name} (round {rnd})",
        scopes={**current.scopes, **cand.scopes()},
    )
    # parameters the candidate adds to the current model (its own and the base parameters
    # it makes observable that the current model did not fit)
    current_free = {p.name for p in current.parameters}
    n_extra = len(cand.parameters) + sum(p.name not in current_free for p in cand.refit_base)
    try:
        # a candidate that changes the piston's friction law moves the static friction's
        # stick-event basins: it gets the restarts the base calibration had; the others
        # start from the calibrated base's basin
        fit = run_fit(problem, start=start, max_nfev=nfev, friction_restarts=cand.requires_motion)
    except (ValueError, FloatingPointError) as exc:  # e.g. a parameter set the kernel rejects
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
    nrmse, _ = split.heldout_nrmse(fit)
    mean = _mean(nrmse)
    rel = (current_mean - mean) / current_mean if current_mean > 0 else 0.0
    # BIC(candidate) - BIC(current): N_eff ln(RSS_c / RSS_m) + (extra parameters) ln(N_eff)
    delta_ic = _ic(fit.rss, n_res, n_eff, n_extra) - _ic(current.rss, n_res, n_eff, 0)
    plausible = all(fit.plausible[p.name] for p in cand.parameters)
    identified = True
    reasons = []
    for p in cand.parameters:
        lo, hi = fit.ci[p.name]
        if not fit.identified[p.name]:
            identified = False
            reasons.append(f"{p.name} not identified ({'; '.join(fit.flags[p.name])})")
        elif p.neutral is not None and lo <= p.neutral <= hi:
            identified = False
            reasons.append(
                f"{p.name}: its confidence interval [{lo:.3g}, {hi:.3g}] contains the "
                f"neutral value {p.neutral:g} (effect off)"
            )
        if not fit.plausible[p.name]:
            reasons.append(
                f"{p.name} = {fit.values[p.name]:.4g} {p.unit} is outside the plausible "
                f"range [{p.plausible_min:g}, {p.plausible_max:g}]"
            )
    if rel < min_rel:
        reasons.append(f"held-out improvement {100 * rel:.1f} % < {100 * min_rel:.0f} %")
    if delta_ic > -min_ic:
        reasons.append(f"BIC change {delta_ic:.1f} > -{min_ic:g}")
    accepted = rel >= min_rel and delta_ic <= -min_ic and plausible and identified
    return CandidateScore(
        cand, rnd, fit, nrmse, mean, rel, delta_ic, plausible, identified, accepted, reasons
    )
