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

Uncertainty: the Gauss-Newton covariance ``s^2 (J^T J)^-1`` at the optimum, with the
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
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares
from scipy.stats import norm

from pneumatic_env.params import ConfigError, parameter_array, save_parameters
from pneumatic_env.physics.layout import PARAMETER_NAMES
from pneumatic_env.recording import Recording
from pneumatic_env.replay import PREDICTED_CHANNELS, recording_parameters, substeps_for
from pneumatic_env.simulator import BatchSimulator

from .candidates import SENSOR_NEUTRAL, apply_sensor_model
from .checks import FITTED_CHANNELS, check_recordings, usable_masks
from .config import FitParameter, IdentificationConfig, load_config

__all__ = [
    "Calibration",
    "Dataset",
    "FitProblem",
    "FitResult",
    "base_fit_parameters",
    "calibrate",
    "channel_nrmse",
    "dataset_overrides",
    "prepare_datasets",
    "run_fit",
]

log = logging.getLogger("pneumatic_env.identification")
_ROW = {name: i for i, name in enumerate(PARAMETER_NAMES)}


# --------------------------------------------------------------------------- datasets


@dataclass
class Dataset:
    """One recording prepared for fitting."""

    name: str
    recording: Recording
    values: dict[str, float]  # the parameter set before fitting (configs + params + rig)
    channels: tuple[str, ...]  # channels that enter the residual
    scales: dict[str, float]  # residual scale of each channel
    usable: dict[str, np.ndarray]  # per channel: samples not clipped
    dt_s: float
    substeps: int  # RK4 substeps per sample for the recording's rod mode
    initial: dict | None
    moving: bool
    rod_mode: str = "fixed"  # the sidecar's piston.mode
    substeps_moving: int = 0  # substeps when the simulated rod moves (0: = substeps)

    @property
    def n_samples(self) -> int:
        return self.recording.n_samples

    def measured(self, channel: str) -> np.ndarray:
        return self.recording.channels[channel]


def channel_scale(channel: str, values: Mapping[str, float], config: IdentificationConfig) -> float:
    """Residual scale of a channel (see ``channel_scales`` in the config)."""
    span = values["supply_pressure_pa"] - values["ambient_pressure_pa"]
    if channel in ("p1", "p2"):
        return span
    if channel == "f":
        return span * math.pi * values["bore_diameter_m"] ** 2 / 4.0
    if channel == "x":
        return config.number("channel_scales", "x", positive=True) * values["stroke_m"]
    if channel == "x_s":
        return config.number("channel_scales", "x_s", positive=True) * values["hole_radius_m"]
    if channel == "v":
        return config.number("channel_scales", "v", positive=True)
    raise ConfigError(f"channel {channel!r} has no residual scale; allowed: p1, p2, f, x, v, x_s")


def prepare_datasets(
    recordings: Sequence[Recording],
    params=None,
    config: IdentificationConfig | None = None,
    check: bool = True,
) -> tuple[list[Dataset], list]:
    """Datasets for ``recordings`` and the data issues found (errors raise ``BadDataError``).

    ``params`` is a parameter file or mapping layered under each recording's sidecar (see
    :func:`pneumatic_env.replay.recording_parameters`).
    """
    config = config or load_config()
    values = [recording_parameters(rec, params) for rec in recordings]
    issues = check_recordings(recordings, values, config=config) if check else []
    datasets = []
    for k, (rec, vals) in enumerate(zip(recordings, values)):
        name = rec.path.stem if rec.path is not None else f"recording{k}"
        dropped = {
            i.channel
            for i in issues
            if i.code == "constant" and i.recording in (rec.path.name if rec.path else "recording")
        }
        mode = rec.rig["piston"]["mode"]
        max_substep = config.number(
            "fit", "max_substep_s" if mode == "fixed" else "max_substep_moving_s", positive=True
        )
        moving_substep = config.number("fit", "max_substep_moving_s", positive=True)
        initial = rec.rig.get("initial")
        if mode == "fixed":  # the rod starts at the clamp, also when a candidate frees it
            initial = {"x": vals["fixed_position_m"], **(initial or {})}
        channels = tuple(
            c
            for c in FITTED_CHANNELS
            if c in rec.channels
            and c not in dropped
            and c in PREDICTED_CHANNELS
            and not (c == "x" and mode == "fixed")
        )
        datasets.append(
            Dataset(
                name=name,
                recording=rec,
                values=vals,
                channels=channels,
                scales={c: channel_scale(c, vals, config) for c in channels},
                usable=usable_masks(rec, channels),
                dt_s=rec.dt,
                substeps=substeps_for(rec.dt, max_substep),
                initial=initial,
                moving=mode in ("free", "spring") and "x" in channels,
                rod_mode=mode,
                substeps_moving=substeps_for(rec.dt, moving_substep),
            )
        )
    return datasets, issues


def base_fit_parameters(
    datasets: Sequence[Dataset],
    names: Sequence[str] | None = None,
    config: IdentificationConfig | None = None,
) -> list[FitParameter]:
    """The base parameters to fit: ``names``, else the config's default set for the data."""
    config = config or load_config()
    if names is None:
        names = list(config.base_fit_names("fit_always"))
        if any(ds.moving for ds in datasets):
            names += config.base_fit_names("fit_when_moving")
    out = []
    for name in names:
        if name not in config.base_parameters:
            raise ConfigError(
                f"cannot fit {name!r}: no entry under base_parameters in "
                f"{config.path}; fittable: {', '.join(config.base_parameters)}"
            )
        out.append(config.base_parameters[name])
    return out


# --------------------------------------------------------------------------- the problem


def dataset_overrides(
    ds: Dataset,
    overrides: Mapping[str, float | str],
    scopes: Mapping[str, Sequence[str]] | None = None,
) -> dict[str, float]:
    """The kernel-parameter ``overrides`` that apply to ``ds``, as numbers.

    A name whose ``scopes`` entry (rod modes) does not include the recording's rod mode is
    dropped; a text value names a kernel parameter whose value in ``ds``'s set is used.
    """
    scopes = scopes or {}
    out = {}
    for name, v in overrides.items():
        if name not in _ROW:
            continue
        if name in scopes and ds.rod_mode not in scopes[name]:
            continue
        out[name] = float(ds.values[v]) if isinstance(v, str) else float(v)
    return out


def _simulate(
    ds: Dataset,
    columns: Sequence[Mapping[str, float]],
    n_samples: int,
    scopes: Mapping[str, Sequence[str]] | None = None,
) -> dict[str, np.ndarray]:
    """True (plant) channels of ``ds`` for each column of overrides: ``(n_samples, m)``."""
    m = len(columns)
    base = parameter_array([ds.values])
    arr = np.repeat(base, m, axis=1)
    for j, overrides in enumerate(columns):
        for name, v in dataset_overrides(ds, overrides, scopes).items():
            arr[_ROW[name], j] = v
    moving = bool(np.any(arr[_ROW["piston_mode"]] != 0))
    substeps = ds.substeps_moving if moving and ds.substeps_moving else ds.substeps
    sim = BatchSimulator(arr, ds.dt_s, substeps)
    if ds.initial:
        sim.reset(initial=ds.initial)
    first = sim.outputs.copy()
    currents = np.repeat(ds.recording.i_c[: n_samples - 1, None], m, axis=1)
    rows = np.concatenate([first[None], sim.rollout(currents)], axis=0)
    return {ch: rows[:, PREDICTED_CHANNELS[ch], :] for ch in ds.channels}


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
        for name, v in self.fixed.items():
            if name not in _ROW and name not in SENSOR_NEUTRAL:
                raise ConfigError(
                    f"fixed value {name!r} is neither a kernel nor a sensor parameter"
                )
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
        plant = {k: v for k, v in self.fixed.items() if k in _ROW}
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


# --------------------------------------------------------------------------- results


@dataclass
class FitResult:
    """Outcome of one fit (values in physical units; ``ci`` at the config's level)."""

    parameters: list[FitParameter]
    values: dict[str, float]
    fixed: dict[str, float]
    std: dict[str, float]
    ci: dict[str, tuple[float, float]]
    identified: dict[str, bool]
    plausible: dict[str, bool]
    flags: dict[str, list[str]]
    correlations: list[tuple[str, str, float]]
    condition_number: float
    cost: float
    rss: float
    n_residuals: int
    rho1: float
    n_eff: float
    nfev: int
    message: str
    u: np.ndarray = field(repr=False, default=None)
    scopes: dict[str, tuple[str, ...]] = field(default_factory=dict)

    def plant_values(self) -> dict[str, float | str]:
        """Fixed and fitted kernel parameters (overrides on the datasets' sets; a text value
        names the dataset's parameter to use, see :func:`dataset_overrides`)."""
        out = {k: v for k, v in self.fixed.items() if k in _ROW}
        out.update((p.name, self.values[p.name]) for p in self.parameters if p.kind == "plant")
        return out

    def sensor_values(self) -> dict[str, float]:
        out = {k: v for k, v in self.fixed.items() if k in SENSOR_NEUTRAL}
        out.update((p.name, self.values[p.name]) for p in self.parameters if p.kind == "sensor")
        return out

    def all_values(self) -> dict[str, float | str]:
        return {**self.plant_values(), **self.sensor_values()}

    def dataset_values(self, ds: Dataset) -> dict[str, float]:
        """The complete kernel parameter set of dataset ``ds`` with this fit applied."""
        return {**ds.values, **dataset_overrides(ds, self.plant_values(), self.scopes)}

    def file_values(self, datasets: Sequence[Dataset]) -> dict[str, float]:
        """Kernel overrides for a parameter file: scoped values and text references are
        resolved on the first dataset they apply to (left out if none)."""
        out: dict[str, float] = {}
        for ds in reversed(list(datasets)):
            out.update(dataset_overrides(ds, self.plant_values(), self.scopes))
        return out

    def to_dict(self) -> dict:
        """JSON-ready summary."""
        return {
            "parameters": {
                p.name: {
                    "value": self.values[p.name],
                    "unit": p.unit,
                    "kind": p.kind,
                    "std": _finite(self.std[p.name]),
                    "ci": [_finite(self.ci[p.name][0]), _finite(self.ci[p.name][1])],
                    "identified": self.identified[p.name],
                    "plausible": self.plausible[p.name],
                    "flags": self.flags[p.name],
                }
                for p in self.parameters
            },
            "fixed": dict(self.fixed),
            "scopes": {k: list(v) for k, v in self.scopes.items()},
            "correlations": [[a, b, r] for a, b, r in self.correlations],
            "condition_number": _finite(self.condition_number),
            "cost": self.cost,
            "rss": self.rss,
            "n_residuals": self.n_residuals,
            "lag1_autocorrelation": self.rho1,
            "effective_samples": self.n_eff,
            "nfev": self.nfev,
            "message": self.message,
        }


def _finite(x: float):
    return float(x) if math.isfinite(x) else None


def pooled_lag1(r: np.ndarray, blocks) -> float:
    """Pooled lag-1 autocorrelation of the residual over its contiguous blocks."""
    num = den = 0.0
    for _, _, a, b in blocks:
        x = r[a:b]
        if x.size > 1:
            num += float(x[1:] @ x[:-1])
            den += float(x @ x)
    return num / den if den > 0 else 0.0


def _statistics(problem: FitProblem, u: np.ndarray, r: np.ndarray, J: np.ndarray) -> dict:
    cfg = problem.config
    n, p = J.shape
    s2 = float(r @ r) / max(n - p, 1)
    rho = min(max(pooled_lag1(r, problem.blocks), 0.0), cfg.number("fit", "max_autocorrelation"))
    inflation = (1.0 + rho) / (1.0 - rho)
    norms = np.linalg.norm(J, axis=0)
    tiny = norms <= 1e-12 * max(float(norms.max(initial=0.0)), 1e-300)
    safe = np.where(tiny, 1.0, norms)
    Jn = J / safe[None, :]
    Jn[:, tiny] = 0.0
    # Singular values and right singular vectors of Jn from the small normal matrix
    # (a LAPACK SVD of the tall Jn is slow under thread oversubscription).
    eig, V = np.linalg.eigh(Jn.T @ Jn)
    order = np.argsort(eig)[::-1]
    S = np.sqrt(np.clip(eig[order], 0.0, None))
    Vt = V[:, order].T
    smax = float(S[0]) if S.size else 0.0
    ratio = cfg.number("fit", "singular_ratio", positive=True)
    weight = cfg.number("fit", "singular_direction_weight", positive=True)
    weak = [k for k in range(S.size) if S[k] < ratio * smax]
    collinear: dict[int, set] = {j: set() for j in range(p)}
    for k in weak:
        members = [j for j in range(p) if abs(Vt[k, j]) > weight and not tiny[j]]
        for j in members:
            collinear[j].update(problem.free[i].name for i in members if i != j)
    # (J^T J)^-1 from the SVD; an exactly singular direction gets a huge variance.
    inv_s2 = np.full(S.shape, 1e30)
    ok = S > 1e-14 * max(smax, 1e-300)
    inv_s2[ok] = 1.0 / S[ok] ** 2
    cov_n = (Vt.T * inv_s2[None, :]) @ Vt
    cov_u = cov_n / np.outer(safe, safe) * s2 * inflation
    std_u = np.sqrt(np.abs(np.diag(cov_u)))
    std_u[tiny] = np.inf
    level = cfg.number("fit", "confidence_level", positive=True)
    z = float(norm.ppf(0.5 + 0.5 * level))
    lo_b, hi_b = problem.bounds()
    out = {"std": {}, "ci": {}, "identified": {}, "plausible": {}, "flags": {}}
    for j, par in enumerate(problem.free):
        value = par.from_u(u[j])
        flags = []
        if tiny[j]:
            flags.append("no sensitivity: the data do not depend on it")
        if collinear[j]:
            flags.append("near-collinear with " + ", ".join(sorted(collinear[j])))
        if math.isfinite(std_u[j]):
            lo, hi = par.from_u(u[j] - z * std_u[j]), par.from_u(u[j] + z * std_u[j])
            std = std_u[j] * (par.scale if not par.log else value * math.log(10.0))
        else:
            lo, hi, std = -math.inf, math.inf, math.inf
        if (hi - lo) > (par.plausible_max - par.plausible_min):
            flags.append("confidence interval wider than the plausible range")
        if abs(u[j] - lo_b[j]) < 1e-9 or abs(u[j] - hi_b[j]) < 1e-9:
            flags.append("at a bound of the fit")
        out["std"][par.name] = float(std)
        out["ci"][par.name] = (float(lo), float(hi))
        out["identified"][par.name] = not (
            tiny[j] or collinear[j] or (hi - lo) > (par.plausible_max - par.plausible_min)
        )
        out["plausible"][par.name] = par.plausible_min <= value <= par.plausible_max
        out["flags"][par.name] = flags
    corr_limit = cfg.number("fit", "correlation_warning", positive=True)
    correlations = []
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov_u / np.outer(std_u, std_u)
    for a in range(p):
        for b in range(a + 1, p):
            c = corr[a, b]
            if math.isfinite(c) and abs(c) > corr_limit:
                correlations.append((problem.free[a].name, problem.free[b].name, float(c)))
    out["correlations"] = correlations
    out["condition_number"] = float(smax / S[-1]) if S.size and S[-1] > 0 else math.inf
    out["rho1"] = rho
    out["n_eff"] = n / inflation
    return out


def _least_squares(problem: FitProblem, u0: np.ndarray, max_nfev: int):
    """SciPy's robust least squares on ``problem`` from ``u0`` (settings under ``fit``)."""
    cfg = problem.config
    lo, hi = problem.bounds()
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
    )


def _friction_restarts(problem: FitProblem, u0: np.ndarray) -> list[np.ndarray]:
    """Further starts of a fit that frees the piston's static friction: ``u0`` with the
    static friction times each factor of ``fit.static_friction_restarts`` (within its
    bounds). A sliding piston's free-run error jumps where the static friction decides
    whether the rod sticks, so the error has one basin per sequence of stick events and
    a local fit stays in the basin it starts in; the fit keeps the start whose optimum
    has the lowest cost on the fitting data."""
    names = [p.name for p in problem.free]
    if "static_friction_n" not in names:
        return []
    i = names.index("static_friction_n")
    p = problem.free[i]
    starts = []
    for factor in problem.config.positive_numbers("fit", "static_friction_restarts"):
        u = u0.copy()
        u[i] = p.to_u(min(max(p.from_u(float(u0[i])) * factor, p.lower), p.upper))
        starts.append(u)
    return starts


def run_fit(
    problem: FitProblem,
    start: Mapping[str, float] | None = None,
    max_nfev: int | None = None,
    friction_restarts: bool = True,
) -> FitResult:
    """Least-squares fit of ``problem`` from the warm start; statistics at the optimum.

    With ``friction_restarts`` a fit that frees the static friction also runs from the
    starts of ``_friction_restarts`` and keeps the lowest cost.
    """
    cfg = problem.config
    u0 = problem.initial_u(start)
    max_nfev = int(max_nfev or cfg.number("fit", "max_nfev", positive=True))
    if problem.free:
        sol = _least_squares(problem, u0, max_nfev)
        nfev = int(sol.nfev)
        for u_restart in _friction_restarts(problem, u0) if friction_restarts else []:
            try:
                other = _least_squares(problem, u_restart, max_nfev)
            except (ValueError, FloatingPointError) as exc:  # a start the kernel rejects
                log.info("%s: a friction restart failed: %s", problem.label, exc)
                continue
            nfev += int(other.nfev)
            if other.cost < sol.cost:
                sol = other
        u, message = sol.x, str(sol.message)
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
        "%s: done after %d evaluations (%s), cost %.6g",
        problem.label,
        nfev,
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
