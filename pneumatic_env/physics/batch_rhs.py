"""The batch path's right-hand side: ``right_hand_side.derivatives`` for the environments the
batch path advances (``constants.batch_lane_kind``), branch-free so that a loop over
environments compiles to SIMD code, and its RK4 substep (``rk4_base_substep``).

``base_derivatives`` is the paper's model (``constants.base_model_only``);
``batch_derivatives`` adds, behind flags that are constants where it is inlined (so a loop
without the effects compiles as before), the leaks (``leaks``: the orifices and the
laminar leak), the valve's four paths with its null leak (``four_paths``) and the
effects each lane selects for itself (``selected``: the energy equation with wall heat
transfer, the tubes' isothermal air, the ISO 6358 flow law). Both give ``derivatives``'
numbers bit for bit: the same operations in the same order, a closed leak or valve path
adding 0.0 as it does there.
"""

import math

from numba import njit

from .chamber import pressure_rate
from .effects import chamber_energy_rates, laminar_leak_flow, rate_with_isothermal_tube_air
from .flow import FLOW_LAW_PAPER
from .nodes import chamber_end_flow, line_chamber_flows, path_mass_flow
from .right_hand_side import _axpy, _motion_and_spool, _rk4_combine, _volumes
from .valve import orifice_area_inv_radius


@njit(cache=True, forceinline=True, error_model="numpy")
def base_derivatives(c, coil_current_a, x_s, v_s, p1, p2, x, v, direction, spool_delayed):
    """``derivatives`` for an environment where ``base_model_only`` holds, branch-free.

    With x_s(t - tau) > 0 chamber 1 is open to the supply and chamber 2 to the exhaust
    through the same area A_in(x_s) (Eqs. 44, 45); with x_s <= 0 the other way round
    through A_in(-x_s). Each chamber exchanges air through one orifice and one tube, so a
    loop over environments evaluates 1 area and 2 flows where the general form takes 2 and
    6, and compiles to SIMD code.
    """
    t = c.temperature
    y = (x_s, v_s, p1, p2, x, v, 0.0, t, t)
    return batch_derivatives(
        c,
        coil_current_a,
        y,
        direction,
        spool_delayed,
        False,
        False,
        False,
        c.supply_pa,
        c.ambient_pa,
    )


@njit(cache=True, forceinline=True, error_model="numpy")
def _chamber_rates(c, p, t, volume, volume_rate, flow_in, flow_out, enthalpy_in, selected):
    """(dP/dt, dT/dt) of a chamber: Eq. 14, or with ``selected`` as the lane has it
    (``right_hand_side._chamber_rates``): the energy equation (``chamber_energy_rates``),
    or Eq. 14 with the tube's isothermal air (``rate_with_isothermal_tube_air``)."""
    dp = pressure_rate(
        p,
        volume,
        volume_rate,
        flow_in,
        flow_out,
        c.gas_rt,
        c.alpha_in,
        c.alpha_out,
        c.alpha_motion,
    )
    if not selected:
        return dp, 0.0
    with_air = rate_with_isothermal_tube_air(dp, volume, c.tube_air, c.alpha_in, c.alpha_out)
    dp = with_air if c.tube_air > 0.0 else dp
    dp_energy, dt_energy = chamber_energy_rates(
        p,
        t,
        volume,
        volume_rate,
        flow_in,
        flow_out,
        enthalpy_in,
        c.gas,
        c.k,
        c.heat_conductance,
        c.temperature,
    )
    on = c.energy != 0.0
    return (dp_energy if on else dp), (dt_energy if on else 0.0)


@njit(cache=True, forceinline=True, error_model="numpy")
def _valve_flows(
    c, spool_delayed, p1, p2, inv_sqrt_t1, inv_sqrt_t2, law, four_paths, supply_pa, exhaust_pa
):
    """The valve's flows at the chamber ends of the tubes: (into 1, out of 1, into 2, out of
    2, to the exhaust), kg/s. One path per chamber (``base_derivatives``), or with
    ``four_paths`` the supply and exhaust paths of both chambers, each area plus the null
    leak, as ``nodes.valve_chamber_flows`` gives them (supply at ``supply_pa``: P_s, or
    drooped behind a supply resistance; exhaust at ``exhaust_pa``: P_a, or the node behind
    a vent)."""
    t_node = c.inv_sqrt_t  # the supply's and the atmosphere's air
    if four_paths:
        radius, inv_radius = c.hole_radius, c.inv_hole_radius
        area_a = orifice_area_inv_radius(spool_delayed, radius, inv_radius, c.half_width, c.holes)
        area_b = orifice_area_inv_radius(-spool_delayed, radius, inv_radius, c.half_width, c.holes)
        area_a = area_a + c.null_leak
        area_b = area_b + c.null_leak
        supply, d_supply, d_exhaust = supply_pa, c.discharge, c.discharge_ex
        supply_1 = path_mass_flow(c, d_supply, area_a, supply, p1, t_node, inv_sqrt_t1, law)
        exhaust_1 = path_mass_flow(c, d_exhaust, area_b, p1, exhaust_pa, inv_sqrt_t1, t_node, law)
        supply_2 = path_mass_flow(c, d_supply, area_b, supply, p2, t_node, inv_sqrt_t2, law)
        exhaust_2 = path_mass_flow(c, d_exhaust, area_a, p2, exhaust_pa, inv_sqrt_t2, t_node, law)
        supply_1 = chamber_end_flow(c, supply_1, p1)
        exhaust_1 = chamber_end_flow(c, exhaust_1, p1)
        supply_2 = chamber_end_flow(c, supply_2, p2)
        exhaust_2 = chamber_end_flow(c, exhaust_2, p2)
        return (
            max(supply_1, 0.0) + max(-exhaust_1, 0.0),
            max(-supply_1, 0.0) + max(exhaust_1, 0.0),
            max(supply_2, 0.0) + max(-exhaust_2, 0.0),
            max(-supply_2, 0.0) + max(exhaust_2, 0.0),
            max(exhaust_1, 0.0) + max(exhaust_2, 0.0),
        )
    to_chamber_1 = spool_delayed > 0.0
    area = orifice_area_inv_radius(
        abs(spool_delayed), c.hole_radius, c.inv_hole_radius, c.half_width, c.holes
    )
    node_1 = c.supply_pa if to_chamber_1 else c.ambient_pa
    node_2 = c.ambient_pa if to_chamber_1 else c.supply_pa
    discharge_1 = c.discharge if to_chamber_1 else c.discharge_ex
    discharge_2 = c.discharge_ex if to_chamber_1 else c.discharge
    flow_1 = chamber_end_flow(
        c,
        path_mass_flow(c, discharge_1, area, node_1, p1, t_node, inv_sqrt_t1, law),
        p1,
    )
    flow_2 = chamber_end_flow(
        c,
        path_mass_flow(c, discharge_2, area, node_2, p2, t_node, inv_sqrt_t2, law),
        p2,
    )
    exhaust_rate = max(-flow_2, 0.0) if to_chamber_1 else max(-flow_1, 0.0)
    return max(flow_1, 0.0), max(-flow_1, 0.0), max(flow_2, 0.0), max(-flow_2, 0.0), exhaust_rate


@njit(cache=True, forceinline=True, error_model="numpy")
def batch_derivatives(
    c,
    coil_current_a,
    y,
    direction,
    spool_delayed,
    leaks,
    selected,
    four_paths,
    supply_pa,
    exhaust_pa,
    arriving=None,
):
    """``base_derivatives`` of the RK4 state ``y``, plus with ``leaks`` the leaks (orifices,
    laminar; cross-piston, rod seal: their flows added to the chambers' in- and outflows in
    ``derivatives``' order), with ``selected`` the effects each lane has on or off (the
    energy equation: gas temperatures T1, T2, the valve's flows at the upstream air's
    temperature; the tubes' isothermal air; the ISO 6358 flow law) and with
    ``four_paths`` the valve's four paths with its null leak (``_valve_flows``; their
    supply at ``supply_pa``, their exhaust at ``exhaust_pa``). Given the waves
    ``arriving`` at the lines' chamber ends (``right_hand_side.chamber_end_waves``), the
    tubes are transmission lines (``tube_waves``): each chamber's flow comes from its line
    (``nodes.line_chamber_flows``), the valve acting at the lines' other ends."""
    x_s, v_s, p1, p2, x, v, t1, t2 = y[0], y[1], y[2], y[3], y[4], y[5], y[7], y[8]
    inv_sqrt_t1 = inv_sqrt_t2 = c.inv_sqrt_t
    law = c.flow_law if selected else FLOW_LAW_PAPER
    if selected:  # right_hand_side.inv_sqrt_temperatures, lane by lane
        inv_sqrt_t1 = 1.0 / math.sqrt(t1) if c.energy != 0.0 else c.inv_sqrt_t
        inv_sqrt_t2 = 1.0 / math.sqrt(t2) if c.energy != 0.0 else c.inv_sqrt_t
    if arriving is None:
        in_1, out_1, in_2, out_2, exhaust_rate = _valve_flows(
            c,
            spool_delayed,
            p1,
            p2,
            inv_sqrt_t1,
            inv_sqrt_t2,
            law,
            four_paths,
            supply_pa,
            exhaust_pa,
        )
    else:  # the lines' signed flows; their valve exhaust is counted at the boundaries
        flow_1, flow_2 = line_chamber_flows(c, arriving, p1, p2)
        in_1, out_1 = max(flow_1, 0.0), max(-flow_1, 0.0)
        in_2, out_2 = max(flow_2, 0.0), max(-flow_2, 0.0)
        exhaust_rate = 0.0
    t_node = c.inv_sqrt_t
    enthalpy_1 = in_1 * c.temperature
    enthalpy_2 = in_2 * c.temperature
    if leaks:
        leak_12 = path_mass_flow(
            c, c.discharge, c.leak_area, p1, p2, inv_sqrt_t1, inv_sqrt_t2, law
        ) + laminar_leak_flow(c.leak_conductance, p1, p2)
        seal_2 = path_mass_flow(
            c, c.discharge, c.seal_leak, p2, c.ambient_pa, inv_sqrt_t2, t_node, law
        )
        if selected:  # leakage air enters at the temperature of the chamber it left
            enthalpy_1 = in_1 * c.temperature + max(-leak_12, 0.0) * t2
            enthalpy_2 = (in_2 + max(-seal_2, 0.0)) * c.temperature + max(leak_12, 0.0) * t1
        in_1 = in_1 + max(-leak_12, 0.0)
        out_1 = out_1 + max(leak_12, 0.0)
        in_2 = in_2 + max(leak_12, 0.0) + max(-seal_2, 0.0)
        out_2 = out_2 + max(-leak_12, 0.0) + max(seal_2, 0.0)
        exhaust_rate = exhaust_rate + max(seal_2, 0.0)
    velocity = v if direction != 0.0 else 0.0
    v1, v2 = _volumes(c, x)
    dp1, dt1 = _chamber_rates(
        c, p1, t1, v1, c.area_cap * velocity, in_1, out_1, enthalpy_1, selected
    )
    dp2, dt2 = _chamber_rates(
        c, p2, t2, v2, -c.area_rod * velocity, in_2, out_2, enthalpy_2, selected
    )
    accel, a_s = _motion_and_spool(
        c, coil_current_a, x_s, v_s, p1, p2, x, velocity, direction, c.dynamic_friction
    )
    return v_s, a_s, dp1, dp2, velocity, accel, exhaust_rate, dt1, dt2


@njit(cache=True, forceinline=True, error_model="numpy")
def rk4_base_substep(c, y, drive_a, direction, spool_delayed, h, leaks, selected, four_paths):
    """One whole RK4 substep of ``batch_derivatives`` (``leaks``, ``selected``,
    ``four_paths``: with those effects). ``drive_a`` and ``spool_delayed`` are the currents
    driving the spool (``coil_at``) and the delayed spool positions (``delayed_value``) at
    its start, middle and end."""
    flags = (leaks, selected, four_paths, c.supply_pa, c.ambient_pa)
    k1 = batch_derivatives(c, drive_a[0], y, direction, spool_delayed[0], *flags)
    k2 = batch_derivatives(
        c, drive_a[1], _axpy(y, 0.5 * h, k1), direction, spool_delayed[1], *flags
    )
    k3 = batch_derivatives(
        c, drive_a[1], _axpy(y, 0.5 * h, k2), direction, spool_delayed[1], *flags
    )
    k4 = batch_derivatives(c, drive_a[2], _axpy(y, h, k3), direction, spool_delayed[2], *flags)
    return _rk4_combine(c, y, k1, k2, k3, k4, h, direction)


@njit(cache=True, forceinline=True, error_model="numpy")
def rk4_line_substep(c, y, drive_a, direction, arriving, h, leaks, selected):
    """``rk4_base_substep`` with the tubes as transmission lines: ``arriving`` holds the
    waves at the lines' chamber ends (``right_hand_side.chamber_end_waves``) at the
    substep's start, middle and end."""
    flags = (leaks, selected, False, c.supply_pa, c.ambient_pa)
    k1 = batch_derivatives(c, drive_a[0], y, direction, 0.0, *flags, arriving[0])
    k2 = batch_derivatives(
        c, drive_a[1], _axpy(y, 0.5 * h, k1), direction, 0.0, *flags, arriving[1]
    )
    k3 = batch_derivatives(
        c, drive_a[1], _axpy(y, 0.5 * h, k2), direction, 0.0, *flags, arriving[1]
    )
    k4 = batch_derivatives(c, drive_a[2], _axpy(y, h, k3), direction, 0.0, *flags, arriving[2])
    return _rk4_combine(c, y, k1, k2, k3, k4, h, direction)
