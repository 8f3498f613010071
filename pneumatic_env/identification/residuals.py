"""Residual analysis of a fit: per channel and per phase of the valve, whiteness, and the
cross-correlation with the coil current (step 2 of :mod:`.diagnose`)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
from scipy.stats import chi2, norm

from .calibrate import Dataset
from .checks import dead_band_current
from .config import IdentificationConfig

__all__ = ["PHASES", "phase_masks", "residual_analysis"]

PHASES = ("flow", "after_flow", "rest", "reversal")


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
        phase_stats: dict[str, dict] = {}
        for ph in PHASES:
            x = np.concatenate(acc[ph])
            phase_stats[ph] = {
                "n": int(x.size),
                "nrmse": float(np.sqrt(np.mean(x**2))) if x.size else None,
                "bias": float(np.mean(x)) if x.size else None,
            }
        out[c] = {
            "nrmse": float(np.sqrt(np.mean(e**2))) if e.size else None,
            "bias": float(np.mean(e)) if e.size else None,
            "n": int(e.size),
            "phases": phase_stats,
            "whiteness": _whiteness(e, max_lag, alpha),
            "input_correlation": _input_correlation(e, u, max_lag, alpha),
        }
    return out
