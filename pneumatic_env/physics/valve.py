"""Proportional spool valve: spool dynamics (Eq. 38) and orifice areas (Eqs. 41-45)."""
import math

from numba import njit


@njit(cache=True)
def spool_acceleration(spool_position_m, spool_velocity_m_per_s, coil_current_a, spool_mass_kg,
                       spool_damping_n_s_per_m, spool_spring_n_per_m, coil_force_n_per_a):
    """Eq. 38: M_s x_s'' + c_s x_s' + 2 k_s x_s = K_fc i_c."""
    return (coil_force_n_per_a * coil_current_a - spool_damping_n_s_per_m * spool_velocity_m_per_s
            - 2.0 * spool_spring_n_per_m * spool_position_m) / spool_mass_kg


@njit(cache=True)
def steady_spool_position(coil_current_a, spool_spring_n_per_m, coil_force_n_per_a):
    """Eq. 46: the spool displacement a constant coil current holds."""
    return coil_force_n_per_a * coil_current_a / (2.0 * spool_spring_n_per_m)


@njit(cache=True)
def orifice_area(spool_position_m, hole_radius_m, spool_half_width_m, holes_per_path):
    """Open area of the supply path (Eq. 44) as ``n_h`` circle segments.

    The effective opening is x_e = x_s - (p_w - R_h) (Eq. 43 corrected); a segment of
    height x_e of a hole of radius R_h has area R_h^2 acos((R_h - x_e)/R_h) -
    (R_h - x_e) sqrt(x_e (2 R_h - x_e)), the arctangent form of Eq. 42. The exhaust path
    of Eq. 45 is ``orifice_area(-x_s, ...)``.
    """
    opening = spool_position_m - (spool_half_width_m - hole_radius_m)
    if opening <= 0.0:
        return 0.0
    if opening >= 2.0 * hole_radius_m:
        return holes_per_path * math.pi * hole_radius_m * hole_radius_m
    depth = hole_radius_m - opening
    return holes_per_path * (hole_radius_m * hole_radius_m * math.acos(depth / hole_radius_m)
                             - depth * math.sqrt(opening * (2.0 * hole_radius_m - opening)))
