"""``simulate_segmented_line``: a segmented tube line, the independent reference of the
kernel's transmission line (``tube_waves``, docs/effects.md)."""

from __future__ import annotations

import math

import numpy as np

from .model import (
    NEUTRAL_EFFECTS,
    PISTON_FIXED,
    ModelConstants,
    chamber_pressure_rate,
    chamber_volumes,
    orifice_area,
    orifice_mass_flow,
    reynolds_number,
    spool_acceleration,
    tube_resistance,
)


def simulate_segmented_line(
    params: dict,
    coil_current_a: float,
    duration_s: float,
    n_segments: int = 40,
    sample_dt_s: float = 1e-3,
    rtol: float = 1e-8,
) -> dict:
    """A clamped rod driven by a constant current through two tubes of ``n_segments``
    finite volumes each: the reference for the kernel's transmission line
    (``tube_waves = 1``, docs/effects.md), written without it.

    Each segment of length dx = L_t / n is a node of volume A_t dx, its pressure changing
    isentropically with the mass it gains, dP_k/dt = k R T (m_{k-1} - m_k) / (A_t dx), and
    a link to the next node (the last one to the chamber) whose mass flow obeys the
    momentum balance of its air, dm_k/dt = A_t (P_k - P_{k+1}) / dx - R_t m_k / rho, with
    the tube friction R_t of Eqs. 33, 35 and rho the mean density of its two nodes. The
    valve feeds the first node (Eq. 39, four paths, spool of Eq. 38, no delay); the
    chambers follow Eq. 14 at the clamp. As n grows the line tends to the wave equation
    with friction, whose waves travel at c = sqrt(k R T) (Eq. 31).

    The segments replace the tube, so ``tube_coupling`` and ``tube_waves`` do not apply;
    any other effect beyond the paper is refused. Returns ``t``, ``p1``, ``p2`` and
    ``valve_p1``, ``valve_p2`` (the first nodes) at ``sample_dt_s``, and the line's air
    mass at the end (``line_mass_kg``) with the mass the valve let in (``valve_mass_kg``)
    and the chambers received (``chamber_mass_kg``), for a conservation check.
    """
    from scipy.integrate import solve_ivp

    switched_on = [
        n
        for n, neutral in NEUTRAL_EFFECTS.items()
        if n != "tube_waves" and n in params and float(params[n]) != neutral
    ]
    if switched_on:
        raise NotImplementedError(
            f"simulate_segmented_line models the paper's valve and chambers with a segmented "
            f"tube only; effects switched on: {switched_on}"
        )
    # the segments are the tube: the paper's tube coupling and the line switch do not apply
    m = ModelConstants.from_params({**params, "tube_waves": 0.0, "tube_coupling": 0.0})
    if m.piston_mode != PISTON_FIXED:
        raise ValueError("simulate_segmented_line models a clamped rod (piston_mode = 0) only")
    n = int(n_segments)
    if n < 2:
        raise ValueError(f"n_segments = {n_segments} is not allowed: must be an integer >= 2")
    area_t = math.pi * m.tube_d**2 / 4.0
    dx = m.tube_length / n
    rt = m.R * m.T
    v1, v2 = chamber_volumes(m, m.x_fixed)
    # state: x_s, v_s, mass let in by the valve, mass into the chambers, then per tube: n
    # node pressures, n link flows, the chamber pressure
    tube = 2 * n + 1

    def resistance(mdot):
        re = reynolds_number(m, mdot)
        return tube_resistance(m, re, re >= m.re_t)

    def rhs(_t, y):
        x_s, v_s = y[0], y[1]
        out = np.zeros_like(y)
        out[0] = v_s
        out[1] = spool_acceleration(m, x_s, v_s, coil_current_a)
        a_in, a_ex = orifice_area(m, x_s), orifice_area(m, -x_s)
        for side, (supply_area, exhaust_area, volume) in enumerate(
            ((a_in, a_ex, v1), (a_ex, a_in, v2))
        ):
            first = 4 + side * tube
            nodes = y[first : first + n]
            links = y[first + n : first + 2 * n]
            chamber = y[first + 2 * n]
            valve = orifice_mass_flow(m, supply_area, m.p_s, nodes[0]) - orifice_mass_flow(
                m, exhaust_area, nodes[0], m.p_a
            )
            out[2] += valve
            inflow = np.concatenate([[valve], links[:-1]])
            out[first : first + n] = m.k * rt * (inflow - links) / (area_t * dx)
            downstream = np.append(nodes[1:], chamber)
            rho = 0.5 * (nodes + downstream) / rt
            friction = np.array([resistance(q) for q in links])
            out[first + n : first + 2 * n] = (
                area_t * (nodes - downstream) / dx - friction * links / rho
            )
            out[3] += links[-1]
            out[first + 2 * n] = chamber_pressure_rate(
                m, chamber, volume, 0.0, max(links[-1], 0.0), max(-links[-1], 0.0)
            )
        return out

    y0 = np.zeros(4 + 2 * tube)
    for side in range(2):
        first = 4 + side * tube
        y0[first : first + n] = m.p_a
        y0[first + 2 * n] = m.p_a
    t = np.arange(int(round(duration_s / sample_dt_s)) + 1) * sample_dt_s
    scale = np.concatenate(
        [
            [m.r_h, m.r_h * 1e3, 1e-6, 1e-6],
            np.tile(np.concatenate([np.full(n, m.p_a), np.full(n, 1e-3), [m.p_a]]), 2),
        ]
    )
    sol = solve_ivp(rhs, (0.0, t[-1]), y0, method="LSODA", t_eval=t, rtol=rtol, atol=rtol * scale)
    if not sol.success:
        raise RuntimeError(f"segmented line: solve_ivp failed: {sol.message}")
    end = sol.y[:, -1]
    # the line's air gained since t = 0 (isentropic: dm = V dP / (k R T))
    line_mass = sum(
        (end[4 + s * tube : 4 + s * tube + n] - m.p_a).sum() * area_t * dx / (m.k * rt)
        for s in range(2)
    )
    return {
        "t": t,
        "p1": sol.y[4 + 2 * n],
        "p2": sol.y[4 + tube + 2 * n],
        "valve_p1": sol.y[4],
        "valve_p2": sol.y[4 + tube],
        "line_mass_kg": line_mass,
        "chamber_mass_kg": end[3],
        "valve_mass_kg": end[2],
    }
