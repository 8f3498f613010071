"""The paper's model, written independently of the kernel in :mod:`pneumatic_env.physics`
(it shares nothing with it but the parameter names): the constants of a parameter set and
one function per sub-model, with the equation numbers of Richer & Hurmuzlu (2000) and the
corrections of ``docs/model.md``."""

from __future__ import annotations

import math
from dataclasses import dataclass

from pneumatic_env.physics.layout import EFFECT_NEUTRAL_VALUES

# Continuous state layout of the reference integrator (independent of physics/layout.py).
IX_XS, IX_VS, IX_XD, IX_VD, IX_P1, IX_P2, IX_X, IX_V = range(8)
N_Y = 8

PISTON_FIXED, PISTON_FREE, PISTON_SPRING = 0, 1, 2
COUPLING_COMMAND, COUPLING_LITERAL = 0, 1

# The four valve-tube paths, in this order (and the chamber each one feeds):
#   0: chamber 1 <-> supply  through A_in(x_s)
#   1: chamber 1 <-> exhaust through A_ex(x_s) = A_in(-x_s)
#   2: chamber 2 <-> supply  through A_ex(x_s)
#   3: chamber 2 <-> exhaust through A_in(x_s)
PATH_CHAMBER = (0, 0, 1, 1)


_REQUIRED = (
    "gas_constant_j_per_kg_k",
    "heat_capacity_ratio",
    "temperature_k",
    "ambient_pressure_pa",
    "supply_pressure_pa",
    "air_viscosity_pa_s",
    "alpha_in",
    "alpha_out",
    "alpha_motion",
    "spool_mass_kg",
    "spool_damping_n_s_per_m",
    "spool_spring_n_per_m",
    "coil_force_n_per_a",
    "discharge_coefficient",
    "hole_radius_m",
    "spool_half_width_m",
    "holes_per_path",
    "tube_length_m",
    "tube_inner_diameter_m",
    "reynolds_turbulent",
    "tube_coupling",
    "bore_diameter_m",
    "rod_diameter_m",
    "stroke_m",
    "dead_volume_cap_m3",
    "dead_volume_rod_m3",
    "piston_mass_kg",
    "static_friction_n",
    "dynamic_friction_n",
    "viscous_friction_n_s_per_m",
    "leakage_area_m2",
    "piston_mode",
    "fixed_position_m",
    "load_mass_kg",
    "load_force_n",
    "spring_stiffness_n_per_m",
    "spring_rest_position_m",
    "flow_linear_ratio",
)


# Effects beyond the paper's model (docs/effects.md) and their neutral values. The
# reference implements docs/model.md only, so it refuses a parameter set that switches
# one of them on rather than silently computing a different model.
NEUTRAL_EFFECTS = EFFECT_NEUTRAL_VALUES

# --------------------------------------------------------------------------------------
# Constants
# --------------------------------------------------------------------------------------


def flow_constants(k: float, gas_constant: float) -> tuple[float, float, float]:
    """``(C1, C2, P_cr)`` of the orifice flow (Eq. 40, exponents corrected).

    ``C1 = sqrt(k/R (2/(k+1))^((k+1)/(k-1)))``, ``C2 = sqrt(2k/(R(k-1)))``,
    ``P_cr = (2/(k+1))^(k/(k-1))``; 0.040418, 0.156174, 0.528 for air.
    """
    c1 = math.sqrt(k / gas_constant * (2.0 / (k + 1.0)) ** ((k + 1.0) / (k - 1.0)))
    c2 = math.sqrt(2.0 * k / (gas_constant * (k - 1.0)))
    p_cr = (2.0 / (k + 1.0)) ** (k / (k - 1.0))
    return c1, c2, p_cr


@dataclass(frozen=True)
class ModelConstants:
    """Parameters and derived constants of one parameter set, in SI units."""

    R: float
    k: float
    T: float
    sqrt_T: float
    p_a: float
    p_s: float
    mu: float
    alpha_in: float
    alpha_out: float
    alpha: float
    # spool and orifice
    m_s: float
    c_s: float
    k_s: float
    k_fc: float
    c_f: float
    r_h: float
    p_w: float
    n_h: float
    c1: float
    c2: float
    p_cr: float
    r_lin: float
    m_r_lin: float  # unlinearised reduced flow at r_lin (0 when r_lin >= 1)
    # tube
    tube_length: float
    tube_d: float
    re_t: float
    c_sound: float
    tau: float
    coupling: int
    # cylinder and load
    a1: float
    a2: float
    a_r: float
    stroke: float
    v01: float
    v02: float
    mass: float  # M_p + M_L
    f_sf: float
    f_df: float
    f_stick: float  # max(F_sf, F_df)
    beta: float
    a_leak: float
    piston_mode: int
    x_fixed: float
    f_load: float
    k_env: float
    x_rest: float

    @classmethod
    def from_params(cls, params: dict) -> ModelConstants:
        missing = [n for n in _REQUIRED if n not in params]
        if missing:
            raise KeyError(f"parameter set lacks {missing}")
        switched_on = [
            n
            for n, neutral in NEUTRAL_EFFECTS.items()
            if n in params and float(params[n]) != neutral
        ]
        if switched_on:
            raise NotImplementedError(
                f"the reference solution implements docs/model.md only; effects switched "
                f"on: {switched_on} (set them to their neutral values {NEUTRAL_EFFECTS})"
            )
        p = {n: float(params[n]) for n in _REQUIRED}
        R, k, T = p["gas_constant_j_per_kg_k"], p["heat_capacity_ratio"], p["temperature_k"]
        c1, c2, p_cr = flow_constants(k, R)
        r_lin = p["flow_linear_ratio"]
        c_sound = math.sqrt(k * R * T)
        a1 = math.pi * p["bore_diameter_m"] ** 2 / 4.0
        a_r = math.pi * p["rod_diameter_m"] ** 2 / 4.0
        mode = int(round(p["piston_mode"]))
        coupling = int(round(p["tube_coupling"]))
        if mode not in (PISTON_FIXED, PISTON_FREE, PISTON_SPRING):
            raise ValueError(f"piston_mode must be 0, 1 or 2, got {p['piston_mode']}")
        if coupling not in (COUPLING_COMMAND, COUPLING_LITERAL):
            raise ValueError(f"tube_coupling must be 0 or 1, got {p['tube_coupling']}")
        const = cls(
            R=R,
            k=k,
            T=T,
            sqrt_T=math.sqrt(T),
            p_a=p["ambient_pressure_pa"],
            p_s=p["supply_pressure_pa"],
            mu=p["air_viscosity_pa_s"],
            alpha_in=p["alpha_in"],
            alpha_out=p["alpha_out"],
            alpha=p["alpha_motion"],
            m_s=p["spool_mass_kg"],
            c_s=p["spool_damping_n_s_per_m"],
            k_s=p["spool_spring_n_per_m"],
            k_fc=p["coil_force_n_per_a"],
            c_f=p["discharge_coefficient"],
            r_h=p["hole_radius_m"],
            p_w=p["spool_half_width_m"],
            n_h=p["holes_per_path"],
            c1=c1,
            c2=c2,
            p_cr=p_cr,
            r_lin=r_lin,
            m_r_lin=0.0,
            tube_length=p["tube_length_m"],
            tube_d=p["tube_inner_diameter_m"],
            re_t=p["reynolds_turbulent"],
            c_sound=c_sound,
            tau=p["tube_length_m"] / c_sound,
            coupling=coupling,
            a1=a1,
            a2=a1 - a_r,
            a_r=a_r,
            stroke=p["stroke_m"],
            v01=p["dead_volume_cap_m3"],
            v02=p["dead_volume_rod_m3"],
            mass=p["piston_mass_kg"] + p["load_mass_kg"],
            f_sf=p["static_friction_n"],
            f_df=p["dynamic_friction_n"],
            f_stick=max(p["static_friction_n"], p["dynamic_friction_n"]),
            beta=p["viscous_friction_n_s_per_m"],
            a_leak=p["leakage_area_m2"],
            piston_mode=mode,
            x_fixed=p["fixed_position_m"],
            f_load=p["load_force_n"],
            k_env=p["spring_stiffness_n_per_m"],
            x_rest=p["spring_rest_position_m"],
        )
        if r_lin < 1.0:
            object.__setattr__(const, "m_r_lin", _reduced_flow_exact(const, r_lin))
        return const


# --------------------------------------------------------------------------------------
# Sub-models
# --------------------------------------------------------------------------------------


def spool_acceleration(m: ModelConstants, x_s: float, v_s: float, i_c: float) -> float:
    """Spool acceleration from ``M_s x_s'' + c_s x_s' + 2 k_s x_s = K_fc i_c`` (Eq. 38)."""
    return (m.k_fc * i_c - m.c_s * v_s - 2.0 * m.k_s * x_s) / m.m_s


def orifice_area(m: ModelConstants, x_s: float) -> float:
    """Area of the path that opens for positive spool displacement, ``A_in(x_s)``.

    Eqs. 41-44 with the corrected effective opening ``x_e = x_s - (p_w - R_h)`` (Eq. 43):
    ``n_h`` circle segments of height ``x_e`` of holes of radius ``R_h``. The other path
    is ``A_ex(x_s) = A_in(-x_s)`` (Eq. 45).
    """
    r = m.r_h
    x_e = x_s - (m.p_w - r)
    if x_e <= 0.0:
        return 0.0
    if x_e >= 2.0 * r:
        return math.pi * m.n_h * r * r
    h = r - x_e
    return m.n_h * (r * r * math.acos(h / r) - h * math.sqrt(x_e * (2.0 * r - x_e)))


def _reduced_flow_exact(m: ModelConstants, r: float) -> float:
    """Reduced flow of Eq. 52 without the linearisation near ``r = 1``."""
    if r <= m.p_cr:
        return m.c1
    return m.c2 * r ** (1.0 / m.k) * math.sqrt(max(0.0, 1.0 - r ** ((m.k - 1.0) / m.k)))


def reduced_flow(m: ModelConstants, r: float) -> float:
    """Reduced flow ``m_r(r)`` of the pressure ratio ``r = P_d / P_u`` in ``[0, 1]``.

    Choked (``C1``) for ``r <= P_cr``, subsonic (Eq. 52) up to ``r_lin =
    flow_linear_ratio``, and linearised to zero above it:
    ``m_r(r) = m_r(r_lin) (1 - r) / (1 - r_lin)`` for ``r_lin < r <= 1`` (docs/model.md,
    *Numerics*), which keeps the slope finite at ``r -> 1``.
    """
    if r > m.r_lin and m.r_lin < 1.0:
        return m.m_r_lin * (1.0 - r) / (1.0 - m.r_lin) if r < 1.0 else 0.0
    return _reduced_flow_exact(m, r)


def orifice_mass_flow(m: ModelConstants, area: float, p_from: float, p_to: float) -> float:
    """Signed mass flow (kg/s) through an orifice, positive from ``p_from`` to ``p_to``.

    Eq. 39 (with Eq. 52's reduced flow): ``C_f A P_u / sqrt(T) m_r(P_d / P_u)``, the flow
    passing from the higher pressure ``P_u`` to the lower ``P_d``.
    """
    if area <= 0.0 or p_from == p_to:
        return 0.0
    if p_from > p_to:
        return m.c_f * area * p_from / m.sqrt_T * reduced_flow(m, p_to / p_from)
    return -m.c_f * area * p_to / m.sqrt_T * reduced_flow(m, p_from / p_to)


def reynolds_number(m: ModelConstants, mdot: float) -> float:
    """Tube Reynolds number of a mass flow, ``Re = 4 |mdot| / (pi D mu)``."""
    return 4.0 * abs(mdot) / (math.pi * m.tube_d * m.mu)


def tube_resistance(m: ModelConstants, reynolds: float, turbulent: bool) -> float:
    """Tube resistance ``R_t``: laminar ``32 mu / D^2`` (Eq. 33) or wholly turbulent
    ``0.158 mu Re^(3/4) / D^2`` (Blasius, Eqs. 34-35).

    The regime is passed in (``turbulent = Re >= Re_t``) because the integrator locks it
    between located switching times.
    """
    if turbulent:
        return 0.158 * m.mu * reynolds**0.75 / m.tube_d**2
    return 32.0 * m.mu / m.tube_d**2


def tube_attenuation(m: ModelConstants, r_t: float, p_end: float) -> float:
    """Tube flow attenuation ``phi = exp(-R_t R T tau / (2 P))`` (Eqs. 25, 30), with
    ``P`` the tube-end (chamber) pressure and ``tau = L_t / c``."""
    return math.exp(-r_t * m.R * m.T * m.tau / (2.0 * p_end))


def chamber_volumes(m: ModelConstants, x: float) -> tuple[float, float]:
    """Chamber volumes ``V1 = V01 + A1 (L/2 + x)``, ``V2 = V02 + A2 (L/2 - x)`` (Eq. 15)."""
    half = 0.5 * m.stroke
    return m.v01 + m.a1 * (half + x), m.v02 + m.a2 * (half - x)


def chamber_pressure_rate(
    m: ModelConstants, p: float, volume: float, volume_rate: float, mdot_in: float, mdot_out: float
) -> float:
    """``dP/dt = R T / V (alpha_in mdot_in - alpha_out mdot_out) - alpha P V' / V``
    (Eq. 14 with Eq. 15, i.e. Eq. 16 / corrected Eq. 55); ``mdot_in``, ``mdot_out >= 0``."""
    return (
        m.R * m.T * (m.alpha_in * mdot_in - m.alpha_out * mdot_out) - m.alpha * p * volume_rate
    ) / volume


def pneumatic_force(m: ModelConstants, p1: float, p2: float) -> float:
    """Actuator force ``F_p = P1 A1 - P2 A2 - P_a A_r`` (right-hand side of Eq. 1)."""
    return p1 * m.a1 - p2 * m.a2 - m.p_a * m.a_r


def load_force(m: ModelConstants, x: float) -> float:
    """External force ``F_L`` resisting extension: ``load_force_n`` in free mode,
    ``k_env (x - x_rest)`` in spring mode, 0 in fixed mode (docs/model.md)."""
    if m.piston_mode == PISTON_FREE:
        return m.f_load
    if m.piston_mode == PISTON_SPRING:
        return m.k_env * (x - m.x_rest)
    return 0.0


def piston_acceleration(
    m: ModelConstants, applied_force: float, v: float, slip_direction: float
) -> float:
    """Piston acceleration while slipping (Eq. 1 with Karnopp friction, Eq. 47 corrected):
    ``(M_p + M_L) x'' = (F_p - F_L) - beta v - F_df s``, ``s = sign(v)`` the slip direction
    (locked during a slip phase, so it is defined at ``v = 0`` too)."""
    return (applied_force - m.beta * v - m.f_df * slip_direction) / m.mass


def output_force(m: ModelConstants, p1: float, p2: float, x: float) -> float:
    """Force output: ``F_p`` in fixed and free mode, ``k_env (x - x_rest)`` in spring mode."""
    if m.piston_mode == PISTON_SPRING:
        return m.k_env * (x - m.x_rest)
    return pneumatic_force(m, p1, p2)
