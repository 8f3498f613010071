"""The fit problem: free-run simulation error of parameter sets on recordings.

:class:`FitProblem` maps a vector of free parameters (scaled) to the residual of every
measured channel of every recording (one :class:`~pneumatic_env.simulator.BatchSimulator`
rollout per recording for many parameter sets at once: a forward-difference Jacobian is
one rollout with one column per perturbed plant parameter; sensor-side parameters only
re-filter the unperturbed simulation). The optimiser that minimises it is
:func:`.calibrate.run_fit`.
"""

from __future__ import annotations

import logging
import os
from collections import OrderedDict
from collections.abc import Iterator, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numba
import numpy as np

from pneumatic_env.ids import MODE_FIXED
from pneumatic_env.params import ConfigError, parameter_array
from pneumatic_env.physics.constants import lane_class_cost, lane_classes
from pneumatic_env.physics.layout import PARAMETER_INDEX as _ROW  # name -> row
from pneumatic_env.replay import PREDICTED_CHANNELS
from pneumatic_env.simulator import BatchSimulator

from . import progress
from .candidates import SENSOR_NEUTRAL, apply_sensor_model
from .config import FitParameter, IdentificationConfig, load_config
from .datasets import Dataset, dataset_overrides, kernel_name

log = logging.getLogger("pneumatic_env.identification")
PREDICTED_CHANNELS_ORDER = tuple(PREDICTED_CHANNELS)
#: The piston's friction parameters: they act only on a rod that moves.
FRICTION_NAMES = ("static_friction_n", "dynamic_friction_n", "viscous_friction_n_s_per_m")


#: One simulation job: a dataset, its columns of overrides, the samples to simulate, the
#: scopes of every column and, optionally, each column's own (``column_scopes[j]``, default
#: the job's scopes for every column).
SimulationJob = tuple[
    Dataset,
    Sequence[Mapping[str, float]],
    int,
    Mapping[str, Sequence[str]] | None,
    Sequence[Mapping[str, Sequence[str]]] | None,
]
_pools: dict[int, ThreadPoolExecutor] = {}  # thread count -> its pool


class CostLevelledOff(Exception):
    """Raised by :meth:`FitProblem.jacobian` when the cost has stopped falling fast
    (:attr:`FitProblem.early_stop`): the fit stops at ``u``, an accepted point."""

    def __init__(self, u: np.ndarray, relative_decrease: float):
        super().__init__(f"cost fell by {relative_decrease:.3g} relative in the last step")
        self.u = u
        self.relative_decrease = relative_decrease


class CostPlateau(Exception):
    """Raised by :meth:`FitProblem.jacobian` when one least-squares fit has lowered its
    robust cost by less than a relative amount over its last few Jacobians
    (:attr:`FitProblem.plateau`): the fit has converged as far as the data can tell, and
    stops at ``u``, an accepted point, with robust cost ``cost``."""

    def __init__(self, u: np.ndarray, cost: float, relative_decrease: float, n_jacobians: int):
        super().__init__(
            f"levelled off: cost fell by {relative_decrease:.2g} relative over the last "
            f"{n_jacobians} Jacobians"
        )
        self.u = u
        self.cost = cost
        self.n_jacobians = n_jacobians


def _threads() -> int:
    """Threads the simulations share out over: numba's thread count (``NUMBA_NUM_THREADS``,
    by default one per core), the package's one threading setting."""
    return max(1, int(numba.get_num_threads()))


def simulation_threads() -> int:
    """The threads the fits' simulations share out over (:func:`_threads`)."""
    return _threads()


def _forget_pool() -> None:
    """After a fork the child has none of the parent's pool threads: start a new pool."""
    _pools.clear()


os.register_at_fork(after_in_child=_forget_pool)


def _plant_array(
    ds: Dataset,
    columns: Sequence[Mapping[str, float]],
    scopes: Mapping[str, Sequence[str]] | None,
    column_scopes: Sequence[Mapping[str, Sequence[str]]] | None,
) -> np.ndarray:
    """Kernel parameter array ``(n_params, m)`` of ``ds`` with each column's overrides."""
    m = len(columns)
    arr = np.repeat(parameter_array([ds.values]), m, axis=1)
    for j, overrides in enumerate(columns):
        sc = scopes if column_scopes is None else column_scopes[j]
        for name, v in dataset_overrides(ds, overrides, sc).items():
            arr[_ROW[name], j] = v
    return arr


def _rollout_piece(ds: Dataset, params: np.ndarray, n_samples: int, substeps: int) -> np.ndarray:
    """Outputs ``(n_samples, O_*, m)`` of one batch rollout of ``ds``'s current over the
    parameter columns ``params`` (``rollout_serial`` releases the GIL: pieces run in
    threads side by side). Each column's result does not depend on the others'."""
    sim = BatchSimulator(np.ascontiguousarray(params), ds.dt_s, substeps)
    if ds.initial:
        sim.reset(initial=ds.initial)
    first = sim.outputs.copy()
    currents = np.repeat(ds.recording.i_c[: n_samples - 1, None], params.shape[1], axis=1)
    return np.concatenate([first[None], sim.rollout(currents)], axis=0)


def _pieces(ds: Dataset, arr: np.ndarray) -> list[tuple[np.ndarray, int, float]]:
    """The column groups of one job, each as (column indices, substeps, relative cost per
    substep and column, ``lane_class_cost``): columns whose rod moves and columns whose
    rod is clamped apart, each at its own substep; within each, columns that run the
    kernel's same loops apart (``lane_classes``: a batch chunk runs the costliest loop of
    any of its lanes for all of them, so one exhaust-node column among the screening's
    would make every column in its chunk cost as much)."""
    moving = arr[_ROW["piston_mode"]] != MODE_FIXED
    pieces = []
    for group in (np.flatnonzero(~moving), np.flatnonzero(moving)):
        if group.size == 0:
            continue
        substeps = ds.substeps_moving if moving[group[0]] and ds.substeps_moving else ds.substeps
        classes = lane_classes(np.ascontiguousarray(arr[:, group]), ds.dt_s / substeps)
        for code in np.unique(classes):
            members = group[classes == code]
            pieces.append((members, substeps, lane_class_cost(int(code))))
    return pieces


BALANCE_TOLERANCE = 1.1  # a split is worth its smaller batches above this load imbalance


def _makespan(costs: Sequence[float], n_threads: int) -> float:
    """The busiest thread's cost when pieces go, costliest first, to the least busy."""
    loads = [0.0] * n_threads
    for cost in sorted(costs, reverse=True):
        loads[loads.index(min(loads))] += cost
    return max(loads)


def _balanced(tasks: list[tuple], n_threads: int) -> list[tuple]:
    """``tasks`` (cost, work, job, columns, substeps), the costliest cut in two (every
    second column) until the threads' loads are within ``BALANCE_TOLERANCE`` of even:
    whole pieces keep more lanes per batch chunk (a base Jacobian's recordings balance
    as they are), a lone piece is shared by every thread."""
    tasks = list(tasks)
    while n_threads > 1:
        total = sum(t[0] for t in tasks)
        if _makespan([t[0] for t in tasks], n_threads) <= BALANCE_TOLERANCE * total / n_threads:
            break
        splittable = [i for i, t in enumerate(tasks) if t[3].size > 1]
        if not splittable:
            break
        cost, work, k, cols, substeps = tasks.pop(max(splittable, key=lambda i: tasks[i][0]))
        for half in (cols[0::2], cols[1::2]):
            share = half.size / cols.size
            tasks.append((cost * share, work * share, k, half, substeps))
    return tasks


def _run_pieces(calls: Sequence[tuple], n_threads: int) -> Iterator[np.ndarray]:
    """:func:`_rollout_piece` of every argument tuple, in order: on a pool of ``n_threads``
    threads (one per thread count, made on first use), or here when one suffices."""
    if n_threads < 2 or len(calls) < 2:
        return (_rollout_piece(*call) for call in calls)
    if n_threads not in _pools:
        _pools[n_threads] = ThreadPoolExecutor(n_threads, thread_name_prefix="identification")
    futures = [_pools[n_threads].submit(_rollout_piece, *call) for call in calls]
    return (future.result() for future in futures)


def simulate_jobs(jobs: Sequence[SimulationJob]) -> list[dict[str, np.ndarray]]:
    """The true (plant) channels ``(n_samples, m)`` of every job's columns of overrides,
    all of them at once: columns whose rod moves and columns whose rod is clamped at their
    own substeps, the batch rollouts cut into column pieces (:func:`_pieces`,
    :func:`_balanced`) and shared out over :func:`_threads` threads, the costliest first.
    The results are bit-identical to one rollout per job. The work done is reported to
    :mod:`.progress`."""
    n_threads = _threads()
    arrays, outs, tasks = [], [], []
    for k, (ds, columns, n_samples, scopes, column_scopes) in enumerate(jobs):
        arr = _plant_array(ds, columns, scopes, column_scopes)
        arrays.append(arr)
        outs.append(np.empty((n_samples, len(PREDICTED_CHANNELS_ORDER), len(columns))))
        for part, substeps, cost in _pieces(ds, arr):
            work = n_samples * substeps * part.size
            tasks.append((work * cost, work, k, part, substeps))
    tasks = sorted(_balanced(tasks, n_threads), key=lambda task: -task[0])
    rows = [PREDICTED_CHANNELS[c] for c in PREDICTED_CHANNELS_ORDER]
    calls = [
        (jobs[k][0], arrays[k][:, part], jobs[k][2], substeps) for _, _, k, part, substeps in tasks
    ]
    for (_, work, k, part, _), piece in zip(tasks, _run_pieces(calls, n_threads)):
        outs[k][:, :, part] = piece[:, rows, :]
        progress.advance(work)
    return [
        {ch: out[:, PREDICTED_CHANNELS_ORDER.index(ch), :] for ch in job[0].channels}
        for job, out in zip(jobs, outs)
    ]


def simulate_unique(
    ds: Dataset,
    columns: Sequence[Mapping[str, float | str]],
    n_samples: int,
    column_scopes: Sequence[Mapping[str, Sequence[str]]],
) -> dict[str, np.ndarray]:
    """:func:`simulate_jobs` of ``columns``, each plant that reaches ``ds`` simulated once: a
    value scoped away from its rod mode, or the piston's friction on a clamped rod, does
    not make a column differ."""
    return simulate_unique_jobs([(ds, columns, n_samples, column_scopes)])[0]


def simulate_unique_jobs(jobs: Sequence[tuple]) -> list[dict[str, np.ndarray]]:
    """:func:`simulate_unique` of every ``(ds, columns, n_samples, column_scopes)``, all
    in one :func:`simulate_jobs` call (the threads stay busy across the datasets)."""
    indices, sim_jobs = [], []
    for ds, columns, n_samples, column_scopes in jobs:
        unique: dict = {}  # plant key -> its position among the simulated columns
        plants: list[dict] = []
        idx: list[int] = []
        for plant, scopes in zip(columns, column_scopes):
            resolved = dataset_overrides(ds, plant, scopes)
            if ds.rod_mode == "fixed" and resolved.get("piston_mode", MODE_FIXED) == MODE_FIXED:
                resolved = {k: v for k, v in resolved.items() if k not in FRICTION_NAMES}
            key = tuple(sorted(resolved.items()))
            if key not in unique:
                unique[key] = len(plants)
                plants.append(resolved)
            idx.append(unique[key])
        indices.append(idx)
        sim_jobs.append((ds, plants, n_samples, None, None))
    return [
        {c: y[:, idx] for c, y in sims.items()}
        for idx, sims in zip(indices, simulate_jobs(sim_jobs))
    ]


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
            if p.kind == "plant" and kernel_name(p.name) not in _ROW:
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
        #: (relative decrease, Jacobians): stop once the robust cost fell by less than this
        #: from one Jacobian to the next, after at least that many (None: never)
        self.early_stop: tuple[float, int] | None = None
        self._jacobian_costs: list[float] = []
        #: (relative decrease, Jacobians): stop a least-squares fit once its robust cost fell
        #: by less than this over that many Jacobians (None: never; ``fit.plateau_*``)
        self.plateau: tuple[float, int] | None = None
        self.fit_costs: list[float] = []  # robust cost at each Jacobian of the current fit
        self.blocks = self._blocks()

    # -- parameter vectors ----------------------------------------------------------------
    def values(self, u: np.ndarray) -> dict[str, float]:
        """Free parameter values (physical units) of the optimiser vector ``u``."""
        return {p.name: p.from_u(float(x)) for p, x in zip(self.free, u)}

    def initial_u(self, start: Mapping[str, float | str] | None = None) -> np.ndarray:
        """Warm start: ``start``, else the parameter's ``initial``, else the data's value
        (a free parameter's entries are numbers)."""
        start = dict(start or {})
        u = []
        for p in self.free:
            v: Any
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
    def _simulate_each(
        self, columns: Sequence[Mapping[str, float]], n_samples: Sequence[int]
    ) -> list[dict[str, np.ndarray]]:
        """:func:`simulate_jobs` of ``columns`` on every dataset (``n_samples[k]`` of dataset
        k), all datasets in one :func:`simulate_jobs` call."""
        return simulate_jobs(
            [(ds, columns, n, self.scopes, None) for ds, n in zip(self.datasets, n_samples)]
        )

    def _plant(self, u: np.ndarray) -> list[dict[str, np.ndarray]]:
        key = np.asarray(u, float).tobytes()
        if key in self._cache:
            return self._cache[key]
        plant, _ = self._split(self.values(u))
        out = self._simulate_each([plant], self.n_samples)
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
            sims = self._simulate_each([plant], n_samples)
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
        # per dataset: channel -> (n, n_free)
        col_preds: list[dict] = [dict() for _ in self.datasets]
        columns = [{**plant, self.free[j].name: perturbed[j]} for j in plant_idx]
        plant_sims = self._simulate_each(columns, self.n_samples)
        for k, (ds, sims) in enumerate(zip(self.datasets, plant_sims)):
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
        self._check_early_stop(u)
        return J

    def _check_early_stop(self, u: np.ndarray) -> None:
        """Raise :class:`CostLevelledOff` when :attr:`early_stop` says the fit may stop at
        ``u`` (the point of the latest Jacobian), else :class:`CostPlateau` when
        :attr:`plateau` does (the early stop first: a base fit stopped early for the
        screening is finished at the fine substep, one that levelled off is not)."""
        self._jacobian_costs.append(self.cost_history[-1])
        self.fit_costs.append(self.cost_history[-1])
        if self.early_stop is not None and len(self._jacobian_costs) >= max(2, self.early_stop[1]):
            before, now = self._jacobian_costs[-2:]
            decrease = (before - now) / before if before > 0 else 0.0
            if decrease < self.early_stop[0]:
                raise CostLevelledOff(np.array(u, dtype=float), decrease)
        if self.plateau is not None and len(self.fit_costs) > self.plateau[1]:
            before, now = self.fit_costs[-1 - self.plateau[1]], self.fit_costs[-1]
            decrease = (before - now) / before if before > 0 else 0.0
            if decrease < self.plateau[0]:
                raise CostPlateau(np.array(u, dtype=float), now, decrease, self.plateau[1])
