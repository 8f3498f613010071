"""The outcome of a fit and its statistics: Gauss-Newton covariance inflated for the
residual's autocorrelation, confidence intervals, identifiability flags, correlations."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy.stats import norm

from pneumatic_env.physics.layout import PARAMETER_INDEX as _ROW  # name -> row

from .candidates import SENSOR_NEUTRAL
from .config import FitParameter
from .datasets import Dataset, dataset_overrides, kernel_name

# the flag of a parameter whose confidence interval is wider than its plausible range
WIDE_INTERVAL = "confidence interval wider than the plausible range"

if TYPE_CHECKING:
    from .problem import FitProblem

__all__ = ["FitResult", "pooled_lag1"]


@dataclass
class FitResult:
    """Outcome of one fit (values in physical units; ``ci`` at the config's level)."""

    parameters: list[FitParameter]
    values: dict[str, float]
    fixed: dict[str, float | str]
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
    u: np.ndarray | None = field(repr=False, default=None)
    scopes: dict[str, tuple[str, ...]] = field(default_factory=dict)
    cost_history: list[float] = field(default_factory=list)  # robust cost, accepted points
    n_jacobians: int = 0

    def plant_values(self) -> dict[str, float | str]:
        """Fixed and fitted kernel parameters (overrides on the datasets' sets; a text value
        names the dataset's parameter to use, see :func:`dataset_overrides`)."""
        out: dict[str, float | str] = {
            k: v for k, v in self.fixed.items() if kernel_name(k) in _ROW
        }
        out.update((p.name, self.values[p.name]) for p in self.parameters if p.kind == "plant")
        return out

    def sensor_values(self) -> dict[str, float]:
        out = {k: float(v) for k, v in self.fixed.items() if k in SENSOR_NEUTRAL}
        out.update((p.name, self.values[p.name]) for p in self.parameters if p.kind == "sensor")
        return out

    def all_values(self) -> dict[str, float | str]:
        return {**self.plant_values(), **self.sensor_values()}

    def dataset_values(self, ds: Dataset) -> dict[str, float]:
        """The complete kernel parameter set of dataset ``ds`` with this fit applied."""
        return {**ds.values, **dataset_overrides(ds, self.plant_values(), self.scopes)}

    def file_values(self, datasets: Sequence[Dataset]) -> dict[str, float]:
        """Kernel overrides for a parameter file: scoped values and text references are
        resolved on the first dataset they apply to (left out if none); a plain value wins
        over a scoped key of the same parameter (``name@modes``)."""
        values = self.plant_values()
        plain = {k: v for k, v in values.items() if kernel_name(k) == k}
        out: dict[str, float] = {}
        for ds in reversed(list(datasets)):
            out.update(dataset_overrides(ds, plain, self.scopes))
        for ds in datasets:
            for k, v in dataset_overrides(ds, values, self.scopes).items():
                out.setdefault(k, v)
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
            "n_jacobians": self.n_jacobians,
            "cost_history": list(self.cost_history),
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
    out: dict[str, Any] = {"std": {}, "ci": {}, "identified": {}, "plausible": {}, "flags": {}}
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
            flags.append(WIDE_INTERVAL)
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
