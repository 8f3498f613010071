"""Connecting tube: delay and attenuation of the valve flow (Eqs. 30, 31, 33, 35)."""
import math

from numba import njit

from .vecmath import exp_

LAMINAR_RESISTANCE_FACTOR = 32.0  # Eq. 33: R_t = 32 mu / D^2
TURBULENT_RESISTANCE_FACTOR = 0.158  # Eq. 35: R_t = 0.158 mu Re^(3/4) / D^2 (Blasius)


@njit(cache=True, forceinline=True, error_model="numpy")
def reynolds_number(mass_flow_kg_per_s, tube_inner_diameter_m, air_viscosity_pa_s):
    """Re = 4 |mdot| / (pi D mu) of the flow through a tube."""
    return 4.0 * abs(mass_flow_kg_per_s) / (math.pi * tube_inner_diameter_m * air_viscosity_pa_s)


@njit(cache=True, forceinline=True, error_model="numpy")
def tube_resistance(reynolds, tube_inner_diameter_m, air_viscosity_pa_s, reynolds_turbulent):
    """Tube resistance R_t (Pa s / m^2): laminar Eq. 33 below ``reynolds_turbulent``, else Eq. 35."""
    base = air_viscosity_pa_s / (tube_inner_diameter_m * tube_inner_diameter_m)
    turbulent = TURBULENT_RESISTANCE_FACTOR * base * math.sqrt(reynolds * math.sqrt(reynolds))
    return LAMINAR_RESISTANCE_FACTOR * base if reynolds < reynolds_turbulent else turbulent


@njit(cache=True, forceinline=True, error_model="numpy")
def tube_attenuation(mass_flow_kg_per_s, end_pressure_pa, gas_rt, delay_s, tube_inner_diameter_m,
                     air_viscosity_pa_s, reynolds_turbulent):
    """phi = exp(-R_t R T tau / (2 P)) of Eq. 30, with R_t chosen by the flow's Reynolds number.

    Branch-free (a zero delay gives phi = 1), so a loop over environments vectorises.
    """
    reynolds = reynolds_number(mass_flow_kg_per_s, tube_inner_diameter_m, air_viscosity_pa_s)
    resistance = tube_resistance(reynolds, tube_inner_diameter_m, air_viscosity_pa_s,
                                 reynolds_turbulent)
    return exp_(-resistance * gas_rt * delay_s / (2.0 * end_pressure_pa))


@njit(cache=True)
def sound_speed(heat_capacity_ratio, gas_constant, temperature_k):
    """c = sqrt(k R T); the tube delay is tau = L_t / c (Eq. 31)."""
    return math.sqrt(heat_capacity_ratio * gas_constant * temperature_k)
