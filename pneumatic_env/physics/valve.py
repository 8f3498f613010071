"""Proportional spool valve: spool dynamics (Eq. 38) and orifice areas (Eqs. 41-45)."""

import math

from numba import njit

from .vecmath import acos_


@njit(cache=True, forceinline=True, error_model="numpy")
def spool_acceleration(
    spool_position_m,
    spool_velocity_m_per_s,
    coil_current_a,
    inverse_spool_mass_per_kg,
    spool_damping_n_s_per_m,
    spool_spring_n_per_m,
    coil_force_n_per_a,
):
    """Eq. 38: M_s x_s'' + c_s x_s' + 2 k_s x_s = K_fc i_c, given 1/M_s (a multiplication
    where a division would take a divider's latency per evaluation)."""
    return (
        coil_force_n_per_a * coil_current_a
        - spool_damping_n_s_per_m * spool_velocity_m_per_s
        - 2.0 * spool_spring_n_per_m * spool_position_m
    ) * inverse_spool_mass_per_kg


@njit(cache=True)
def steady_spool_position(coil_current_a, spool_spring_n_per_m, coil_force_n_per_a):
    """Eq. 46: the spool displacement a constant coil current holds."""
    return coil_force_n_per_a * coil_current_a / (2.0 * spool_spring_n_per_m)


@njit(cache=True, forceinline=True, error_model="numpy")
def orifice_area(spool_position_m, hole_radius_m, spool_half_width_m, holes_per_path):
    """Open area of the supply path (Eq. 44) as ``n_h`` circle segments.

    The effective opening is x_e = x_s - (p_w - R_h) (Eq. 43 corrected), clipped to the
    hole's diameter [0, 2 R_h]; a segment of height x_e = u R_h has area
    R_h^2 (acos(1 - u) - (1 - u) sqrt(u (2 - u))), the arctangent form of Eq. 42: zero
    for a closed hole, pi R_h^2 for a fully open one. The exhaust path of Eq. 45 is
    ``orifice_area(-x_s, ...)``. Branch-free (``vecmath``), so it vectorises.
    """
    return orifice_area_inv_radius(
        spool_position_m, hole_radius_m, 1.0 / hole_radius_m, spool_half_width_m, holes_per_path
    )


@njit(cache=True, forceinline=True, error_model="numpy")
def orifice_area_inv_radius(
    spool_position_m, hole_radius_m, inverse_hole_radius_per_m, spool_half_width_m, holes_per_path
):
    """``orifice_area`` given 1/R_h as well, which the kernel caches per environment."""
    u = min(
        max(
            (spool_position_m - (spool_half_width_m - hole_radius_m)) * inverse_hole_radius_per_m,
            0.0,
        ),
        2.0,
    )
    depth = 1.0 - u
    segment = acos_(depth) - depth * math.sqrt(u * (2.0 - u))
    return holes_per_path * hole_radius_m * hole_radius_m * segment
