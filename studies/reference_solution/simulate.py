"""``simulate_reference``: the model of ``docs/model.md`` integrated to high accuracy by the
hybrid integrator (:mod:`.hybrid`)."""

from __future__ import annotations

import math

import numpy as np

from .hybrid import _HybridSimulation
from .model import (
    IX_P1,
    IX_P2,
    IX_V,
    IX_VD,
    IX_VS,
    IX_X,
    IX_XD,
    IX_XS,
    N_Y,
    PISTON_FIXED,
    ModelConstants,
)


def _default_atol(m: ModelConstants, rtol: float) -> np.ndarray:
    """Absolute tolerances scaled to each state's natural size."""
    omega_s = math.sqrt(2.0 * m.k_s / m.m_s)
    scale = np.empty(N_Y)
    scale[[IX_XS, IX_XD]] = m.r_h
    scale[[IX_VS, IX_VD]] = m.r_h * omega_s
    scale[[IX_P1, IX_P2]] = m.p_a
    scale[IX_X] = m.stroke
    scale[IX_V] = 0.1
    return rtol * scale


def simulate_reference(
    params: dict,
    coil_current_a: np.ndarray,
    control_dt_s: float,
    initial: dict | None = None,
    rtol: float = 1e-9,
    atol=None,
    method: str = "DOP853",
) -> dict:
    """Integrate the model of ``docs/model.md`` to high accuracy.

    Parameters
    ----------
    params
        Parameter set, a dict ``name -> float`` with the names of
        ``pneumatic_env.physics.layout.PARAMETER_NAMES`` (extra names are ignored).
    coil_current_a
        Coil current (A) of each control period, held constant (zero-order hold) over
        ``[k dt, (k+1) dt)``.
    control_dt_s
        Control period ``dt`` (s).
    initial
        Initial state, keys among ``p1``, ``p2`` (Pa abs), ``x`` (m), ``v`` (m/s),
        ``x_s`` (m), ``v_s`` (m/s). Defaults: both chambers at ambient pressure, piston at
        rest at ``fixed_position_m`` (fixed mode) or ``x = 0``, spool centred at rest. The
        delay history before ``t = 0`` equals the initial state.
    rtol, atol
        Tolerances of ``solve_ivp``; ``atol`` defaults to ``rtol`` times a natural scale
        of each state (hole radius, ambient pressure, stroke, ...).
    method
        ``solve_ivp`` method (explicit "DOP853" by default; "Radau" and "LSODA" work too).

    Returns
    -------
    dict of arrays of length ``n + 1`` sampled at ``t_k = k dt``: ``t``, ``p1``, ``p2``,
    ``x``, ``v``, ``f`` (force output: ``F_p`` for fixed and free rods,
    ``k_env (x - x_rest)`` for the spring mode), ``x_s``.
    """
    m = ModelConstants.from_params(params)
    currents = np.asarray(coil_current_a, dtype=float).ravel()
    if currents.size == 0:
        raise ValueError("coil_current_a is empty")
    if not np.all(np.isfinite(currents)):
        raise ValueError("coil_current_a contains non-finite values")
    if not control_dt_s > 0.0:
        raise ValueError("control_dt_s must be positive")
    init = {
        "p1": m.p_a,
        "p2": m.p_a,
        "x": m.x_fixed if m.piston_mode == PISTON_FIXED else 0.0,
        "v": 0.0,
        "x_s": 0.0,
        "v_s": 0.0,
    }
    if initial:
        unknown = set(initial) - set(init)
        if unknown:
            raise KeyError(f"unknown initial-state keys {sorted(unknown)}")
        init.update({key: float(val) for key, val in initial.items()})
    if m.piston_mode == PISTON_FIXED and (init["x"] != m.x_fixed or init["v"] != 0.0):
        raise ValueError("fixed rod: initial x must be fixed_position_m and v must be 0")
    if abs(init["x"]) > 0.5 * m.stroke:
        raise ValueError("initial piston position beyond the end stops")
    if init["p1"] <= 0.0 or init["p2"] <= 0.0:
        raise ValueError("initial pressures must be positive (absolute)")
    y0 = np.zeros(N_Y)
    y0[IX_XS] = y0[IX_XD] = init["x_s"]
    y0[IX_VS] = init["v_s"]
    y0[IX_VD] = 0.0  # delayed spool frozen at the initial position until t = tau
    y0[IX_P1], y0[IX_P2] = init["p1"], init["p2"]
    y0[IX_X], y0[IX_V] = init["x"], init["v"]
    if m.tau == 0.0:
        y0[IX_VD] = init["v_s"]
    if atol is None:
        atol = _default_atol(m, rtol)
    sim = _HybridSimulation(m, currents, float(control_dt_s), y0, rtol, atol, method)
    return sim.run()
