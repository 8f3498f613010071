"""Calibration: fit model parameters to recordings by free-run simulation error.

The recording's coil current drives the model from its initial state (the replay of
:mod:`pneumatic_env.replay`: sample k held from ``t[k]`` to ``t[k+1]``, sample 0 is the
initial state), and :func:`scipy.optimize.least_squares` (robust loss ``soft_l1``) moves
the free parameters to minimise the residual of every measured channel, each divided by
its scale (``supply - ambient`` for pressures, that times the cap area for the force,
half the stroke for ``x``, see ``channel_scales`` in ``configs/identification.yaml``).

Values applied on top of a recording's parameter set ("overrides": fitted or fixed) may
be *scoped* to recordings whose rod is in given modes, and a fixed value may be the name
of a kernel parameter, resolved per recording (:func:`dataset_overrides`; a candidate's
``rod_modes`` and ``set``, see :mod:`.candidates`). A parameter set whose rod moves is
simulated with the moving-piston substep even when the recording's rod was clamped.

The residual and its Jacobian are :class:`.problem.FitProblem`'s (batched rollouts);
this module minimises it (:func:`run_fit`) and wraps the base calibration.

A fit that frees the static friction on data with a moving rod picks its stick-event
basin by a 1-D search (one batch rollout, :func:`_friction_search`) before the fit and
around its optimum; every accepted point lowers the robust cost (``cost_history``).

Uncertainty (:mod:`.results`): the Gauss-Newton covariance ``s^2 (J^T J)^-1`` at the
optimum, with the
residual variance inflated by ``(1 + rho) / (1 - rho)``, rho the pooled lag-1
autocorrelation of the residuals (effective sample size ``N (1 - rho) / (1 + rho)``).
A parameter is *not identified* when its Jacobian column is zero, when it lies in a
near-singular direction of the column-normalised Jacobian, or when its confidence
interval is wider than its plausible range.
"""

from __future__ import annotations

import itertools
import logging
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import OptimizeResult, least_squares

from pneumatic_env.params import save_parameters
from pneumatic_env.recording import Recording

from .config import IdentificationConfig, load_config
from .datasets import (
    Dataset,
    base_fit_parameters,
    channel_scale,
    dataset_overrides,
    prepare_datasets,
)
from .problem import CostLevelledOff, CostPlateau, FitProblem, simulate_unique
from .results import FitResult, _statistics, pooled_lag1

__all__ = [
    "Calibration",
    "Dataset",
    "FitProblem",
    "FitResult",
    "base_fit_parameters",
    "pooled_lag1",
    "calibrate",
    "channel_nrmse",
    "channel_scale",
    "dataset_overrides",
    "prepare_datasets",
    "run_fit",
    "simulate_unique",
]

log = logging.getLogger("pneumatic_env.identification")


def _least_squares(
    problem: FitProblem, u0: np.ndarray, max_nfev: int, tolerance: float | None = None
):
    """SciPy's robust least squares on ``problem`` from ``u0`` (settings under ``fit``);
    ``tolerance`` is its ``ftol`` and ``xtol`` (default SciPy's 1e-8). With
    ``problem.plateau`` set, it also stops once the cost has levelled off
    (:class:`.problem.CostPlateau`; ``message`` says so)."""
    cfg = problem.config
    lo, hi = problem.bounds()
    tol = {} if tolerance is None else {"ftol": tolerance, "xtol": tolerance}
    problem.fit_costs = []
    try:
        return least_squares(
            problem.residual,
            u0,
            jac=problem.jacobian,
            bounds=(lo, hi),
            method="trf",
            tr_solver=str(cfg.fit("tr_solver")),
            loss=str(cfg.fit("loss")),
            f_scale=cfg.number("fit", "f_scale", positive=True),
            max_nfev=max_nfev,
            x_scale=1.0,
            **tol,
        )
    except CostPlateau as stop:  # nfev: the accepted points, one per Jacobian
        return OptimizeResult(
            x=stop.u, cost=stop.cost, nfev=len(problem.fit_costs), message=str(stop)
        )


def diagnosis_fit_stops(cfg: IdentificationConfig) -> dict:
    """The stopping rules of a diagnosis's fits (base, refits, re-convergence), as
    :func:`run_fit` keywords: ``fit.diagnosis_tolerance`` and the plateau
    (``fit.plateau_relative_decrease`` over ``fit.plateau_jacobians``)."""
    return {
        "tolerance": cfg.number("fit", "diagnosis_tolerance", positive=True),
        "plateau": (
            cfg.number("fit", "plateau_relative_decrease", minimum=0.0),
            int(cfg.number("fit", "plateau_jacobians", positive=True)),
        ),
    }


def _grid_columns(
    problem: FitProblem, u: np.ndarray, axes: Sequence[tuple[str, Sequence[float]]]
) -> list[np.ndarray]:
    """``u`` and ``u`` with the parameters of ``axes`` times every combination of their
    factors (each axis with factor 1 added; within the bounds)."""
    free = [p.name for p in problem.free]
    grids = [[1.0] + [f for f in factors if f != 1.0] for _, factors in axes]
    us = [u]
    for combo in itertools.product(*grids):
        if all(f == 1.0 for f in combo):
            continue
        v = u.copy()
        for (name, _), factor in zip(axes, combo):
            i = free.index(name)
            p = problem.free[i]
            v[i] = p.to_u(min(max(p.from_u(float(u[i])) * factor, p.lower), p.upper))
        us.append(v)
    return us


def _best_column(problem: FitProblem, us: Sequence[np.ndarray]) -> tuple[np.ndarray, float]:
    """The vector of ``us`` with the lowest robust cost (one batch rollout per dataset)."""
    costs = [problem.robust_cost(r) for r in problem.residual_columns(us).T]
    best = int(np.argmin(costs))
    return us[best], float(costs[best])


def _coordinate_search(
    problem: FitProblem, u: np.ndarray, names: Sequence[str], factors: Sequence[float]
) -> tuple[np.ndarray, float]:
    """The robust cost at ``u`` and at each parameter in ``names`` times each factor (one
    parameter at a time, the others at ``u``, within its bounds), all in one batch rollout
    per dataset; returns the best vector and its cost."""
    us = [u]
    for name in names:
        us += _grid_columns(problem, u, [(name, factors)])[1:]
    return _best_column(problem, us)


def _basin_search(
    problem: FitProblem, u: np.ndarray, names: Sequence[str]
) -> tuple[np.ndarray, float]:
    """A 1-D search of each parameter in ``names`` by the factors of
    ``fit.friction_law_search``: a friction law's parameters (a Stribeck velocity) decide
    stick events as the static friction does (:func:`_friction_search`)."""
    factors = problem.config.positive_numbers("fit", "friction_law_search")
    return _coordinate_search(problem, u, names, factors)


def _friction_search(
    problem: FitProblem, u: np.ndarray, joint: bool = False
) -> tuple[np.ndarray, float]:
    """A grid search of the piston's friction around ``u``: the robust cost at the static
    friction times 1 and each factor of ``fit.static_friction_restarts`` (within its
    bounds) and, with ``joint`` and a free dynamic friction, at every combination of those
    with the dynamic friction times each of ``fit.dynamic_friction_factors``, all in one
    batch rollout per dataset; returns the best vector and its cost.

    A sliding piston's free-run error is a staircase in the static friction (it decides
    whether and when the rod sticks): the error has one basin per sequence of stick
    events, and a gradient step cannot leave the basin it starts in. The search picks the
    basin; the least-squares fit then converges inside it. Where the stick events fall
    depends on the dynamic friction too (the speed at which the rod comes to rest): from a
    fit in a wrong basin the right static friction is no better unless the dynamic
    friction moves with it, hence the joint grid after a fit.
    """
    cfg = problem.config
    axes = [("static_friction_n", cfg.positive_numbers("fit", "static_friction_restarts"))]
    if joint and "dynamic_friction_n" in {p.name for p in problem.free}:
        axes.append(("dynamic_friction_n", cfg.positive_numbers("fit", "dynamic_friction_factors")))
    return _best_column(problem, _grid_columns(problem, u, axes))


def run_fit(
    problem: FitProblem,
    start: Mapping[str, float | str] | None = None,
    max_nfev: int | None = None,
    friction_restarts: bool = True,
    tolerance: float | None = None,
    basin_search: Sequence[str] = (),
    early_stop: tuple[float, int] | None = None,
    plateau: tuple[float, int] | None = None,
) -> FitResult:
    """Least-squares fit of ``problem`` from the warm start; statistics at the optimum.

    With ``friction_restarts``, a fit that frees the static friction on data with a moving
    rod brackets each least-squares fit by :func:`_friction_search`: before it when it
    starts from a given ``start`` (a fitted model; from the config's nominal values the
    cost is dominated by the other parameters' misfit and picks a basin at random: on a
    1 s spring and free campaign it led the fit to 0.45 x the rig's static friction),
    and after it (jointly with the dynamic friction) up to ``fit.friction_searches``
    times: a better basin found is fitted again. Every
    accepted point lowers the robust cost (``cost_history``); the number of Jacobians is
    at most ``(1 + friction_searches) max_nfev``; ``message`` states why it stopped.
    ``tolerance``: the relative change of cost and parameters below which it stops.
    ``basin_search``: free parameters of a friction law searched (:func:`_basin_search`)
    before the first least-squares fit, on data with a moving rod. ``early_stop``
    (relative decrease, Jacobians): stop the first least-squares fit at the first
    Jacobian, from the given count on, where the robust cost fell by less than that
    relative amount since the previous one (:class:`.problem.CostLevelledOff`; no friction
    search after it; ``message`` starts with "stopped early"): the point where screening
    may start, finished by a fit from it. ``plateau`` (relative decrease, Jacobians): stop
    each least-squares fit once its robust cost fell by less than that over that many
    Jacobians (:func:`diagnosis_fit_stops`).
    """
    cfg = problem.config
    u0 = problem.initial_u(start)
    max_nfev = int(max_nfev or cfg.number("fit", "max_nfev", positive=True))
    search = (
        friction_restarts
        and "static_friction_n" in {p.name for p in problem.free}
        and any(ds.moving for ds in problem.datasets)
    )
    if problem.free:
        problem.early_stop = early_stop
        problem.plateau = plateau
        try:
            u, nfev, message = _fit_free(
                problem, u0, start, max_nfev, search, tolerance, basin_search
            )
        finally:
            problem.early_stop = None
            problem.plateau = None
    else:
        u, nfev, message = u0, 1, "nothing to fit"
    r = problem.residual(u)
    if problem.free:
        stats = _statistics(problem, u, r, problem.jacobian(u))
    else:
        stats = _statistics_of_nothing_free(problem, r)
    log.info(
        "%s: done after %d evaluations, %d Jacobians (%s), cost %.6g",
        problem.label,
        nfev,
        problem.n_jacobians,
        message,
        0.5 * float(r @ r),
    )
    return FitResult(
        parameters=list(problem.free),
        values=problem.values(u),
        fixed=dict(problem.fixed),
        std=stats["std"],
        ci=stats["ci"],
        identified=stats["identified"],
        plausible=stats["plausible"],
        flags=stats["flags"],
        correlations=stats["correlations"],
        condition_number=stats["condition_number"],
        cost=0.5 * float(r @ r),
        rss=float(r @ r),
        n_residuals=int(r.size),
        rho1=float(stats["rho1"]),
        n_eff=float(stats["n_eff"]),
        nfev=nfev,
        message=message,
        u=u,
        scopes=dict(problem.scopes),
        cost_history=list(problem.cost_history),
        n_jacobians=problem.n_jacobians,
    )


def _fit_free(
    problem: FitProblem,
    u0: np.ndarray,
    start: Mapping[str, float | str] | None,
    max_nfev: int,
    search: bool,
    tolerance: float | None,
    basin_search: Sequence[str],
) -> tuple[np.ndarray, int, str]:
    """:func:`run_fit`'s searches and least-squares fits: the optimum, the number of
    evaluations and why it stopped (``search``: bracket by friction searches)."""
    notes = []
    if search and start is not None:
        u0, cost0 = _friction_search(problem, u0)
        problem.cost_history.append(cost0)
    if basin_search and any(ds.moving for ds in problem.datasets):
        u0, cost0 = _basin_search(problem, u0, basin_search)
        problem.cost_history.append(cost0)
    try:
        sol = _least_squares(problem, u0, max_nfev, tolerance)
    except CostLevelledOff as stop:  # the rest is the caller's (a fit from this point)
        return stop.u, problem.n_jacobians, f"stopped early: {stop}"
    nfev = int(sol.nfev)
    u, cost = sol.x, float(sol.cost)
    message = str(sol.message)
    searches = int(problem.config.number("fit", "friction_searches", minimum=0)) if search else 0
    for k in range(searches):
        u_next, cost_next = _friction_search(problem, u, joint=True)
        if not cost_next < cost:
            notes.append(f"friction search {k + 1}: no better stick-event basin")
            break
        problem.cost_history.append(cost_next)
        try:
            sol = _least_squares(problem, u_next, max_nfev, tolerance)
        except (ValueError, FloatingPointError) as exc:  # a start the kernel rejects
            notes.append(f"friction search {k + 1}: refit failed ({exc})")
            u, cost = u_next, cost_next
            break
        nfev += int(sol.nfev)
        u, cost, message = sol.x, float(sol.cost), str(sol.message)
        notes.append(f"friction search {k + 1}: a better basin, refitted")
    if notes:
        message = message + " (" + "; ".join(notes) + ")"
    return u, nfev, message


def _statistics_of_nothing_free(problem: FitProblem, r: np.ndarray) -> dict:
    """:func:`_statistics`'s keys when nothing is free: the residual's lag-1
    autocorrelation and effective sample size only."""
    rho = min(
        max(pooled_lag1(r, problem.blocks), 0.0),
        problem.config.number("fit", "max_autocorrelation"),
    )
    return {
        "std": {},
        "ci": {},
        "identified": {},
        "plausible": {},
        "flags": {},
        "correlations": [],
        "condition_number": 1.0,
        "rho1": rho,
        "n_eff": r.size * (1 - rho) / (1 + rho),
    }


def channel_nrmse(
    datasets: Sequence[Dataset],
    preds: Sequence[Mapping[str, np.ndarray]],
    masks: Sequence[Mapping[str, np.ndarray]],
) -> dict[str, float]:
    """Per channel, ``sqrt(mean(((pred - measured) / scale)^2))`` pooled over datasets."""
    sums: dict[str, float] = {}
    counts: dict[str, int] = {}
    for ds, pred, mask in zip(datasets, preds, masks):
        for c in ds.channels:
            m = mask[c] & ds.usable[c]
            e = (pred[c][m] - ds.measured(c)[m]) / ds.scales[c]
            sums[c] = sums.get(c, 0.0) + float(e @ e)
            counts[c] = counts.get(c, 0) + int(m.sum())
    return {c: math.sqrt(sums[c] / counts[c]) if counts[c] else math.nan for c in sums}


# --------------------------------------------------------------------------- calibrate


@dataclass
class Calibration:
    """Datasets, the fit problem and its result; :meth:`save` writes the fitted set."""

    datasets: list[Dataset]
    problem: FitProblem
    result: FitResult
    issues: list

    def parameter_set(self, k: int = 0) -> dict[str, float]:
        """Complete parameter set of dataset ``k`` with the fitted values."""
        return self.result.dataset_values(self.datasets[k])

    def predict(self, n_samples: Sequence[int] | None = None) -> list[dict[str, np.ndarray]]:
        """Predicted recorded channels of every dataset (whole recordings by default)."""
        n = n_samples or [ds.n_samples for ds in self.datasets]
        assert self.result.u is not None  # a fit's result keeps its point
        return self.problem.predict(self.result.u, n)

    def save(self, path: str | os.PathLike, notes: str = "") -> None:
        """Fitted kernel parameters as a file ``load_parameters(params=path)`` and
        ``gym.make(id, params=path)`` accept; sensor-side values are not kernel
        parameters and are not written (see diagnosis.json)."""
        values = self.result.file_values(self.datasets)
        std = {k: v for k, v in self.result.std.items() if k in values and math.isfinite(v)}
        names = ", ".join(ds.name for ds in self.datasets)
        save_parameters(
            path, values, notes=notes or f"pneumatic_env identify on {names}", uncertainties=std
        )


def calibrate(
    recordings: Sequence[Recording],
    params=None,
    fit: Sequence[str] | None = None,
    fixed: Mapping[str, float] | None = None,
    train_fraction: float | None = None,
    config: IdentificationConfig | None = None,
    max_nfev: int | None = None,
    datasets: Sequence[Dataset] | None = None,
) -> Calibration:
    """Fit the base parameters (``fit`` names, default from the config) to ``recordings``.

    ``train_fraction`` < 1 fits on the start of each recording only. ``fixed`` holds
    values (kernel or sensor) kept fixed. ``params`` is layered under the sidecars.
    """
    config = config or load_config()
    issues: list = []
    if datasets is None:
        datasets, issues = prepare_datasets(recordings, params, config)
    free = base_fit_parameters(datasets, fit, config)
    n_samples = None
    if train_fraction is not None:
        if not 0.0 < train_fraction <= 1.0:
            raise ValueError(
                f"train_fraction = {train_fraction!r} is not allowed: must be in (0, 1]"
            )
        n_samples = [max(2, int(round(train_fraction * ds.n_samples))) for ds in datasets]
    problem = FitProblem(
        datasets, free, fixed=fixed, n_samples=n_samples, config=config, label="calibration"
    )
    result = run_fit(problem, max_nfev=max_nfev)
    return Calibration(datasets=list(datasets), problem=problem, result=result, issues=issues)
