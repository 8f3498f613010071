"""The integrator kernel: advances a batch of actuators by one control period.

Each environment is advanced through ``n_substeps`` classical Runge-Kutta (RK4) substeps
with the coil current held (zero-order hold). The tube delay reads a per-environment ring
buffer holding the spool position and chamber pressures at substep boundaries; delayed
values between boundaries are interpolated linearly. Piston friction and end stops are
handled between substeps (``piston.motion_direction`` / ``piston.end_of_substep``), so
each RK4 substep integrates a smooth right-hand side.
"""
import math
from collections import namedtuple

import numpy as np
from numba import njit, prange

from . import layout as L
from .chamber import chamber_volumes, pressure_rate
from .flow import flow_constants, orifice_mass_flow, subsonic_reduced_flow
from .piston import (MODE_FIXED, end_of_substep, external_force, motion_direction,
                     output_force, piston_acceleration, pneumatic_force)
from .tube import sound_speed, tube_attenuation
from .valve import orifice_area, spool_acceleration

Constants = namedtuple("Constants", (
    "gas_rt", "inv_sqrt_t", "k", "c1", "c2", "critical_ratio", "linear_ratio", "linear_slope",
    "supply_pa", "ambient_pa", "viscosity", "alpha_in", "alpha_out", "alpha_motion",
    "spool_mass", "spool_damping", "spool_spring", "coil_force", "discharge", "hole_radius",
    "half_width", "holes", "delay_s", "delay_substeps", "tube_diameter", "reynolds_turbulent",
    "literal", "area_cap", "area_rod", "rod_area", "half_stroke", "dead_cap", "dead_rod",
    "moving_mass", "dynamic_friction", "stick_threshold", "viscous", "leak_area", "mode",
    "load_force", "spring_k", "spring_rest",
))


@njit(cache=True)
def env_constants(params, env, substep_s):
    """Per-environment constants derived once per control period from the parameter column."""
    p = params[:, env]
    k = p[L.P_HEAT_CAPACITY_RATIO]
    gas = p[L.P_GAS_CONSTANT_J_PER_KG_K]
    temperature = p[L.P_TEMPERATURE_K]
    c1, c2, critical_ratio = flow_constants(k, gas)
    linear_ratio = p[L.P_FLOW_LINEAR_RATIO]
    linear_slope = subsonic_reduced_flow(linear_ratio, k, c2) / (1.0 - linear_ratio)
    delay_s = p[L.P_TUBE_LENGTH_M] / sound_speed(k, gas, temperature)
    bore = p[L.P_BORE_DIAMETER_M]
    rod = p[L.P_ROD_DIAMETER_M]
    area_cap = 0.25 * math.pi * bore * bore
    rod_area = 0.25 * math.pi * rod * rod
    return Constants(
        gas * temperature, 1.0 / math.sqrt(temperature), k, c1, c2, critical_ratio,
        linear_ratio, linear_slope,
        p[L.P_SUPPLY_PRESSURE_PA], p[L.P_AMBIENT_PRESSURE_PA], p[L.P_AIR_VISCOSITY_PA_S],
        p[L.P_ALPHA_IN], p[L.P_ALPHA_OUT], p[L.P_ALPHA_MOTION],
        p[L.P_SPOOL_MASS_KG], p[L.P_SPOOL_DAMPING_N_S_PER_M], p[L.P_SPOOL_SPRING_N_PER_M],
        p[L.P_COIL_FORCE_N_PER_A], p[L.P_DISCHARGE_COEFFICIENT], p[L.P_HOLE_RADIUS_M],
        p[L.P_SPOOL_HALF_WIDTH_M], p[L.P_HOLES_PER_PATH],
        delay_s, delay_s / substep_s, p[L.P_TUBE_INNER_DIAMETER_M], p[L.P_REYNOLDS_TURBULENT],
        p[L.P_TUBE_COUPLING] == 1.0,
        area_cap, area_cap - rod_area, rod_area, 0.5 * p[L.P_STROKE_M],
        p[L.P_DEAD_VOLUME_CAP_M3], p[L.P_DEAD_VOLUME_ROD_M3],
        p[L.P_PISTON_MASS_KG] + p[L.P_LOAD_MASS_KG], p[L.P_DYNAMIC_FRICTION_N],
        max(p[L.P_STATIC_FRICTION_N], p[L.P_DYNAMIC_FRICTION_N]),
        p[L.P_VISCOUS_FRICTION_N_S_PER_M], p[L.P_LEAKAGE_AREA_M2], int(p[L.P_PISTON_MODE]),
        p[L.P_LOAD_FORCE_N], p[L.P_SPRING_STIFFNESS_N_PER_M], p[L.P_SPRING_REST_POSITION_M],
    )


@njit(cache=True)
def _flow(c, area, p_from, p_to):
    return orifice_mass_flow(area, c.discharge, p_from, p_to, c.inv_sqrt_t, c.k, c.c1, c.c2,
                             c.critical_ratio, c.linear_ratio, c.linear_slope)


@njit(cache=True)
def _tube(c, mass_flow, chamber_pa):
    return mass_flow * tube_attenuation(mass_flow, chamber_pa, c.gas_rt, c.delay_s,
                                        c.tube_diameter, c.viscosity, c.reynolds_turbulent)


@njit(cache=True)
def valve_chamber_flows(c, spool_delayed_m, valve_p1_pa, valve_p2_pa, p1_pa, p2_pa):
    """Mass flows into (+) each chamber through its tube: supply and exhaust paths (Eqs. 50-55).

    ``spool_delayed_m`` is x_s(t - tau); ``valve_p*`` are the chamber pressures the valve
    flow is evaluated with (current ones for the command coupling, delayed ones for the
    literal Eq. 55); ``p*_pa`` are the current tube-end pressures used by the attenuation.
    Returns (supply->1, 1->exhaust, supply->2, 2->exhaust) as flows at the chamber end.
    """
    area_a = orifice_area(spool_delayed_m, c.hole_radius, c.half_width, c.holes)
    area_b = orifice_area(-spool_delayed_m, c.hole_radius, c.half_width, c.holes)
    supply_1 = _tube(c, _flow(c, area_a, c.supply_pa, valve_p1_pa), p1_pa)
    exhaust_1 = _tube(c, _flow(c, area_b, valve_p1_pa, c.ambient_pa), p1_pa)
    supply_2 = _tube(c, _flow(c, area_b, c.supply_pa, valve_p2_pa), p2_pa)
    exhaust_2 = _tube(c, _flow(c, area_a, valve_p2_pa, c.ambient_pa), p2_pa)
    return supply_1, exhaust_1, supply_2, exhaust_2


@njit(cache=True)
def derivatives(c, coil_current_a, x_s, v_s, p1, p2, x, v, direction, spool_delayed,
                valve_p1, valve_p2):
    """Right-hand side of the state (x_s, v_s, P1, P2, x, v, exhaust mass)."""
    supply_1, exhaust_1, supply_2, exhaust_2 = valve_chamber_flows(
        c, spool_delayed, valve_p1, valve_p2, p1, p2)
    leak_12 = _flow(c, c.leak_area, p1, p2)
    in_1 = max(supply_1, 0.0) + max(-exhaust_1, 0.0) + max(-leak_12, 0.0)
    out_1 = max(-supply_1, 0.0) + max(exhaust_1, 0.0) + max(leak_12, 0.0)
    in_2 = max(supply_2, 0.0) + max(-exhaust_2, 0.0) + max(leak_12, 0.0)
    out_2 = max(-supply_2, 0.0) + max(exhaust_2, 0.0) + max(-leak_12, 0.0)
    velocity = v if direction != 0.0 else 0.0
    v1, v2 = chamber_volumes(x, c.half_stroke, c.area_cap, c.area_rod, c.dead_cap, c.dead_rod)
    dp1 = pressure_rate(p1, v1, c.area_cap * velocity, in_1, out_1, c.gas_rt,
                        c.alpha_in, c.alpha_out, c.alpha_motion)
    dp2 = pressure_rate(p2, v2, -c.area_rod * velocity, in_2, out_2, c.gas_rt,
                        c.alpha_in, c.alpha_out, c.alpha_motion)
    accel = 0.0
    if direction != 0.0:
        applied = (pneumatic_force(p1, p2, c.area_cap, c.area_rod, c.rod_area, c.ambient_pa)
                   - external_force(c.mode, x, c.load_force, c.spring_k, c.spring_rest))
        accel = piston_acceleration(applied, velocity, direction, c.dynamic_friction,
                                    c.viscous, c.moving_mass)
    a_s = spool_acceleration(x_s, v_s, coil_current_a, c.spool_mass, c.spool_damping,
                             c.spool_spring, c.coil_force)
    exhaust_rate = max(exhaust_1, 0.0) + max(exhaust_2, 0.0)
    return v_s, a_s, dp1, dp2, velocity, accel, exhaust_rate


@njit(cache=True)
def delayed_value(history, env, channel, head, stage_substeps, delay_substeps, value_at_head,
                  value_at_stage):
    """Value of a history channel at (stage time - delay), by linear interpolation.

    Times are in substeps relative to the last boundary ``head``; a query after ``head``
    (a delay shorter than the stage offset) interpolates towards the stage's own value.
    """
    query = stage_substeps - delay_substeps
    if query >= 0.0:
        if stage_substeps <= 0.0:
            return value_at_head
        return value_at_head + (query / stage_substeps) * (value_at_stage - value_at_head)
    n_slots = history.shape[1]
    base = math.floor(query)
    weight = query - base
    lower = history[env, (head + int(base)) % n_slots, channel]
    upper = history[env, (head + int(base) + 1) % n_slots, channel]
    return lower + weight * (upper - lower)


@njit(cache=True)
def _stage(c, history, env, head, frac, coil_current_a, y, y0, direction):
    spool_delayed = delayed_value(history, env, L.H_X_S, head, frac, c.delay_substeps, y0[0], y[0])
    if c.literal:
        valve_p1 = delayed_value(history, env, L.H_P1, head, frac, c.delay_substeps, y0[2], y[2])
        valve_p2 = delayed_value(history, env, L.H_P2, head, frac, c.delay_substeps, y0[3], y[3])
    else:
        valve_p1 = y[2]
        valve_p2 = y[3]
    return derivatives(c, coil_current_a, y[0], y[1], y[2], y[3], y[4], y[5], direction,
                       spool_delayed, valve_p1, valve_p2)


@njit(cache=True)
def _axpy(y, h, k):
    return (y[0] + h * k[0], y[1] + h * k[1], y[2] + h * k[2], y[3] + h * k[3],
            y[4] + h * k[4], y[5] + h * k[5], y[6] + h * k[6])


@njit(cache=True)
def advance_env(params, state, history, env, head, coil_current_a, control_dt_s, n_substeps,
                outputs):
    """Advance environment ``env`` by one control period; write its outputs row."""
    h = control_dt_s / n_substeps
    c = env_constants(params, env, h)
    n_slots = history.shape[1]
    y = (state[L.S_X_S, env], state[L.S_V_S, env], state[L.S_P1, env], state[L.S_P2, env],
         state[L.S_X, env], state[L.S_V, env], state[L.S_EXHAUST, env])
    pressure_floor = 1e-3 * c.ambient_pa
    for sub in range(n_substeps):
        head_sub = head + sub
        direction = 0.0
        if c.mode != MODE_FIXED:
            applied = (pneumatic_force(y[2], y[3], c.area_cap, c.area_rod, c.rod_area,
                                       c.ambient_pa)
                       - external_force(c.mode, y[4], c.load_force, c.spring_k, c.spring_rest))
            direction = motion_direction(y[4], y[5], applied, c.stick_threshold, c.half_stroke)
        k1 = _stage(c, history, env, head_sub, 0.0, coil_current_a, y, y, direction)
        k2 = _stage(c, history, env, head_sub, 0.5, coil_current_a, _axpy(y, 0.5 * h, k1), y,
                    direction)
        k3 = _stage(c, history, env, head_sub, 0.5, coil_current_a, _axpy(y, 0.5 * h, k2), y,
                    direction)
        k4 = _stage(c, history, env, head_sub, 1.0, coil_current_a, _axpy(y, h, k3), y,
                    direction)
        w = h / 6.0
        x_s = y[0] + w * (k1[0] + 2.0 * k2[0] + 2.0 * k3[0] + k4[0])
        v_s = y[1] + w * (k1[1] + 2.0 * k2[1] + 2.0 * k3[1] + k4[1])
        p1 = max(y[2] + w * (k1[2] + 2.0 * k2[2] + 2.0 * k3[2] + k4[2]), pressure_floor)
        p2 = max(y[3] + w * (k1[3] + 2.0 * k2[3] + 2.0 * k3[3] + k4[3]), pressure_floor)
        x = y[4]
        v = y[5]
        if direction != 0.0:
            x, v = end_of_substep(y[4] + w * (k1[4] + 2.0 * k2[4] + 2.0 * k3[4] + k4[4]),
                                  y[5] + w * (k1[5] + 2.0 * k2[5] + 2.0 * k3[5] + k4[5]),
                                  direction, c.half_stroke)
        exhaust = y[6] + w * (k1[6] + 2.0 * k2[6] + 2.0 * k3[6] + k4[6])
        y = (x_s, v_s, p1, p2, x, v, exhaust)
        slot = (head_sub + 1) % n_slots
        history[env, slot, L.H_X_S] = x_s
        history[env, slot, L.H_P1] = p1
        history[env, slot, L.H_P2] = p2
    for row in range(L.N_STATE):
        state[row, env] = y[row]
    f_p = pneumatic_force(y[2], y[3], c.area_cap, c.area_rod, c.rod_area, c.ambient_pa)
    outputs[L.O_P1, env] = y[2]
    outputs[L.O_P2, env] = y[3]
    outputs[L.O_X, env] = y[4]
    outputs[L.O_F, env] = output_force(c.mode, f_p, y[4], c.spring_k, c.spring_rest)
    outputs[L.O_V, env] = y[5]
    outputs[L.O_X_S, env] = y[0]
    outputs[L.O_EXHAUST, env] = y[6]


@njit(cache=True)
def step_serial(params, state, history, head, coil_current_a, control_dt_s, n_substeps, outputs):
    """Advance every environment of the batch by one control period on one thread."""
    for env in range(state.shape[1]):
        advance_env(params, state, history, env, head, coil_current_a[env], control_dt_s,
                    n_substeps, outputs)


@njit(cache=True, parallel=True)
def step_parallel(params, state, history, head, coil_current_a, control_dt_s, n_substeps,
                  outputs):
    """Advance every environment of the batch by one control period, environments in parallel."""
    for env in prange(state.shape[1]):
        advance_env(params, state, history, env, head, coil_current_a[env], control_dt_s,
                    n_substeps, outputs)


@njit(cache=True)
def rollout_serial(params, state, history, head, coil_current_a, control_dt_s, n_substeps,
                   outputs):
    """Run a whole open-loop current sequence ``coil_current_a[step, env]`` in one call.

    ``outputs[step, O_*, env]`` receives the outputs after each control period.
    """
    for step in range(coil_current_a.shape[0]):
        step_serial(params, state, history, head + step * n_substeps, coil_current_a[step],
                    control_dt_s, n_substeps, outputs[step])


def history_slots(max_delay_s, control_dt_s, n_substeps):
    """Ring-buffer length for delays up to ``max_delay_s`` (a whole number of substeps + 2)."""
    return int(np.ceil(max_delay_s / (control_dt_s / n_substeps))) + 2
