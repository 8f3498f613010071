"""The rig's own forms of effects the kernel also has as a parameter.

Issue 20: a rig effect that tests a candidate must not share the candidate's form (an
inverse crime). These plant forms act around the kernel's steps (operator splitting, as
:mod:`.rig_plants`), with the kernel's own parameter for the effect left neutral:

===================  ===================================================================
effect               rig form (candidate form in brackets)
===================  ===================================================================
valve_null_leak      laminar clearance flow of a compressible gas in a narrow gap,
                     mass flow proportional to p_up^2 - p_down^2, from the supply into
                     each chamber and from each chamber to the exhaust (an orifice area
                     added to every valve path, Eq. 39)
tube_volume          each tube's air is a state of its own: a volume exchanging with
                     its chamber through the tube's laminar (Hagen-Poiseuille)
                     resistance, filled and emptied adiabatically and relaxing to the
                     wall temperature with the bore's heat-diffusion time constant
                     (isothermal tube air at the chamber's pressure, no resistance)
iso_flow_law         ISO 6358-2 (2013) flow with the subsonic index m = 0.6, as a
                     correction of the valve's flow at the chamber nodes (ISO 6358-1's
                     ellipse, m = 0.5, inside the valve)
exhaust_discharge    an exhaust discharge coefficient that falls with the pressure ratio
                     p_down/p_up (a constant ratio on the exhaust paths)
stribeck             a Lorentzian Stribeck curve 1 / (1 + (v/v_s)^2) as a load force
                     (the kernel's Gaussian exp(-(v/v_s)^2))
===================  ===================================================================
"""

from __future__ import annotations

import math

from pneumatic_env.physics import layout as L
from pneumatic_env.physics.derived import circle_area_m2

from .rig_plants import _orifice_flow, _valve_path
from .rig_plants import _PlantForm as PlantForm

__all__ = ["OWN_FORM_EFFECTS", "own_form"]

#: Effects with a rig form of their own here (the kernel's parameter stays neutral).
OWN_FORM_EFFECTS = (
    "valve_null_leak",
    "tube_volume",
    "iso_flow_law",
    "exhaust_discharge",
    "stribeck",
)
#: Subsonic index of the rig's ISO 6358-2 flow (the candidate's ellipse has 0.5).
ISO_SUBSONIC_INDEX = 0.6


def _add_mass(
    state, row_p: int, volume_m3: float, mass_kg: float, gas_rt: float, alpha: float
) -> None:
    """Add ``mass_kg`` to the chamber at state row ``row_p`` (Eq. 29's p-form, held T)."""
    state[row_p, 0] += alpha * gas_rt / volume_m3 * mass_kg


class _ClearanceLeak(PlantForm):
    """``valve_null_leak``: laminar compressible flow through the spool's clearance,
    ``G (p_up^2 - p_down^2)``, supply -> each chamber and each chamber -> exhaust; ``G``
    passes an orifice's flow (area ``area_m2``, C_f, Eq. 39) from supply to half span."""

    def __init__(self, true: dict, area_m2: float):
        super().__init__(true)
        ps, pa = true["supply_pressure_pa"], true["ambient_pressure_pa"]
        mid = 0.5 * (ps + pa)
        self.conductance = _orifice_flow(
            self.gas, area_m2, true["discharge_coefficient"], ps, mid
        ) / (ps * ps - mid * mid)

    def before_step(self, sim, plant_step, h_s):
        t, state = self.true, sim.state
        ps, pa = t["supply_pressure_pa"], t["ambient_pressure_pa"]
        for row, volume in zip((L.S_P1, L.S_P2), self.volumes(state)):
            p = state[row, 0]
            inflow = self.conductance * (ps * ps - p * p) * h_s
            outflow = self.conductance * (p * p - pa * pa) * h_s
            _add_mass(state, row, volume, inflow, self.gas_rt, t["alpha_in"])
            _add_mass(state, row, volume, -outflow, self.gas_rt, t["alpha_out"])


class _TubeVolumes(PlantForm):
    """``tube_volume``: per chamber, the tube's air (a fraction of its volume) as a volume
    of its own, exchanging with the chamber through the tube's laminar resistance (the
    pressure difference decays exactly over each step, linear conductance held, the
    exchanged mass conserved). The air entering or leaving the tube does so adiabatically
    (a volume of capacity V_t / (k R T)); between exchanges it trades heat with the wall,
    its pressure relaxing to the isothermal pressure of its mass with the radial
    heat-diffusion time constant of the bore: adiabatic in fast transients, isothermal in
    slow ones."""

    def __init__(self, true: dict, fraction: float, thermal_time_constant_s: float):
        super().__init__(true)
        d, length = true["tube_inner_diameter_m"], true["tube_length_m"]
        self.tube_volume = fraction * circle_area_m2(d) * length
        # Hagen-Poiseuille: mass flow = rho pi d^4 / (128 mu L) dp, rho = p / (R T)
        self.conductance_per_pa = (
            math.pi * d**4 / (128.0 * true["air_viscosity_pa_s"] * length * self.gas_rt)
        )
        self.thermal_time_constant_s = thermal_time_constant_s
        pa = true["ambient_pressure_pa"]
        self.tube_pa = [pa, pa]
        self.tube_kg = [pa * self.tube_volume / self.gas_rt] * 2

    def before_step(self, sim, plant_step, h_s):
        if self.tube_volume <= 0.0:
            return
        t, state = self.true, sim.state
        c_tube = self.tube_volume / (t["heat_capacity_ratio"] * self.gas_rt)  # adiabatic
        relax = math.exp(-h_s / self.thermal_time_constant_s)
        for k, (row, volume) in enumerate(zip((L.S_P1, L.S_P2), self.volumes(state))):
            p_c, p_t = state[row, 0], self.tube_pa[k]
            g = self.conductance_per_pa * 0.5 * (p_c + p_t)  # kg/s per Pa
            alpha = t["alpha_out"] if p_c > p_t else t["alpha_in"]
            c_chamber = volume / (alpha * self.gas_rt)  # kg per Pa
            inv = 1.0 / c_chamber + 1.0 / c_tube
            dp = p_c - p_t
            mass = dp * (1.0 - math.exp(-g * inv * h_s)) / inv  # chamber -> tube
            state[row, 0] = p_c - mass / c_chamber
            self.tube_kg[k] += mass
            isothermal = self.tube_kg[k] * self.gas_rt / self.tube_volume
            self.tube_pa[k] = isothermal + (p_t + mass / c_tube - isothermal) * relax


class _ValveFlowCorrection(PlantForm):
    """``iso_flow_law`` and ``exhaust_discharge``: the valve's flow by the rig's law, as
    the kernel's (the paper's orifice, Eq. 39) plus a correction applied at the chamber
    nodes before every plant substep."""

    every_substep = True

    def __init__(self, true: dict, law: str, value: float):
        super().__init__(true)
        self.law, self.value = law, value
        self.c1 = self.gas[2]

    def _iso_flow(self, area_m2: float, p_up: float, p_down: float) -> float:
        """ISO 6358-2 (2013): choked below b, ``[1 - ((r - b)/(1 - b))^2]^m`` above."""
        b, r = self.value, p_down / p_up
        shape = 1.0 if r <= b else max(1.0 - ((r - b) / (1.0 - b)) ** 2, 0.0) ** ISO_SUBSONIC_INDEX
        return self.true["discharge_coefficient"] * area_m2 * p_up * self.gas[0] * self.c1 * shape

    def _correction(self, area_m2: float, p_from: float, p_to: float, exhaust: bool) -> float:
        """Rig flow minus the kernel's (kg/s, from -> to, both ways signed)."""
        t = self.true
        paper = _orifice_flow(self.gas, area_m2, t["discharge_coefficient"], p_from, p_to)
        up, down = max(p_from, p_to), min(p_from, p_to)
        if self.law == "iso":
            return math.copysign(self._iso_flow(area_m2, up, down), p_from - p_to) - paper
        if not exhaust:
            return 0.0
        # exhaust discharge ratio falling with the pressure ratio, value at r = 0.5
        ratio = 1.0 - (1.0 - self.value) * (0.6 + 0.8 * down / up)
        return (ratio - 1.0) * paper

    def before_step(self, sim, plant_step, h_s):
        t, state = self.true, sim.state
        area, fed_pa, out_pa = _valve_path(t, state)
        if area <= 0.0:
            return
        spool = state[L.S_X_S, 0]
        fed_row, out_row = (L.S_P1, L.S_P2) if spool > 0.0 else (L.S_P2, L.S_P1)
        v1, v2 = self.volumes(state)
        volume = {L.S_P1: v1, L.S_P2: v2}
        into_fed = self._correction(area, t["supply_pressure_pa"], fed_pa, False) * h_s
        out_of = self._correction(area, out_pa, t["ambient_pressure_pa"], True) * h_s
        _add_mass(
            state,
            fed_row,
            volume[fed_row],
            into_fed,
            self.gas_rt,
            t["alpha_in"] if into_fed > 0 else t["alpha_out"],
        )
        _add_mass(
            state,
            out_row,
            volume[out_row],
            -out_of,
            self.gas_rt,
            t["alpha_out"] if out_of > 0 else t["alpha_in"],
        )


class _LorentzStribeck(PlantForm):
    """``stribeck``: the rig's sliding friction F_df + (F_sf - F_df) / (1 + (v/v_s)^2)
    (the kernel's Karnopp stick and its F_df slide, plus this load force)."""

    every_substep = True

    def __init__(self, true: dict, stribeck_velocity_m_per_s: float):
        super().__init__(true)
        self.excess_n = max(true["static_friction_n"] - true["dynamic_friction_n"], 0.0)
        self.velocity = stribeck_velocity_m_per_s

    def before_step(self, sim, plant_step, h_s):
        v = sim.state[L.S_V, 0]
        extra = (
            0.0 if v == 0.0 else math.copysign(self.excess_n / (1.0 + (v / self.velocity) ** 2), v)
        )
        sim.set_parameter("load_force_n", 0, self.true["load_force_n"] + extra)


def own_form(
    effect: str, value: float, true: dict, tube_thermal_time_constant_s: float
) -> PlantForm:
    """The rig's form of ``effect`` at the kernel-parameter ``value`` it stands for; the
    caller leaves the kernel's own parameter neutral in ``true``. The tube air's thermal
    time constant is ``virtual_rig.tube_air_thermal_time_constant_s``."""
    if effect == "valve_null_leak":
        return _ClearanceLeak(true, value)
    if effect == "tube_volume":
        return _TubeVolumes(true, value, tube_thermal_time_constant_s)
    if effect == "iso_flow_law":
        return _ValveFlowCorrection(true, "iso", value)
    if effect == "exhaust_discharge":
        return _ValveFlowCorrection(true, "exhaust", value)
    if effect == "stribeck":
        return _LorentzStribeck(true, value)
    raise ValueError(
        f"effect {effect!r} has no own rig form; allowed: {', '.join(OWN_FORM_EFFECTS)}"
    )
