"""The kernel's right-hand side and its RK4 steps.

``derivatives`` is the general form (all four valve paths, the leakage orifices, every
effect); ``base_derivatives`` the paper's model where ``constants.base_model_only`` holds,
branch-free so that a loop over environments compiles to SIMD code. The delayed inputs are
read from the ring buffer of substep boundaries (``delayed_value``); ``rk4_step`` takes one RK4
step of the general form over a fraction of a substep (``batch_rhs.rk4_base_substep`` one
whole substep of the batch path's form).
"""

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from . import layout as L
from .chamber import chamber_volumes, pressure_rate
from .effects import (
    chamber_energy_rates,
    coil_force_gain,
    lagged_coil_current,
    lagged_coil_force_current,
    laminar_leak_flow,
    rate_with_isothermal_tube_air,
    stribeck_friction,
)
from .nodes import line_chamber_flows, path_mass_flow, valve_chamber_flows
from .piston import external_force, piston_acceleration, pneumatic_force
from .valve import spool_acceleration

N_RK = 9  # state rows the RK4 integrates (S_X_S .. S_T2)


@njit(cache=True, forceinline=True, error_model="numpy")
def _motion_and_spool(c, coil_current_a, x_s, v_s, p1, p2, x, velocity, direction, friction_n):
    """Piston acceleration (Eq. 1; zero while held) and spool acceleration (Eq. 38)."""
    applied = pneumatic_force(
        p1, p2, c.area_cap, c.area_rod, c.rod_area, c.ambient_pa
    ) - external_force(c.mode, x, c.load_force, c.spring_k, c.spring_rest)
    accel = piston_acceleration(
        applied, velocity, direction, friction_n, c.viscous, c.inv_moving_mass
    )
    a_s = spool_acceleration(
        x_s, v_s, coil_current_a, c.inv_spool_mass, c.spool_damping, c.spool_spring, c.coil_force
    )
    return accel, a_s


@njit(cache=True, inline="always")
def sliding_friction(c, velocity):
    """The sliding friction's magnitude at ``velocity``: F_df (Eq. 47), or the Stribeck
    curve; Karnopp's while sliding, and the curve LuGre's bristles relax towards."""
    if c.stribeck:
        return stribeck_friction(velocity, c.dynamic_friction, c.static_friction, c.stribeck_v)
    return c.dynamic_friction


@njit(cache=True, forceinline=True, error_model="numpy")
def _volumes(c, x):
    """Chamber volumes (Eq. 15) with the position held in the stroke (a trial step may
    overshoot)."""
    x_in_stroke = min(max(x, -c.half_stroke), c.half_stroke)
    return chamber_volumes(
        x_in_stroke, c.half_stroke, c.area_cap, c.area_rod, c.dead_cap, c.dead_rod
    )


class ValveInputs(NamedTuple):
    """What the valve's flows are evaluated with (``valve_inputs``)."""

    spool_m: float  # the delayed spool position x_s(t - tau)
    p1_pa: float  # chamber 1's pressure as the valve sees it (delayed with the literal Eq. 55)
    p2_pa: float  # chamber 2's, the same


@njit(cache=True, forceinline=True)
def derivatives(
    c, coil_current_a, y, direction, valve, arriving, exhaust_node_pa, lugre_friction_n=0.0
):
    """Right-hand side of the RK4 state ``y`` = (x_s, v_s, P1, P2, x, v, exhaust mass, T1,
    T2).

    The general form: all four valve paths, the leakage orifices and every effect.
    ``coil_current_a`` is the current driving the spool (lagged if the coil lag is on).
    T1, T2 change only with the energy model on (``wall_heat_transfer_w_per_k > 0``).
    ``valve``: the ``ValveInputs``. With the tubes as transmission lines (``tube_waves``)
    the chamber flows come from the waves ``arriving`` at the lines' chamber ends
    (``chamber_end_waves``, ``line_chamber_flows``) and ``valve`` is unused; the lines'
    valve exhaust is added to the exhaust mass at the substep boundaries
    (``general_path.close_substep``). With LuGre
    friction on, ``lugre_friction_n`` (held over the substep, ``lugre_bristle_step``)
    replaces the sliding friction.
    """
    x_s, v_s, p1, p2, x, v = y[0], y[1], y[2], y[3], y[4], y[5]
    t1, t2 = y[7], y[8]
    inv_sqrt_t1, inv_sqrt_t2 = inv_sqrt_temperatures(c, t1, t2)
    flows = _chamber_mass_flows(
        c, p1, p2, valve, arriving, exhaust_node_pa, inv_sqrt_t1, inv_sqrt_t2
    )
    supply_1, exhaust_1, supply_2, exhaust_2, leak_12, seal_2 = flows
    velocity = v if direction != 0.0 else 0.0
    dp1, dp2, dt1, dt2 = _chamber_rates(c, p1, p2, x, t1, t2, velocity, flows)
    # piston_acceleration applies friction * direction (+-1 while moving)
    friction = lugre_friction_n * direction if c.lugre else sliding_friction(c, velocity)
    accel, a_s = _motion_and_spool(
        c, coil_current_a, x_s, v_s, p1, p2, x, velocity, direction, friction
    )
    exhaust_rate = max(exhaust_1, 0.0) + max(exhaust_2, 0.0) + max(seal_2, 0.0)
    return v_s, a_s, dp1, dp2, velocity, accel, exhaust_rate, dt1, dt2


@njit(cache=True, forceinline=True)  # inlined: a call would pass every constant
def _chamber_mass_flows(c, p1, p2, valve, arriving, exhaust_node_pa, inv_sqrt_t1, inv_sqrt_t2):
    """The signed mass flows of ``derivatives``: (supply -> 1, 1 -> exhaust, supply -> 2,
    2 -> exhaust, leak 1 -> 2, rod seal 2 -> ambient)."""
    if c.waves:  # a signed flow into each chamber from its line; the line's air at T_s
        supply_1, supply_2 = line_chamber_flows(c, arriving, p1, p2)
        exhaust_1 = 0.0
        exhaust_2 = 0.0
    else:
        supply_1, exhaust_1, supply_2, exhaust_2 = valve_chamber_flows(
            c, valve[0], valve[1], valve[2], p1, p2, inv_sqrt_t1, inv_sqrt_t2, exhaust_node_pa
        )
    leak_12 = path_mass_flow(
        c, c.discharge, c.leak_area, p1, p2, inv_sqrt_t1, inv_sqrt_t2, c.flow_law
    ) + laminar_leak_flow(c.leak_conductance, p1, p2)
    seal_2 = path_mass_flow(
        c, c.discharge, c.seal_leak, p2, c.ambient_pa, inv_sqrt_t2, c.inv_sqrt_t, c.flow_law
    )
    return supply_1, exhaust_1, supply_2, exhaust_2, leak_12, seal_2


@njit(cache=True, forceinline=True)  # inlined: a call would pass every constant
def _chamber_rates(c, p1, p2, x, t1, t2, velocity, flows):
    """(dP1, dP2, dT1, dT2) of ``derivatives`` from its ``_chamber_mass_flows``: Eq. 14/16,
    or the energy model, with the isothermal tube air if on."""
    supply_1, exhaust_1, supply_2, exhaust_2, leak_12, seal_2 = flows
    in_1 = max(supply_1, 0.0) + max(-exhaust_1, 0.0) + max(-leak_12, 0.0)
    out_1 = max(-supply_1, 0.0) + max(exhaust_1, 0.0) + max(leak_12, 0.0)
    in_2 = max(supply_2, 0.0) + max(-exhaust_2, 0.0) + max(leak_12, 0.0) + max(-seal_2, 0.0)
    out_2 = max(-supply_2, 0.0) + max(exhaust_2, 0.0) + max(-leak_12, 0.0) + max(seal_2, 0.0)
    v1, v2 = _volumes(c, x)
    if c.energy:
        # air from the supply or the atmosphere enters at temperature_k, leakage air at
        # the temperature of the chamber it left
        enthalpy_1 = (max(supply_1, 0.0) + max(-exhaust_1, 0.0)) * c.temperature + max(
            -leak_12, 0.0
        ) * t2
        enthalpy_2 = (
            max(supply_2, 0.0) + max(-exhaust_2, 0.0) + max(-seal_2, 0.0)
        ) * c.temperature + max(leak_12, 0.0) * t1
        dp1, dt1 = chamber_energy_rates(
            p1,
            t1,
            v1,
            c.area_cap * velocity,
            in_1,
            out_1,
            enthalpy_1,
            c.gas,
            c.k,
            c.heat_conductance,
            c.temperature,
        )
        dp2, dt2 = chamber_energy_rates(
            p2,
            t2,
            v2,
            -c.area_rod * velocity,
            in_2,
            out_2,
            enthalpy_2,
            c.gas,
            c.k,
            c.heat_conductance,
            c.temperature,
        )
        return dp1, dp2, dt1, dt2
    dp1 = pressure_rate(
        p1,
        v1,
        c.area_cap * velocity,
        in_1,
        out_1,
        c.gas_rt,
        c.alpha_in,
        c.alpha_out,
        c.alpha_motion,
    )
    dp2 = pressure_rate(
        p2,
        v2,
        -c.area_rod * velocity,
        in_2,
        out_2,
        c.gas_rt,
        c.alpha_in,
        c.alpha_out,
        c.alpha_motion,
    )
    if c.tube_air > 0.0:
        dp1 = rate_with_isothermal_tube_air(dp1, v1, c.tube_air, c.alpha_in, c.alpha_out)
        dp2 = rate_with_isothermal_tube_air(dp2, v2, c.tube_air, c.alpha_in, c.alpha_out)
    return dp1, dp2, 0.0, 0.0


@njit(cache=True, forceinline=True)
def ring_slot(index, n_slots):
    """``index`` modulo ``n_slots`` (a ring-buffer slot, in [0, n_slots)); a compare instead
    of an integer division for -n_slots <= index < n_slots, the case of a delay read from
    a head already in the ring."""
    if index < -n_slots or index >= n_slots:
        return index % n_slots
    return index + n_slots if index < 0 else index


@njit(cache=True)
def delayed_value(
    history, env, channel, head, stage_substeps, delay_substeps, value_at_head, value_at_stage
):
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
def valve_inputs(c, history, env, head, frac, y, y0):
    """What the valve sees ``frac`` of a substep after boundary ``head`` (state ``y``; ``y0``
    at the boundary): the delayed spool x_s(t - tau) and the chamber pressures its flow is
    evaluated with (the delayed ones with the literal Eq. 55, else the present ones): the
    ``ValveInputs``."""
    spool_delayed = delayed_value(history, env, L.H_X_S, head, frac, c.delay_substeps, y0[0], y[0])
    if c.literal:
        return ValveInputs(
            spool_delayed,
            delayed_value(history, env, L.H_P1, head, frac, c.delay_substeps, y0[2], y[2]),
            delayed_value(history, env, L.H_P2, head, frac, c.delay_substeps, y0[3], y[3]),
        )
    return ValveInputs(spool_delayed, y[2], y[3])


@njit(cache=True, inline="always")
def inv_sqrt_temperatures(c, t1, t2):
    """1/sqrt(T) of the chamber air: of the gas temperatures with the energy model, else
    of ``temperature_k`` (cached)."""
    if c.energy:
        return 1.0 / math.sqrt(t1), 1.0 / math.sqrt(t2)
    return c.inv_sqrt_t, c.inv_sqrt_t


class SubstepDrive(NamedTuple):
    """What drives the general path's RK4 over (part of) a substep besides the constants and
    the state."""

    history: np.ndarray  # the delay ring buffer (slots, N_HISTORY, n_envs)
    env: int  # the environment's column
    head: int  # ring slot of the substep's start boundary
    h: float  # the substep, s
    command_a: float  # the held coil current command, A
    coil_start: tuple  # (coil, force) currents at the substep's start (``coil_at``), A
    exhaust_node_pa: float  # the exhaust node's pressure, held over the substep
    lugre_friction_n: float  # the LuGre friction, held over the part (0 with LuGre off)


@njit(cache=True, inline="always")  # inlined: a call would pass every constant as an argument
def _stage(c, drive, frac, coil_current_a, y, y0, direction):
    valve = valve_inputs(c, drive.history, drive.env, drive.head, frac, y, y0)
    arriving = (0.0, 0.0)
    if c.waves:
        arriving = chamber_end_waves(c, drive.history, drive.env, drive.head, frac)
    return derivatives(
        c,
        coil_current_a,
        y,
        direction,
        valve,
        arriving,
        drive.exhaust_node_pa,
        drive.lugre_friction_n,
    )


@njit(cache=True, forceinline=True)
def arriving_waves(c, history, env, head, frac):
    """The waves at the four line ends ``frac`` of a substep after boundary ``head``: each
    sent by the other end one delay earlier (the delay is at least one substep). (At
    valve end 1, at valve end 2, then ``chamber_end_waves``.)"""
    d = c.delay_substeps
    at_chambers = chamber_end_waves(c, history, env, head, frac)
    return (
        delayed_value(history, env, L.H_WAVE_CHAMBER_1, head, frac, d, 0.0, 0.0),
        delayed_value(history, env, L.H_WAVE_CHAMBER_2, head, frac, d, 0.0, 0.0),
        at_chambers[0],
        at_chambers[1],
    )


@njit(cache=True, forceinline=True)
def chamber_end_waves(c, history, env, head, frac):
    """The waves arriving at the two chamber ends (``arriving_waves``' last two), all the
    RK4 stages need: the valve ends are solved at the substep boundaries only."""
    d = c.delay_substeps
    return (
        delayed_value(history, env, L.H_WAVE_VALVE_1, head, frac, d, 0.0, 0.0),
        delayed_value(history, env, L.H_WAVE_VALVE_2, head, frac, d, 0.0, 0.0),
    )


@njit(cache=True, forceinline=True, error_model="numpy")
def _axpy(y, h, k):
    return (
        y[0] + h * k[0],
        y[1] + h * k[1],
        y[2] + h * k[2],
        y[3] + h * k[3],
        y[4] + h * k[4],
        y[5] + h * k[5],
        y[6] + h * k[6],
        y[7] + h * k[7],
        y[8] + h * k[8],
    )


@njit(cache=True, inline="always")
def coil_at(c, command_a, coil_start, frac):
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
        decay = c.coil_decay_full**frac
    coil = lagged_coil_current(command_a, coil_start[0], decay)
    if not c.coil_force_lag:
        return coil, coil
    return coil, lagged_coil_force_current(
        command_a,
        coil_start[0],
        coil_start[1],
        math.exp(-frac * c.force_rate),
        coil_force_gain(decay, frac * c.force_rate, frac * c.force_rate_difference),
    )


@njit(cache=True)
def rk4_step(c, drive, frac0, dfrac, y, y0, direction):
    """One classical RK4 step over substep fractions [frac0, frac0 + dfrac] of the
    ``SubstepDrive`` ``drive``'s substep.

    ``y0`` is the state at the substep boundary ``drive.head`` (the delay interpolation's
    anchor).
    """
    hh = dfrac * drive.h
    fm = frac0 + 0.5 * dfrac
    fe = frac0 + dfrac
    command_a, coil_start = drive.command_a, drive.coil_start
    k1 = _stage(c, drive, frac0, coil_at(c, command_a, coil_start, frac0)[1], y, y0, direction)
    k2 = _stage(
        c,
        drive,
        fm,
        coil_at(c, command_a, coil_start, fm)[1],
        _axpy(y, 0.5 * hh, k1),
        y0,
        direction,
    )
    k3 = _stage(
        c,
        drive,
        fm,
        coil_at(c, command_a, coil_start, fm)[1],
        _axpy(y, 0.5 * hh, k2),
        y0,
        direction,
    )
    k4 = _stage(
        c, drive, fe, coil_at(c, command_a, coil_start, fe)[1], _axpy(y, hh, k3), y0, direction
    )
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
    return (
        y[0] + w * (k1[0] + 2.0 * k2[0] + 2.0 * k3[0] + k4[0]),
        y[1] + w * (k1[1] + 2.0 * k2[1] + 2.0 * k3[1] + k4[1]),
        p1,
        p2,
        x,
        v,
        y[6] + w * (k1[6] + 2.0 * k2[6] + 2.0 * k3[6] + k4[6]),
        t1,
        t2,
    )
