"""Plant forms of the virtual rig's effects that are not the kernel's own.

Each form differs from the candidate model it tests (see :mod:`.virtual_rig`'s table):
filters on the command (coil, spool friction), on the sensors (lags), and effects applied
around the kernel's steps by operator splitting (:class:`PlantForm`: leaks, wall heat
exchange, supply line, muffler, LuGre friction).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.signal import cont2discrete, lfilter, lfilter_zi

from pneumatic_env.identification.config import IdentificationConfig
from pneumatic_env.physics import layout as L
from pneumatic_env.physics.chamber import chamber_volumes
from pneumatic_env.physics.derived import orifice_gas_constants, piston_areas_m2
from pneumatic_env.physics.effects import lugre_bristle_step, stribeck_friction
from pneumatic_env.physics.flow import orifice_mass_flow
from pneumatic_env.physics.valve import orifice_area
from pneumatic_env.simulator import BatchSimulator


def _two_lags(y: np.ndarray, total_tau_s: float, dt_s: float) -> np.ndarray:
    """Two cascaded first-order lags of ``total_tau_s / 2`` (exact for a held input)."""
    if total_tau_s <= 0:
        return y
    a = math.exp(-dt_s / (0.5 * total_tau_s))
    for _ in range(2):
        y, _ = lfilter([1.0 - a], [1.0, -a], y, zi=[a * y[0]])
    return y


def _coil_filter(total_tau_s: float, dt_s: float, force_share: float):
    """(num, den) of the rig's coil lags (``_coil_plant``) discretised exactly for a
    command held over each ``dt_s``."""
    den = np.polymul([(1.0 - force_share) * total_tau_s, 1.0], [force_share * total_tau_s, 1.0])
    num, den = cont2discrete(([1.0], np.trim_zeros(den, "f")), dt_s, method="zoh")[:2]
    return np.ravel(num), den


def _coil_plant(
    command_a: np.ndarray,
    total_tau_s: float,
    dt_s: float,
    amplifier_period_s: float,
    force_share: float,
) -> np.ndarray:
    """The current-equivalent of the rig's coil force at the end of each plant step: the
    amplifier holds the command over each of its periods (a whole number of plant steps),
    then a current lag of ``(1 - force_share) total_tau_s`` and a force lag of
    ``force_share total_tau_s`` in series (their exact zero-order-hold discretisation),
    starting at rest at the first command."""
    hold = max(1, int(round(amplifier_period_s / dt_s)))
    held = np.repeat(command_a[::hold], hold)[: command_a.size]
    num, den = _coil_filter(total_tau_s, dt_s, force_share)
    # lfilter's y[n] is the value at sample n with the input held over the step before it
    padded = np.append(held, held[-1])
    y, _ = lfilter(num, den, padded, zi=lfilter_zi(num, den) * held[0])
    return y[1:]


def _stick_slip_play(
    current_a: np.ndarray, band_a: float, breakaway_a: float, state: list | None = None
) -> np.ndarray:
    """The current a spool with Coulomb and static friction follows (quasi-static).

    Stuck, the spool holds its current ``h`` until the command leaves ``h +/- breakaway_a``
    (static friction); it then slides, held ``band_a`` behind the command (Coulomb
    friction), for as long as the command keeps moving that way. With ``breakaway_a =
    band_a`` this is the candidate's play (``effects.spool_play_current``). ``state``: the
    spool's [held current, sliding direction] to start from (default at rest at 0), updated
    in place at the end (to run the play a chunk at a time).
    """
    out = np.empty_like(current_a)
    held, sliding = (0.0, 0.0) if state is None else state
    for k, command in enumerate(current_a):
        if sliding != 0.0:
            target = command - sliding * band_a
            if (target - held) * sliding > 0.0:
                held = target
            else:
                sliding = 0.0
        if sliding == 0.0 and abs(command - held) > breakaway_a:
            sliding = 1.0 if command > held else -1.0
            held = command - sliding * band_a
        out[k] = held
    if state is not None:
        state[:] = [held, sliding]
    return out


def _orifice_gas(p: dict) -> tuple:
    """The gas's arguments of ``orifice_mass_flow`` (Eqs. 39, 40, 52) for parameters ``p``,
    computed once: 1/sqrt(T), k, C1, C2, P_cr, the linear ratio and its slope."""
    return orifice_gas_constants(
        p["heat_capacity_ratio"],
        p["gas_constant_j_per_kg_k"],
        p["temperature_k"],
        p["flow_linear_ratio"],
    )


def _orifice_flow(
    gas: tuple, area_m2: float, discharge: float, p_from_pa: float, p_to_pa: float
) -> float:
    """Signed mass flow (kg/s) of the paper's orifice (Eq. 39) for ``_orifice_gas``'s gas."""
    return orifice_mass_flow(area_m2, discharge, p_from_pa, p_to_pa, *gas)


def _laminar_conductance(p: dict, area_m2: float) -> float:
    """Laminar leak conductance (kg/s/Pa) passing the same flow as an orifice of
    ``area_m2`` (Eq. 39, C_f) from supply pressure to half the supply span below it."""
    ps, pa = p["supply_pressure_pa"], p["ambient_pressure_pa"]
    dp = 0.5 * (ps - pa)
    return _orifice_flow(_orifice_gas(p), area_m2, p["discharge_coefficient"], ps, ps - dp) / dp


def _muffler_step(
    muffler_pa: float,
    inflow_kg_per_s: float,
    vent_kg_per_s: float,
    volume_m3: float,
    gas_rt: float,
    h_s: float,
) -> float:
    """The exhaust muffler's pressure after h_s (explicit Euler, isothermal): a volume
    filled by the valve's exhaust flow and vented to the atmosphere through its porous
    element, dp/dt = R T / V (inflow - vent); never below zero."""
    return max(muffler_pa + gas_rt / volume_m3 * (inflow_kg_per_s - vent_kg_per_s) * h_s, 0.0)


def _supply_line_step(
    line_pa: float,
    regulator_pa: float,
    resistance_pa_s_per_kg: float,
    time_constant_s: float,
    draw_kg_per_s: float,
    h_s: float,
) -> float:
    """The supply line's pressure after h_s: a volume V fed through the regulator's linear
    resistance R from its set pressure, drained by the valve's draw (held over the step):
    dp/dt = (R T / V) ((p_set - p) / R - draw), exact for the held draw; the time constant
    is R V / (R_gas T). In steady flow it droops by R draw, as the candidate's resistance
    does at once."""
    steady = regulator_pa - resistance_pa_s_per_kg * draw_kg_per_s
    return steady + (line_pa - steady) * math.exp(-h_s / time_constant_s)


def _wall_heat_exchange(
    p_pa: float,
    t_k: float,
    volume_m3: float,
    h_s: float,
    conductance_ref_w_per_k: float,
    density_ref_kg_m3: float,
    density_exponent: float,
    wall_t_k: float,
    gas_constant: float,
    heat_capacity_ratio: float,
) -> tuple[float, float]:
    """A chamber's gas after exchanging heat with its wall for h_s at constant volume and mass.

    hA = hA_ref (rho / rho_ref)^n (natural convection: Nu ~ Ra^(1/3), Ra ~ rho^2, so
    n = 2/3), held over the step; the gas temperature relaxes exactly towards the wall's
    with the time constant m c_v / hA, m c_v = p V / ((k - 1) T), and p/T stays (the mass).
    Returns (p, T).
    """
    density = p_pa / (gas_constant * t_k)
    conductance = conductance_ref_w_per_k * (density / density_ref_kg_m3) ** density_exponent
    heat_capacity = p_pa * volume_m3 / ((heat_capacity_ratio - 1.0) * t_k)
    t_new = wall_t_k + (t_k - wall_t_k) * math.exp(-conductance * h_s / heat_capacity)
    return p_pa * t_new / t_k, t_new


class _PlantForm:
    """An effect the rig applies around the kernel's steps (operator splitting): on the
    state or the parameters of ``sim`` (one environment) before each step, and on the
    outputs after each plant step. ``every_substep``: the kernel steps one plant substep
    at a time (stiff forms); otherwise one plant step."""

    every_substep = False

    def __init__(self, true: dict):
        self.true = true
        self.cap_area, self.rod_side_area, _ = piston_areas_m2(
            true["bore_diameter_m"], true["rod_diameter_m"]
        )
        self.gas_rt = true["gas_constant_j_per_kg_k"] * true["temperature_k"]
        self.gas = _orifice_gas(true)

    def volumes(self, state: np.ndarray) -> tuple[float, float]:
        t = self.true
        return chamber_volumes(
            state[L.S_X, 0],
            0.5 * t["stroke_m"],
            self.cap_area,
            self.rod_side_area,
            t["dead_volume_cap_m3"],
            t["dead_volume_rod_m3"],
        )

    def before_step(self, sim: BatchSimulator, plant_step: int, h_s: float) -> None:
        raise NotImplementedError

    def correct_output(self, row: np.ndarray) -> None:
        """The recorded outputs of a plant step (default: as the kernel gave them)."""


class _LaminarLeak(_PlantForm):
    """``leakage`` (chamber 1 -> 2) or ``rod_seal_leak`` (chamber 2 -> air): a laminar leak,
    flow proportional to the pressure difference, over each plant step."""

    def __init__(self, true: dict, conductance_kg_per_s_pa: float, across_piston: bool):
        super().__init__(true)
        self.conductance = conductance_kg_per_s_pa
        self.across_piston = across_piston

    def before_step(self, sim, plant_step, h_s):
        t, state = self.true, sim.state
        v1, v2 = self.volumes(state)
        p1, p2 = state[L.S_P1, 0], state[L.S_P2, 0]
        if self.across_piston:
            mdot = self.conductance * (p1 - p2)  # chamber 1 -> chamber 2
            a_1 = t["alpha_out"] if mdot > 0 else t["alpha_in"]
            a_2 = t["alpha_in"] if mdot > 0 else t["alpha_out"]
            state[L.S_P1, 0] = p1 - a_1 * self.gas_rt / v1 * mdot * h_s
            state[L.S_P2, 0] = p2 + a_2 * self.gas_rt / v2 * mdot * h_s
        else:
            mdot = self.conductance * (p2 - t["ambient_pressure_pa"])  # chamber 2 -> air
            a_2 = t["alpha_out"] if mdot > 0 else t["alpha_in"]
            state[L.S_P2, 0] = p2 - a_2 * self.gas_rt / v2 * mdot * h_s


class _SupplyRipple(_PlantForm):
    """``supply_ripple``: the supply pressure oscillates by ``amplitude`` (relative) at 3 Hz."""

    def __init__(self, true: dict, amplitude: float):
        super().__init__(true)
        self.amplitude = amplitude

    def before_step(self, sim, plant_step, h_s):
        sim.set_parameter(
            "supply_pressure_pa",
            0,
            self.true["supply_pressure_pa"]
            * (1.0 + self.amplitude * math.sin(2.0 * math.pi * 3.0 * plant_step * h_s)),
        )


class _WallExchange(_PlantForm):
    """``heat_transfer``: ``_wall_heat_exchange`` in each chamber over each plant step."""

    def __init__(self, true: dict, conductance_ref_w_per_k: float, density_exponent: float):
        super().__init__(true)
        self.conductance_ref = conductance_ref_w_per_k
        self.density_exponent = density_exponent
        self.density_ref = (
            0.5 * (true["supply_pressure_pa"] + true["ambient_pressure_pa"]) / self.gas_rt
        )

    def before_step(self, sim, plant_step, h_s):
        t, state = self.true, sim.state
        v1, v2 = self.volumes(state)
        for p_row, t_row, volume in ((L.S_P1, L.S_T1, v1), (L.S_P2, L.S_T2, v2)):
            state[p_row, 0], state[t_row, 0] = _wall_heat_exchange(
                state[p_row, 0],
                state[t_row, 0],
                volume,
                h_s,
                self.conductance_ref,
                self.density_ref,
                self.density_exponent,
                t["temperature_k"],
                t["gas_constant_j_per_kg_k"],
                t["heat_capacity_ratio"],
            )


def _valve_path(true: dict, state: np.ndarray) -> tuple[float, float, float]:
    """The valve's open area (m^2) at its spool's position now, and the pressures of the
    chamber it feeds and of the one it exhausts (Eqs. 44, 45)."""
    spool = state[L.S_X_S, 0]
    area = orifice_area(
        abs(spool), true["hole_radius_m"], true["spool_half_width_m"], true["holes_per_path"]
    )
    p1, p2 = state[L.S_P1, 0], state[L.S_P2, 0]
    return (area, p1, p2) if spool > 0.0 else (area, p2, p1)


class _SupplyLine(_PlantForm):
    """``supply_droop``: the valve draws on a supply line (``_supply_line_step``)."""

    def __init__(self, true: dict, resistance_pa_s_per_kg: float, line_volume_m3: float):
        super().__init__(true)
        self.resistance = resistance_pa_s_per_kg
        self.time_constant = resistance_pa_s_per_kg * line_volume_m3 / self.gas_rt
        self.line_pa = true["supply_pressure_pa"]

    def before_step(self, sim, plant_step, h_s):
        area, fed_pa, _ = _valve_path(self.true, sim.state)
        draw = _orifice_flow(
            self.gas, area, self.true["discharge_coefficient"], self.line_pa, fed_pa
        )
        self.line_pa = _supply_line_step(
            self.line_pa,
            self.true["supply_pressure_pa"],
            self.resistance,
            self.time_constant,
            draw,
            h_s,
        )
        sim.set_parameter("supply_pressure_pa", 0, self.line_pa)


class _Muffler(_PlantForm):
    """``exhaust_muffler``: the kernel's exhaust node is a muffler
    (``_muffler_step``); the atmosphere, not the muffler, pushes on the rod."""

    every_substep = True

    def __init__(self, true: dict, vent_area_m2: float, volume_m3: float, piston: str):
        super().__init__(true)
        self.vent_area = vent_area_m2
        self.volume = volume_m3
        self.force_is_f_p = piston != "spring"  # the force channel is F_p (Eq. 1)
        self.muffler_pa = true["ambient_pressure_pa"]

    def before_step(self, sim, plant_step, h_s):
        t = self.true
        area, _, exhausting_pa = _valve_path(t, sim.state)
        self.muffler_pa = _muffler_step(
            self.muffler_pa,
            _orifice_flow(
                self.gas, area, t["discharge_coefficient"], exhausting_pa, self.muffler_pa
            ),
            _orifice_flow(self.gas, self.vent_area, 1.0, self.muffler_pa, t["ambient_pressure_pa"]),
            self.volume,
            self.gas_rt,
            h_s,
        )
        sim.set_parameter("ambient_pressure_pa", 0, self.muffler_pa)
        sim.set_parameter("load_force_n", 0, t["load_force_n"] - self._rod_force_error())

    def _rod_force_error(self) -> float:
        return (self.muffler_pa - self.true["ambient_pressure_pa"]) * (
            self.cap_area - self.rod_side_area
        )

    def correct_output(self, row):
        if self.force_is_f_p:
            row[L.O_F] += self._rod_force_error()


class _LuGre(_PlantForm):
    """``lugre``: LuGre friction (``effects.lugre_bristle_step``) on the Stribeck curve as
    the load force, its bristle damping falling with speed (``_lugre_damping``)."""

    every_substep = True

    def __init__(
        self,
        true: dict,
        static_n: float,
        coulomb_n: float,
        stribeck_velocity_m_per_s: float,
        stiffness_n_per_m: float,
        damping_n_s_per_m: float,
        damping_decay_velocity_m_per_s: float,
    ):
        super().__init__(true)
        self.damping_decay_velocity = damping_decay_velocity_m_per_s
        self.static_n, self.coulomb_n = static_n, coulomb_n
        self.stribeck_velocity = stribeck_velocity_m_per_s
        self.stiffness, self.damping = stiffness_n_per_m, damping_n_s_per_m
        self.bristle_m = 0.0

    def before_step(self, sim, plant_step, h_s):
        v = sim.state[L.S_V, 0]
        self.bristle_m, friction = lugre_bristle_step(
            self.bristle_m,
            v,
            h_s,
            self.stiffness,
            _lugre_damping(self.damping, v, self.damping_decay_velocity),
            stribeck_friction(v, self.coulomb_n, self.static_n, self.stribeck_velocity),
        )
        sim.set_parameter("load_force_n", 0, self.true["load_force_n"] + friction)


def _lugre_damping(
    damping_n_s_per_m: float, velocity_m_per_s: float, decay_velocity_m_per_s: float
) -> float:
    """A bristle damping sigma1 exp(-(v/v_d)^2) that damps the pre-sliding motion more than
    the sliding one (a velocity-dependent sigma1 as discussed by Canudas de Wit et al. 1995)."""
    return damping_n_s_per_m * math.exp(-((velocity_m_per_s / decay_velocity_m_per_s) ** 2))


def _plant_form(
    effect: str,
    strength: float,
    reference: float,
    true: dict,
    truth: dict,
    cfg: IdentificationConfig,
    piston: str,
) -> _PlantForm:
    """The rig's form of ``effect`` at ``strength`` (``reference`` at strength 1):
    switches the kernel's own form off in ``true`` and states the truth in ``truth``."""
    rig = lambda name, **kw: cfg.number("virtual_rig", name, **kw)  # noqa: E731
    value = strength * reference
    if effect in ("leakage", "rod_seal_leak"):
        return _LaminarLeak(true, _laminar_conductance(true, value), effect == "leakage")
    if effect == "supply_ripple":
        return _SupplyRipple(true, value)
    if effect == "heat_transfer":
        truth["wall_heat_transfer_w_per_k"] = value
        # the kernel's full energy equation on (any hA > 0) with a negligible wall
        # exchange of its own: the rig's exchange is applied between the steps
        true["wall_heat_transfer_w_per_k"] = 1e-12
        return _WallExchange(true, value, rig("heat_transfer_density_exponent", minimum=0.0))
    if effect == "supply_droop":  # the kernel's resistance stays 0
        truth["supply_resistance_pa_s_per_kg"] = value
        return _SupplyLine(true, value, rig("supply_line_volume_m3", positive=True))
    if effect == "lugre":  # LuGre replaces the kernel's Karnopp friction
        # strength scales the bristles' compliance; the damping keeps its ratio to sqrt(sigma0)
        damping = rig("lugre_damping_n_s_per_m", positive=True) / math.sqrt(strength)
        stribeck_velocity = cfg.number("virtual_rig", "effects", "stribeck", positive=True)
        stiffness = reference / strength
        truth.update(
            lugre_stiffness_n_per_m=stiffness,
            lugre_damping_n_s_per_m=damping,
            stribeck_velocity_m_per_s=stribeck_velocity,
        )
        true.update(static_friction_n=0.0, dynamic_friction_n=0.0, stribeck_velocity_m_per_s=0.0)
        return _LuGre(
            true,
            truth["static_friction_n"],
            truth["dynamic_friction_n"],
            stribeck_velocity,
            stiffness,
            damping,
            rig("lugre_damping_decay_velocity_m_per_s", positive=True),
        )
    if effect == "exhaust_muffler":  # the kernel's vent stays off: its node is the muffler
        vent_area = reference / strength  # strength scales the vent's resistance
        volume = rig("exhaust_muffler_volume_m3", positive=True)
        truth.update(exhaust_vent_area_m2=vent_area, exhaust_volume_m3=volume)
        return _Muffler(true, vent_area, volume, piston)
    raise ValueError(f"effect {effect!r} has no plant form of the rig's own")
