"""Cylinder chambers: volumes (Eq. 15) and pressure dynamics (Eq. 14/16, corrected Eq. 55)."""

from numba import njit


@njit(cache=True, forceinline=True, error_model="numpy")
def chamber_volumes(
    piston_position_m,
    half_stroke_m,
    area_cap_m2,
    area_rod_m2,
    dead_volume_cap_m3,
    dead_volume_rod_m3,
):
    """Eq. 15: V1 = V01 + A1 (L/2 + x), V2 = V02 + A2 (L/2 - x)."""
    v1 = dead_volume_cap_m3 + area_cap_m2 * (half_stroke_m + piston_position_m)
    v2 = dead_volume_rod_m3 + area_rod_m2 * (half_stroke_m - piston_position_m)
    return v1, v2


@njit(cache=True, forceinline=True, error_model="numpy")
def pressure_rate(
    pressure_pa,
    volume_m3,
    volume_rate_m3_per_s,
    mass_in_kg_per_s,
    mass_out_kg_per_s,
    gas_rt,
    alpha_in,
    alpha_out,
    alpha_motion,
):
    """Eq. 14: dP/dt = RT/V (alpha_in mdot_in - alpha_out mdot_out) - alpha P Vdot / V.

    1/V (known from the state at once) times the bracket, rather than the bracket over V:
    the divider's latency then overlaps the flows' computation instead of following it.
    """
    inverse_volume = 1.0 / volume_m3
    return (
        gas_rt * (alpha_in * mass_in_kg_per_s - alpha_out * mass_out_kg_per_s)
        - alpha_motion * pressure_pa * volume_rate_m3_per_s
    ) * inverse_volume
