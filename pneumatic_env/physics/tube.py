"""Connecting tube: delay and attenuation of the valve flow (Eqs. 30, 31, 33, 35)."""

import math

from numba import njit

from .vecmath import exp_, log_

LAMINAR_RESISTANCE_FACTOR = 32.0  # Eq. 33: R_t = 32 mu / D^2
TURBULENT_RESISTANCE_FACTOR = 0.158  # Eq. 35: R_t = 0.158 mu Re^(3/4) / D^2 (Blasius)


@njit(cache=True, forceinline=True, error_model="numpy")
def reynolds_number(mass_flow_kg_per_s, tube_inner_diameter_m, air_viscosity_pa_s):
    """Re = 4 |mdot| / (pi D mu) of the flow through a tube."""
    return abs(mass_flow_kg_per_s) * reynolds_per_mass_flow(
        tube_inner_diameter_m, air_viscosity_pa_s
    )


@njit(cache=True, forceinline=True, error_model="numpy")
def reynolds_per_mass_flow(tube_inner_diameter_m, air_viscosity_pa_s):
    """Re / |mdot| = 4 / (pi D mu) (s/kg)."""
    return 4.0 / (math.pi * tube_inner_diameter_m * air_viscosity_pa_s)


@njit(cache=True, forceinline=True, error_model="numpy")
def viscous_scale(tube_inner_diameter_m, air_viscosity_pa_s):
    """mu / D^2 (Pa s / m^2), the factor common to Eqs. 33 and 35."""
    return air_viscosity_pa_s / (tube_inner_diameter_m * tube_inner_diameter_m)


@njit(cache=True, forceinline=True, error_model="numpy")
def tube_resistance(reynolds, tube_inner_diameter_m, air_viscosity_pa_s, reynolds_turbulent):
    """Tube resistance R_t (Pa s / m^2): laminar Eq. 33 below ``reynolds_turbulent``, else
    Eq. 35."""
    return scaled_tube_resistance(
        reynolds, viscous_scale(tube_inner_diameter_m, air_viscosity_pa_s), reynolds_turbulent
    )


@njit(cache=True, forceinline=True, error_model="numpy")
def scaled_tube_resistance(reynolds, viscous_scale_pa_s_per_m2, reynolds_turbulent):
    """``tube_resistance`` given mu / D^2 (``viscous_scale``)."""
    base = viscous_scale_pa_s_per_m2
    turbulent = TURBULENT_RESISTANCE_FACTOR * base * math.sqrt(reynolds * math.sqrt(reynolds))
    return LAMINAR_RESISTANCE_FACTOR * base if reynolds < reynolds_turbulent else turbulent


@njit(cache=True, forceinline=True, error_model="numpy")
def tube_attenuation(
    mass_flow_kg_per_s,
    end_pressure_pa,
    gas_rt,
    delay_s,
    tube_inner_diameter_m,
    air_viscosity_pa_s,
    reynolds_turbulent,
):
    """phi = exp(-R_t R T tau / (2 P)) of Eq. 30, with R_t chosen by the flow's Reynolds number.

    Branch-free (a zero delay gives phi = 1), so a loop over environments vectorises.
    """
    return tube_attenuation_scaled(
        mass_flow_kg_per_s,
        end_pressure_pa,
        0.5 * gas_rt * delay_s,
        reynolds_per_mass_flow(tube_inner_diameter_m, air_viscosity_pa_s),
        viscous_scale(tube_inner_diameter_m, air_viscosity_pa_s),
        reynolds_turbulent,
    )


@njit(cache=True, forceinline=True, error_model="numpy")
def tube_attenuation_scaled(
    mass_flow_kg_per_s,
    end_pressure_pa,
    half_rt_delay,
    reynolds_per_flow,
    viscous_scale_pa_s_per_m2,
    reynolds_turbulent,
):
    """``tube_attenuation`` given R T tau / 2, ``reynolds_per_mass_flow`` and
    ``viscous_scale``, which the kernel caches per environment (multiplications where
    divisions by constants would take a divider's latency per evaluation)."""
    reynolds = abs(mass_flow_kg_per_s) * reynolds_per_flow
    resistance = scaled_tube_resistance(reynolds, viscous_scale_pa_s_per_m2, reynolds_turbulent)
    # R T tau / (2 P) first: it needs only the end pressure, so the divider works while the
    # flow is computed
    return exp_(-resistance * (half_rt_delay / end_pressure_pa))


@njit(cache=True)
def sound_speed(heat_capacity_ratio, gas_constant, temperature_k):
    """c = sqrt(k R T); the tube delay is tau = L_t / c (Eq. 31)."""
    return math.sqrt(heat_capacity_ratio * gas_constant * temperature_k)


# --------------------------------------------------------------------------- transmission line
# The tube as a transmission line (effect ``tube_waves``, docs/effects.md), by the method of
# characteristics: a wave leaving one end arrives at the other one delay tau = L_t / c later
# (Eq. 31), the line's characteristic impedance for mass flow is Z_c = c / A_t, and the
# tube friction of Eqs. 33/35 over the whole length is lumped half at each end. At an end
# with pressure P and mass flow q into the line, P = W_in + (Z_c + R/2) q, W_in the wave
# arriving there; the wave it sends is W_out = P - (R/2) q + Z_c q. Steady flow gives
# the friction's pressure drop R q; a closed end (q = 0) reflects the wave fully.

LINE_FLOW_RTOL = 1e-12  # solver accuracy of the chamber-end flow (not physics)
LINE_FLOW_W_RTOL = 0.25 * LINE_FLOW_RTOL  # of its fourth root, which the solver iterates
LINE_MAX_ITERATIONS = 60  # a safeguard; Newton from above takes a handful


@njit(cache=True)
def line_resistance(
    mass_flow_kg_per_s,
    pressure_pa,
    line_friction,
    tube_inner_diameter_m,
    air_viscosity_pa_s,
    reynolds_turbulent,
):
    """Friction of the whole line, R = R_t L_t / (rho A_t) with rho = P / (R T) (Pa s/kg).

    ``line_friction = L_t R T / A_t``; R_t laminar (Eq. 33) or turbulent (Eq. 35) by the
    flow's Reynolds number, as in the attenuation of Eq. 30.
    """
    return line_resistance_scaled(
        mass_flow_kg_per_s,
        pressure_pa,
        line_friction,
        reynolds_per_mass_flow(tube_inner_diameter_m, air_viscosity_pa_s),
        viscous_scale(tube_inner_diameter_m, air_viscosity_pa_s),
        reynolds_turbulent,
    )


@njit(cache=True, forceinline=True, error_model="numpy")
def line_resistance_scaled(
    mass_flow_kg_per_s,
    pressure_pa,
    line_friction,
    reynolds_per_flow,
    viscous_scale_pa_s_per_m2,
    reynolds_turbulent,
):
    """``line_resistance`` given ``reynolds_per_mass_flow`` and ``viscous_scale``, which the
    kernel caches per environment (two divisions fewer per evaluation)."""
    reynolds = abs(mass_flow_kg_per_s) * reynolds_per_flow
    resistance = scaled_tube_resistance(reynolds, viscous_scale_pa_s_per_m2, reynolds_turbulent)
    return resistance * line_friction / pressure_pa


@njit(cache=True)
def line_end_wave(pressure_pa, mass_flow_into_line_kg_per_s, impedance, resistance):
    """The wave an end sends into the line, P - (R/2) q + Z_c q (Pa)."""
    return pressure_pa + (impedance - 0.5 * resistance) * mass_flow_into_line_kg_per_s


@njit(cache=True)
def line_flow_coefficients(
    line_friction, tube_inner_diameter_m, air_viscosity_pa_s, reynolds_turbulent
):
    """The constants of ``line_chamber_flow`` for a line: R P at zero flow (laminar, Eq. 33),
    k P of the turbulent friction R = k |m|^(3/4) (Eq. 35 with Re = 4 |m| / (pi D mu)), and
    the mass flow at ``reynolds_turbulent``. The kernel caches them per environment."""
    scale = viscous_scale(tube_inner_diameter_m, air_viscosity_pa_s)
    laminar = scaled_tube_resistance(0.0, scale, reynolds_turbulent) * line_friction
    reynolds_per_flow = reynolds_per_mass_flow(tube_inner_diameter_m, air_viscosity_pa_s)
    turbulent = (
        TURBULENT_RESISTANCE_FACTOR
        * air_viscosity_pa_s
        / (tube_inner_diameter_m * tube_inner_diameter_m)
        * reynolds_per_flow**0.75
        * line_friction
    )
    transition = reynolds_turbulent * math.pi * tube_inner_diameter_m * air_viscosity_pa_s / 4.0
    return laminar, turbulent, transition


@njit(cache=True, forceinline=True, error_model="numpy")
def line_chamber_flow(
    wave_in_pa, chamber_pa, impedance, laminar_friction, turbulent_friction, transition_flow
):
    """Mass flow from the line into a chamber, m, the root of m (Z_c + R(m)/2) = W_in - P,
    given the line's ``line_flow_coefficients``.

    The left side grows with |m|: linear while laminar, m (Z_c + K |m|^(3/4)) when
    turbulent (Newton from the frictionless flow, which bounds it from above). Where the
    jump of R_t at ``reynolds_turbulent`` leaves no root, the flow stays at the transition.
    """
    drive = wave_in_pa - chamber_pa
    if drive == 0.0:
        return 0.0
    sign = 1.0 if drive > 0.0 else -1.0
    magnitude = abs(drive)
    laminar = magnitude / (impedance + 0.5 * (laminar_friction / chamber_pa))
    if laminar < transition_flow:
        return sign * laminar
    # turbulent: R(u) = k u^(3/4). With w = u^(1/4) the balance Z u + k/2 u^(7/4) = |drive|
    # is g(w) = Z w^4 + k/2 w^7 - |drive|, a polynomial convex and rising for w > 0: Newton
    # from above without a pow per iteration, started from the smaller of the flows each
    # term alone would carry (both bound the root from above). Its error after a step of
    # relative size s is under 3 s^2 (quadratic convergence, g''w / 2g' <= 3), so it stops
    # once that is within the tolerance.
    half_k = 0.5 * turbulent_friction / chamber_pa
    u = min(magnitude / impedance, exp_(log_(magnitude / half_k) * (4.0 / 7.0)))
    w = math.sqrt(math.sqrt(u))
    for _ in range(LINE_MAX_ITERATIONS):
        w3 = w * w * w
        w4 = w3 * w
        g = impedance * w4 + half_k * (w4 * w3) - magnitude
        step = g / (4.0 * impedance * w3 + 7.0 * half_k * (w3 * w3))
        w -= step
        if 3.0 * step * step <= LINE_FLOW_W_RTOL * w * w:
            break
    u = (w * w) * (w * w)
    return sign * max(u, transition_flow)
