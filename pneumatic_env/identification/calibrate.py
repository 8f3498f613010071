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

One :class:`~pneumatic_env.simulator.BatchSimulator` rollout per recording evaluates many
parameter sets at once: a forward-difference Jacobian is one rollout with one column per
perturbed plant parameter; sensor-side parameters (:mod:`.candidates`) only re-filter
the unperturbed simulation.

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

import logging
import math
import os
from collections import OrderedDict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from pneumatic_env.ids import MODE_FIXED
from pneumatic_env.params import ConfigError, parameter_array, save_parameters
from pneumatic_env.recording import Recording
from pneumatic_env.replay import PREDICTED_CHANNELS
from pneumatic_env.simulator import BatchSimulator

from . import progress
from .candidates import SENSOR_NEUTRAL, apply_sensor_model
from .config import FitParameter, IdentificationConfig, load_config
from .datasets import (
    _ROW,
    Dataset,
    base_fit_parameters,
    channel_scale,
    dataset_overrides,
    kernel_name,
    prepare_datasets,
)
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
PREDICTED_CHANNELS_ORDER = tuple(PREDICTED_CHANNELS)
#: The piston's friction parameters: they act only on a rod that moves.
FRICTION_NAMES = ("static_friction_n", "dynamic_friction_n", "viscous_friction_n_s_per_m")


# --------------------------------------------------------------------------- the problem


def _simulate(
    ds: Dataset,
    columns: Sequence[Mapping[str, float]],
    n_samples: int,
    scopes: Mapping[str, Sequence[str]] | None = None,
    column_scopes: Sequence[Mapping[str, Sequence[str]]] | None = None,
) -> dict[str, np.ndarray]:
    """True (plant) channels of ``ds`` for each column of overrides: ``(n_samples, m)``.

    ``column_scopes[j]`` (default: ``scopes`` for every column) scopes column j's values.
    Columns whose rod moves and columns whose rod is clamped are simulated in separate
    batches, each at its own substep. The work done is reported to :mod:`.progress`.
    """
    m = len(columns)
    base = parameter_array([ds.values])
    arr = np.repeat(base, m, axis=1)
    for j, overrides in enumerate(columns):
        sc = scopes if column_scopes is None else column_scopes[j]
        for name, v in dataset_overrides(ds, overrides, sc).items():
            arr[_ROW[name], j] = v
    moving = arr[_ROW["piston_mode"]] != MODE_FIXED
    out = np.empty((n_samples, len(PREDICTED_CHANNELS_ORDER), m))
    for group in (np.flatnonzero(~moving), np.flatnonzero(moving)):
        if group.size == 0:
            continue
        substeps = ds.substeps_moving if moving[group[0]] and ds.substeps_moving else ds.substeps
        sim = BatchSimulator(np.ascontiguousarray(arr[:, group]), ds.dt_s, substeps)
        if ds.initial:
            sim.reset(initial=ds.initial)
        first = sim.outputs.copy()
        currents = np.repeat(ds.recording.i_c[: n_samples - 1, None], group.size, axis=1)
        rows = np.concatenate([first[None], sim.rollout(currents)], axis=0)
        out[:, :, group] = rows[:, [PREDICTED_CHANNELS[c] for c in PREDICTED_CHANNELS_ORDER], :]
        progress.advance(n_samples * substeps * group.size)
    return {ch: out[:, PREDICTED_CHANNELS_ORDER.index(ch), :] for ch in ds.channels}


def simulate_unique(
    ds: Dataset,
    columns: Sequence[Mapping[str, float | str]],
    n_samples: int,
    column_scopes: Sequence[Mapping[str, Sequence[str]]],
) -> dict[str, np.ndarray]:
    """:func:`_simulate` of ``columns``, each plant that reaches ``ds`` simulated once: a
    value scoped away from its rod mode, or the piston's friction on a clamped rod, does
    not make a column differ."""
    keys, unique = [], {}
    for plant, scopes in zip(columns, column_scopes):
        resolved = dataset_overrides(ds, plant, scopes)
        if ds.rod_mode == "fixed" and resolved.get("piston_mode", MODE_FIXED) == MODE_FIXED:
            resolved = {k: v for k, v in resolved.items() if k not in FRICTION_NAMES}
        key = tuple(sorted(resolved.items()))
        unique.setdefault(key, resolved)
        keys.append(key)
    order = list(unique)
    sims = _simulate(ds, [unique[k] for k in order], n_samples)
    idx = [order.index(k) for k in keys]
    return {c: y[:, idx] for c, y in sims.items()}


class FitProblem:
    """Residuals and Jacobian of a set of datasets for some free parameters.

    ``fixed`` holds values (plant or sensor) applied to every dataset (a plant value may
    be a kernel parameter's name, resolved per dataset); ``scopes`` limits plant names to
    datasets of some rod modes (:func:`dataset_overrides`); ``n_samples[k]`` is how much
    of dataset k is simulated and ``masks[k][ch]`` which samples count.
    """

    def __init__(
        self,
        datasets: Sequence[Dataset],
        free: Sequence[FitParameter],
        fixed: Mapping[str, float | str] | None = None,
        n_samples: Sequence[int] | None = None,
        masks: Sequence[Mapping[str, np.ndarray]] | None = None,
        config: IdentificationConfig | None = None,
        label: str = "fit",
        scopes: Mapping[str, Sequence[str]] | None = None,
    ):
        self.config = config or load_config()
        self.datasets = list(datasets)
        self.free = list(free)
        names = [p.name for p in self.free]
        if len(set(names)) != len(names):
            raise ValueError(f"free parameters repeat a name: {names}")
        for p in self.free:
            if p.kind == "plant" and p.name not in _ROW:
                raise ConfigError(f"{p.name!r} is not a kernel parameter")
        self.fixed = dict(fixed or {})
        for key, v in self.fixed.items():
            name = kernel_name(key)
            if name not in _ROW and name not in SENSOR_NEUTRAL:
                raise ConfigError(f"fixed value {key!r} is neither a kernel nor a sensor parameter")
            if isinstance(v, str) and (name not in _ROW or v not in _ROW):
                raise ConfigError(
                    f"fixed value {name!r} = {v!r} is not allowed: a text value "
                    "must name a kernel parameter, for a kernel parameter"
                )
        self.scopes = {k: tuple(v) for k, v in (scopes or {}).items()}
        for name in self.scopes:
            if name not in _ROW:
                raise ConfigError(f"scoped value {name!r} is not a kernel parameter")
        self.n_samples = (
            list(n_samples) if n_samples is not None else [ds.n_samples for ds in self.datasets]
        )
        if masks is None:
            masks = [{c: np.ones(ds.n_samples, bool) for c in ds.channels} for ds in self.datasets]
        self.masks = []
        for ds, n, mask in zip(self.datasets, self.n_samples, masks):
            self.masks.append({c: (mask[c] & ds.usable[c])[:n] for c in ds.channels})
        self.label = label
        self.fd_step = float(self.config.number("fit", "fd_relative_step", positive=True))
        self._cache: OrderedDict = OrderedDict()
        self._jac_cache: OrderedDict = OrderedDict()
        self.n_jacobians = 0
        self.cost_history: list[float] = []  # robust cost at each Jacobian (accepted points)
        self.blocks = self._blocks()

    # -- parameter vectors ----------------------------------------------------------------
    def values(self, u: np.ndarray) -> dict[str, float]:
        """Free parameter values (physical units) of the optimiser vector ``u``."""
        return {p.name: p.from_u(float(x)) for p, x in zip(self.free, u)}

    def initial_u(self, start: Mapping[str, float] | None = None) -> np.ndarray:
        """Warm start: ``start``, else the parameter's ``initial``, else the data's value."""
        start = dict(start or {})
        u = []
        for p in self.free:
            if p.name in start:
                v = start[p.name]
            elif p.name in self.fixed:
                v = self.fixed[p.name]
            elif p.initial is not None:
                v = p.initial
            elif p.kind == "plant":
                v = self.datasets[0].values[p.name]
            else:
                v = SENSOR_NEUTRAL[p.name]
            v = min(max(v, p.lower), p.upper)
            u.append(p.to_u(v))
        return np.array(u, dtype=float)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        lo, hi = zip(*(p.bounds_u for p in self.free)) if self.free else ((), ())
        return np.array(lo, dtype=float), np.array(hi, dtype=float)

    def _split(self, values: Mapping[str, float]) -> tuple[dict, dict]:
        plant = {k: v for k, v in self.fixed.items() if kernel_name(k) in _ROW}
        sensor = {k: v for k, v in self.fixed.items() if k in SENSOR_NEUTRAL}
        for p in self.free:
            (plant if p.kind == "plant" else sensor)[p.name] = values[p.name]
        return plant, sensor

    # -- simulation -----------------------------------------------------------------------
    def _plant(self, u: np.ndarray) -> list[dict[str, np.ndarray]]:
        key = np.asarray(u, float).tobytes()
        if key in self._cache:
            return self._cache[key]
        plant, _ = self._split(self.values(u))
        out = [
            _simulate(ds, [plant], n, self.scopes) for ds, n in zip(self.datasets, self.n_samples)
        ]
        self._cache[key] = out
        while len(self._cache) > 4:
            self._cache.popitem(last=False)
        return out

    def predict(
        self, u: np.ndarray, n_samples: Sequence[int] | None = None
    ) -> list[dict[str, np.ndarray]]:
        """Recorded-channel predictions ``(n,)`` per dataset (plant then sensor model).

        ``n_samples`` other than the problem's simulates that many samples (e.g. a whole
        recording after fitting on its start).
        """
        plant, sensor = self._split(self.values(u))
        if n_samples is None:
            sims = self._plant(u)
        else:
            sims = [
                _simulate(ds, [plant], n, self.scopes) for ds, n in zip(self.datasets, n_samples)
            ]
        return [
            {c: y[:, 0] for c, y in apply_sensor_model(sim, [sensor], ds.dt_s).items()}
            for ds, sim in zip(self.datasets, sims)
        ]

    def _blocks(self) -> list[tuple[int, str, int, int]]:
        blocks, start = [], 0
        for k, (ds, mask) in enumerate(zip(self.datasets, self.masks)):
            for c in ds.channels:
                stop = start + int(mask[c].sum())
                blocks.append((k, c, start, stop))
                start = stop
        return blocks

    def _residual_of(self, preds: Sequence[Mapping[str, np.ndarray]]) -> np.ndarray:
        """Stack ``(pred - measured) / scale`` over datasets, channels and masked samples.

        ``preds[k][c]`` may be ``(n,)`` or ``(n, m)`` (one residual column per column).
        """
        parts = []
        for ds, n, mask, pred in zip(self.datasets, self.n_samples, self.masks, preds):
            for c in ds.channels:
                y = pred[c][:n]
                meas = ds.measured(c)[:n]
                if y.ndim == 2:
                    meas = meas[:, None]
                parts.append(((y - meas) / ds.scales[c])[mask[c]])
        return np.concatenate(parts, axis=0)

    def residual(self, u: np.ndarray) -> np.ndarray:
        return self._residual_of(self.predict(u))

    def robust_cost(self, r: np.ndarray) -> float:
        """The cost ``least_squares`` minimises: ``f^2 sum(sqrt(1 + (r/f)^2) - 1)`` for the
        ``soft_l1`` loss (``0.5 sum r^2`` for ``linear``), ``f`` = ``fit.f_scale``."""
        if str(self.config.fit("loss")) == "linear":
            return 0.5 * float(r @ r)
        f = self.config.number("fit", "f_scale", positive=True)
        if str(self.config.fit("loss")) != "soft_l1":
            raise ConfigError(
                f"fit.loss = {self.config.fit('loss')!r} is not allowed: must be "
                "'soft_l1' or 'linear'"
            )
        return float(f * f * np.sum(np.sqrt(1.0 + (r / f) ** 2) - 1.0))

    def residual_columns(self, us: Sequence[np.ndarray]) -> np.ndarray:
        """Residuals ``(n, m)`` of several optimiser vectors, one batch rollout per dataset.

        Columns that give a dataset the same plant are simulated once (the piston's
        friction does not act on a clamped rod).
        """
        splits = [self._split(self.values(u)) for u in us]
        preds = []
        for ds, n in zip(self.datasets, self.n_samples):
            sims = simulate_unique(
                ds, [plant for plant, _ in splits], n, [self.scopes] * len(splits)
            )
            preds.append(apply_sensor_model(sims, [se for _, se in splits], ds.dt_s))
        return self._residual_of(preds)

    def jacobian(self, u: np.ndarray) -> np.ndarray:
        """Forward-difference Jacobian: one batch rollout per dataset for all plant columns."""
        key = np.asarray(u, float).tobytes()
        if key in self._jac_cache:
            return self._jac_cache[key]
        values = self.values(u)
        plant, sensor = self._split(values)
        base_sims = self._plant(u)
        lo, hi = self.bounds()
        steps, perturbed = [], []
        for j, p in enumerate(self.free):
            h = p.fd_step if p.fd_step is not None else self.fd_step * max(1.0, abs(u[j]))
            if u[j] + h > hi[j]:
                h = -h
            uj = u.copy()
            uj[j] += h
            steps.append(h)
            perturbed.append(self.values(uj)[p.name])
        plant_idx = [j for j, p in enumerate(self.free) if p.kind == "plant"]
        sensor_idx = [j for j, p in enumerate(self.free) if p.kind == "sensor"]
        base_res = self.residual(u)
        J = np.empty((base_res.size, len(self.free)))
        col_preds = [dict() for _ in self.datasets]  # per dataset: channel -> (n, n_free)
        for k, (ds, n) in enumerate(zip(self.datasets, self.n_samples)):
            columns = []
            for j in plant_idx:
                columns.append({**plant, self.free[j].name: perturbed[j]})
            sims = _simulate(ds, columns, n, self.scopes) if columns else {}
            sensor_cols = [sensor] * len(plant_idx)
            for j in sensor_idx:
                sensor_cols.append({**sensor, self.free[j].name: perturbed[j]})
            merged = {}
            for c in ds.channels:
                parts = []
                if plant_idx:
                    parts.append(sims[c])
                if sensor_idx:
                    parts.append(np.repeat(base_sims[k][c], len(sensor_idx), axis=1))
                merged[c] = np.concatenate(parts, axis=1)
            filtered = apply_sensor_model(merged, sensor_cols, ds.dt_s)
            order = plant_idx + sensor_idx
            for c in ds.channels:
                full = np.empty_like(filtered[c])
                full[:, order] = filtered[c]
                col_preds[k][c] = full
        R = self._residual_of(col_preds)
        J[:] = (R - base_res[:, None]) / np.array(steps)[None, :]
        self.n_jacobians += 1
        self.cost_history.append(self.robust_cost(base_res))
        log.info(
            "%s: Jacobian %d, cost %.6g, %s",
            self.label,
            self.n_jacobians,
            0.5 * float(base_res @ base_res),
            ", ".join(f"{p.name}={values[p.name]:.4g}" for p in self.free),
        )
        self._jac_cache[key] = J
        while len(self._jac_cache) > 2:
            self._jac_cache.popitem(last=False)
        return J


def _least_squares(
    problem: FitProblem, u0: np.ndarray, max_nfev: int, tolerance: float | None = None
):
    """SciPy's robust least squares on ``problem`` from ``u0`` (settings under ``fit``);
    ``tolerance`` is its ``ftol`` and ``xtol`` (default SciPy's 1e-8)."""
    cfg = problem.config
    lo, hi = problem.bounds()
    tol = {} if tolerance is None else {"ftol": tolerance, "xtol": tolerance}
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


def _coordinate_search(
    problem: FitProblem, u: np.ndarray, names: Sequence[str], factors: Sequence[float]
) -> tuple[np.ndarray, float]:
    """The robust cost at ``u`` and at each parameter in ``names`` times each factor (one
    parameter at a time, the others at ``u``, within its bounds), all in one batch rollout
    per dataset; returns the best vector and its cost."""
    free = [p.name for p in problem.free]
    us = [u]
    for name in names:
        i = free.index(name)
        p = problem.free[i]
        for factor in factors:
            v = u.copy()
            v[i] = p.to_u(min(max(p.from_u(float(u[i])) * factor, p.lower), p.upper))
            us.append(v)
    costs = [problem.robust_cost(r) for r in problem.residual_columns(us).T]
    best = int(np.argmin(costs))
    return us[best], float(costs[best])


def _basin_search(
    problem: FitProblem, u: np.ndarray, names: Sequence[str]
) -> tuple[np.ndarray, float]:
    """A 1-D search of each parameter in ``names`` by the factors of
    ``fit.friction_law_search``: a friction law's parameters (a Stribeck velocity) decide
    stick events as the static friction does (:func:`_friction_search`)."""
    factors = problem.config.positive_numbers("fit", "friction_law_search")
    return _coordinate_search(problem, u, names, factors)


def _friction_search(problem: FitProblem, u: np.ndarray) -> tuple[np.ndarray, float]:
    """A 1-D search of the static friction around ``u``: the robust cost at the static
    friction times 1 and each factor of ``fit.static_friction_restarts`` (within its
    bounds), all in one batch rollout per dataset; returns the best vector and its cost.

    A sliding piston's free-run error is a staircase in the static friction (it decides
    whether and when the rod sticks): the error has one basin per sequence of stick
    events, and a gradient step cannot leave the basin it starts in. The search picks the
    basin; the least-squares fit then converges inside it.
    """
    factors = problem.config.positive_numbers("fit", "static_friction_restarts")
    return _coordinate_search(problem, u, ["static_friction_n"], factors)


def run_fit(
    problem: FitProblem,
    start: Mapping[str, float] | None = None,
    max_nfev: int | None = None,
    friction_restarts: bool = True,
    tolerance: float | None = None,
    basin_search: Sequence[str] = (),
) -> FitResult:
    """Least-squares fit of ``problem`` from the warm start; statistics at the optimum.

    With ``friction_restarts``, a fit that frees the static friction on data with a moving
    rod brackets each least-squares fit by :func:`_friction_search` (before it, and after
    it up to ``fit.friction_searches`` times: a better basin found is fitted again). Every
    accepted point lowers the robust cost (``cost_history``); the number of Jacobians is
    at most ``(1 + friction_searches) max_nfev``; ``message`` states why it stopped.
    ``tolerance``: the relative change of cost and parameters below which it stops.
    ``basin_search``: free parameters of a friction law searched (:func:`_basin_search`)
    before the first least-squares fit, on data with a moving rod.
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
        notes = []
        if search:
            u0, cost0 = _friction_search(problem, u0)
            problem.cost_history.append(cost0)
        if basin_search and any(ds.moving for ds in problem.datasets):
            u0, cost0 = _basin_search(problem, u0, basin_search)
            problem.cost_history.append(cost0)
        sol = _least_squares(problem, u0, max_nfev, tolerance)
        nfev = int(sol.nfev)
        u, cost = sol.x, float(sol.cost)
        message = str(sol.message)
        searches = int(cfg.number("fit", "friction_searches", minimum=0)) if search else 0
        for k in range(searches):
            u_next, cost_next = _friction_search(problem, u)
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
    else:
        u, nfev, message = u0, 1, "nothing to fit"
    r = problem.residual(u)
    if problem.free:
        stats = _statistics(problem, u, r, problem.jacobian(u))
    else:
        rho = min(
            max(pooled_lag1(r, problem.blocks), 0.0), cfg.number("fit", "max_autocorrelation")
        )
        stats = {
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
