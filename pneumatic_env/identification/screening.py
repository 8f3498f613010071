"""Screening: rank the whole candidate catalogue before any candidate is refitted.

From the current model (the calibrated base, later with the selected effects) one
Gauss-Newton step per candidate predicts what its refit would give:

1. the current model's residual ``r`` and Jacobian ``J`` (its refitted parameters but the
   piston's friction, whose free-run derivative is a staircase) over every recording,
   training and held-out samples alike;
2. per candidate, the model with the effect at its warm start (its ``set`` values and
   each parameter's ``initial``; the neutral value where no warm start is given) and the
   forward-difference columns of its parameters there; where the effect's parameters have
   a finite neutral value (not fitted in log10) also at the neutral point (a score test),
   and for effects fitted in log10 also one decade either side of the warm start; the
   best prediction counts. Every plant candidate's columns of
   every recording are one call of :func:`.problem.simulate_jobs`; sensor candidates
   only re-filter the current simulation;
   A moving rod is simulated at ``screening.max_substep_moving_s`` (coarser than the
   fits' substep: the same model for the current fit and every candidate);
3. the step ``delta`` minimising ``|r_c + [J, J_c] delta|`` on the training rows (the
   effect's parameters clipped to their bounds); its predictions of the training and
   held-out errors are compared with the same step for the current model alone.

The ranking is the linearised BIC change on the training rows (``N_eff ln(RSS_c /
RSS) + k ln(N_eff)``, the effective sample size of the current fit): the step's
prediction where it was fitted. The predicted held-out improvement is reported too but
does not rank: a linear step extrapolates poorly to held-out data of a moving rod (a
leak's prediction on a small campaign: 91 % better on the training rows, -140 % on the
held-out end of its spring recording, where the refit is right). Only the top few
are refitted, whatever their prediction (``screening.refit_top`` in
``configs/identification.yaml``): a linear step from a warm start far from the truth can
predict too little for an effect that is there; ``--quick`` stops here.
The linear prediction is a ranking, not a verdict: acceptance is decided by the refits.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from pneumatic_env.replay import substeps_for

from .calibrate import Dataset, FitResult
from .candidates import Candidate, apply_sensor_model
from .config import FitParameter, IdentificationConfig
from .holdout import index_of
from .problem import FRICTION_NAMES, FitProblem, simulate_unique_jobs

__all__ = ["Screen", "screen_candidates"]

log = logging.getLogger("pneumatic_env.identification")
#: Singular values of the column-normalised step problem below this fraction of the
#: largest are cut (a truncated SVD): a near-collinear direction would otherwise give a
#: huge linear step that fits the training rows and extrapolates wildly held out.
SVD_CUTOFF = 1e-3


@dataclass
class Screen:
    """The screening's prediction for one candidate."""

    candidate: Candidate
    predicted_heldout: float  # relative drop of the mean held-out NRMSE (linearised)
    predicted_train: float  # relative drop of the training residual sum of squares
    predicted_delta_ic: float = math.nan  # linearised BIC change on the training rows
    per_recording: dict[str, float] = field(default_factory=dict)  # held-out, per recording
    values: dict[str, float] = field(default_factory=dict)  # effect parameters after the step

    @property
    def name(self) -> str:
        return self.candidate.name

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "predicted_heldout_improvement": _num(self.predicted_heldout),
            "predicted_training_improvement": _num(self.predicted_train),
            "predicted_delta_ic": _num(self.predicted_delta_ic),
            "predicted_per_recording": {k: _num(v) for k, v in self.per_recording.items()},
            "step_values": {k: _num(v) for k, v in self.values.items()},
        }


def _num(x: float):
    return float(x) if math.isfinite(x) else None


def _start_value(p: FitParameter, current: Mapping[str, float | str], ds: Dataset) -> float:
    if p.name in current and not isinstance(current[p.name], str):
        v = float(current[p.name])
    elif p.initial is not None:
        v = p.initial
    elif p.neutral is not None and math.isfinite(p.neutral):
        v = p.neutral
    else:
        v = float(ds.values[p.name])
    return min(max(v, p.lower), p.upper)


def _row_sets(
    problem: FitProblem,
    train: Sequence[Dataset],
    train_n: Sequence[int],
    held: Sequence[Dataset],
    held_masks,
) -> tuple[np.ndarray, list]:
    """Training rows (mask) and, per held-out (dataset, channel), its rows."""
    n_rows = problem.blocks[-1][3] if problem.blocks else 0
    is_train = np.zeros(n_rows, dtype=bool)
    held_rows = []
    for k, c, a, b in problem.blocks:
        ds = problem.datasets[k]
        idx = np.flatnonzero(problem.masks[k][c])
        rows = np.arange(a, b)
        k_train, k_held = index_of(ds, train), index_of(ds, held)
        if k_train >= 0:
            is_train[rows[idx < train_n[k_train]]] = True
        if k_held >= 0:
            keep = held_masks[k_held][c][idx]
            held_rows.append((ds.name, c, rows[keep]))
    return is_train, held_rows


def _heldout_mean(r: np.ndarray, held_rows) -> tuple[float, dict[str, float]]:
    """Mean over channels of the pooled held-out NRMSE, and per recording."""
    sums: dict[str, float] = {}
    counts: dict[str, int] = {}
    per: dict[str, list] = {}
    for name, c, rows in held_rows:
        e = r[rows]
        sums[c] = sums.get(c, 0.0) + float(e @ e)
        counts[c] = counts.get(c, 0) + rows.size
        if rows.size:
            per.setdefault(name, []).append(math.sqrt(float(e @ e) / rows.size))
    chans = [math.sqrt(sums[c] / counts[c]) for c in sums if counts[c]]
    return (
        float(np.mean(chans)) if chans else math.nan,
        {k: float(np.mean(v)) for k, v in per.items()},
    )


def _gauss_newton(
    r: np.ndarray,
    A: np.ndarray,
    rows: np.ndarray,
    free_lo: np.ndarray,
    free_hi: np.ndarray,
    clip_from: int,
) -> np.ndarray:
    """The step minimising ``|r + A d|`` on ``rows`` (columns normalised, tiny ones
    dropped); components from ``clip_from`` on are clipped to ``[free_lo, free_hi]`` and
    the others refitted with them held."""
    At, rt = A[rows], r[rows]
    norms = np.linalg.norm(At, axis=0)
    ok = norms > 1e-12 * max(float(norms.max(initial=0.0)), 1e-300)
    d = np.zeros(A.shape[1])
    if not ok.any():
        return d
    sol = np.linalg.lstsq(At[:, ok] / norms[ok], -rt, rcond=SVD_CUTOFF)[0]
    d[ok] = sol / norms[ok]
    if clip_from < A.shape[1]:
        clipped = np.clip(d[clip_from:], free_lo, free_hi)
        if not np.allclose(clipped, d[clip_from:]):
            d[clip_from:] = clipped
            base = np.flatnonzero(ok[:clip_from])
            if base.size:
                rest = rt + At[:, clip_from:] @ clipped
                sol = np.linalg.lstsq(At[:, base] / norms[base], -rest, rcond=SVD_CUTOFF)[0]
                d[base] = sol / norms[base]
    return d


def _spec(cand: Candidate, params: Sequence[FitParameter], start: dict, fd: float) -> tuple:
    """(candidate, parameters, start, forward-difference steps, perturbed values)."""
    steps, perturbed = [], []
    for p in params:
        u = p.to_u(start[p.name])
        h = p.fd_step if p.fd_step is not None else fd * max(1.0, abs(u))
        if u + h > p.bounds_u[1]:
            h = -h
        steps.append(h)
        perturbed.append(p.from_u(u + h))
    return cand, list(params), start, steps, perturbed


def coarse_dataset(ds: Dataset, config: IdentificationConfig) -> Dataset:
    """``ds`` with the screening's coarser substep for a moving rod
    (``screening.max_substep_moving_s``): the screening's model, and the base fit's while
    it is far from its optimum (:func:`.diagnose._fit_base`)."""
    coarse = substeps_for(
        ds.dt_s, config.number("screening", "max_substep_moving_s", positive=True)
    )
    return replace(
        ds,
        substeps=coarse if ds.moving or ds.rod_mode != "fixed" else ds.substeps,
        substeps_moving=coarse,
    )


def _coarse_datasets(
    datasets: Sequence[Dataset],
    train: Sequence[Dataset],
    held: Sequence[Dataset],
    config: IdentificationConfig,
) -> tuple[list[Dataset], list[Dataset], list[Dataset]]:
    """``datasets``, ``train`` and ``held`` as :func:`coarse_dataset` (a ranking: the
    current model and every candidate see the same model)."""
    screen_ds = [coarse_dataset(ds, config) for ds in datasets]
    train = [screen_ds[index_of(ds, datasets)] for ds in train]
    held = [screen_ds[index_of(ds, datasets)] for ds in held]
    return screen_ds, train, held


def _starts(cand: Candidate, params: Sequence[FitParameter], values: dict, ds0, log_starts):
    """A candidate's starting points: the warm start; where every parameter has a neutral
    value it can be differentiated at (finite, not fitted in log10), the neutral point
    (the score test: the current model with the effect off); for log10 parameters, the
    warm start times each of ``log_starts``."""
    starts = [{p.name: _start_value(p, values, ds0) for p in params}]
    neutral = {p.name: p.neutral for p in cand.parameters if p.neutral is not None}
    if len(neutral) == len(cand.parameters) and all(
        math.isfinite(neutral[p.name]) and not p.log and p.lower <= neutral[p.name] <= p.upper
        for p in cand.parameters
    ):
        starts.append({**starts[0], **neutral})
    logs = [p for p in cand.parameters if p.log]
    for factor in log_starts if logs else ():
        starts.append(
            {
                **starts[0],
                **{p.name: min(max(starts[0][p.name] * factor, p.lower), p.upper) for p in logs},
            }
        )
    return starts


def _simulate_columns(
    datasets: Sequence[Dataset],
    n_samples: Sequence[int],
    specs: Sequence[tuple],
    base_sims: Sequence[dict],
    plant_now: dict,
    sensor_now: dict,
    scopes,
) -> list[dict]:
    """Per dataset k, predictions on its first ``n_samples[k]`` of every spec's start and
    perturbed columns (the plant columns of every dataset in one batch simulation; a
    sensor candidate reuses ``base_sims[k]``)."""
    plant_cols, plant_scopes, sensor_cols, owner = [], [], [], []
    sensor_parts = []
    for cand, params, start, _, perturbed in specs:
        variants = [dict(start)] + [{**start, p.name: v} for p, v in zip(params, perturbed)]
        for var in variants:
            if cand.kind == "plant":
                plant_cols.append({**plant_now, **cand.scoped_set(), **var})
                plant_scopes.append({**scopes, **cand.scopes()})
                sensor_cols.append(dict(sensor_now))
                owner.append(("plant", len(plant_cols) - 1))
            else:
                sensor_parts.append({**sensor_now, **var})
                owner.append(("sensor", len(sensor_parts) - 1))
    jobs = [(ds, plant_cols, n, plant_scopes) for ds, n in zip(datasets, n_samples)]
    all_sims = simulate_unique_jobs(jobs) if plant_cols else [{} for _ in datasets]
    sensors = [sensor_cols[j] if kind == "plant" else sensor_parts[j] for kind, j in owner]
    preds = []
    for ds, sims, base_sim in zip(datasets, all_sims, base_sims):
        merged = {}
        for c in ds.channels:
            cols = [sims[c][:, j] if kind == "plant" else base_sim[c][:, 0] for kind, j in owner]
            merged[c] = np.stack(cols, axis=1)
        preds.append(apply_sensor_model(merged, sensors, ds.dt_s))
    return preds


def screen_candidates(
    candidates: Sequence[Candidate],
    current: FitResult,
    free: Sequence[FitParameter],
    datasets: Sequence[Dataset],
    train: Sequence[Dataset],
    train_n: Sequence[int],
    held: Sequence[Dataset],
    held_masks,
    config: IdentificationConfig,
    training_only: bool = False,
) -> list[Screen]:
    """Predicted held-out improvement of each candidate over ``current`` (best first).

    ``free`` are the current model's refitted parameters; ``train``/``train_n`` the
    training recordings and samples, ``held``/``held_masks`` the held-out ones.
    ``training_only`` (``--quick``): simulate the training samples only, which is all the
    ranking reads; the held-out predictions are then NaN.
    """
    train_n = [train_n[k] for k in range(len(train))]
    n_samples = None
    if training_only:
        datasets, held, held_masks, n_samples = list(train), [], [], train_n
    datasets, train, held = _coarse_datasets(datasets, train, held, config)
    # the piston's friction stays at the current fit's values: its free-run derivative is
    # a staircase (stick events), so a linear step in it extrapolates wildly held out
    # (a leak's prediction fell from +93 % on the training rows to -142 % held out)
    free = [p for p in free if p.name not in FRICTION_NAMES]
    names = {p.name for p in free}
    values = current.all_values()
    fixed = {k: v for k, v in values.items() if k not in names}
    problem = FitProblem(
        datasets,
        free,
        fixed=fixed,
        n_samples=n_samples,
        config=config,
        label="screening",
        scopes=current.scopes,
    )
    u0 = problem.initial_u(values)
    r_base = problem.residual(u0)
    J_base = problem.jacobian(u0)
    is_train, held_rows = _row_sets(problem, list(train), train_n, list(held), held_masks)
    fd = config.number("fit", "fd_relative_step", positive=True)
    plant_now, sensor_now = problem._split(problem.values(u0))

    # per candidate and starting point: the columns to simulate (the start, then one per
    # parameter)
    log_starts = config.positive_numbers("screening", "log_start_factors")
    specs = []
    for cand in candidates:
        extra = [p for p in cand.refit_base if p.name not in names]
        params = list(cand.parameters) + extra
        for start in _starts(cand, params, values, datasets[0], log_starts):
            specs.append(_spec(cand, params, start, fd))
    base_sims = problem._plant(u0)
    preds = _simulate_columns(
        datasets, problem.n_samples, specs, base_sims, plant_now, sensor_now, current.scopes
    )
    R = problem._residual_of(preds)

    lo, hi = problem.bounds()
    d_base = _gauss_newton(r_base, J_base, is_train, lo, hi, J_base.shape[1])
    base_pred = r_base + J_base @ d_base
    # effective sample size of the training rows (the current fit's autocorrelation)
    n_eff = current.n_eff / max(current.n_residuals, 1) * float(is_train.sum())
    out = _best_screens(specs, R, J_base, base_pred, is_train, held_rows, n_eff)
    log.info(
        "screening: %s",
        ", ".join(
            f"{s.name} {s.predicted_delta_ic:.0f} ({100 * s.predicted_train:.1f} %)" for s in out
        ),
    )
    return out


def _best_screens(
    specs: Sequence[tuple],
    R: np.ndarray,
    J_base: np.ndarray,
    base_pred: np.ndarray,
    is_train: np.ndarray,
    held_rows,
    n_eff: float,
) -> list[Screen]:
    """Each candidate's best starting point's Gauss-Newton step from the simulated columns
    ``R`` (next to the current model's Jacobian ``J_base``), scored; best first."""
    base_mean, base_per = _heldout_mean(base_pred, held_rows)
    base_train = float(base_pred[is_train] @ base_pred[is_train])
    best: dict[str, Screen] = {}
    col = 0
    for cand, params, start, steps, _ in specs:
        r0 = R[:, col]
        Jc = (R[:, col + 1 : col + 1 + len(params)] - r0[:, None]) / np.array(steps)[None, :]
        col += 1 + len(params)
        u_start = np.array([p.to_u(start[p.name]) for p in params])
        c_lo = np.array([p.bounds_u[0] for p in params]) - u_start
        c_hi = np.array([p.bounds_u[1] for p in params]) - u_start
        A = np.concatenate([J_base, Jc], axis=1)
        d = _gauss_newton(r0, A, is_train, c_lo, c_hi, J_base.shape[1])
        pred = r0 + A @ d
        mean, per = _heldout_mean(pred, held_rows)
        train_rss = float(pred[is_train] @ pred[is_train])
        step_values = {
            p.name: p.from_u(u + dj) for p, u, dj in zip(params, u_start, d[J_base.shape[1] :])
        }
        screen = Screen(
            cand,
            predicted_heldout=(
                (base_mean - mean) / base_mean
                if base_mean > 0
                else (math.nan if math.isnan(base_mean) else 0.0)
            ),
            predicted_train=1.0 - train_rss / base_train if base_train > 0 else 0.0,
            per_recording={
                k: (base_per[k] - per[k]) / base_per[k] if base_per[k] > 0 else 0.0 for k in per
            },
            values=step_values,
        )
        screen.predicted_delta_ic = n_eff * math.log(
            max(train_rss, 1e-300) / max(base_train, 1e-300)
        ) + len(cand.parameters) * math.log(max(n_eff, 2.0))
        if cand.name not in best or screen.predicted_delta_ic < best[cand.name].predicted_delta_ic:
            best[cand.name] = screen  # the best of the starting points
    return sorted(best.values(), key=lambda s: s.predicted_delta_ic)
