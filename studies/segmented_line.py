"""The virtual rig's tubes as segmented lines: a plant of higher fidelity than the
candidates' tube models (``tube_waves``: a transmission line with its friction lumped at
the ends; ``tube_volume``: a storage volume; the paper's delay and attenuation, Eqs. 30-35).

Each tube is ``n`` finite volumes (nodes) of A_t dx, dx = L_t / n, joined by links whose
air has inertia: the node pressures change isentropically with the mass they gain,

    dP_k/dt = k R T (q_{k-1} - q_k) / (A_t dx)                     (q_{-1}: the valve's flow)

and a link's mass flow obeys the momentum balance of its air with the tube's friction
spread along the line (R_t of Eqs. 33, 35 by the link's Reynolds number, Eq. 32),

    dq_k/dt = A_t (P_k - P_{k+1}) / dx - R_t q_k / rho_k,          rho_k = (P_k + P_{k+1}) / (2 R T)

the last link ending in the chamber (P_n = the chamber's pressure, Eq. 14). The valve
(Eq. 38 spool, Eqs. 39-45 orifices, no delay: the line is the delay) feeds the first
node of each tube. With the rod clamped (Eq. 1 gives the load-cell force) these are the
equations of ``reference_solution.simulate_segmented_line`` (SciPy, a constant current),
here jitted with fixed RK4 steps and a current that changes every plant step, built on the
kernel's sub-model functions; ``tests/test_virtual_rig.py`` compares the two. With the rod
free or on a spring the piston moves by Eq. 1 with Karnopp friction (Eq. 47): its direction
is chosen at the start of each RK4 step (``piston.motion_direction``) and held over it, a
velocity that changes sign within a step ends at zero, and the stops are inelastic; the
chambers' volumes (Eq. 15) and their rates enter Eq. 14. With ``line_constants``'s
``wall_heat`` the chambers follow the energy equation instead (their temperatures are
states), exchanging heat with the wall (the closed-loop rig's ``heat_transfer``,
``rig_plants_closed_loop``); the exhaust mass (the valve's flow out of the tubes' first
volumes) is a state as well.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from pneumatic_env.physics import layout as L
from pneumatic_env.physics.chamber import chamber_volumes, pressure_rate
from pneumatic_env.physics.derived import circle_area_m2, orifice_gas_constants, piston_areas_m2
from pneumatic_env.physics.effects import chamber_energy_rates
from pneumatic_env.physics.flow import orifice_mass_flow
from pneumatic_env.physics.piston import (
    MODE_FIXED,
    end_of_substep,
    external_force,
    motion_direction,
    output_force,
    piston_acceleration,
    pneumatic_force,
)
from pneumatic_env.physics.tube import reynolds_number, tube_resistance
from pneumatic_env.physics.valve import orifice_area, spool_acceleration

__all__ = [
    "line_rows",
    "line_constants",
    "segmented_line_advance",
    "segmented_line_rest",
    "segmented_line_rollout",
]

# rows of the constants vector
(
    _M_INV_SPOOL,
    _C_S,
    _K_S,
    _K_F,
    _R_H,
    _P_W,
    _N_H,
    _C_F,
    _P_S,
    _P_A,
    _INV_SQRT_T,
    _K,
    _C1,
    _C2,
    _P_CR,
    _LIN,
    _SLOPE,
    _RT,
    _ALPHA_IN,
    _ALPHA_OUT,
    _ALPHA_MOTION,
    _A_T,
    _DX,
    _D_T,
    _MU,
    _RE_T,
    _A_LEAK,
    _A1,
    _A2,
    _A_ROD,
    _MODE,
    _HALF_STROKE,
    _V01,
    _V02,
    _X0,
    _INV_MASS,
    _F_SF,
    _F_DF,
    _BETA,
    _F_LOAD,
    _K_SPRING,
    _X_REST,
    _R_GAS,
    _T_WALL,
    _HA_REF,
    _RHO_REF,
    _HA_EXPONENT,
    _N_CONSTANTS,
) = range(48)


def line_constants(
    p: dict, n_segments: int, wall_heat: tuple[float, float, float] | None = None
) -> np.ndarray:
    """The constants of :func:`segmented_line_rollout` for the parameters ``p`` (a
    ``load_parameters`` dict, any piston mode) and ``n_segments`` nodes per tube.

    ``wall_heat`` = (hA_ref in W/K, rho_ref in kg/m^3, n): the chambers follow the energy
    equation (``effects.chamber_energy_rates``) with a wall conductance hA_ref (rho /
    rho_ref)^n, the air entering them at the wall's temperature (the line's); default:
    Eq. 14."""
    switched_on = [
        n
        for n, neutral in L.EFFECT_NEUTRAL_VALUES.items()
        if n not in ("tube_waves", "tube_volume_fraction") and float(p.get(n, neutral)) != neutral
    ]
    if switched_on:
        raise ValueError(
            f"the segmented line plant has the paper's valve and chambers only; "
            f"effects switched on: {switched_on}"
        )
    if not (isinstance(n_segments, (int, np.integer)) and n_segments >= 2):
        raise ValueError(f"n_segments = {n_segments!r} is not allowed: must be an integer >= 2")
    r_gas, temp = p["gas_constant_j_per_kg_k"], p["temperature_k"]
    inv_sqrt_t, k, c1, c2, pcr, lin, slope = orifice_gas_constants(
        p["heat_capacity_ratio"], r_gas, temp, p["flow_linear_ratio"]
    )
    area_cap, area_rod_side, _ = piston_areas_m2(p["bore_diameter_m"], p["rod_diameter_m"])
    c = np.empty(_N_CONSTANTS)
    c[_M_INV_SPOOL] = 1.0 / p["spool_mass_kg"]
    c[_C_S], c[_K_S] = p["spool_damping_n_s_per_m"], p["spool_spring_n_per_m"]
    c[_K_F], c[_R_H] = p["coil_force_n_per_a"], p["hole_radius_m"]
    c[_P_W], c[_N_H] = p["spool_half_width_m"], p["holes_per_path"]
    c[_C_F], c[_P_S], c[_P_A] = (
        p["discharge_coefficient"],
        p["supply_pressure_pa"],
        p["ambient_pressure_pa"],
    )
    c[_INV_SQRT_T], c[_K], c[_C1], c[_C2], c[_P_CR] = inv_sqrt_t, k, c1, c2, pcr
    c[_LIN] = lin
    c[_SLOPE] = slope
    c[_RT] = r_gas * temp
    c[_ALPHA_IN], c[_ALPHA_OUT], c[_ALPHA_MOTION] = p["alpha_in"], p["alpha_out"], p["alpha_motion"]
    c[_A_T] = circle_area_m2(p["tube_inner_diameter_m"])
    c[_DX] = p["tube_length_m"] / n_segments
    c[_D_T], c[_MU], c[_RE_T] = (
        p["tube_inner_diameter_m"],
        p["air_viscosity_pa_s"],
        p["reynolds_turbulent"],
    )
    c[_A_LEAK] = p["leakage_area_m2"]
    c[_A1], c[_A2] = area_cap, area_rod_side
    c[_A_ROD] = area_cap - area_rod_side
    fixed = int(p["piston_mode"]) == MODE_FIXED
    c[_MODE], c[_HALF_STROKE] = int(p["piston_mode"]), 0.5 * p["stroke_m"]
    c[_V01], c[_V02] = p["dead_volume_cap_m3"], p["dead_volume_rod_m3"]
    c[_X0] = p["fixed_position_m"] if fixed else 0.0  # the kernel's initial state
    c[_INV_MASS] = 1.0 / (p["piston_mass_kg"] + p["load_mass_kg"])
    c[_F_SF], c[_F_DF] = p["static_friction_n"], p["dynamic_friction_n"]
    c[_BETA], c[_F_LOAD] = p["viscous_friction_n_s_per_m"], p["load_force_n"]
    c[_K_SPRING], c[_X_REST] = p["spring_stiffness_n_per_m"], p["spring_rest_position_m"]
    c[_R_GAS], c[_T_WALL] = r_gas, temp
    c[_HA_REF], c[_RHO_REF], c[_HA_EXPONENT] = wall_heat or (0.0, 1.0, 0.0)
    return c


@njit(cache=True)
def _flow(c, area, p_from, p_to):
    """Eq. 39 through an orifice of ``area`` with the valve's C_f (signed, from -> to)."""
    return orifice_mass_flow(
        area,
        c[_C_F],
        p_from,
        p_to,
        c[_INV_SQRT_T],
        c[_K],
        c[_C1],
        c[_C2],
        c[_P_CR],
        c[_LIN],
        c[_SLOPE],
    )


@njit(cache=True)
def _derivatives(c, n, coil_current_a, direction, y, out):
    """dy/dt of the state [x_s, v_s, tube 1 (n nodes, n links, chamber 1), tube 2 (...),
    x, v, T1, T2, exhaust mass] with the piston's direction of motion held (0: held, the
    clamp included)."""
    x_s, v_s = y[0], y[1]
    ix = 2 + 2 * (2 * n + 1)
    x, v = y[ix], y[ix + 1]
    out[0] = v_s
    out[1] = spool_acceleration(
        x_s, v_s, coil_current_a, c[_M_INV_SPOOL], c[_C_S], c[_K_S], c[_K_F]
    )
    a_in = orifice_area(x_s, c[_R_H], c[_P_W], c[_N_H])
    a_ex = orifice_area(-x_s, c[_R_H], c[_P_W], c[_N_H])
    node_rate = c[_K] * c[_RT] / (c[_A_T] * c[_DX])
    p1, p2 = y[2 + 2 * n], y[2 + 2 * (2 * n + 1) - 1]
    v1, v2 = chamber_volumes(x, c[_HALF_STROKE], c[_A1], c[_A2], c[_V01], c[_V02])
    moving = direction != 0.0
    out[ix] = v if moving else 0.0
    applied = pneumatic_force(p1, p2, c[_A1], c[_A2], c[_A_ROD], c[_P_A]) - external_force(
        int(c[_MODE]), x, c[_F_LOAD], c[_K_SPRING], c[_X_REST]
    )
    out[ix + 1] = piston_acceleration(applied, v, direction, c[_F_DF], c[_BETA], c[_INV_MASS])
    leak = _flow(c, c[_A_LEAK], p2, p1)  # chamber 2 -> chamber 1 (Sec. 2.2)
    out[ix + 4] = 0.0
    for side in range(2):
        first = 2 + side * (2 * n + 1)
        supply_area = a_in if side == 0 else a_ex
        exhaust_area = a_ex if side == 0 else a_in
        exhaust = _flow(c, exhaust_area, y[first], c[_P_A])
        out[ix + 4] += max(exhaust, 0.0)
        inflow = _flow(c, supply_area, c[_P_S], y[first]) - exhaust
        for j in range(n):
            node = y[first + j]
            downstream = y[first + j + 1] if j < n - 1 else y[first + 2 * n]
            q = y[first + n + j]
            out[first + j] = node_rate * (inflow - q)
            density = 0.5 * (node + downstream) / c[_RT]
            friction = tube_resistance(
                reynolds_number(q, c[_D_T], c[_MU]), c[_D_T], c[_MU], c[_RE_T]
            )
            out[first + n + j] = c[_A_T] * (node - downstream) / c[_DX] - friction * q / density
            inflow = q
        chamber_in = inflow + (leak if side == 0 else -leak)
        chamber = y[first + 2 * n]
        volume = v1 if side == 0 else v2
        volume_rate = (c[_A1] * out[ix]) if side == 0 else (-c[_A2] * out[ix])
        out[ix + 2 + side] = 0.0
        if c[_HA_REF] == 0.0:
            out[first + 2 * n] = pressure_rate(
                chamber,
                volume,
                volume_rate,
                max(chamber_in, 0.0),
                max(-chamber_in, 0.0),
                c[_RT],
                c[_ALPHA_IN],
                c[_ALPHA_OUT],
                c[_ALPHA_MOTION],
            )
            continue
        gas_t = y[ix + 2 + side]
        density = chamber / (c[_R_GAS] * gas_t)
        out[first + 2 * n], out[ix + 2 + side] = chamber_energy_rates(
            chamber,
            gas_t,
            volume,
            volume_rate,
            max(chamber_in, 0.0),
            max(-chamber_in, 0.0),
            max(chamber_in, 0.0) * c[_T_WALL],
            c[_R_GAS],
            c[_K],
            c[_HA_REF] * (density / c[_RHO_REF]) ** c[_HA_EXPONENT],
            c[_T_WALL],
        )


def line_rows(n: int) -> dict[str, int]:
    """The state rows of the chambers' pressures and temperatures, the rod's position and
    velocity and the exhaust mass (kg let out since rest)."""
    ix = 2 + 2 * (2 * n + 1)
    return {
        "p1": 2 + 2 * n,
        "p2": ix - 1,
        "x": ix,
        "v": ix + 1,
        "t1": ix + 2,
        "t2": ix + 3,
        "exhaust_kg": ix + 4,
    }


@njit(cache=True)
def segmented_line_rest(c, n):
    """The plant at rest: spool centred, every node and chamber at ambient, no flow, the
    piston at rest at the kernel's initial position."""
    ix = 2 + 2 * (2 * n + 1)
    y = np.zeros(ix + 5)
    for side in range(2):
        first = 2 + side * (2 * n + 1)
        y[first : first + n] = c[_P_A]
        y[first + 2 * n] = c[_P_A]
    y[ix] = c[_X0]
    y[ix + 2] = y[ix + 3] = c[_T_WALL]
    return y


@njit(cache=True)
def segmented_line_advance(c, n, y, coil_current_a, step_s, substeps):
    """Advance the state ``y`` in place with ``coil_current_a[j]`` held over plant step j
    (``substeps`` RK4 steps of ``step_s / substeps``). Returns (steps + 1, 4): p1, p2 (Pa),
    the force channel (N: the load cell at a clamp, else as ``piston.output_force``) and
    the piston position (m) at the start and the end of every step."""
    size = y.size
    k1, k2, k3, k4 = np.empty(size), np.empty(size), np.empty(size), np.empty(size)
    stage = np.empty(size)
    out = np.empty((coil_current_a.size + 1, 4))
    h = step_s / substeps
    i1, i2 = 2 + 2 * n, 2 + 2 * (2 * n + 1) - 1
    ix, iv = i2 + 1, i2 + 2
    mode = int(c[_MODE])
    stick = max(c[_F_SF], c[_F_DF])  # Karnopp's threshold, as the kernel's
    for j in range(coil_current_a.size + 1):
        f_p = pneumatic_force(y[i1], y[i2], c[_A1], c[_A2], c[_A_ROD], c[_P_A])
        out[j, 0], out[j, 1], out[j, 3] = y[i1], y[i2], y[ix]
        out[j, 2] = output_force(mode, f_p, y[ix], c[_K_SPRING], c[_X_REST])
        if j == coil_current_a.size:
            break
        current = coil_current_a[j]
        for _ in range(substeps):
            direction = 0.0
            if mode != MODE_FIXED:
                f_p = pneumatic_force(y[i1], y[i2], c[_A1], c[_A2], c[_A_ROD], c[_P_A])
                applied = f_p - external_force(mode, y[ix], c[_F_LOAD], c[_K_SPRING], c[_X_REST])
                direction = motion_direction(y[ix], y[iv], applied, stick, c[_HALF_STROKE])
            _derivatives(c, n, current, direction, y, k1)
            stage[:] = y + 0.5 * h * k1
            _derivatives(c, n, current, direction, stage, k2)
            stage[:] = y + 0.5 * h * k2
            _derivatives(c, n, current, direction, stage, k3)
            stage[:] = y + h * k3
            _derivatives(c, n, current, direction, stage, k4)
            y += (h / 6.0) * (k1 + 2.0 * (k2 + k3) + k4)
            if direction != 0.0 and y[iv] * direction < 0.0:
                y[iv] = 0.0  # the velocity reversed: the piston stops, friction decides next
            y[ix], y[iv] = end_of_substep(y[ix], y[iv], c[_HALF_STROKE])
    return out


@njit(cache=True)
def segmented_line_rollout(c, n, coil_current_a, step_s, substeps):
    """Run the plant from rest (:func:`segmented_line_rest`) with ``coil_current_a[j]``
    held over plant step j; returns :func:`segmented_line_advance`'s outputs."""
    return segmented_line_advance(c, n, segmented_line_rest(c, n), coil_current_a, step_s, substeps)
