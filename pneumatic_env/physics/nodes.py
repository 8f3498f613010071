"""Algebraic nodes of the kernel: the valve-chamber flows (Eqs. 39, 50-55) and the
pressures that are roots of a flow balance rather than states: the supply pressure behind a
supply resistance, the exhaust node behind a vent (docs/effects.md) and the valve ends of
the tubes as transmission lines (``tube_waves``). Each solver brackets its root and runs
Illinois regula falsi (``_illinois_update``).

Every function takes the environment's ``constants.Constants`` as ``c``.
"""

from numba import njit

from .effects import drooped_supply_pressure
from .flow import orifice_mass_flow_inv_k
from .tube import line_chamber_flow, line_end_wave, line_resistance_scaled, tube_attenuation_scaled
from .valve import orifice_area_inv_radius


@njit(cache=True, forceinline=True, error_model="numpy")
def path_mass_flow(c, discharge, area, p_from, p_to, inv_sqrt_t_from, inv_sqrt_t_to, flow_law):
    """Eq. 39 from node ``from`` to node ``to``, at the upstream node's temperature.

    A closed orifice returns at once on the general (scalar) path; in the vectorised loop
    the test becomes a select.
    """
    if area <= 0.0:
        return 0.0
    inv_sqrt_t = inv_sqrt_t_from if p_from >= p_to else inv_sqrt_t_to
    return orifice_mass_flow_inv_k(
        area,
        discharge,
        p_from,
        p_to,
        inv_sqrt_t,
        c.inv_k,
        c.c1,
        c.c2,
        c.critical_ratio,
        c.linear_ratio,
        c.linear_slope,
        flow_law,
    )


@njit(cache=True, forceinline=True, error_model="numpy")
def chamber_end_flow(c, mass_flow, chamber_pa):
    """The flow delivered at the chamber end of the tube (Eq. 30); none in, none out."""
    if mass_flow == 0.0:
        return 0.0
    return mass_flow * tube_attenuation_scaled(
        mass_flow,
        chamber_pa,
        c.half_rt_delay,
        c.reynolds_per_flow,
        c.viscous_scale,
        c.reynolds_turbulent,
    )


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


@njit(cache=True, forceinline=True)
def _supply_flow(c, supply_pa, area_a, area_b, valve_p1_pa, valve_p2_pa, inv_sqrt_t1, inv_sqrt_t2):
    """Total valve flow out of the supply (both paths, before the tubes), >= 0."""
    return max(
        path_mass_flow(
            c, c.discharge, area_a, supply_pa, valve_p1_pa, c.inv_sqrt_t, inv_sqrt_t1, c.flow_law
        )
        + path_mass_flow(
            c, c.discharge, area_b, supply_pa, valve_p2_pa, c.inv_sqrt_t, inv_sqrt_t2, c.flow_law
        ),
        0.0,
    )


@njit(cache=True, forceinline=True)  # inlined: batch_nodes' loops vectorise
def supply_node_balance(c, supply_pa, area_a, area_b, p1_pa, p2_pa, inv_sqrt_t1, inv_sqrt_t2):
    """f(P) = P - P_s + R_sup mdot_s(P) of ``supply_pressure_at_valve`` at P = ``supply_pa``."""
    flow = _supply_flow(c, supply_pa, area_a, area_b, p1_pa, p2_pa, inv_sqrt_t1, inv_sqrt_t2)
    return supply_pa - c.supply_pa + c.supply_resistance * flow


@njit(cache=True, forceinline=True)
def supply_pressure_at_valve(c, area_a, area_b, valve_p1_pa, valve_p2_pa, inv_sqrt_t1, inv_sqrt_t2):
    """Supply pressure the valve sees through the supply resistance (effect, docs/effects.md).

    The root of f(P) = P - P_s + R_sup mdot_s(P), mdot_s the total supply flow (its
    positive part: a back flow does not raise the supply); f increases with P, so the root
    is unique and bracketed by [max(P_s - R_sup mdot_s(P_s), min(P1, P2)), P_s]. Started
    at the choked estimate (``effects.drooped_supply_pressure``, exact while choked), then
    Illinois regula falsi to ``SUPPLY_DROOP_RTOL``. No flow means no droop.
    """
    supply_pa = c.supply_pa
    resistance = c.supply_resistance
    flow_at_supply = _supply_flow(
        c, supply_pa, area_a, area_b, valve_p1_pa, valve_p2_pa, inv_sqrt_t1, inv_sqrt_t2
    )
    if flow_at_supply <= 0.0:
        return supply_pa
    tolerance = SUPPLY_DROOP_RTOL * supply_pa
    hi = supply_pa
    f_hi = resistance * flow_at_supply
    lo = max(supply_pa - f_hi, min(valve_p1_pa, valve_p2_pa))
    f_lo = supply_node_balance(
        c, lo, area_a, area_b, valve_p1_pa, valve_p2_pa, inv_sqrt_t1, inv_sqrt_t2
    )
    if f_lo >= 0.0:
        return lo
    guess = drooped_supply_pressure(supply_pa, flow_at_supply, resistance)
    side = 0
    for _ in range(SUPPLY_DROOP_MAX_ITERATIONS):
        f_guess = supply_node_balance(
            c, guess, area_a, area_b, valve_p1_pa, valve_p2_pa, inv_sqrt_t1, inv_sqrt_t2
        )
        if abs(f_guess) <= tolerance:
            return guess
        lo, f_lo, hi, f_hi, side = _illinois_update(lo, f_lo, hi, f_hi, guess, f_guess, side)
        guess = (lo * f_hi - hi * f_lo) / (f_hi - f_lo)
    return guess


@njit(cache=True, forceinline=True)  # inlined: batch_nodes' loops vectorise
def _exhaust_node_balance(
    c, exhaust_pa, area_a, area_b, valve_p1_pa, valve_p2_pa, inv_sqrt_t1, inv_sqrt_t2
):
    """Valve flow into the exhaust node (chamber 1 through path b, chamber 2 through path
    a, Eq. 39) minus the vent's flow out of it to the atmosphere (Eq. 39 with C_f = 1 on
    the effective vent area), kg/s; it decreases as ``exhaust_pa`` rises."""
    into_node = path_mass_flow(
        c, c.discharge_ex, area_b, valve_p1_pa, exhaust_pa, inv_sqrt_t1, c.inv_sqrt_t, c.flow_law
    ) + path_mass_flow(
        c, c.discharge_ex, area_a, valve_p2_pa, exhaust_pa, inv_sqrt_t2, c.inv_sqrt_t, c.flow_law
    )
    vented = path_mass_flow(
        c, 1.0, c.exhaust_vent, exhaust_pa, c.ambient_pa, c.inv_sqrt_t, c.inv_sqrt_t, c.flow_law
    )
    return into_node - vented


@njit(cache=True)
def exhaust_pressure_at_valve(
    c,
    area_a,
    area_b,
    valve_p1_pa,
    valve_p2_pa,
    inv_sqrt_t1,
    inv_sqrt_t2,
    storage_kg_per_pa,
    previous_pa,
):
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
        c, lo, area_a, area_b, valve_p1_pa, valve_p2_pa, inv_sqrt_t1, inv_sqrt_t2
    )
    hi_f = storage_kg_per_pa * (hi - previous_pa) - _exhaust_node_balance(
        c, hi, area_a, area_b, valve_p1_pa, valve_p2_pa, inv_sqrt_t1, inv_sqrt_t2
    )
    if lo_f >= 0.0:
        return lo
    if hi_f <= 0.0:
        return hi
    tolerance = SUPPLY_DROOP_RTOL * c.supply_pa
    guess = (lo * hi_f - hi * lo_f) / (hi_f - lo_f)
    side = 0
    for _ in range(SUPPLY_DROOP_MAX_ITERATIONS):
        f_guess = storage_kg_per_pa * (guess - previous_pa) - _exhaust_node_balance(
            c, guess, area_a, area_b, valve_p1_pa, valve_p2_pa, inv_sqrt_t1, inv_sqrt_t2
        )
        if f_guess == 0.0:
            return guess
        lo, lo_f, hi, hi_f, side = _illinois_update(lo, lo_f, hi, hi_f, guess, f_guess, side)
        previous_guess = guess
        guess = (lo * hi_f - hi * lo_f) / (hi_f - lo_f)
        if abs(guess - previous_guess) <= tolerance:
            return guess
    return guess


@njit(cache=True, forceinline=True)
def scalar_area(c, spool_m):
    """``orifice_area`` on the general (scalar) path, returning at once for a closed hole."""
    if spool_m <= c.half_width - c.hole_radius:
        return 0.0
    return orifice_area_inv_radius(spool_m, c.hole_radius, c.inv_hole_radius, c.half_width, c.holes)


@njit(cache=True)
def valve_chamber_flows(
    c,
    spool_delayed_m,
    valve_p1_pa,
    valve_p2_pa,
    p1_pa,
    p2_pa,
    inv_sqrt_t1,
    inv_sqrt_t2,
    exhaust_node_pa,
):
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
    area_a = scalar_area(c, spool_delayed_m) + c.null_leak
    area_b = scalar_area(c, -spool_delayed_m) + c.null_leak
    supply_pa, exhaust_pa = _valve_supply_and_exhaust(
        c, area_a, area_b, valve_p1_pa, valve_p2_pa, inv_sqrt_t1, inv_sqrt_t2, exhaust_node_pa
    )
    t_supply, law = c.inv_sqrt_t, c.flow_law
    supply_1 = chamber_end_flow(
        c,
        path_mass_flow(c, c.discharge, area_a, supply_pa, valve_p1_pa, t_supply, inv_sqrt_t1, law),
        p1_pa,
    )
    exhaust_1 = chamber_end_flow(
        c,
        path_mass_flow(
            c, c.discharge_ex, area_b, valve_p1_pa, exhaust_pa, inv_sqrt_t1, t_supply, law
        ),
        p1_pa,
    )
    supply_2 = chamber_end_flow(
        c,
        path_mass_flow(c, c.discharge, area_b, supply_pa, valve_p2_pa, t_supply, inv_sqrt_t2, law),
        p2_pa,
    )
    exhaust_2 = chamber_end_flow(
        c,
        path_mass_flow(
            c, c.discharge_ex, area_a, valve_p2_pa, exhaust_pa, inv_sqrt_t2, t_supply, law
        ),
        p2_pa,
    )
    return supply_1, exhaust_1, supply_2, exhaust_2


@njit(cache=True, forceinline=True)  # inlined: a call would pass every constant
def _valve_supply_and_exhaust(
    c, area_a, area_b, valve_p1_pa, valve_p2_pa, inv_sqrt_t1, inv_sqrt_t2, exhaust_node_pa
):
    """The pressures (Pa) at the valve's supply port (drooping with the supply flow) and
    exhaust ports (behind a vent: the node's) for ``valve_chamber_flows``."""
    supply_pa = c.supply_pa
    if c.supply_resistance > 0.0:
        supply_pa = supply_pressure_at_valve(
            c, area_a, area_b, valve_p1_pa, valve_p2_pa, inv_sqrt_t1, inv_sqrt_t2
        )
    exhaust_pa = c.ambient_pa
    if c.exhaust_vent > 0.0:
        exhaust_pa = exhaust_node_pa
        if c.exhaust_capacity == 0.0:
            exhaust_pa = exhaust_pressure_at_valve(
                c,
                area_a,
                area_b,
                valve_p1_pa,
                valve_p2_pa,
                inv_sqrt_t1,
                inv_sqrt_t2,
                0.0,
                c.ambient_pa,
            )
    return supply_pa, exhaust_pa


LINE_PRESSURE_RTOL = 1e-10  # solver accuracy of the line's valve-end pressure, relative to P_s


@njit(cache=True, forceinline=True)
def _port_flow_into_line(c, supply_area, exhaust_area, port_pa):
    """Net valve flow into a line at valve-end pressure ``port_pa``, and its exhaust part
    (port -> atmosphere, Eq. 39; the line's air at ``temperature_k``)."""
    supply = path_mass_flow(
        c, c.discharge, supply_area, c.supply_pa, port_pa, c.inv_sqrt_t, c.inv_sqrt_t, c.flow_law
    )
    exhaust = path_mass_flow(
        c,
        c.discharge_ex,
        exhaust_area,
        port_pa,
        c.ambient_pa,
        c.inv_sqrt_t,
        c.inv_sqrt_t,
        c.flow_law,
    )
    return supply - exhaust, exhaust


@njit(cache=True, forceinline=True)
def _line_valve_end_residual(c, supply_area, exhaust_area, wave_in_pa, port_pa):
    """f(P) = P - W_in - (Z_c + R(q, P)/2) q(P) at a valve-end pressure, and q, the exhaust flow."""
    q, exhaust = _port_flow_into_line(c, supply_area, exhaust_area, port_pa)
    resistance = line_resistance_scaled(
        q, port_pa, c.line_friction, c.reynolds_per_flow, c.viscous_scale, c.reynolds_turbulent
    )
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


@njit(cache=True, forceinline=True)
def line_valve_areas(c, spool_m):
    """The valve's open areas (spool at ``spool_m``, with its null leak) from the supply
    into line 1 and from line 1 to the exhaust; mirrored for line 2."""
    return scalar_area(c, spool_m) + c.null_leak, scalar_area(c, -spool_m) + c.null_leak


@njit(cache=True, forceinline=True)
def line_valve_ends(c, spool_m, arriving):
    """The valve ends of lines 1 and 2 (``_line_valve_end``: pressure, flow into the line,
    exhaust flow), the spool at ``spool_m``, the waves ``arriving`` there first in it."""
    area_a, area_b = line_valve_areas(c, spool_m)
    return (
        _line_valve_end(c, area_a, area_b, arriving[0]),
        _line_valve_end(c, area_b, area_a, arriving[1]),
    )


@njit(cache=True)
def line_flows(c, spool_m, arriving, p1_pa, p2_pa):
    """The tubes as transmission lines (effect ``tube_waves``): the flows at their ends.

    ``arriving`` = (W at valve end 1, at valve end 2, at chamber end 1, at chamber end 2),
    the waves the other ends sent one delay ago. The valve acts on the line at once (no
    spool delay: the line delays). Returns (flow into chamber 1, into chamber 2, the
    valve's exhaust flow to the atmosphere, and the pressure and the flow into the line at
    valve end 1 and at valve end 2).
    """
    (port_1, q_1, exhaust_1), (port_2, q_2, exhaust_2) = line_valve_ends(c, spool_m, arriving)
    flow_1, flow_2 = line_chamber_flows(c, (arriving[2], arriving[3]), p1_pa, p2_pa)
    return flow_1, flow_2, exhaust_1 + exhaust_2, port_1, q_1, port_2, q_2


@njit(cache=True, forceinline=True)
def line_chamber_flows(c, chamber_waves, p1_pa, p2_pa):
    """The flows from the lines into chambers 1 and 2 (``line_flows``' first two), which
    need only the waves arriving at the chamber ends, ``chamber_waves``: the chamber
    pressures' right-hand side takes these, the valve end is solved once per substep
    boundary."""
    flow_1 = line_chamber_flow(
        chamber_waves[0],
        p1_pa,
        c.line_impedance,
        c.line_laminar_friction,
        c.line_turbulent_friction,
        c.line_transition_flow,
    )
    flow_2 = line_chamber_flow(
        chamber_waves[1],
        p2_pa,
        c.line_impedance,
        c.line_laminar_friction,
        c.line_turbulent_friction,
        c.line_transition_flow,
    )
    return flow_1, flow_2


@njit(cache=True, forceinline=True)
def sent_wave(c, pressure_pa, mass_flow_into_line):
    """The wave a line end sends (``tube.line_end_wave``) with the line's friction there."""
    return line_end_wave(
        pressure_pa,
        mass_flow_into_line,
        c.line_impedance,
        line_resistance_scaled(
            mass_flow_into_line,
            pressure_pa,
            c.line_friction,
            c.reynolds_per_flow,
            c.viscous_scale,
            c.reynolds_turbulent,
        ),
    )
