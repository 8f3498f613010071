"""Effects beyond the paper's model (docs/effects.md); each is off at its neutral value.

The kernel decides once per control period (``constants.env_constants``) which effects are
on; the functions here are called only for those, or reduce exactly to the paper's
quantity at the neutral value. The ISO 6358 flow law is in ``flow.py``.
"""

import math

from numba import njit

from .derived import circle_area_m2


@njit(cache=True)
def dead_volume_with_tube(
    dead_volume_m3, tube_volume_fraction, tube_inner_diameter_m, tube_length_m
):
    """Eq. 15's dead volume V0i plus a fraction f of the tube's air, f pi D^2/4 L_t.

    The paper leaves the tube's own air out of the chamber volume (docs/model.md); f = 0
    is the paper's model, f = 1 counts the whole tube as chamber volume.
    """
    tube_volume = circle_area_m2(tube_inner_diameter_m) * tube_length_m
    return dead_volume_m3 + tube_volume_fraction * tube_volume


@njit(cache=True, forceinline=True, error_model="numpy")
def rate_with_isothermal_tube_air(
    pressure_rate_pa_per_s, volume_m3, tube_air_m3, alpha_in, alpha_out
):
    """Eq. 14's pressure rate of a chamber that shares its pressure with an isothermal
    volume ``tube_air_m3`` (its tube's air at the wall temperature).

    The chamber exchanges air with the tube as with any port (Eq. 14: leaving at
    alpha_out, entering at alpha_in), and the tube's air obeys V_t dP/dt = R T mdot_t, so
    V dP/dt = B - alpha R T mdot_t with B the bracket of Eq. 14 gives
    dP/dt = B / (V + alpha V_t): alpha_out while the pressure rises (air into the tube),
    alpha_in while it falls. ``pressure_rate_pa_per_s`` is B / V.
    """
    bracket = pressure_rate_pa_per_s * volume_m3
    alpha = alpha_out if bracket > 0.0 else alpha_in
    return bracket / (volume_m3 + alpha * tube_air_m3)


@njit(cache=True, forceinline=True, error_model="numpy")
def laminar_leak_flow(conductance_kg_per_pa_s, p_from_pa, p_to_pa):
    """Mass flow of a laminar leak from ``from`` to ``to`` (effect, docs/effects.md): a
    seal clearance's viscous flow, proportional to the pressure difference, G (P_from -
    P_to), where the orifice of Eq. 39 goes with its square root and chokes."""
    return conductance_kg_per_pa_s * (p_from_pa - p_to_pa)


@njit(cache=True)
def drooped_supply_pressure(
    supply_pressure_pa, supply_flow_kg_per_s, supply_resistance_pa_s_per_kg
):
    """First estimate of the supply pressure at the valve, P_s' = P_s - R_sup mdot_s(P_s').

    ``supply_flow_kg_per_s`` is the valve's total supply flow evaluated at P_s. With the
    flow proportional to the supply pressure (exact while the supply paths are choked,
    Eq. 39) the root is P_s / (1 + R_sup mdot_s(P_s) / P_s); the kernel refines it
    (``kernel.supply_pressure_at_valve``). Returns P_s exactly when R_sup = 0.
    """
    return supply_pressure_pa / (
        1.0 + supply_resistance_pa_s_per_kg * max(supply_flow_kg_per_s, 0.0) / supply_pressure_pa
    )


@njit(cache=True)
def coil_decay(coil_time_constant_s, interval_s):
    """exp(-dt / tau_c): the part of a coil-current error left after ``interval_s`` (0: no lag)."""
    if coil_time_constant_s <= 0.0:
        return 0.0
    return math.exp(-interval_s / coil_time_constant_s)


@njit(cache=True)
def lagged_coil_current(command_a, current_at_start_a, decay):
    """Coil current of tau_c di/dt = i_cmd - i with the command held (exact solution).

    ``decay = coil_decay(tau_c, t)`` for the current ``t`` after ``current_at_start_a``.
    The spool (Eq. 38) is driven by this current instead of the command.
    """
    return command_a + (current_at_start_a - command_a) * decay


@njit(cache=True)
def coil_time_constants(coil_lag_s, coil_lag_shape):
    """(tau_c, tau_f) of the coil lag and the force lag from their total T = tau_c + tau_f
    and shape r = tau_c tau_f / T^2 (0: one lag of T; 1/4: two lags of T/2): the roots
    T (1 +- sqrt(1 - 4 r)) / 2, the larger taken as the coil's.

    The force current's response 1 / (tau_c tau_f s^2 + T s + 1) depends on (T, r T^2)
    smoothly, with no fold where the two time constants are equal, so both are identifiable
    from data (a fit in (tau_c, tau_f) has a singular Jacobian there).
    """
    root = math.sqrt(max(1.0 - 4.0 * coil_lag_shape, 0.0))
    # the smaller root as 2 r T / (1 + root): no cancellation for a small shape
    return 0.5 * coil_lag_s * (1.0 + root), 2.0 * coil_lag_shape * coil_lag_s / (1.0 + root)


@njit(cache=True)
def coil_force_gain(coil_decay_now, elapsed_over_force_tau, elapsed_rate_difference):
    """g(t) = tau_c / (tau_c - tau_f) (exp(-t/tau_c) - exp(-t/tau_f)): the share of the coil
    current's initial error (i0 - i_cmd) in the force current j at time t.

    Written as exp(-t/tau_c) (t/tau_f) expm1(z)/z with z = -t (1/tau_f - 1/tau_c), which has
    no cancellation as tau_f -> tau_c (the limit (t/tau) exp(-t/tau)). Arguments:
    ``coil_decay_now`` = exp(-t/tau_c), ``elapsed_over_force_tau`` = t/tau_f,
    ``elapsed_rate_difference`` = t (1/tau_f - 1/tau_c).
    """
    z = -elapsed_rate_difference
    ratio = 1.0 + 0.5 * z if abs(z) < 1e-8 else math.expm1(z) / z
    return coil_decay_now * elapsed_over_force_tau * ratio


@njit(cache=True)
def lagged_coil_force_current(
    command_a, coil_at_start_a, force_at_start_a, force_decay, force_gain
):
    """Force current j of tau_f dj/dt = i - j, driven by the lagged coil current i of
    ``lagged_coil_current`` with the command held (exact solution of the two cascaded lags).

    ``force_decay`` = exp(-t/tau_f), ``force_gain`` = ``coil_force_gain`` at t. The spool
    (Eq. 38) feels the coil force K_f j (eddy currents in the armature and pole pieces make
    the force lag the current).
    """
    return (
        command_a
        + (force_at_start_a - command_a) * force_decay
        + (coil_at_start_a - command_a) * force_gain
    )


@njit(cache=True, forceinline=True, error_model="numpy")  # inlined: the batch path's SIMD loop
def chamber_energy_rates(
    pressure_pa,
    temperature_k,
    volume_m3,
    volume_rate_m3_per_s,
    mass_in_kg_per_s,
    mass_out_kg_per_s,
    enthalpy_in_kg_k_per_s,
    gas_constant,
    heat_capacity_ratio,
    heat_conductance_w_per_k,
    wall_temperature_k,
):
    """dP/dt and dT/dt of a chamber from the energy equation (Eqs. 5-8), replacing Eq. 14.

    dP/dt = (k-1)/V q + k R/V (sum mdot_in T_in - mdot_out T) - k P Vdot/V with the wall
    heat flow q = hA (T_wall - T); ``enthalpy_in_kg_k_per_s`` is sum mdot_in T_in. The
    temperature follows from the ideal gas law T = P V / (m R):
    dT/dt = T (Pdot/P + Vdot/V) - R T^2 (mdot_in - mdot_out) / (P V).
    """
    k = heat_capacity_ratio
    heat_w = heat_conductance_w_per_k * (wall_temperature_k - temperature_k)
    dp = (
        (k - 1.0) * heat_w
        + k * gas_constant * (enthalpy_in_kg_k_per_s - mass_out_kg_per_s * temperature_k)
        - k * pressure_pa * volume_rate_m3_per_s
    ) / volume_m3
    dt = temperature_k * (
        dp / pressure_pa + volume_rate_m3_per_s / volume_m3
    ) - gas_constant * temperature_k * temperature_k * (mass_in_kg_per_s - mass_out_kg_per_s) / (
        pressure_pa * volume_m3
    )
    return dp, dt


@njit(cache=True)
def stribeck_friction(
    velocity_m_per_s, dynamic_friction_n, static_friction_n, stribeck_velocity_m_per_s
):
    """Sliding friction magnitude F_df + (F_sf - F_df) exp(-(v/v_s)^2) (Stribeck; Eq. 47's F_df).

    The kernel applies it with the sign of the motion; it falls from F_sf at breakaway
    to F_df at speeds well above v_s.
    """
    z = velocity_m_per_s / stribeck_velocity_m_per_s
    return dynamic_friction_n + (static_friction_n - dynamic_friction_n) * math.exp(-z * z)


LUGRE_SERIES_BELOW = 1e-4  # rate * h below which lugre_bristle_step uses its series forms


@njit(cache=True)
def lugre_bristle_step(
    bristle_m, velocity_m_per_s, h_s, stiffness_n_per_m, damping_n_s_per_m, sliding_friction_n
):
    """LuGre friction (Canudas de Wit et al. 1995) over ``h_s`` at a velocity held over it.

    The mean bristle deflection z obeys dz/dt = v - r z, r = sigma0 |v| / g with g the
    sliding friction at v (``sliding_friction_n``: F_df, or ``stribeck_friction``), so it
    relaxes towards g sgn(v) / sigma0 at the rate r, which reaches 1e5 /s when sliding: too
    stiff for an RK4 substep, so it is solved exactly for the held v. Returns the
    deflection at the end and the friction force sigma0 z + sigma1 dz/dt averaged over the
    step (positive resists extension; the viscous part beta v is the piston's own):
    z(h) = z + (v - r z) h phi(r h) and mean z = z + (v - r z) h psi(r h), with phi(x) =
    (1 - e^-x) / x and psi(x) = (x - 1 + e^-x) / x^2 (with expm1, and in series form
    for small x: no cancellation; at v = 0 the bristles hold: z stays, the force is
    sigma0 z). Sliding steadily, the force is g sgn(v): the Stribeck curve of
    ``stribeck_friction``.
    """
    g = max(sliding_friction_n, 1e-12)  # a frictionless seal: the bristles carry nothing
    rate = stiffness_n_per_m * abs(velocity_m_per_s) / g
    x = rate * h_s
    if x < LUGRE_SERIES_BELOW:
        phi = 1.0 - x * (0.5 - x / 6.0)
        psi = 0.5 - x * (1.0 / 6.0 - x / 24.0)
    else:
        decay_minus_one = math.expm1(-x)  # e^-x - 1, exact for small x
        phi = -decay_minus_one / x
        psi = (x + decay_minus_one) / (x * x)
    drift = (velocity_m_per_s - rate * bristle_m) * h_s
    new = bristle_m + drift * phi
    mean = bristle_m + drift * psi
    return new, stiffness_n_per_m * mean + damping_n_s_per_m * (new - bristle_m) / h_s


@njit(cache=True)
def spool_play_band(spool_coulomb_friction_n, coil_force_n_per_a):
    """Half-width F_cs / K_f (A) of the current band a spool friction F_cs holds still (Eq. 38)."""
    if coil_force_n_per_a <= 0.0:
        return 0.0
    return spool_coulomb_friction_n / coil_force_n_per_a


@njit(cache=True)
def spool_play_current(held_a, command_a, band_a):
    """Current the spool follows under Coulomb friction: a play (backlash) operator.

    In Eq. 38 with a friction F_cs on the spool, the spool stays where it is while the
    coil force K_f i differs from its spring force by less than F_cs, and moves with a
    force K_f i -/+ F_cs when pushed past that band. Where the spool is fast against the
    command (quasi-static limit) this is Eq. 38 driven by ``held_a`` moved just enough to
    keep ``command_a`` within ``band_a = F_cs / K_f`` of it. Returns ``command_a`` exactly
    when ``band_a`` is 0.
    """
    return min(max(held_a, command_a - band_a), command_a + band_a)
