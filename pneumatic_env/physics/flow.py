"""Compressible flow through an orifice (paper Eqs. 39, 40, 52)."""

import math

from numba import njit

from .vecmath import exp_, log_

FLOW_LAW_PAPER = 0  # Eq. 52
FLOW_LAW_ISO = 1  # ISO 6358-1 elliptic law with critical ratio b (docs/effects.md)


@njit(cache=True)
def flow_constants(heat_capacity_ratio, gas_constant):
    """C1, C2 and the critical pressure ratio P_cr of Eq. 40 (exponents as corrected)."""
    k = heat_capacity_ratio
    c1 = math.sqrt(k / gas_constant * (2.0 / (k + 1.0)) ** ((k + 1.0) / (k - 1.0)))
    c2 = math.sqrt(2.0 * k / (gas_constant * (k - 1.0)))
    critical_ratio = (2.0 / (k + 1.0)) ** (k / (k - 1.0))
    return c1, c2, critical_ratio


@njit(cache=True, forceinline=True, error_model="numpy")
def subsonic_reduced_flow(pressure_ratio, heat_capacity_ratio, c2):
    """The unchoked branch of Eq. 52: C2 r^(1/k) sqrt(1 - r^((k-1)/k))."""
    return subsonic_reduced_flow_inv_k(pressure_ratio, 1.0 / heat_capacity_ratio, c2)


@njit(cache=True, forceinline=True, error_model="numpy")
def subsonic_reduced_flow_inv_k(pressure_ratio, inverse_heat_capacity_ratio, c2):
    """``subsonic_reduced_flow`` given 1/k, which the kernel caches per environment: a
    multiplication where a division by k would take a divider's latency per evaluation."""
    r_pow = exp_(log_(pressure_ratio) * inverse_heat_capacity_ratio)  # r^(1/k)
    return c2 * r_pow * math.sqrt(max(1.0 - pressure_ratio / r_pow, 0.0))


@njit(cache=True, forceinline=True, error_model="numpy")
def iso_subsonic_reduced_flow(pressure_ratio, c1, critical_ratio_b):
    """ISO 6358-1 subsonic branch (replaces Eq. 52's): C1 sqrt(1 - ((r - b)/(1 - b))^2).

    It meets the choked value C1 at r = b and falls to 0 at r = 1 (an ellipse).
    """
    z = (pressure_ratio - critical_ratio_b) / (1.0 - critical_ratio_b)
    return c1 * math.sqrt(max(1.0 - z * z, 0.0))


@njit(cache=True, forceinline=True, error_model="numpy")
def reduced_flow(
    pressure_ratio,
    heat_capacity_ratio,
    c1,
    c2,
    critical_ratio,
    linear_ratio,
    linear_slope,
    flow_law=FLOW_LAW_PAPER,
):
    """Reduced flow m_r(P_d/P_u) of Eq. 52, linearised above ``linear_ratio``.

    Eq. 52 has an infinite slope at r -> 1, which a fixed-step integrator cannot follow;
    above ``linear_ratio`` the function is replaced by the straight line
    ``linear_slope * (1 - r)`` that meets it at ``linear_ratio`` (continuous, finite slope,
    zero at r = 1). ``linear_slope = m_r(linear_ratio) / (1 - linear_ratio)``. Every
    branch is computed and one selected (branch-free), so a loop over environments
    vectorises; with early returns LLVM keeps the loop scalar.
    With ``flow_law = FLOW_LAW_ISO`` the subsonic branch is ISO 6358's ellipse and
    ``critical_ratio`` is its b (docs/effects.md); the linearisation is the same.
    """
    return reduced_flow_inv_k(
        pressure_ratio,
        1.0 / heat_capacity_ratio,
        c1,
        c2,
        critical_ratio,
        linear_ratio,
        linear_slope,
        flow_law,
    )


@njit(cache=True, forceinline=True, error_model="numpy")
def reduced_flow_inv_k(
    pressure_ratio,
    inverse_heat_capacity_ratio,
    c1,
    c2,
    critical_ratio,
    linear_ratio,
    linear_slope,
    flow_law=FLOW_LAW_PAPER,
):
    """``reduced_flow`` given 1/k (``subsonic_reduced_flow_inv_k``)."""
    iso = iso_subsonic_reduced_flow(pressure_ratio, c1, critical_ratio)
    paper = subsonic_reduced_flow_inv_k(pressure_ratio, inverse_heat_capacity_ratio, c2)
    subsonic = iso if flow_law == FLOW_LAW_ISO else paper
    unchoked = subsonic if pressure_ratio < linear_ratio else linear_slope * (1.0 - pressure_ratio)
    return c1 if pressure_ratio <= critical_ratio else unchoked


@njit(cache=True, forceinline=True, error_model="numpy")
def orifice_mass_flow(
    area_m2,
    discharge_coefficient,
    p_from_pa,
    p_to_pa,
    inv_sqrt_temperature,
    heat_capacity_ratio,
    c1,
    c2,
    critical_ratio,
    linear_ratio,
    linear_slope,
    flow_law=FLOW_LAW_PAPER,
):
    """Signed mass flow (kg/s) from node ``from`` to node ``to`` through an orifice (Eq. 39).

    The flow always runs from the higher to the lower pressure; a negative value means
    the air flows from ``to`` to ``from``. ``flow_law`` selects the reduced flow
    (:func:`reduced_flow`). Equal pressures give m_r(1) = 0 and a closed orifice a zero
    area, so neither needs a branch.
    """
    return orifice_mass_flow_inv_k(
        area_m2,
        discharge_coefficient,
        p_from_pa,
        p_to_pa,
        inv_sqrt_temperature,
        1.0 / heat_capacity_ratio,
        c1,
        c2,
        critical_ratio,
        linear_ratio,
        linear_slope,
        flow_law,
    )


@njit(cache=True, forceinline=True, error_model="numpy")
def orifice_mass_flow_inv_k(
    area_m2,
    discharge_coefficient,
    p_from_pa,
    p_to_pa,
    inv_sqrt_temperature,
    inverse_heat_capacity_ratio,
    c1,
    c2,
    critical_ratio,
    linear_ratio,
    linear_slope,
    flow_law=FLOW_LAW_PAPER,
):
    """``orifice_mass_flow`` given 1/k (``subsonic_reduced_flow_inv_k``)."""
    upstream = max(p_from_pa, p_to_pa)
    downstream = min(p_from_pa, p_to_pa)
    sign = 1.0 if p_from_pa > p_to_pa else -1.0
    m_r = reduced_flow_inv_k(
        downstream / upstream,
        inverse_heat_capacity_ratio,
        c1,
        c2,
        critical_ratio,
        linear_ratio,
        linear_slope,
        flow_law,
    )
    return sign * discharge_coefficient * area_m2 * upstream * inv_sqrt_temperature * m_r
