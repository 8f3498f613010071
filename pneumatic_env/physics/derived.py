"""Derived physical quantities, one home each: the piston areas (Eq. 1), the force scale,
the valve's dead-band and full-opening currents (Eqs. 43, 44, 46), the orifice gas
constants (Eqs. 39, 40, 52) and the tube delay (Eq. 31).

Each is a small jitted function that the kernel (``constants.env_constants``) and Python
callers (the tasks, the controllers, the studies) share, so every caller gets the same
bits. Keep each formula's arithmetic as it is: the order of a float formula decides its
last bits (``0.25 * pi * d * d`` and ``0.25 * pi * d ** 2`` differ for about a third of the
diameters), and the tests compare outputs bit for bit.
"""

import math
from typing import NamedTuple

from numba import njit

from .flow import (
    FLOW_LAW_ISO,
    FLOW_LAW_PAPER,
    flow_constants,
    iso_subsonic_reduced_flow,
    subsonic_reduced_flow,
)
from .tube import sound_speed
from .valve import steady_spool_position

__all__ = [
    "circle_area_m2",
    "piston_areas_m2",
    "force_scale_n",
    "valve_currents_a",
    "linear_flow_slope",
    "OrificeGas",
    "orifice_gas_constants",
    "tube_delay_s",
]


@njit(cache=True)
def circle_area_m2(diameter_m):
    """Cross-section pi d^2 / 4 (m^2) of a circle of ``diameter_m`` (bore, rod, tube)."""
    return 0.25 * math.pi * diameter_m * diameter_m


@njit(cache=True)
def piston_areas_m2(bore_diameter_m, rod_diameter_m):
    """(A1, A2, A_r) of Eq. 1 in m^2: the cap-side effective area, the rod-side effective
    area A1 - A_r and the rod's cross-section A_r."""
    cap_area = circle_area_m2(bore_diameter_m)
    rod_area = circle_area_m2(rod_diameter_m)
    return cap_area, cap_area - rod_area, rod_area


@njit(cache=True)
def force_scale_n(supply_pressure_pa, ambient_pressure_pa, bore_diameter_m, rod_diameter_m):
    """The force (N) the cylinder holds in both directions, (P_s - P_a) min(A1, A2) (Eq. 1
    with one chamber at supply and the other at ambient): the smaller of the push and the
    pull."""
    cap_area, rod_side_area, _ = piston_areas_m2(bore_diameter_m, rod_diameter_m)
    span_pa = supply_pressure_pa - ambient_pressure_pa
    return min(span_pa * cap_area, span_pa * rod_side_area)


@njit(cache=True)
def valve_currents_a(spool_half_width_m, hole_radius_m, spool_spring_n_per_m, coil_force_n_per_a):
    """(dead-band current, full-opening current) in A (Eqs. 43, 44, 46).

    The supply path opens when x_s > p_w - R_h and is fully open at x_s = p_w + R_h; Eq. 46
    (x_s = K_fc i / (2 k_s)) turns both spool positions into currents. A spool no wider
    than the hole (no overlap) has no dead band.
    """
    spool_m_per_a = steady_spool_position(1.0, spool_spring_n_per_m, coil_force_n_per_a)
    overlap_m = spool_half_width_m - hole_radius_m
    full_m = spool_half_width_m + hole_radius_m
    return max(overlap_m, 0.0) / spool_m_per_a, full_m / spool_m_per_a


@njit(cache=True)
def linear_flow_slope(
    linear_ratio, heat_capacity_ratio, c1, c2, critical_ratio, flow_law=FLOW_LAW_PAPER
):
    """Slope m_r(r_lin) / (1 - r_lin) of the reduced flow's linearisation above
    ``linear_ratio`` (``flow.reduced_flow``): Eq. 52's subsonic branch, or ISO 6358's with
    its critical ratio b as ``critical_ratio`` (``flow_law = FLOW_LAW_ISO``)."""
    if flow_law == FLOW_LAW_ISO:
        return iso_subsonic_reduced_flow(linear_ratio, c1, critical_ratio) / (1.0 - linear_ratio)
    return subsonic_reduced_flow(linear_ratio, heat_capacity_ratio, c2) / (1.0 - linear_ratio)


class OrificeGas(NamedTuple):
    """The gas's arguments of ``flow.orifice_mass_flow`` after the pressures, in its order
    (``orifice_mass_flow(area, discharge, p_from, p_to, *gas)``), for the paper's flow law
    (Eqs. 39, 40, 52)."""

    inv_sqrt_t: float  # 1 / sqrt(T) of the gas, 1/sqrt(K)
    k: float  # heat capacity ratio
    c1: float  # C1 of Eq. 40 (flow_constants)
    c2: float  # C2 of Eq. 40
    critical_ratio: float  # P_cr of Eq. 40
    linear_ratio: float  # the flow law's linear ratio (flow_linear_ratio, Eq. 52)
    linear_slope: float  # its slope (linear_flow_slope)


@njit(cache=True)
def orifice_gas_constants(
    heat_capacity_ratio, gas_constant_j_per_kg_k, temperature_k, flow_linear_ratio
):
    """The ``OrificeGas`` of a gas at ``temperature_k`` (the linear ratio's slope from
    ``linear_flow_slope``)."""
    c1, c2, critical_ratio = flow_constants(heat_capacity_ratio, gas_constant_j_per_kg_k)
    slope = linear_flow_slope(flow_linear_ratio, heat_capacity_ratio, c1, c2, critical_ratio)
    return OrificeGas(
        1.0 / math.sqrt(temperature_k),
        heat_capacity_ratio,
        c1,
        c2,
        critical_ratio,
        flow_linear_ratio,
        slope,
    )


@njit(cache=True)
def tube_delay_s(tube_length_m, heat_capacity_ratio, gas_constant_j_per_kg_k, temperature_k):
    """Tube delay tau = L_t / c (s) of Eq. 31, c = sqrt(k R T) the speed of sound."""
    return tube_length_m / sound_speed(heat_capacity_ratio, gas_constant_j_per_kg_k, temperature_k)
