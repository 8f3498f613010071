"""The integrator kernel: advances a batch of actuators by one control period.

Each environment is advanced through ``n_substeps`` classical Runge-Kutta (RK4) substeps
with the coil current held (zero-order hold). The tube delay reads a per-environment ring
buffer holding the spool position and chamber pressures at substep boundaries (and, with
the tubes as transmission lines, ``tube_waves``, the waves each tube end sends); delayed
values between boundaries are interpolated linearly. Piston friction and end stops are
handled between substeps (``piston.motion_direction`` / ``piston.end_of_substep``), so
each RK4 substep integrates a smooth right-hand side.

The effects beyond the paper's model (docs/effects.md, ``effects.py``) are switched per
environment by their parameter rows; ``env_constants`` turns each into a flag or a
neutral constant once per control period, so an effect that is off costs a branch.

Two paths share the sub-models. The batch path (``advance_chunk``, used by every step
function) advances chunks of ``CHUNK_ENVS`` environments running the paper's model one
RK4 substep at a time in a single loop over the chunk that LLVM compiles to SIMD code
(``base_derivatives``, branch-free, ``vecmath``). The general path (``advance_env``, one
environment through the whole control period, ``derivatives``) takes environments with
other effects on, and redoes a lane's substep that is stiff or crosses a piston event.
Both give the same numbers bit for bit (tests/test_physics.py).
"""
import math
from collections import namedtuple

import numpy as np
from numba import njit, prange

from . import layout as L
from .chamber import chamber_volumes, pressure_rate
from .effects import (chamber_energy_rates, coil_decay, coil_force_gain, coil_time_constants,
                      dead_volume_with_tube,
                      drooped_supply_pressure, lagged_coil_current,
                      lagged_coil_force_current, lugre_bristle_step, spool_play_band,
                      spool_play_current, stribeck_friction)
from .flow import (FLOW_LAW_ISO, FLOW_LAW_PAPER, flow_constants, iso_subsonic_reduced_flow,
                   orifice_mass_flow_inv_k,
                   subsonic_reduced_flow)
from .piston import (MODE_FIXED, apply_event, end_of_substep, event_fraction,
                     external_force, motion_direction,
                     output_force, piston_acceleration, pneumatic_force)
from .tube import (line_chamber_flow, line_end_wave, line_resistance, sound_speed,
                   reynolds_per_mass_flow, tube_attenuation_scaled, viscous_scale)
from .valve import orifice_area_inv_radius, spool_acceleration
from .vecmath import _float_to_bits

# advance_env integrates the state rows 0 .. S_T2 with RK4 and sets S_COIL, S_PLAY,
# S_COIL_FORCE, S_EXHAUST_NODE and S_BRISTLE exactly.
assert (L.S_T1, L.S_T2, L.S_COIL, L.S_PLAY, L.S_COIL_FORCE, L.S_EXHAUST_NODE, L.S_BRISTLE,
        L.N_STATE) == (7, 8, 9, 10, 11, 12, 13, 14), \
    "kernel assumes this state layout"

Constants = namedtuple("Constants", (
    "gas_rt", "inv_sqrt_t", "k", "c1", "c2", "critical_ratio", "linear_ratio", "linear_slope",
    "supply_pa", "ambient_pa", "viscosity", "alpha_in", "alpha_out", "alpha_motion",
    "inv_spool_mass", "spool_damping", "spool_spring", "coil_force", "discharge", "hole_radius",
    "half_width", "holes", "delay_s", "delay_substeps", "tube_diameter", "reynolds_turbulent",
    "literal", "area_cap", "area_rod", "rod_area", "half_stroke", "dead_cap", "dead_rod",
    "inv_moving_mass", "dynamic_friction", "stick_threshold", "viscous", "leak_area", "mode",
    "load_force", "spring_k", "spring_rest",
    # effects (docs/effects.md)
    "discharge_ex", "null_leak", "seal_leak", "flow_law", "supply_resistance", "exhaust_vent",
    "exhaust_capacity", "coil_lag", "coil_decay_half", "coil_decay_full", "coil_force_lag",
    "force_rate", "force_rate_difference",
    "energy", "gas", "temperature", "heat_conductance",
    "static_friction", "stribeck", "stribeck_v", "spool_play_band",
    "lugre", "lugre_stiffness", "lugre_damping",
    "waves", "line_impedance", "line_friction",
    # numerical guards (docs/convergence.md): pressures and gas temperatures stay positive
    "pressure_floor", "temperature_floor",
    "stiffness_volume",  # lambda_max * V (m^3/s): see refinement()
    # reciprocals and products the right-hand side would otherwise divide by per evaluation
    # (a division takes a divider's latency; a product does not), as inv_spool_mass (1/M_s)
    # and inv_moving_mass (1/(M_p + M_L)) above: 1/k, 1/R_h, R T tau / 2, Re per kg/s,
    # mu / D^2
    "inv_k", "inv_hole_radius", "half_rt_delay", "reynolds_per_flow", "viscous_scale",
))


PRESSURE_FLOOR_FRACTION = 1e-3  # of ambient: a guard that keeps log/pow arguments positive
TEMPERATURE_FLOOR_FRACTION = 1e-3  # of the wall temperature, the same guard for T1, T2


@njit(cache=True)
def env_constants(params, env, substep_s):
    """Per-environment constants derived once per control period from the parameter column.

    Every field is a float (flags are 0.0 / 1.0), so the batch kernel can hold them as the
    rows of one array (``store_constants`` / ``load_constants``).
    """
    p = params[:, env]
    k = p[L.P_HEAT_CAPACITY_RATIO]
    gas = p[L.P_GAS_CONSTANT_J_PER_KG_K]
    temperature = p[L.P_TEMPERATURE_K]
    c1, c2, critical_ratio = flow_constants(k, gas)
    linear_ratio = p[L.P_FLOW_LINEAR_RATIO]
    flow_law = int(p[L.P_FLOW_LAW])
    if flow_law == FLOW_LAW_ISO:
        critical_ratio = p[L.P_ISO_CRITICAL_RATIO_B]
        linear_slope = (iso_subsonic_reduced_flow(linear_ratio, c1, critical_ratio)
                        / (1.0 - linear_ratio))
    else:
        linear_slope = subsonic_reduced_flow(linear_ratio, k, c2) / (1.0 - linear_ratio)
    tube_length = p[L.P_TUBE_LENGTH_M]
    tube_diameter = p[L.P_TUBE_INNER_DIAMETER_M]
    delay_s = tube_length / sound_speed(k, gas, temperature)
    bore = p[L.P_BORE_DIAMETER_M]
    rod = p[L.P_ROD_DIAMETER_M]
    area_cap = 0.25 * math.pi * bore * bore
    rod_area = 0.25 * math.pi * rod * rod
    tube_fraction = p[L.P_TUBE_VOLUME_FRACTION]
    coil_tau, force_tau = coil_time_constants(p[L.P_COIL_TIME_CONSTANT_S],
                                              p[L.P_COIL_LAG_SHAPE])
    heat_conductance = p[L.P_WALL_HEAT_TRANSFER_W_PER_K]
    stribeck_v = p[L.P_STRIBECK_VELOCITY_M_PER_S]
    literal_flag = 1.0 if p[L.P_TUBE_COUPLING] == 1.0 else 0.0
    coil_lag_flag = 1.0 if coil_tau > 0.0 else 0.0
    force_lag_flag = 1.0 if force_tau > 0.0 else 0.0
    force_rate = substep_s / force_tau if force_tau > 0.0 else 0.0  # substeps per tau_f
    force_rate_difference = 0.0  # substep (1/tau_f - 1/tau_c), with both lags on
    if force_tau > 0.0 and coil_tau > 0.0:
        force_rate_difference = force_rate - substep_s / coil_tau
    energy_flag = 1.0 if heat_conductance > 0.0 else 0.0
    stribeck_flag = 1.0 if stribeck_v > 0.0 else 0.0
    lugre_flag = 1.0 if p[L.P_LUGRE_STIFFNESS_N_PER_M] > 0.0 else 0.0
    # Karnopp's stick threshold; LuGre friction has none (its bristles hold the rod)
    stick_threshold = max(p[L.P_STATIC_FRICTION_N], p[L.P_DYNAMIC_FRICTION_N])
    if lugre_flag:
        stick_threshold = 0.0
    waves_flag = 1.0 if p[L.P_TUBE_WAVES] == 1.0 else 0.0
    tube_area = 0.25 * math.pi * tube_diameter * tube_diameter
    line_impedance = sound_speed(k, gas, temperature) / tube_area
    return Constants(
        gas * temperature, 1.0 / math.sqrt(temperature), k, c1, c2, critical_ratio,
        linear_ratio, linear_slope,
        p[L.P_SUPPLY_PRESSURE_PA], p[L.P_AMBIENT_PRESSURE_PA], p[L.P_AIR_VISCOSITY_PA_S],
        p[L.P_ALPHA_IN], p[L.P_ALPHA_OUT], p[L.P_ALPHA_MOTION],
        1.0 / p[L.P_SPOOL_MASS_KG], p[L.P_SPOOL_DAMPING_N_S_PER_M], p[L.P_SPOOL_SPRING_N_PER_M],
        p[L.P_COIL_FORCE_N_PER_A], p[L.P_DISCHARGE_COEFFICIENT], p[L.P_HOLE_RADIUS_M],
        p[L.P_SPOOL_HALF_WIDTH_M], p[L.P_HOLES_PER_PATH],
        delay_s, delay_s / substep_s, tube_diameter, p[L.P_REYNOLDS_TURBULENT],
        literal_flag,
        area_cap, area_cap - rod_area, rod_area, 0.5 * p[L.P_STROKE_M],
        dead_volume_with_tube(p[L.P_DEAD_VOLUME_CAP_M3], tube_fraction, tube_diameter,
                              tube_length),
        dead_volume_with_tube(p[L.P_DEAD_VOLUME_ROD_M3], tube_fraction, tube_diameter,
                              tube_length),
        1.0 / (p[L.P_PISTON_MASS_KG] + p[L.P_LOAD_MASS_KG]), p[L.P_DYNAMIC_FRICTION_N],
        stick_threshold,
        p[L.P_VISCOUS_FRICTION_N_S_PER_M], p[L.P_LEAKAGE_AREA_M2], float(int(p[L.P_PISTON_MODE])),
        p[L.P_LOAD_FORCE_N], p[L.P_SPRING_STIFFNESS_N_PER_M], p[L.P_SPRING_REST_POSITION_M],
        p[L.P_DISCHARGE_COEFFICIENT] * p[L.P_EXHAUST_DISCHARGE_RATIO],
        p[L.P_VALVE_NULL_LEAK_AREA_M2], p[L.P_ROD_SEAL_LEAK_AREA_M2], float(flow_law),
        p[L.P_SUPPLY_RESISTANCE_PA_S_PER_KG], p[L.P_EXHAUST_VENT_AREA_M2],
        p[L.P_EXHAUST_VOLUME_M3] / (gas * temperature), coil_lag_flag,
        coil_decay(coil_tau, 0.5 * substep_s), coil_decay(coil_tau, substep_s),
        force_lag_flag, force_rate, force_rate_difference,
        energy_flag, gas, temperature, heat_conductance,
        p[L.P_STATIC_FRICTION_N], stribeck_flag, stribeck_v,
        spool_play_band(p[L.P_SPOOL_COULOMB_FRICTION_N], p[L.P_COIL_FORCE_N_PER_A]),
        lugre_flag, p[L.P_LUGRE_STIFFNESS_N_PER_M], p[L.P_LUGRE_DAMPING_N_S_PER_M],
        waves_flag, line_impedance, tube_length * gas * temperature / tube_area,
        PRESSURE_FLOOR_FRACTION * p[L.P_AMBIENT_PRESSURE_PA], TEMPERATURE_FLOOR_FRACTION * temperature,
        gas * temperature * max(p[L.P_ALPHA_IN], k)
        * p[L.P_DISCHARGE_COEFFICIENT] * max(1.0, p[L.P_EXHAUST_DISCHARGE_RATIO])
        * (p[L.P_HOLES_PER_PATH] * math.pi * p[L.P_HOLE_RADIUS_M] ** 2
           + p[L.P_VALVE_NULL_LEAK_AREA_M2] + p[L.P_LEAKAGE_AREA_M2] + p[L.P_ROD_SEAL_LEAK_AREA_M2])
        * (linear_slope + c1) / math.sqrt(temperature)
        + waves_flag * gas * temperature * max(p[L.P_ALPHA_IN], k) / line_impedance,
        1.0 / k, 1.0 / p[L.P_HOLE_RADIUS_M], 0.5 * gas * temperature * delay_s,
        reynolds_per_mass_flow(tube_diameter, p[L.P_AIR_VISCOSITY_PA_S]),
        viscous_scale(tube_diameter, p[L.P_AIR_VISCOSITY_PA_S]),
    )


@njit(cache=True, forceinline=True, error_model="numpy")
def _flow(c, discharge, area, p_from, p_to, inv_sqrt_t_from, inv_sqrt_t_to, flow_law):
    """Eq. 39 from node ``from`` to node ``to``, at the upstream node's temperature.

    A closed orifice returns at once on the general (scalar) path; in the vectorised loop
    the test becomes a select.
    """
    if area <= 0.0:
        return 0.0
    inv_sqrt_t = inv_sqrt_t_from if p_from >= p_to else inv_sqrt_t_to
    return orifice_mass_flow_inv_k(area, discharge, p_from, p_to, inv_sqrt_t, c.inv_k, c.c1,
                                   c.c2, c.critical_ratio, c.linear_ratio, c.linear_slope,
                                   flow_law)


@njit(cache=True, forceinline=True, error_model="numpy")
def _tube(c, mass_flow, chamber_pa):
    """The flow delivered at the chamber end of the tube (Eq. 30); none in, none out."""
    if mass_flow == 0.0:
        return 0.0
    return mass_flow * tube_attenuation_scaled(mass_flow, chamber_pa, c.half_rt_delay,
                                               c.reynolds_per_flow, c.viscous_scale,
                                               c.reynolds_turbulent)


SUPPLY_DROOP_RTOL = 1e-10  # solver accuracy of the supply droop, relative to P_s (not physics)
SUPPLY_DROOP_MAX_ITERATIONS = 60  # a safeguard; the root is usually found in 1-4 steps


@njit(cache=True, inline="always")
def _illinois_update(lo, f_lo, hi, f_hi, x, f, side):
    """One bracket update of the Illinois method (regula falsi) with the new point (x, f):
    it replaces the end of its sign, and halves the other end's value when that end was
    kept twice in a row (``side``: the sign replaced last). Returns (lo, f_lo, hi, f_hi,
    side)."""
    if f > 0.0:
        if side == 1:
            f_lo *= 0.5
        return lo, f_lo, x, f, 1
    if side == -1:
        f_hi *= 0.5
    return x, f, hi, f_hi, -1


@njit(cache=True)
def _supply_flow(c, supply_pa, area_a, area_b, valve_p1_pa, valve_p2_pa, inv_sqrt_t1,
                 inv_sqrt_t2):
    """Total valve flow out of the supply (both paths, before the tubes), >= 0."""
    return max(_flow(c, c.discharge, area_a, supply_pa, valve_p1_pa, c.inv_sqrt_t, inv_sqrt_t1,
                     c.flow_law)
               + _flow(c, c.discharge, area_b, supply_pa, valve_p2_pa, c.inv_sqrt_t,
                       inv_sqrt_t2, c.flow_law), 0.0)


@njit(cache=True)
def supply_pressure_at_valve(c, area_a, area_b, valve_p1_pa, valve_p2_pa, inv_sqrt_t1,
                             inv_sqrt_t2):
    """Supply pressure the valve sees through the supply resistance (effect, docs/effects.md).

    The root of f(P) = P - P_s + R_sup mdot_s(P), mdot_s the total supply flow (its
    positive part: a back flow does not raise the supply); f increases with P, so the root
    is unique and bracketed by [max(P_s - R_sup mdot_s(P_s), min(P1, P2)), P_s]. Started
    at the choked estimate (``effects.drooped_supply_pressure``, exact while choked), then
    Illinois regula falsi to ``SUPPLY_DROOP_RTOL``. No flow means no droop.
    """
    supply_pa = c.supply_pa
    resistance = c.supply_resistance
    flow_at_supply = _supply_flow(c, supply_pa, area_a, area_b, valve_p1_pa, valve_p2_pa,
                                  inv_sqrt_t1, inv_sqrt_t2)
    if flow_at_supply <= 0.0:
        return supply_pa
    tolerance = SUPPLY_DROOP_RTOL * supply_pa
    hi = supply_pa
    f_hi = resistance * flow_at_supply
    lo = max(supply_pa - f_hi, min(valve_p1_pa, valve_p2_pa))
    f_lo = lo - supply_pa + resistance * _supply_flow(c, lo, area_a, area_b, valve_p1_pa,
                                                      valve_p2_pa, inv_sqrt_t1, inv_sqrt_t2)
    if f_lo >= 0.0:
        return lo
    guess = drooped_supply_pressure(supply_pa, flow_at_supply, resistance)
    side = 0
    for _ in range(SUPPLY_DROOP_MAX_ITERATIONS):
        f_guess = guess - supply_pa + resistance * _supply_flow(
            c, guess, area_a, area_b, valve_p1_pa, valve_p2_pa, inv_sqrt_t1, inv_sqrt_t2)
        if abs(f_guess) <= tolerance:
            return guess
        lo, f_lo, hi, f_hi, side = _illinois_update(lo, f_lo, hi, f_hi, guess, f_guess, side)
        guess = (lo * f_hi - hi * f_lo) / (f_hi - f_lo)
    return guess


@njit(cache=True)
def _exhaust_node_balance(c, exhaust_pa, area_a, area_b, valve_p1_pa, valve_p2_pa,
                          inv_sqrt_t1, inv_sqrt_t2):
    """Valve flow into the exhaust node (chamber 1 through path b, chamber 2 through path
    a, Eq. 39) minus the vent's flow out of it to the atmosphere (Eq. 39 with C_f = 1 on
    the effective vent area), kg/s; it decreases as ``exhaust_pa`` rises."""
    into_node = (_flow(c, c.discharge_ex, area_b, valve_p1_pa, exhaust_pa, inv_sqrt_t1,
                       c.inv_sqrt_t, c.flow_law)
                 + _flow(c, c.discharge_ex, area_a, valve_p2_pa, exhaust_pa, inv_sqrt_t2,
                         c.inv_sqrt_t, c.flow_law))
    vented = _flow(c, 1.0, c.exhaust_vent, exhaust_pa, c.ambient_pa, c.inv_sqrt_t,
                   c.inv_sqrt_t, c.flow_law)
    return into_node - vented


@njit(cache=True)
def exhaust_pressure_at_valve(c, area_a, area_b, valve_p1_pa, valve_p2_pa, inv_sqrt_t1,
                              inv_sqrt_t2, storage_kg_per_pa, previous_pa):
    """Pressure of the exhaust node behind a vent (exhaust back-pressure, docs/effects.md).

    The root of ``_exhaust_node_balance(P) - storage_kg_per_pa (P - previous_pa)``. With no
    storage (the node holds no air) what the valve exhausts leaves through the vent at
    once; with the storage V / (R T h) of a node of volume V, this is the backward-Euler
    step of dP/dt = (R T / V) balance(P) over h from ``previous_pa``. The function falls
    as P rises, so the root is unique and bracketed by the lowest and the highest of P_a,
    P1, P2 (and ``previous_pa``): at the lowest, air can only enter the node; at the
    highest, only leave it. Illinois regula falsi until a step is below
    ``SUPPLY_DROOP_RTOL`` P_s. A node with no storage and no open exhaust path is at P_a.
    """
    if storage_kg_per_pa == 0.0 and area_a <= 0.0 and area_b <= 0.0:
        return c.ambient_pa
    lo = min(c.ambient_pa, valve_p1_pa, valve_p2_pa)
    hi = max(c.ambient_pa, valve_p1_pa, valve_p2_pa)
    if storage_kg_per_pa > 0.0:
        lo = min(lo, previous_pa)
        hi = max(hi, previous_pa)
    # regula falsi on the negative of the falling function, which rises
    lo_f = storage_kg_per_pa * (lo - previous_pa) - _exhaust_node_balance(
        c, lo, area_a, area_b, valve_p1_pa, valve_p2_pa, inv_sqrt_t1, inv_sqrt_t2)
    hi_f = storage_kg_per_pa * (hi - previous_pa) - _exhaust_node_balance(
        c, hi, area_a, area_b, valve_p1_pa, valve_p2_pa, inv_sqrt_t1, inv_sqrt_t2)
    if lo_f >= 0.0:
        return lo
    if hi_f <= 0.0:
        return hi
    tolerance = SUPPLY_DROOP_RTOL * c.supply_pa
    guess = (lo * hi_f - hi * lo_f) / (hi_f - lo_f)
    side = 0
    for _ in range(SUPPLY_DROOP_MAX_ITERATIONS):
        f_guess = storage_kg_per_pa * (guess - previous_pa) - _exhaust_node_balance(
            c, guess, area_a, area_b, valve_p1_pa, valve_p2_pa, inv_sqrt_t1, inv_sqrt_t2)
        if f_guess == 0.0:
            return guess
        lo, lo_f, hi, hi_f, side = _illinois_update(lo, lo_f, hi, hi_f, guess, f_guess, side)
        previous_guess = guess
        guess = (lo * hi_f - hi * lo_f) / (hi_f - lo_f)
        if abs(guess - previous_guess) <= tolerance:
            return guess
    return guess


@njit(cache=True)
def exhaust_node_after_substep(c, history, env, slot, y, exhaust_node_pa, h):
    """The exhaust node's pressure after a substep of ``h`` s when it has a volume V
    (``exhaust_volume_m3``; docs/effects.md): one backward-Euler step of
    dP_e/dt = (R T / V) ``_exhaust_node_balance``(P_e) with the valve's inputs at the
    boundary ``slot`` (state ``y``), solved by ``exhaust_pressure_at_valve``; stable for
    any volume, and the quasi-static node as V -> 0."""
    spool_delayed, valve_p1, valve_p2 = _valve_inputs(c, history, env, slot, 0.0, y, y)
    inv_sqrt_t1, inv_sqrt_t2 = _inv_sqrt_temperatures(c, y[7], y[8])
    return exhaust_pressure_at_valve(c, _scalar_area(c, spool_delayed) + c.null_leak,
                                     _scalar_area(c, -spool_delayed) + c.null_leak, valve_p1,
                                     valve_p2, inv_sqrt_t1, inv_sqrt_t2,
                                     c.exhaust_capacity / h, exhaust_node_pa)


@njit(cache=True)
def _scalar_area(c, spool_m):
    """``orifice_area`` on the general (scalar) path, returning at once for a closed hole."""
    if spool_m <= c.half_width - c.hole_radius:
        return 0.0
    return orifice_area_inv_radius(spool_m, c.hole_radius, c.inv_hole_radius, c.half_width,
                                   c.holes)


@njit(cache=True)
def valve_chamber_flows(c, spool_delayed_m, valve_p1_pa, valve_p2_pa, p1_pa, p2_pa,
                        inv_sqrt_t1, inv_sqrt_t2, exhaust_node_pa):
    """Mass flows into (+) each chamber through its tube: supply and exhaust paths (Eqs. 50-55).

    ``spool_delayed_m`` is x_s(t - tau); ``valve_p*`` are the chamber pressures the valve
    flow is evaluated with (current ones for the command coupling, delayed ones for the
    literal Eq. 55); ``p*_pa`` are the current tube-end pressures used by the attenuation;
    ``inv_sqrt_t*`` are 1/sqrt(T) of the chamber air (of ``temperature_k`` unless the
    energy model is on). Effects: null leakage adds to both areas, the exhaust paths use
    their own discharge coefficient, the supply pressure droops with the supply flow, the
    exhaust paths discharge into the node behind a vent: at ``exhaust_node_pa`` (the state
    row ``exhaust_node_pa``, held over the substep) when the node has a volume, else at
    its quasi-static pressure (``exhaust_pressure_at_valve``).
    Returns (supply->1, 1->exhaust, supply->2, 2->exhaust) as flows at the chamber end.
    """
    area_a = _scalar_area(c, spool_delayed_m) + c.null_leak
    area_b = _scalar_area(c, -spool_delayed_m) + c.null_leak
    supply_pa = c.supply_pa
    if c.supply_resistance > 0.0:
        supply_pa = supply_pressure_at_valve(c, area_a, area_b, valve_p1_pa, valve_p2_pa,
                                             inv_sqrt_t1, inv_sqrt_t2)
    exhaust_pa = c.ambient_pa
    if c.exhaust_vent > 0.0:
        exhaust_pa = exhaust_node_pa
        if c.exhaust_capacity == 0.0:
            exhaust_pa = exhaust_pressure_at_valve(c, area_a, area_b, valve_p1_pa, valve_p2_pa,
                                                   inv_sqrt_t1, inv_sqrt_t2, 0.0, c.ambient_pa)
    supply_1 = _tube(c, _flow(c, c.discharge, area_a, supply_pa, valve_p1_pa, c.inv_sqrt_t,
                              inv_sqrt_t1, c.flow_law), p1_pa)
    exhaust_1 = _tube(c, _flow(c, c.discharge_ex, area_b, valve_p1_pa, exhaust_pa, inv_sqrt_t1,
                               c.inv_sqrt_t, c.flow_law), p1_pa)
    supply_2 = _tube(c, _flow(c, c.discharge, area_b, supply_pa, valve_p2_pa, c.inv_sqrt_t,
                              inv_sqrt_t2, c.flow_law), p2_pa)
    exhaust_2 = _tube(c, _flow(c, c.discharge_ex, area_a, valve_p2_pa, exhaust_pa, inv_sqrt_t2,
                               c.inv_sqrt_t, c.flow_law), p2_pa)
    return supply_1, exhaust_1, supply_2, exhaust_2


LINE_PRESSURE_RTOL = 1e-10  # solver accuracy of the line's valve-end pressure, relative to P_s


@njit(cache=True)
def _port_flow_into_line(c, supply_area, exhaust_area, port_pa):
    """Net valve flow into a line at valve-end pressure ``port_pa``, and its exhaust part
    (port -> atmosphere, Eq. 39; the line's air at ``temperature_k``)."""
    supply = _flow(c, c.discharge, supply_area, c.supply_pa, port_pa, c.inv_sqrt_t, c.inv_sqrt_t,
                   c.flow_law)
    exhaust = _flow(c, c.discharge_ex, exhaust_area, port_pa, c.ambient_pa, c.inv_sqrt_t,
                    c.inv_sqrt_t, c.flow_law)
    return supply - exhaust, exhaust


@njit(cache=True)
def _line_valve_end_residual(c, supply_area, exhaust_area, wave_in_pa, port_pa):
    """f(P) = P - W_in - (Z_c + R(q, P)/2) q(P) at a valve-end pressure, and q, the exhaust flow."""
    q, exhaust = _port_flow_into_line(c, supply_area, exhaust_area, port_pa)
    resistance = line_resistance(q, port_pa, c.line_friction, c.tube_diameter, c.viscosity,
                                 c.reynolds_turbulent)
    return port_pa - wave_in_pa - (c.line_impedance + 0.5 * resistance) * q, q, exhaust


@njit(cache=True)
def _line_valve_end(c, supply_area, exhaust_area, wave_in_pa):
    """Valve-end pressure P_A of a line, its flow q into the line and the exhaust flow.

    The root of f(P) = P - W_in - (Z_c + R(q, P)/2) q(P), q the valve's net flow at P
    (``tube.py``, transmission line), bracketed by min(P_a, W_in) (f < 0) and
    max(P_s, W_in) (f > 0). First guess: the flow at W_in (exact while the valve is
    choked), then Illinois regula falsi to ``LINE_PRESSURE_RTOL``. A closed valve reflects
    the wave fully.
    """
    if supply_area <= 0.0 and exhaust_area <= 0.0:
        return wave_in_pa, 0.0, 0.0
    tolerance = LINE_PRESSURE_RTOL * c.supply_pa
    lo = max(min(c.ambient_pa, wave_in_pa), c.pressure_floor)
    hi = max(c.supply_pa, wave_in_pa)
    # f(W_in) = -(Z_c + R/2) q(W_in), so the guess W_in + (Z_c + R/2) q(W_in) is W_in - f(W_in)
    f_in, _, _ = _line_valve_end_residual(c, supply_area, exhaust_area, wave_in_pa, wave_in_pa)
    port = min(max(wave_in_pa - f_in, lo), hi)
    f, q, exhaust = _line_valve_end_residual(c, supply_area, exhaust_area, wave_in_pa, port)
    if abs(f) <= tolerance:
        return port, q, exhaust
    if f > 0.0:
        hi, f_hi = port, f
        f_lo, q, exhaust = _line_valve_end_residual(c, supply_area, exhaust_area, wave_in_pa, lo)
        if f_lo >= 0.0:  # only at the pressure floor
            return lo, q, exhaust
    else:
        lo, f_lo = port, f
        f_hi, _, _ = _line_valve_end_residual(c, supply_area, exhaust_area, wave_in_pa, hi)
    side = 0
    for _ in range(SUPPLY_DROOP_MAX_ITERATIONS):
        port = (lo * f_hi - hi * f_lo) / (f_hi - f_lo)
        f, q, exhaust = _line_valve_end_residual(c, supply_area, exhaust_area, wave_in_pa, port)
        if abs(f) <= tolerance or hi - lo <= tolerance:
            break
        lo, f_lo, hi, f_hi, side = _illinois_update(lo, f_lo, hi, f_hi, port, f, side)
    return port, q, exhaust


@njit(cache=True)
def line_flows(c, spool_m, arriving, p1_pa, p2_pa):
    """The tubes as transmission lines (effect ``tube_waves``): the flows at their ends.

    ``arriving`` = (W at valve end 1, at valve end 2, at chamber end 1, at chamber end 2),
    the waves the other ends sent one delay ago. The valve acts on the line at once (no
    spool delay: the line delays). Returns (flow into chamber 1, into chamber 2, the
    valve's exhaust flow to the atmosphere, and the pressure and the flow into the line at
    valve end 1 and at valve end 2).
    """
    area_a = _scalar_area(c, spool_m) + c.null_leak
    area_b = _scalar_area(c, -spool_m) + c.null_leak
    port_1, q_1, exhaust_1 = _line_valve_end(c, area_a, area_b, arriving[0])
    port_2, q_2, exhaust_2 = _line_valve_end(c, area_b, area_a, arriving[1])
    flow_1 = line_chamber_flow(arriving[2], p1_pa, c.line_impedance, c.line_friction,
                               c.tube_diameter, c.viscosity, c.reynolds_turbulent)
    flow_2 = line_chamber_flow(arriving[3], p2_pa, c.line_impedance, c.line_friction,
                               c.tube_diameter, c.viscosity, c.reynolds_turbulent)
    return flow_1, flow_2, exhaust_1 + exhaust_2, port_1, q_1, port_2, q_2


@njit(cache=True)
def _sent_wave(c, pressure_pa, mass_flow_into_line):
    """The wave a line end sends (``tube.line_end_wave``) with the line's friction there."""
    return line_end_wave(pressure_pa, mass_flow_into_line, c.line_impedance, line_resistance(
        mass_flow_into_line, pressure_pa, c.line_friction, c.tube_diameter, c.viscosity,
        c.reynolds_turbulent))


@njit(cache=True, forceinline=True, error_model="numpy")
def _motion_and_spool(c, coil_current_a, x_s, v_s, p1, p2, x, velocity, direction, friction_n):
    """Piston acceleration (Eq. 1; zero while held) and spool acceleration (Eq. 38)."""
    applied = (pneumatic_force(p1, p2, c.area_cap, c.area_rod, c.rod_area, c.ambient_pa)
               - external_force(c.mode, x, c.load_force, c.spring_k, c.spring_rest))
    accel = piston_acceleration(applied, velocity, direction, friction_n, c.viscous,
                                c.inv_moving_mass)
    a_s = spool_acceleration(x_s, v_s, coil_current_a, c.inv_spool_mass, c.spool_damping,
                             c.spool_spring, c.coil_force)
    return accel, a_s


@njit(cache=True, inline="always")
def _sliding_friction(c, velocity):
    """The sliding friction's magnitude at ``velocity``: F_df (Eq. 47), or the Stribeck
    curve; Karnopp's while sliding, and the curve LuGre's bristles relax towards."""
    if c.stribeck:
        return stribeck_friction(velocity, c.dynamic_friction, c.static_friction, c.stribeck_v)
    return c.dynamic_friction


@njit(cache=True, forceinline=True, error_model="numpy")
def _volumes(c, x):
    """Chamber volumes (Eq. 15) with the position held in the stroke (a trial step may overshoot)."""
    x_in_stroke = min(max(x, -c.half_stroke), c.half_stroke)
    return chamber_volumes(x_in_stroke, c.half_stroke, c.area_cap, c.area_rod, c.dead_cap,
                           c.dead_rod)


@njit(cache=True)
def derivatives(c, coil_current_a, x_s, v_s, p1, p2, x, v, t1, t2, direction, spool_delayed,
                valve_p1, valve_p2, arriving, exhaust_node_pa, lugre_friction_n=0.0):
    """Right-hand side of the state (x_s, v_s, P1, P2, x, v, exhaust mass, T1, T2).

    The general form: all four valve paths, the leakage orifices and every effect.
    ``coil_current_a`` is the current driving the spool (lagged if the coil lag is on).
    T1, T2 change only with the energy model on (``wall_heat_transfer_w_per_k > 0``).
    With the tubes as transmission lines (``tube_waves``) the chamber flows come from
    ``line_flows`` and the waves ``arriving`` at the line ends; ``spool_delayed``,
    ``valve_p*`` are then unused. With LuGre friction on, ``lugre_friction_n`` (held over
    the substep, ``lugre_bristle_step``) replaces the sliding friction.
    """
    inv_sqrt_t1, inv_sqrt_t2 = _inv_sqrt_temperatures(c, t1, t2)
    vented = 0.0
    if c.waves:  # a signed flow into each chamber from its line; the line's air at T_s
        supply_1, supply_2, vented, _, _, _, _ = line_flows(c, x_s, arriving, p1, p2)
        exhaust_1 = 0.0
        exhaust_2 = 0.0
    else:
        supply_1, exhaust_1, supply_2, exhaust_2 = valve_chamber_flows(
            c, spool_delayed, valve_p1, valve_p2, p1, p2, inv_sqrt_t1, inv_sqrt_t2,
            exhaust_node_pa)
    leak_12 = _flow(c, c.discharge, c.leak_area, p1, p2, inv_sqrt_t1, inv_sqrt_t2, c.flow_law)
    seal_2 = _flow(c, c.discharge, c.seal_leak, p2, c.ambient_pa, inv_sqrt_t2, c.inv_sqrt_t,
                   c.flow_law)
    in_1 = max(supply_1, 0.0) + max(-exhaust_1, 0.0) + max(-leak_12, 0.0)
    out_1 = max(-supply_1, 0.0) + max(exhaust_1, 0.0) + max(leak_12, 0.0)
    in_2 = max(supply_2, 0.0) + max(-exhaust_2, 0.0) + max(leak_12, 0.0) + max(-seal_2, 0.0)
    out_2 = max(-supply_2, 0.0) + max(exhaust_2, 0.0) + max(-leak_12, 0.0) + max(seal_2, 0.0)
    velocity = v if direction != 0.0 else 0.0
    v1, v2 = _volumes(c, x)
    if c.energy:
        # air from the supply or the atmosphere enters at temperature_k, leakage air at
        # the temperature of the chamber it left
        enthalpy_1 = ((max(supply_1, 0.0) + max(-exhaust_1, 0.0)) * c.temperature
                      + max(-leak_12, 0.0) * t2)
        enthalpy_2 = ((max(supply_2, 0.0) + max(-exhaust_2, 0.0) + max(-seal_2, 0.0))
                      * c.temperature + max(leak_12, 0.0) * t1)
        dp1, dt1 = chamber_energy_rates(p1, t1, v1, c.area_cap * velocity, in_1, out_1,
                                        enthalpy_1, c.gas, c.k, c.heat_conductance,
                                        c.temperature)
        dp2, dt2 = chamber_energy_rates(p2, t2, v2, -c.area_rod * velocity, in_2, out_2,
                                        enthalpy_2, c.gas, c.k, c.heat_conductance,
                                        c.temperature)
    else:
        dp1 = pressure_rate(p1, v1, c.area_cap * velocity, in_1, out_1, c.gas_rt,
                            c.alpha_in, c.alpha_out, c.alpha_motion)
        dp2 = pressure_rate(p2, v2, -c.area_rod * velocity, in_2, out_2, c.gas_rt,
                            c.alpha_in, c.alpha_out, c.alpha_motion)
        dt1 = 0.0
        dt2 = 0.0
    # piston_acceleration applies friction * direction (+-1 while moving)
    friction = lugre_friction_n * direction if c.lugre else _sliding_friction(c, velocity)
    accel, a_s = _motion_and_spool(c, coil_current_a, x_s, v_s, p1, p2, x, velocity, direction,
                                   friction)
    exhaust_rate = max(exhaust_1, 0.0) + max(exhaust_2, 0.0) + max(seal_2, 0.0) + vented
    return v_s, a_s, dp1, dp2, velocity, accel, exhaust_rate, dt1, dt2


@njit(cache=True)
def base_model_only(c):
    """Whether an environment runs the paper's model with no effect that needs ``derivatives``.

    Then the spool overlap (p_w >= R_h, Eq. 43) keeps the supply and exhaust paths of a
    chamber from being open together, and ``base_derivatives`` gives the same result with
    two valve paths instead of four. Three effects are in it (the exhaust discharge ratio,
    the tube volume, the spool friction, whose play acts before the substeps); the others
    send the environment to the general path.
    """
    return (c.energy == 0.0 and c.supply_resistance == 0.0 and c.exhaust_vent == 0.0
            and c.literal == 0.0 and c.leak_area == 0.0 and c.seal_leak == 0.0
            and c.null_leak == 0.0 and c.coil_lag == 0.0 and c.coil_force_lag == 0.0
            and c.stribeck == 0.0 and c.lugre == 0.0
            and c.flow_law == FLOW_LAW_PAPER and c.waves == 0.0
            and c.half_width >= c.hole_radius and c.delay_substeps >= 1.0)


@njit(cache=True, forceinline=True, error_model="numpy")
def base_derivatives(c, coil_current_a, x_s, v_s, p1, p2, x, v, direction, spool_delayed):
    """``derivatives`` for an environment where ``base_model_only`` holds, branch-free.

    With x_s(t - tau) > 0 chamber 1 is open to the supply and chamber 2 to the exhaust
    through the same area A_in(x_s) (Eqs. 44, 45); with x_s <= 0 the other way round
    through A_in(-x_s). Each chamber exchanges air through one orifice and one tube, so a
    loop over environments evaluates 1 area and 2 flows where the general form takes 2 and
    6, and compiles to SIMD code.
    """
    to_chamber_1 = spool_delayed > 0.0
    area = orifice_area_inv_radius(abs(spool_delayed), c.hole_radius, c.inv_hole_radius,
                                   c.half_width, c.holes)
    node_1 = c.supply_pa if to_chamber_1 else c.ambient_pa
    node_2 = c.ambient_pa if to_chamber_1 else c.supply_pa
    discharge_1 = c.discharge if to_chamber_1 else c.discharge_ex
    discharge_2 = c.discharge_ex if to_chamber_1 else c.discharge
    flow_1 = _tube(c, _flow(c, discharge_1, area, node_1, p1, c.inv_sqrt_t, c.inv_sqrt_t,
                            FLOW_LAW_PAPER), p1)
    flow_2 = _tube(c, _flow(c, discharge_2, area, node_2, p2, c.inv_sqrt_t, c.inv_sqrt_t,
                            FLOW_LAW_PAPER), p2)
    velocity = v if direction != 0.0 else 0.0
    v1, v2 = _volumes(c, x)
    dp1 = pressure_rate(p1, v1, c.area_cap * velocity, max(flow_1, 0.0), max(-flow_1, 0.0),
                        c.gas_rt, c.alpha_in, c.alpha_out, c.alpha_motion)
    dp2 = pressure_rate(p2, v2, -c.area_rod * velocity, max(flow_2, 0.0), max(-flow_2, 0.0),
                        c.gas_rt, c.alpha_in, c.alpha_out, c.alpha_motion)
    accel, a_s = _motion_and_spool(c, coil_current_a, x_s, v_s, p1, p2, x, velocity, direction,
                                   c.dynamic_friction)
    exhaust_rate = max(-flow_2, 0.0) if to_chamber_1 else max(-flow_1, 0.0)
    return v_s, a_s, dp1, dp2, velocity, accel, exhaust_rate, 0.0, 0.0


@njit(cache=True, forceinline=True)
def ring_slot(index, n_slots):
    """``index`` modulo ``n_slots`` (a ring-buffer slot, in [0, n_slots)); a compare instead
    of an integer division for -n_slots <= index < n_slots, the case of a delay read from
    a head already in the ring."""
    if index < -n_slots or index >= n_slots:
        return index % n_slots
    return index + n_slots if index < 0 else index


@njit(cache=True)
def delayed_value(history, env, channel, head, stage_substeps, delay_substeps, value_at_head,
                  value_at_stage):
    """Value of a history channel at (stage time - delay), by linear interpolation.

    Times are in substeps relative to the last boundary ``head``; a query after ``head``
    (a delay shorter than the stage offset) interpolates towards the stage's own value.
    The reads are cheapest with ``head`` in [0, n_slots) (``ring_slot``).
    """
    query = stage_substeps - delay_substeps
    if query >= 0.0:
        if stage_substeps <= 0.0:
            return value_at_head
        return value_at_head + (query / stage_substeps) * (value_at_stage - value_at_head)
    n_slots = history.shape[0]
    base = math.floor(query)
    weight = query - base
    lower = history[ring_slot(head + int(base), n_slots), channel, env]
    upper = history[ring_slot(head + int(base) + 1, n_slots), channel, env]
    return lower + weight * (upper - lower)


@njit(cache=True, inline="always")
def _valve_inputs(c, history, env, head, frac, y, y0):
    """What the valve sees ``frac`` of a substep after boundary ``head`` (state ``y``; ``y0``
    at the boundary): the delayed spool x_s(t - tau) and the chamber pressures its flow is
    evaluated with (the delayed ones with the literal Eq. 55, else the present ones)."""
    spool_delayed = delayed_value(history, env, L.H_X_S, head, frac, c.delay_substeps, y0[0], y[0])
    if c.literal:
        return (spool_delayed,
                delayed_value(history, env, L.H_P1, head, frac, c.delay_substeps, y0[2], y[2]),
                delayed_value(history, env, L.H_P2, head, frac, c.delay_substeps, y0[3], y[3]))
    return spool_delayed, y[2], y[3]


@njit(cache=True, inline="always")
def _inv_sqrt_temperatures(c, t1, t2):
    """1/sqrt(T) of the chamber air: of the gas temperatures with the energy model, else
    of ``temperature_k`` (cached)."""
    if c.energy:
        return 1.0 / math.sqrt(t1), 1.0 / math.sqrt(t2)
    return c.inv_sqrt_t, c.inv_sqrt_t


@njit(cache=True, inline="always")  # inlined: a call would pass every constant as an argument
def _stage(c, history, env, head, frac, coil_current_a, y, y0, direction, exhaust_node_pa,
           lugre_friction_n):
    spool_delayed, valve_p1, valve_p2 = _valve_inputs(c, history, env, head, frac, y, y0)
    arriving = (0.0, 0.0, 0.0, 0.0)
    if c.waves:
        arriving = _arriving_waves(c, history, env, head, frac)
    return derivatives(c, coil_current_a, y[0], y[1], y[2], y[3], y[4], y[5], y[7], y[8],
                       direction, spool_delayed, valve_p1, valve_p2, arriving, exhaust_node_pa,
                       lugre_friction_n)


@njit(cache=True)
def _arriving_waves(c, history, env, head, frac):
    """The waves at the four line ends ``frac`` of a substep after boundary ``head``: each
    sent by the other end one delay earlier (the delay is at least one substep)."""
    d = c.delay_substeps
    return (delayed_value(history, env, L.H_WAVE_CHAMBER_1, head, frac, d, 0.0, 0.0),
            delayed_value(history, env, L.H_WAVE_CHAMBER_2, head, frac, d, 0.0, 0.0),
            delayed_value(history, env, L.H_WAVE_VALVE_1, head, frac, d, 0.0, 0.0),
            delayed_value(history, env, L.H_WAVE_VALVE_2, head, frac, d, 0.0, 0.0))


@njit(cache=True, forceinline=True, error_model="numpy")
def _axpy(y, h, k):
    return (y[0] + h * k[0], y[1] + h * k[1], y[2] + h * k[2], y[3] + h * k[3],
            y[4] + h * k[4], y[5] + h * k[5], y[6] + h * k[6], y[7] + h * k[7],
            y[8] + h * k[8])


@njit(cache=True, inline="always")
def _coil_at(c, command_a, coil_start, frac):
    """(coil current, force current) ``frac`` of a substep after ``coil_start`` = their values
    at the substep's start: the exact solution of the coil lag and the force lag behind it
    (``lagged_coil_current``, ``lagged_coil_force_current``); the force current drives the
    spool. Without a lag a current is the command (and the force current the coil current)."""
    if not c.coil_lag and not c.coil_force_lag:
        return command_a, command_a
    if frac == 0.0:
        return coil_start
    if frac == 0.5:
        decay = c.coil_decay_half
    elif frac == 1.0:
        decay = c.coil_decay_full
    else:
        decay = c.coil_decay_full ** frac
    coil = lagged_coil_current(command_a, coil_start[0], decay)
    if not c.coil_force_lag:
        return coil, coil
    return coil, lagged_coil_force_current(
        command_a, coil_start[0], coil_start[1], math.exp(-frac * c.force_rate),
        coil_force_gain(decay, frac * c.force_rate, frac * c.force_rate_difference))


@njit(cache=True)
def _rk4(c, history, env, head, frac0, dfrac, h, command_a, coil_start, y, y0, direction,
         exhaust_node_pa, lugre_friction_n):
    """One classical RK4 step over substep fractions [frac0, frac0 + dfrac] (h: substep, s).

    ``y0`` is the state at the substep boundary ``head`` (the delay interpolation's anchor);
    ``coil_start`` the (coil, force) currents there (``_coil_at``); ``exhaust_node_pa``
    the exhaust node's pressure and ``lugre_friction_n`` the LuGre friction, both held over
    the substep.
    """
    hh = dfrac * h
    fm = frac0 + 0.5 * dfrac
    fe = frac0 + dfrac
    k1 = _stage(c, history, env, head, frac0, _coil_at(c, command_a, coil_start, frac0)[1], y,
                y0, direction, exhaust_node_pa, lugre_friction_n)
    k2 = _stage(c, history, env, head, fm, _coil_at(c, command_a, coil_start, fm)[1],
                _axpy(y, 0.5 * hh, k1), y0, direction, exhaust_node_pa, lugre_friction_n)
    k3 = _stage(c, history, env, head, fm, _coil_at(c, command_a, coil_start, fm)[1],
                _axpy(y, 0.5 * hh, k2), y0, direction, exhaust_node_pa, lugre_friction_n)
    k4 = _stage(c, history, env, head, fe, _coil_at(c, command_a, coil_start, fe)[1],
                _axpy(y, hh, k3), y0, direction, exhaust_node_pa, lugre_friction_n)
    return _rk4_combine(c, y, k1, k2, k3, k4, hh, direction)


@njit(cache=True, forceinline=True, error_model="numpy")
def _rk4_combine(c, y, k1, k2, k3, k4, hh, direction):
    """The RK4 update of a step of length ``hh`` from its four stage slopes.

    Pressures (and gas temperatures) are kept above their floors; the piston's position
    and velocity change only while it slides, the gas temperatures only with the energy
    model.
    """
    w = hh / 6.0
    p1 = max(y[2] + w * (k1[2] + 2.0 * k2[2] + 2.0 * k3[2] + k4[2]), c.pressure_floor)
    p2 = max(y[3] + w * (k1[3] + 2.0 * k2[3] + 2.0 * k3[3] + k4[3]), c.pressure_floor)
    sliding = direction != 0.0
    x = y[4] + w * (k1[4] + 2.0 * k2[4] + 2.0 * k3[4] + k4[4]) if sliding else y[4]
    v = y[5] + w * (k1[5] + 2.0 * k2[5] + 2.0 * k3[5] + k4[5]) if sliding else y[5]
    t1 = y[7]
    t2 = y[8]
    if c.energy:
        t1 = max(t1 + w * (k1[7] + 2.0 * k2[7] + 2.0 * k3[7] + k4[7]), c.temperature_floor)
        t2 = max(t2 + w * (k1[8] + 2.0 * k2[8] + 2.0 * k3[8] + k4[8]), c.temperature_floor)
    return (y[0] + w * (k1[0] + 2.0 * k2[0] + 2.0 * k3[0] + k4[0]),
            y[1] + w * (k1[1] + 2.0 * k2[1] + 2.0 * k3[1] + k4[1]),
            p1, p2, x, v, y[6] + w * (k1[6] + 2.0 * k2[6] + 2.0 * k3[6] + k4[6]), t1, t2)


@njit(cache=True, forceinline=True, error_model="numpy")
def rk4_base_substep(c, y, coil_current_a, direction, spool_delayed_start, spool_delayed_mid,
                     spool_delayed_end, h):
    """One whole RK4 substep of ``base_derivatives``; the delayed spool positions at its
    start, middle and end are read from the ring buffer beforehand (``delayed_value``)."""
    k1 = base_derivatives(c, coil_current_a, y[0], y[1], y[2], y[3], y[4], y[5], direction,
                          spool_delayed_start)
    y2 = _axpy(y, 0.5 * h, k1)
    k2 = base_derivatives(c, coil_current_a, y2[0], y2[1], y2[2], y2[3], y2[4], y2[5],
                          direction, spool_delayed_mid)
    y3 = _axpy(y, 0.5 * h, k2)
    k3 = base_derivatives(c, coil_current_a, y3[0], y3[1], y3[2], y3[3], y3[4], y3[5],
                          direction, spool_delayed_mid)
    y4 = _axpy(y, h, k3)
    k4 = base_derivatives(c, coil_current_a, y4[0], y4[1], y4[2], y4[3], y4[4], y4[5],
                          direction, spool_delayed_end)
    return _rk4_combine(c, y, k1, k2, k3, k4, h, direction)


MAX_EVENTS_PER_SUBSTEP = 4
MIN_EVENT_FRACTION = 1e-6  # events closer than this to the interval start are applied at once
STIFFNESS_LIMIT = 2.0  # largest h * lambda_max before a substep is split (RK4's real-axis limit: 2.79)
LUGRE_COUPLING_LIMIT = 0.5  # largest h sqrt(sigma0 / M) and h sigma1 / M of a LuGre part
MAX_REFINEMENT = 64  # a substep is split into at most this many equal parts


@njit(cache=True, forceinline=True, error_model="numpy")
def stiffness_ratio(c, y, h):
    """h * lambda_max of a substep of ``h`` seconds from ``y`` (see ``refinement``)."""
    x, v = y[4], y[5]
    x_min = min(max(x - abs(v) * h, -c.half_stroke), c.half_stroke)
    x_max = min(max(x + abs(v) * h, -c.half_stroke), c.half_stroke)
    v1, _ = chamber_volumes(x_min, c.half_stroke, c.area_cap, c.area_rod, c.dead_cap, c.dead_rod)
    _, v2 = chamber_volumes(x_max, c.half_stroke, c.area_cap, c.area_rod, c.dead_cap, c.dead_rod)
    return h * c.stiffness_volume / min(v1, v2)


@njit(cache=True)
def refinement(c, y, h):
    """Equal parts (a power of two) to split a substep into so that h * lambda <= the limit.

    lambda bounds the flow-pressure stiffness dPdot/dP of a chamber (Eqs. 14, 39, 52):
    R T alpha C_f A_max (max |m_r'| + C1) / (sqrt(T) V_min), with V_min the smaller
    chamber volume this substep can reach (``stiffness_ratio``). It is large only when a
    chamber is nearly empty (piston near a stop), where a fixed substep would chatter.
    With LuGre friction the parts also keep the bristles' explicit coupling to the rod
    (``_split_substep``) within ``LUGRE_COUPLING_LIMIT``: h sqrt(sigma0 / M) for the
    pre-sliding spring, h sigma1 / M for its damping.
    """
    ratio = stiffness_ratio(c, y, h)
    if c.lugre and c.mode != MODE_FIXED:  # the bristles act on the rod once per part
        ratio = max(ratio, STIFFNESS_LIMIT / LUGRE_COUPLING_LIMIT * h * max(
            math.sqrt(c.lugre_stiffness * c.inv_moving_mass), c.lugre_damping * c.inv_moving_mass))
    parts = 1
    while ratio > STIFFNESS_LIMIT and parts < MAX_REFINEMENT:
        parts *= 2
        ratio *= 0.5
    return parts


@njit(cache=True)
def _advance_interval(c, history, env, head, frac_start, frac_end, h, command_a, coil_start,
                      y, y0, exhaust_node_pa, lugre_friction_n):
    """Integrate substep fractions [frac_start, frac_end], splitting at piston events.

    When the sliding piston's attempted step crosses an end stop or its velocity reverses,
    the step is redone up to the event (located by linear interpolation), the event is
    applied (inelastic stop, or v = 0 and the stick test), and the rest is integrated.
    """
    frac0 = frac_start
    for _ in range(MAX_EVENTS_PER_SUBSTEP):
        direction = 0.0
        if c.mode != MODE_FIXED:
            applied = (pneumatic_force(y[2], y[3], c.area_cap, c.area_rod, c.rod_area,
                                       c.ambient_pa)
                       - external_force(c.mode, y[4], c.load_force, c.spring_k, c.spring_rest)
                       - lugre_friction_n)
            direction = motion_direction(y[4], y[5], applied, c.stick_threshold, c.half_stroke)
        dfrac = frac_end - frac0
        trial = _rk4(c, history, env, head, frac0, dfrac, h, command_a, coil_start, y, y0,
                     direction, exhaust_node_pa, lugre_friction_n)
        theta = -1.0
        if direction != 0.0:
            theta = event_fraction(y[4], y[5], trial[4], trial[5], direction, c.half_stroke)
        if theta < 0.0:
            return trial
        if theta * dfrac > MIN_EVENT_FRACTION:
            y = _rk4(c, history, env, head, frac0, theta * dfrac, h, command_a, coil_start,
                     y, y0, direction, exhaust_node_pa, lugre_friction_n)
            frac0 += theta * dfrac
        x, v = apply_event(y[4], y[5], direction, c.half_stroke)
        y = (y[0], y[1], y[2], y[3], x, v, y[6], y[7], y[8])
    # out of events: the rest of the interval with the piston held
    return _rk4(c, history, env, head, frac0, frac_end - frac0, h, command_a, coil_start, y,
                y0, 0.0, exhaust_node_pa, lugre_friction_n)


@njit(cache=True)
def _split_substep(c, history, env, head_sub, h, command_a, coil_start, y0, parts,
                   exhaust_node_pa, bristle_m):
    """One substep from ``y0`` by the general path, in ``parts`` equal parts
    (``refinement``), each split further at piston events (``_advance_interval``).

    With LuGre friction the bristles (deflection ``bristle_m``) are advanced before each
    part, exactly for the rod's velocity at its start (``lugre_bristle_step``), and their
    mean friction is held over the part (operator splitting). Returns the state and the
    bristles' deflection.
    """
    y = y0
    for part in range(parts):
        lugre_friction_n = 0.0
        if c.lugre:
            bristle_m, lugre_friction_n = lugre_bristle_step(
                bristle_m, y[5], h / parts, c.lugre_stiffness, c.lugre_damping,
                _sliding_friction(c, y[5]))
        y = _advance_interval(c, history, env, head_sub, part / parts, (part + 1) / parts, h,
                              command_a, coil_start, y, y0, exhaust_node_pa, lugre_friction_n)
    return y, bristle_m


@njit(cache=True, forceinline=True)
def _record_history(history, env, slot, x_s, p1, p2):
    """Write the delay history of ``env`` at ring-buffer slot ``slot`` (a substep boundary)."""
    history[slot, L.H_X_S, env] = x_s
    history[slot, L.H_P1, env] = p1
    history[slot, L.H_P2, env] = p2


@njit(cache=True)
def _close_substep(c, history, env, slot, y):
    """The end of a substep: the inelastic stops (``end_of_substep``) and the delay history
    at the new boundary (written at substep boundaries only, whatever the splitting)."""
    x, v = end_of_substep(y[4], y[5], c.half_stroke)
    y = (y[0], y[1], y[2], y[3], x, v, y[6], y[7], y[8])
    if c.waves:  # the waves the line ends send at this boundary
        flow_1, flow_2, _, port_1, q_1, port_2, q_2 = line_flows(
            c, y[0], _arriving_waves(c, history, env, slot, 0.0), y[2], y[3])
        history[slot, L.H_WAVE_VALVE_1, env] = _sent_wave(c, port_1, q_1)
        history[slot, L.H_WAVE_VALVE_2, env] = _sent_wave(c, port_2, q_2)
        history[slot, L.H_WAVE_CHAMBER_1, env] = _sent_wave(c, y[2], -flow_1)
        history[slot, L.H_WAVE_CHAMBER_2, env] = _sent_wave(c, y[3], -flow_2)
    _record_history(history, env, slot, y[0], y[2], y[3])
    return y


@njit(cache=True)
def spool_command(play_band_a, state, env, command_a):
    """The held command as the spool sees it through its Coulomb friction's play of
    half-width ``play_band_a`` (``effects.spool_play_current``), updated in the state row
    ``spool_play_current_a``.

    The command is held over the control period, so the play moves once, at its start.
    A coil lag (``coil_time_constant_s``) then acts on the play's output.
    """
    played = spool_play_current(state[L.S_PLAY, env], command_a, play_band_a)
    state[L.S_PLAY, env] = played
    return played


@njit(cache=True)
def advance_env(params, state, history, env, head, coil_current_a, control_dt_s, n_substeps,
                outputs):
    """Advance environment ``env`` by one control period; write its outputs row.

    ``n_substeps`` RK4 substeps, each split into equal parts where ``refinement`` finds the
    flow stiff, and at piston events (``_advance_interval``). The delay history is written
    at the substep boundaries only, so its length does not depend on the splitting.
    """
    h = control_dt_s / n_substeps
    c = env_constants(params, env, h)
    coil_current_a = spool_command(c.spool_play_band, state, env, coil_current_a)
    n_slots = history.shape[0]
    y = (state[L.S_X_S, env], state[L.S_V_S, env], state[L.S_P1, env], state[L.S_P2, env],
         state[L.S_X, env], state[L.S_V, env], state[L.S_EXHAUST, env], state[L.S_T1, env],
         state[L.S_T2, env])
    coil = (state[L.S_COIL, env], state[L.S_COIL_FORCE, env])
    exhaust_node_pa = state[L.S_EXHAUST_NODE, env]
    bristle_m = state[L.S_BRISTLE, env]
    for sub in range(n_substeps):
        head_sub = ring_slot(head + sub, n_slots)
        coil_now = coil[0] if c.coil_lag else coil_current_a  # the command without a lag
        coil_start = (coil_now, coil[1] if c.coil_force_lag else coil_now)
        y, bristle_m = _split_substep(c, history, env, head_sub, h, coil_current_a, coil_start,
                                      y, refinement(c, y, h), exhaust_node_pa, bristle_m)
        coil = _coil_at(c, coil_current_a, coil_start, 1.0)
        slot = ring_slot(head_sub + 1, n_slots)
        y = _close_substep(c, history, env, slot, y)
        if c.exhaust_vent > 0.0 and c.exhaust_capacity > 0.0:
            exhaust_node_pa = exhaust_node_after_substep(c, history, env, slot, y,
                                                         exhaust_node_pa, h)
    state[L.S_EXHAUST_NODE, env] = exhaust_node_pa
    state[L.S_BRISTLE, env] = bristle_m
    _store_state(c, state, env, y, coil, outputs)


CHUNK_ENVS = 64  # environments advanced together by the batch path (their arrays stay in L1/L2)
# The parallel steps run inside BatchSimulator.call_step_kernel, which has the threads
# take chunks one at a time as each gets free (dynamic scheduling, numba's
# ``parallel_chunksize``) rather than split them evenly up front: a core slowed by other
# processes then takes fewer chunks instead of holding the others up at the region's end.
PARALLEL_CHUNKS_PER_HANDOUT = 1
N_CONSTANTS = len(Constants._fields)
N_RK = 9  # state rows the RK4 integrates (S_X_S .. S_T2)


@njit(cache=True)
def store_constants(c, constants, lane):
    """Write the fields of ``c`` into lane ``lane`` of a flat chunk array (``N_CONSTANTS`` rows
    of ``CHUNK_ENVS`` lanes): in a loop over lanes each field is one contiguous vector load."""
    for i in range(N_CONSTANTS):
        constants[i * CHUNK_ENVS + lane] = c[i]


@njit(cache=True, forceinline=True, error_model="numpy")
def load_constants(constants, lane):
    """The ``Constants`` of column ``lane`` (inverse of ``store_constants``), field by field."""
    # one argument per field, in order: a new Constants field makes this fail to compile
    k = CHUNK_ENVS
    return Constants(
        constants[0 * k + lane], constants[1 * k + lane], constants[2 * k + lane], constants[3 * k + lane],
        constants[4 * k + lane], constants[5 * k + lane], constants[6 * k + lane], constants[7 * k + lane],
        constants[8 * k + lane], constants[9 * k + lane], constants[10 * k + lane], constants[11 * k + lane],
        constants[12 * k + lane], constants[13 * k + lane], constants[14 * k + lane], constants[15 * k + lane],
        constants[16 * k + lane], constants[17 * k + lane], constants[18 * k + lane], constants[19 * k + lane],
        constants[20 * k + lane], constants[21 * k + lane], constants[22 * k + lane], constants[23 * k + lane],
        constants[24 * k + lane], constants[25 * k + lane], constants[26 * k + lane], constants[27 * k + lane],
        constants[28 * k + lane], constants[29 * k + lane], constants[30 * k + lane], constants[31 * k + lane],
        constants[32 * k + lane], constants[33 * k + lane], constants[34 * k + lane], constants[35 * k + lane],
        constants[36 * k + lane], constants[37 * k + lane], constants[38 * k + lane], constants[39 * k + lane],
        constants[40 * k + lane], constants[41 * k + lane], constants[42 * k + lane], constants[43 * k + lane],
        constants[44 * k + lane], constants[45 * k + lane], constants[46 * k + lane], constants[47 * k + lane],
        constants[48 * k + lane], constants[49 * k + lane], constants[50 * k + lane], constants[51 * k + lane],
        constants[52 * k + lane], constants[53 * k + lane], constants[54 * k + lane], constants[55 * k + lane],
        constants[56 * k + lane], constants[57 * k + lane], constants[58 * k + lane], constants[59 * k + lane],
        constants[60 * k + lane], constants[61 * k + lane], constants[62 * k + lane], constants[63 * k + lane],
        constants[64 * k + lane], constants[65 * k + lane], constants[66 * k + lane], constants[67 * k + lane],
        constants[68 * k + lane], constants[69 * k + lane], constants[70 * k + lane], constants[71 * k + lane],
        constants[72 * k + lane], constants[73 * k + lane], constants[74 * k + lane], constants[75 * k + lane],
        constants[76 * k + lane])


# Rows of the batch path's work array, a flat array of N_WORK rows of CHUNK_ENVS lanes: the
# RK4 state rows, the state at the substep's start, the inputs of one substep and the
# lanes the general path redoes. The vectorised loops update the rows in place. Rows are
# CHUNK_ENVS apart, a compile-time constant, so LLVM can prove the lanes independent (with
# run-time row strides it gives up on the aliasing checks).
W_START = N_RK  # the RK4 state at the substep's start: N_RK rows
W_SPOOL_DELAYED = 2 * N_RK  # x_s(t - tau) at the substep's start, middle and end: 3 rows
W_CURRENT = W_SPOOL_DELAYED + 3
W_DIRECTION = W_CURRENT + 1
W_REDO = W_DIRECTION + 1  # 1.0 where the general path redoes the substep (stiff, or an event)
N_WORK = W_REDO + 1

# The batch path caches the per-environment constants (``env_constants``) between control
# periods: per chunk, the N_CONSTANTS rows of ``store_constants`` and a row C_BASE_ONLY
# (1.0 where ``base_model_only`` holds); per environment, a key: the substep length they
# were derived for, NaN when stale. The parameters do not change behind the cache's back:
# ``BatchSimulator.params`` is read-only, and ``set_params`` / ``set_parameter`` mark the
# changed environments' keys stale. (A key of whole parameter columns, compared every
# control period, streamed 0.9 kB per environment and period through the caches.)
C_BASE_ONLY = N_CONSTANTS
C_SPOOL_PLAY_BAND = Constants._fields.index("spool_play_band")  # read per control period
C_DELAY_SUBSTEPS = Constants._fields.index("delay_substeps")  # read per substep
N_CACHED_CONSTANTS = N_CONSTANTS + 1


def constants_cache(n_envs):
    """An empty cache of the batch path's constants for ``n_envs`` environments, every
    entry stale: (key (n_envs,), constants (chunks, N_CACHED_CONSTANTS * CHUNK_ENVS))."""
    n_chunks = (n_envs + CHUNK_ENVS - 1) // CHUNK_ENVS
    return (np.full(n_envs, np.nan), np.zeros((n_chunks, N_CACHED_CONSTANTS * CHUNK_ENVS)))


@njit(cache=True)
def refresh_constants(params, first, stop, substep_s, key, constants):
    """Recompute the cached constants of environments ``first .. stop-1`` (one chunk;
    ``constants`` is its row of the cache) whose key is not ``substep_s`` (a NaN key, set
    when their parameters changed, never is)."""
    for j in range(stop - first):
        env = first + j
        if not key[env] == substep_s:
            c = env_constants(params, env, substep_s)
            store_constants(c, constants, j)
            constants[C_BASE_ONLY * CHUNK_ENVS + j] = 1.0 if base_model_only(c) else 0.0
            key[env] = substep_s


@njit(cache=True, forceinline=True, error_model="numpy")
def _work_rows(work, first_row, j):
    """The RK4 state tuple in rows ``first_row ..`` of lane ``j`` of the flat work array."""
    i = first_row * CHUNK_ENVS + j
    k = CHUNK_ENVS
    return (work[i], work[i + k], work[i + 2 * k], work[i + 3 * k], work[i + 4 * k],
            work[i + 5 * k], work[i + 6 * k], work[i + 7 * k], work[i + 8 * k])


@njit(cache=True, forceinline=True, error_model="numpy")
def _set_work_rows(work, first_row, j, y):
    """Store the state tuple ``y`` in rows ``first_row ..`` of lane ``j`` (row by row: a
    run-time tuple index would not vectorise)."""
    i = first_row * CHUNK_ENVS + j
    k = CHUNK_ENVS
    work[i], work[i + k], work[i + 2 * k] = y[0], y[1], y[2]
    work[i + 3 * k], work[i + 4 * k], work[i + 5 * k] = y[3], y[4], y[5]
    work[i + 6 * k], work[i + 7 * k], work[i + 8 * k] = y[6], y[7], y[8]


@njit(cache=True, error_model="numpy")
def _begin_substeps(constants, work, n_lanes, h):
    """Before a vectorised substep, for every lane of a chunk: keep the state at the
    substep's start, set the piston's direction over the substep (``motion_direction``;
    0 with the rod fixed), and mark the lane for the general path where ``refinement``
    would split the substep (stiff flow). A loop LLVM vectorises."""
    for j in range(n_lanes):
        c = load_constants(constants, j)
        y = _work_rows(work, 0, j)
        _set_work_rows(work, W_START, j, y)
        applied = (pneumatic_force(y[2], y[3], c.area_cap, c.area_rod, c.rod_area, c.ambient_pa)
                   - external_force(c.mode, y[4], c.load_force, c.spring_k, c.spring_rest))
        direction = motion_direction(y[4], y[5], applied, c.stick_threshold, c.half_stroke)
        work[W_DIRECTION * CHUNK_ENVS + j] = 0.0 if c.mode == MODE_FIXED else direction
        stiff = stiffness_ratio(c, y, h) > STIFFNESS_LIMIT  # refinement(c, y, h) > 1
        work[W_REDO * CHUNK_ENVS + j] = 1.0 if stiff else 0.0


@njit(cache=True, error_model="numpy")
def _base_substeps_vectorised(constants, work, n_lanes, h):
    """RK4 substep of ``base_derivatives`` for every lane of a chunk; a loop LLVM vectorises.

    ``error_model="numpy"`` lets a division by zero give inf instead of raising, so the
    divisions do not stop vectorisation.
    """
    for j in range(n_lanes):
        c = load_constants(constants, j)
        out = rk4_base_substep(c, _work_rows(work, 0, j), work[W_CURRENT * CHUNK_ENVS + j],
                               work[W_DIRECTION * CHUNK_ENVS + j],
                               work[W_SPOOL_DELAYED * CHUNK_ENVS + j],
                               work[(W_SPOOL_DELAYED + 1) * CHUNK_ENVS + j],
                               work[(W_SPOOL_DELAYED + 2) * CHUNK_ENVS + j], h)
        _set_work_rows(work, 0, j, out)


@njit(cache=True, error_model="numpy")
def _end_substeps(constants, work, n_lanes):
    """After a vectorised substep, for every lane of a chunk: mark the lane for the general
    path where the sliding piston met an event (a stop or a velocity reversal,
    ``event_fraction``), and apply the end stops (``end_of_substep``). A loop LLVM
    vectorises."""
    k = CHUNK_ENVS
    for j in range(n_lanes):
        c = load_constants(constants, j)
        direction = work[W_DIRECTION * k + j]
        x0, v0 = work[(W_START + L.S_X) * k + j], work[(W_START + L.S_V) * k + j]
        x, v = work[L.S_X * k + j], work[L.S_V * k + j]
        event = direction != 0.0 and event_fraction(x0, v0, x, v, direction,
                                                    c.half_stroke) >= 0.0
        work[W_REDO * k + j] = 1.0 if event else work[W_REDO * k + j]
        work[L.S_X * k + j], work[L.S_V * k + j] = end_of_substep(x, v, c.half_stroke)


@njit(cache=True, forceinline=True, error_model="numpy")
def _delay_slots(head_sub, stage, delay_substeps, n_slots):
    """Where the batch path reads x_s(t - tau) at substep fraction ``stage / 2`` (0, 1/2,
    1; at or before head + 1): (query, lower slot, upper slot, weight of the upper)."""
    query = 0.5 * stage - delay_substeps
    base = math.floor(query)
    lower_slot = head_sub + int(base)  # in [-n_slots, n_slots)
    lower_slot = lower_slot + n_slots if lower_slot < 0 else lower_slot
    upper_slot = lower_slot + 1
    upper_slot = 0 if upper_slot == n_slots else upper_slot
    return query, lower_slot, upper_slot, query - base


@njit(cache=True, error_model="numpy")
def _same_delay(constants, n_lanes):
    """Whether every lane of a chunk has the same tube delay (one tube length: the usual
    case), so that its delayed reads share their ring slots."""
    k = CHUNK_ENVS
    delay = constants[C_DELAY_SUBSTEPS * k]
    same = True
    for j in range(1, n_lanes):
        same &= constants[C_DELAY_SUBSTEPS * k + j] == delay
    return same


@njit(cache=True, error_model="numpy")
def _interpolate_row(work, lower_row, upper_row, n_lanes, row, weight, at_start):
    """Work row ``row`` of every lane from two rows of the ring buffer, ``lower_row +
    weight * (upper_row - lower_row)``, or the substep's start (``at_start``: a delay of
    exactly one substep). A loop LLVM vectorises."""
    k = CHUNK_ENVS
    for j in range(n_lanes):
        lower = lower_row[j]
        interpolated = lower + weight * (upper_row[j] - lower)
        work[row * k + j] = work[W_START * k + j] if at_start else interpolated


@njit(cache=True, error_model="numpy")
def _delayed_spool_rows(constants, work, history, first, n_lanes, head_sub, same_delay):
    """For every lane of a chunk, the delayed spool position x_s(t - tau) at the substep's
    start, middle and end (``delayed_value`` with a delay of at least one substep, as
    ``base_model_only`` requires). With ``same_delay`` (``_same_delay``) the lanes read the
    same ring slots, contiguous rows (``_interpolate_row``); otherwise each lane its own
    (branch-free, so no lane waits on a mispredicted branch; gathers, which LLVM keeps
    scalar)."""
    n_slots = history.shape[0]
    k = CHUNK_ENVS
    stop = first + n_lanes
    if same_delay:
        for stage in range(3):
            query, lower_slot, upper_slot, weight = _delay_slots(
                head_sub, stage, constants[C_DELAY_SUBSTEPS * k], n_slots)
            _interpolate_row(work, history[lower_slot, L.H_X_S, first:stop],
                             history[upper_slot, L.H_X_S, first:stop], n_lanes,
                             W_SPOOL_DELAYED + stage, weight, query >= 0.0)
        return
    for j in range(n_lanes):
        delay_substeps = constants[C_DELAY_SUBSTEPS * k + j]
        x_s = work[W_START * k + j]
        for stage in range(3):
            query, lower_slot, upper_slot, weight = _delay_slots(head_sub, stage,
                                                                 delay_substeps, n_slots)
            lower = history[lower_slot, L.H_X_S, first + j]
            upper = history[upper_slot, L.H_X_S, first + j]
            interpolated = lower + weight * (upper - lower)
            # a query at head + 1 (a delay of exactly one substep) is the start's own value
            work[(W_SPOOL_DELAYED + stage) * k + j] = x_s if query >= 0.0 else interpolated


@njit(cache=True, error_model="numpy", inline="always")
def _any_lane_set(work, row, n_lanes):
    """Whether any lane of work row ``row`` (0.0 or 1.0 flags) is set: an OR of their bits,
    a reduction LLVM vectorises, so the lanes are scanned one by one only when one is."""
    bits = 0
    for j in range(n_lanes):
        bits |= _float_to_bits(work[row * CHUNK_ENVS + j])
    return bits != 0


@njit(cache=True, error_model="numpy")
def _copy_fast_lanes(constants, work, n_lanes, work_row, target_row, keep_redone):
    """Copy row ``work_row`` of a chunk's lanes into ``target_row`` (one row of the chunk's
    state, outputs or delay history at one ring slot) for the lanes of the batch path;
    the lanes of ``advance_env`` keep theirs, and so do the lanes the general path redid
    when ``keep_redone`` (it wrote their history itself). A loop LLVM vectorises (one row
    per loop: with more rows written, it would not check their aliasing at run time)."""
    k = CHUNK_ENVS
    for j in range(n_lanes):
        # both entries loaded and bitwise logic: no branch, so no conditional load
        kept, advanced = target_row[j], work[work_row * k + j]
        keep = ((constants[C_BASE_ONLY * k + j] == 0.0)
                | (keep_redone & (work[W_REDO * k + j] != 0.0)))
        target_row[j] = kept if keep else advanced


@njit(cache=True, error_model="numpy")
def _fast_commands(constants, work, n_lanes, command_row, play_row):
    """The held command of each batch-path lane of a chunk as the spool sees it through
    its play (``spool_command``), into row ``W_CURRENT``; ``play_row`` is the chunk's
    state row ``spool_play_current_a`` (the lanes of ``advance_env`` keep theirs). A loop
    LLVM vectorises."""
    k = CHUNK_ENVS
    for j in range(n_lanes):
        held = play_row[j]
        played = spool_play_current(held, command_row[j], constants[C_SPOOL_PLAY_BAND * k + j])
        play_row[j] = held if constants[C_BASE_ONLY * k + j] == 0.0 else played
        work[W_CURRENT * k + j] = played


@njit(cache=True, error_model="numpy")
def _fast_output_forces(constants, work, n_lanes, force_row):
    """The force output (Eq. 1, ``output_force``) of each batch-path lane of a chunk into
    ``force_row`` (the chunk's outputs row ``O_F``; the lanes of ``advance_env`` keep
    theirs). A loop LLVM vectorises."""
    k = CHUNK_ENVS
    for j in range(n_lanes):
        c = load_constants(constants, j)
        y = _work_rows(work, 0, j)
        force = output_force(c.mode, pneumatic_force(y[2], y[3], c.area_cap, c.area_rod,
                                                     c.rod_area, c.ambient_pa),
                             y[4], c.spring_k, c.spring_rest)
        kept = force_row[j]
        force_row[j] = kept if constants[C_BASE_ONLY * k + j] == 0.0 else force


@njit(cache=True)
def chunk_work(state, first, stop):
    """A new work array for environments ``first .. stop-1`` (one chunk): their RK4 state
    rows, the other rows zero."""
    work = np.zeros(N_WORK * CHUNK_ENVS)
    for row in range(N_RK):
        work[row * CHUNK_ENVS:row * CHUNK_ENVS + stop - first] = state[row, first:stop]
    return work


@njit(cache=True)
def prepare_substep(constants, work, history, first, n_lanes, head_sub, same_delay, h):
    """The inputs of a chunk's RK4 loop for the substep after ring slot ``head_sub``: the
    start state, direction and stiff lanes (``_begin_substeps``), then the delayed spool
    positions (``_delayed_spool_rows``)."""
    _begin_substeps(constants, work, n_lanes, h)
    _delayed_spool_rows(constants, work, history, first, n_lanes, head_sub, same_delay)


@njit(cache=True)
def advance_chunk(params, state, history, first, stop, head, coil_current_a, control_dt_s,
                  n_substeps, outputs, key, constants):
    """Advance environments ``first .. stop-1`` by one control period; write their outputs.

    ``first`` is a multiple of ``CHUNK_ENVS``; ``key``, ``constants`` are the cache of
    ``constants_cache``. Environments where ``base_model_only`` holds advance together:
    per substep, one vectorised loop keeps the start state and finds the piston's
    direction and the stiff lanes (``_begin_substeps``), the delayed spool positions are
    read (``_delayed_spool_rows``), one vectorised RK4 substep
    (``_base_substeps_vectorised``) advances every lane, and one vectorised loop finds the
    lanes whose piston met an event and applies the stops (``_end_substeps``). A lane whose substep needs splitting (stiff
    flow, ``refinement``) or crosses a piston event is redone from the substep's start by
    the general path (``_split_substep``). Other environments take ``advance_env``.
    Either way an environment's result does not depend on the rest of the batch.
    """
    n = stop - first
    h = control_dt_s / n_substeps
    n_slots = history.shape[0]
    chunk_constants = constants[first // CHUNK_ENVS]
    refresh_constants(params, first, stop, h, key, chunk_constants)
    fast = chunk_constants[C_BASE_ONLY * CHUNK_ENVS:]
    for j in range(n):
        env = first + j
        if fast[j] == 0.0:
            advance_env(params, state, history, env, head, coil_current_a[env], control_dt_s,
                        n_substeps, outputs)
    # lanes advance_env advanced are computed below too, and ignored
    work = chunk_work(state, first, stop)
    _fast_commands(chunk_constants, work, n, coil_current_a[first:stop],
                   state[L.S_PLAY, first:stop])
    same_delay = _same_delay(chunk_constants, n)
    for sub in range(n_substeps):
        head_sub = ring_slot(head + sub, n_slots)
        prepare_substep(chunk_constants, work, history, first, n, head_sub, same_delay, h)
        _base_substeps_vectorised(chunk_constants, work, n, h)
        _end_substeps(chunk_constants, work, n)
        slot = ring_slot(head_sub + 1, n_slots)
        for row, channel in ((L.S_X_S, L.H_X_S), (L.S_P1, L.H_P1), (L.S_P2, L.H_P2)):
            _copy_fast_lanes(chunk_constants, work, n, row, history[slot, channel, first:stop],
                             True)
        for j in range(n if _any_lane_set(work, W_REDO, n) else 0):
            if fast[j] != 0.0 and work[W_REDO * CHUNK_ENVS + j] != 0.0:
                env = first + j
                c = load_constants(chunk_constants, j)
                y0 = _work_rows(work, W_START, j)
                current = work[W_CURRENT * CHUNK_ENVS + j]
                y, _ = _split_substep(c, history, env, head_sub, h, current,
                                      (current, current), y0, refinement(c, y0, h),
                                      c.ambient_pa, 0.0)
                _set_work_rows(work, 0, j, _close_substep(c, history, env, slot, y))
    # the batch path's lanes: state and outputs as _store_state writes them
    for row in range(N_RK):
        _copy_fast_lanes(chunk_constants, work, n, row, state[row, first:stop], False)
    for row in (L.S_COIL, L.S_COIL_FORCE):  # no coil lag on the batch path
        _copy_fast_lanes(chunk_constants, work, n, W_CURRENT, state[row, first:stop], False)
    for output_row, row in OUTPUT_STATE_ROWS:
        _copy_fast_lanes(chunk_constants, work, n, row, outputs[output_row, first:stop], False)
    _fast_output_forces(chunk_constants, work, n, outputs[L.O_F, first:stop])


# the outputs that are state rows: (outputs row, state row)
OUTPUT_STATE_ROWS = ((L.O_P1, L.S_P1), (L.O_P2, L.S_P2), (L.O_X, L.S_X), (L.O_V, L.S_V),
                     (L.O_X_S, L.S_X_S), (L.O_EXHAUST, L.S_EXHAUST))


@njit(cache=True)
def _store_state(c, state, env, y, coil, outputs):
    """Write the integrated rows and the (coil, force) currents back, and the outputs row
    (Eq. 1)."""
    for row in range(N_RK):
        state[row, env] = y[row]
    state[L.S_COIL, env] = coil[0]
    state[L.S_COIL_FORCE, env] = coil[1]
    _store_outputs(c, y, env, outputs)


@njit(cache=True)
def _store_outputs(c, y, env, outputs):
    """The outputs row of ``env`` from its state rows ``y`` (the force by Eq. 1)."""
    for output_row, row in OUTPUT_STATE_ROWS:
        outputs[output_row, env] = y[row]
    f_p = pneumatic_force(y[L.S_P1], y[L.S_P2], c.area_cap, c.area_rod, c.rod_area,
                          c.ambient_pa)
    outputs[L.O_F, env] = output_force(c.mode, f_p, y[L.S_X], c.spring_k, c.spring_rest)


@njit(cache=True)
def write_outputs(params, state, envs, outputs):
    """The outputs rows of ``envs`` from their state (after a reset)."""
    for env in envs:
        _store_outputs(env_constants(params, env, 1.0), state[:, env], env, outputs)


@njit(cache=True)
def step_serial(params, state, history, head, coil_current_a, control_dt_s, n_substeps, outputs,
                key, constants):
    """Advance every environment of the batch by one control period on one thread."""
    n_envs = state.shape[1]
    for first in range(0, n_envs, CHUNK_ENVS):
        advance_chunk(params, state, history, first, min(first + CHUNK_ENVS, n_envs), head,
                      coil_current_a, control_dt_s, n_substeps, outputs, key, constants)


@njit(cache=True, parallel=True)
def step_parallel(params, state, history, head, coil_current_a, control_dt_s, n_substeps,
                  outputs, key, constants):
    """Advance every environment of the batch by one control period, chunks in parallel
    (``BatchSimulator.call_step_kernel`` hands them out)."""
    n_envs = state.shape[1]
    for chunk in prange((n_envs + CHUNK_ENVS - 1) // CHUNK_ENVS):
        first = chunk * CHUNK_ENVS
        advance_chunk(params, state, history, first, min(first + CHUNK_ENVS, n_envs), head,
                      coil_current_a, control_dt_s, n_substeps, outputs, key, constants)


@njit(cache=True)
def rollout_serial(params, state, history, head, coil_current_a, control_dt_s, n_substeps,
                   outputs, key, constants):
    """Run a whole open-loop current sequence ``coil_current_a[step, env]`` in one call.

    ``outputs[step, O_*, env]`` receives the outputs after each control period.
    """
    for step in range(coil_current_a.shape[0]):
        step_serial(params, state, history, head + step * n_substeps, coil_current_a[step],
                    control_dt_s, n_substeps, outputs[step], key, constants)


def history_slots(max_delay_s, control_dt_s, n_substeps):
    """Ring-buffer length for delays up to ``max_delay_s`` (a whole number of substeps + 2)."""
    return int(np.ceil(max_delay_s / (control_dt_s / n_substeps))) + 2
