"""Reproduce the experiments of Richer & Hurmuzlu (2000), Part I, on the model.

``pneumatic-env paper --out DIR`` (:mod:`pneumatic_env.studies.paper_report`) writes one
PNG per experiment and ``table.md`` / ``table.json`` with the quantities the paper states
facts about:

(a) valve flow vs coil current and vs downstream pressure (Figs. 7, 9; Eqs. 39, 44, 46);
(b) rod clamped at mid-stroke, 0.5 A coil step, 0.5 m and 2 m tubes, both tube couplings
    (Figs. 15-16): pressures and force vs time, the extra delay of the long tube and the
    ratio of the times to reach the final force;
(c) free rod, no load, 5 Hz sinusoidal coil current, both cylinders (Figs. 17-18);
(d) the tube alone (Fig. 3): Eq. 31 against a numerical solution of Eqs. 19-20.

The experiment settings below are the paper's (Sec. 2.3, Sec. 4) except where marked
as a choice; every model parameter comes from ``configs/`` through ``load_parameters``.
All results are simulated: nothing here is measured data. The figures are drawn by
:mod:`pneumatic_env.studies.paper_figures` (the ``plots`` extra); the table, the files
and the command are :mod:`pneumatic_env.studies.paper_report`'s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from pneumatic_env.ids import CYLINDER_IDS
from pneumatic_env.params import DEFAULT_CYLINDER, load_parameters
from pneumatic_env.physics.derived import orifice_gas_constants, piston_areas_m2, tube_delay_s
from pneumatic_env.physics.flow import orifice_mass_flow
from pneumatic_env.physics.tube import (
    reynolds_number,
    sound_speed,
    tube_attenuation,
    tube_resistance,
)
from pneumatic_env.physics.valve import orifice_area, steady_spool_position
from pneumatic_env.replay import simulate_currents

__all__ = [
    "CYLINDERS",
    "STEP_CURRENT_A",
    "STEP_TUBES_M",
    "COUPLINGS",
    "SINE_AMPLITUDE_A",
    "SINE_FREQUENCY_HZ",
    "Scenario",
    "clamped_step_scenario",
    "free_sine_scenario",
    "run_scenario",
    "valve_flow_vs_current",
    "valve_flow_vs_downstream",
    "valve_numbers",
    "clamped_step_runs",
    "step_metrics",
    "free_sine_runs",
    "tube_response",
]

CYLINDERS = (CYLINDER_IDS["Numatics"], CYLINDER_IDS["Airpel"])  # the paper's two

# (b) Sec. 4, Figs. 15-16: piston fixed at mid-stroke, 0.5 A coil step, 0.5 m and 2 m tubes.
STEP_CURRENT_A = 0.5
STEP_TUBES_M = (0.5, 2.0)
COUPLINGS = ("command", "literal")
STEP_DURATION_S = 0.2
STEP_SAMPLE_S = 1e-4  # output sampling; the substep stays the default one
# "First rise" of p1: above its initial value by this fraction of supply - ambient
# (0.1 %, 0.55 kPa at the default pressures: small, but clearly above zero).
RISE_FRACTION = 1e-3
# "Time to reach the final force": to this fraction of the steady force (P_s - P_a) A1.
FINAL_FRACTION = 0.95
# Window at the end of the step run over which the oscillation near supply is measured.
OSCILLATION_WINDOW_S = 0.05

# (c) Sec. 4, Figs. 17-18: rod free, no load, 5 Hz sinusoidal coil current.
SINE_FREQUENCY_HZ = 5.0
# Choice: the paper states "1.5 V" without the amplifier gain; 0.5 A is assumed.
SINE_AMPLITUDE_A = 0.5
SINE_DURATION_S = 1.0
SINE_CONTROL_DT_S = 1e-3
# Choice: the tube of Figs. 17-18 is not stated; the default (short) tube is used.
SINE_TUBE_M = None

# (d) Sec. 2.3, Fig. 3: 3.2 mm x 3 m tube, sinusoidal inlet flow 6e-3 kg/s at 30 Hz.
TUBE_LENGTH_M = 3.0
TUBE_FLOW_AMPLITUDE_KG_S = 6e-3
TUBE_FLOW_FREQUENCY_HZ = 30.0
# Choice: the paper does not state the pressure in the tube; phi (Eq. 30) and the
# density of Eq. 19 are evaluated at this mean absolute pressure.
TUBE_MEAN_PRESSURE_PA = 4.0e5
TUBE_DURATION_S = 0.1
TUBE_CELLS = 200  # grid of the method-of-characteristics solution

# (a) Figs. 7 and 9.
VALVE_CURRENTS_A = np.linspace(-2.0, 2.0, 401)
DOWNSTREAM_CURRENTS_A = (0.3, 0.5, 0.8, 1.5)


# --------------------------------------------------------------------------- scenarios


@dataclass(frozen=True, eq=False)
class Scenario:
    """One open-loop experiment: the rig (cylinder + parameter settings), the coil current
    of each control period and the period."""

    name: str
    cylinder: str
    settings: dict
    coil_current_a: np.ndarray = field(repr=False)
    control_dt_s: float

    def parameters(self, **overrides) -> dict:
        """The scenario's parameter set (``load_parameters``), with ``overrides`` on top."""
        return load_parameters(self.cylinder, **{**self.settings, **overrides})

    @property
    def params(self) -> dict:
        return self.parameters()

    @property
    def duration_s(self) -> float:
        return len(self.coil_current_a) * self.control_dt_s


def _steps(duration_s: float, control_dt_s: float) -> int:
    if not (duration_s > 0 and control_dt_s > 0):
        raise ValueError(
            f"duration_s = {duration_s} and control_dt_s = {control_dt_s} must both be > 0"
        )
    return max(1, int(round(duration_s / control_dt_s)))


def clamped_step_scenario(
    tube_length_m: float,
    coupling: str = "command",
    duration_s: float = STEP_DURATION_S,
    control_dt_s: float = STEP_SAMPLE_S,
    cylinder: str = DEFAULT_CYLINDER,
) -> Scenario:
    """(b): rod clamped at mid-stroke, coil current stepped to 0.5 A at t = 0 (Figs. 15-16)."""
    settings = dict(
        tube_length_m=tube_length_m,
        tube_coupling=coupling,
        piston_mode="fixed",
        fixed_position_m=0.0,
    )
    n = _steps(duration_s, control_dt_s)
    return Scenario(
        f"(b) step, {tube_length_m:g} m tube, {coupling} coupling",
        cylinder,
        settings,
        np.full(n, STEP_CURRENT_A),
        control_dt_s,
    )


def free_sine_scenario(
    cylinder: str,
    duration_s: float = SINE_DURATION_S,
    control_dt_s: float = SINE_CONTROL_DT_S,
    amplitude_a: float = SINE_AMPLITUDE_A,
    tube_length_m: float | None = SINE_TUBE_M,
) -> Scenario:
    """(c): rod free, no load, i_c = A sin(2 pi 5 Hz t) held per period (Figs. 17-18)."""
    settings = dict(piston_mode="free", load_mass_kg=0.0, load_force_n=0.0)
    if tube_length_m is not None:
        settings["tube_length_m"] = tube_length_m
    n = _steps(duration_s, control_dt_s)
    t = control_dt_s * np.arange(n)
    return Scenario(
        f"(c) sine, {cylinder}",
        cylinder,
        settings,
        amplitude_a * np.sin(2.0 * np.pi * SINE_FREQUENCY_HZ * t),
        control_dt_s,
    )


def run_scenario(scenario: Scenario, substeps: int | None = None, **overrides) -> dict:
    """Simulate a scenario (rows at t_k, row 0 the initial state); ``overrides`` change
    parameters."""
    return simulate_currents(
        scenario.parameters(**overrides),
        scenario.coil_current_a,
        scenario.control_dt_s,
        substeps=substeps,
    )


# --------------------------------------------------------------------------- (a) valve


def _flow_args(p: dict) -> tuple:
    """Constant arguments of ``orifice_mass_flow`` after the pressures (Eqs. 40, 52)."""
    return orifice_gas_constants(
        p["heat_capacity_ratio"],
        p["gas_constant_j_per_kg_k"],
        p["temperature_k"],
        p["flow_linear_ratio"],
    )


def _area(p: dict, spool_m: float) -> float:
    return orifice_area(spool_m, p["hole_radius_m"], p["spool_half_width_m"], p["holes_per_path"])


def _spool(p: dict, current_a: float) -> float:
    return steady_spool_position(current_a, p["spool_spring_n_per_m"], p["coil_force_n_per_a"])


def valve_flow_vs_current(
    params: dict, currents_a=VALVE_CURRENTS_A, chamber_pa: float | None = None
) -> dict:
    """Steady valve flow from supply into a chamber held at ``chamber_pa`` (default ambient).

    The spool sits at its steady position (Eq. 46); path A (supply -> chamber 1) opens with
    A_in(x_s), path B (supply -> chamber 2) with A_ex(x_s) = A_in(-x_s) (Eqs. 44-45);
    the flow is Eq. 39 with the paper's reduced flow (Eq. 52, linearised above
    ``flow_linear_ratio`` as in the kernel); effect parameters beyond the paper (e.g.
    ``flow_law``) are not applied. Returns ``current_a``, ``chamber1_kg_s``, ``chamber2_kg_s``.
    """
    p = params
    chamber = p["ambient_pressure_pa"] if chamber_pa is None else float(chamber_pa)
    args = _flow_args(p)
    currents = np.asarray(currents_a, dtype=float)
    one, two = [], []
    for i in currents:
        x_s = _spool(p, i)
        one.append(
            orifice_mass_flow(
                _area(p, x_s), p["discharge_coefficient"], p["supply_pressure_pa"], chamber, *args
            )
        )
        two.append(
            orifice_mass_flow(
                _area(p, -x_s), p["discharge_coefficient"], p["supply_pressure_pa"], chamber, *args
            )
        )
    return {"current_a": currents, "chamber1_kg_s": np.array(one), "chamber2_kg_s": np.array(two)}


def valve_flow_vs_downstream(params: dict, current_a: float, downstream_pa) -> np.ndarray:
    """Steady flow through path A at ``current_a`` from supply to ``downstream_pa`` (Fig. 9)."""
    p = params
    area = _area(p, _spool(p, current_a))
    args = _flow_args(p)
    return np.array(
        [
            orifice_mass_flow(
                area, p["discharge_coefficient"], p["supply_pressure_pa"], float(pd), *args
            )
            for pd in np.asarray(downstream_pa)
        ]
    )


def valve_numbers(params: dict) -> dict:
    """Spool displacement at 0.5 A (Eq. 46), full-open area (Eq. 44) and its choked flow
    (Eq. 39)."""
    p = params
    full_area = p["holes_per_path"] * math.pi * p["hole_radius_m"] ** 2
    fully_open_spool = p["spool_half_width_m"] + p["hole_radius_m"]  # x_e = 2 R_h
    full_current = fully_open_spool * 2.0 * p["spool_spring_n_per_m"] / p["coil_force_n_per_a"]
    return {
        "spool_displacement_at_step_m": _spool(p, STEP_CURRENT_A),
        "full_open_area_m2": _area(p, fully_open_spool),
        "full_open_area_formula_m2": full_area,
        "full_open_current_a": full_current,
        "choked_flow_full_open_kg_s": orifice_mass_flow(
            full_area,
            p["discharge_coefficient"],
            p["supply_pressure_pa"],
            p["ambient_pressure_pa"],
            *_flow_args(p),
        ),
    }


# --------------------------------------------------------------------------- (b) clamped step


def clamped_step_runs(
    duration_s: float = STEP_DURATION_S,
    control_dt_s: float = STEP_SAMPLE_S,
    substeps: int | None = None,
) -> dict:
    """(b) for both tubes and both couplings: ``{(coupling, tube_m): run}``."""
    return {
        (c, L): run_scenario(clamped_step_scenario(L, c, duration_s, control_dt_s), substeps)
        for c in COUPLINGS
        for L in STEP_TUBES_M
    }


def first_rise_s(run: dict, params: dict) -> float:
    """Time at which p1 first exceeds its initial value by RISE_FRACTION (supply - ambient).

    Linear interpolation between samples. NaN if it never does.
    """
    threshold = run["p1"][0] + RISE_FRACTION * (
        params["supply_pressure_pa"] - params["ambient_pressure_pa"]
    )
    return _crossing(run["t"], run["p1"], threshold)


def _crossing(t, y, level) -> float:
    above = np.flatnonzero(y >= level)
    if above.size == 0:
        return float("nan")
    k = int(above[0])
    if k == 0:
        return float(t[0])
    return float(t[k - 1] + (level - y[k - 1]) / (y[k] - y[k - 1]) * (t[k] - t[k - 1]))


def steady_force_n(params: dict) -> float:
    """Clamped rod, chamber 1 at supply, chamber 2 at ambient: F = (P_s - P_a) A1 (Eq. 1)."""
    a1, _, _ = piston_areas_m2(params["bore_diameter_m"], params["rod_diameter_m"])
    return (params["supply_pressure_pa"] - params["ambient_pressure_pa"]) * a1


def time_to_final_force_s(run: dict, params: dict) -> float:
    """Time from the step until the force first reaches FINAL_FRACTION of the steady force."""
    return _crossing(run["t"], run["f"], FINAL_FRACTION * steady_force_n(params))


def step_metrics(runs: dict) -> dict:
    """Numbers of (b): delays, extra delay of the long tube, times to final force, ratios."""
    short, long_ = STEP_TUBES_M
    out = {}
    for coupling in COUPLINGS:
        params = {L: clamped_step_scenario(L, coupling).params for L in STEP_TUBES_M}
        rise = {L: first_rise_s(runs[(coupling, L)], params[L]) for L in STEP_TUBES_M}
        final = {L: time_to_final_force_s(runs[(coupling, L)], params[L]) for L in STEP_TUBES_M}
        tau = {L: _tube_delay_s(L, params[L]) for L in STEP_TUBES_M}
        out[coupling] = {
            "first_rise_s": {str(L): rise[L] for L in STEP_TUBES_M},
            "extra_delay_s": rise[long_] - rise[short],
            "expected_extra_delay_s": tau[long_] - tau[short],
            "time_to_final_force_s": {str(L): final[L] for L in STEP_TUBES_M},
            "final_force_time_ratio": final[long_] / final[short],
            "steady_force_n": steady_force_n(params[short]),
            "p1_oscillation_amplitude_pa": {
                str(L): _half_range_at_end(runs[(coupling, L)], "p1") for L in STEP_TUBES_M
            },
            "spool_position_at_end_m": runs[(coupling, short)]["x_s"][-1],
        }
    return out


def _half_range_at_end(run: dict, name: str) -> float:
    window = run["t"] >= run["t"][-1] - OSCILLATION_WINDOW_S
    return 0.5 * float(np.ptp(run[name][window]))


def _sound_speed(p: dict) -> float:
    return sound_speed(p["heat_capacity_ratio"], p["gas_constant_j_per_kg_k"], p["temperature_k"])


def _tube_delay_s(length_m: float, p: dict) -> float:
    return tube_delay_s(
        length_m, p["heat_capacity_ratio"], p["gas_constant_j_per_kg_k"], p["temperature_k"]
    )


# --------------------------------------------------------------------------- (c) free sine


def free_sine_runs(duration_s: float = SINE_DURATION_S, substeps: int | None = None) -> dict:
    """(c) for both cylinders: ``{cylinder: run}`` (the run also holds ``i_c``)."""
    runs = {}
    for cylinder in CYLINDERS:
        s = free_sine_scenario(cylinder, duration_s)
        run = run_scenario(s, substeps)
        run["i_c"] = np.append(s.coil_current_a, s.coil_current_a[-1])
        runs[cylinder] = run
    return runs


# --------------------------------------------------------------------------- (d) tube


@njit(cache=True)
def _resistance(mass_flow, diameter_m, viscosity, reynolds_turbulent):
    """R_t (Eq. 33 or 35) of each flow value, by its Reynolds number."""
    out = np.empty(mass_flow.shape[0])
    for j in range(mass_flow.shape[0]):
        re = reynolds_number(mass_flow[j], diameter_m, viscosity)
        out[j] = tube_resistance(re, diameter_m, viscosity, reynolds_turbulent)
    return out


def tube_response(
    params: dict | None = None,
    duration_s: float = TUBE_DURATION_S,
    length_m: float = TUBE_LENGTH_M,
    amplitude_kg_s: float = TUBE_FLOW_AMPLITUDE_KG_S,
    frequency_hz: float = TUBE_FLOW_FREQUENCY_HZ,
    mean_pressure_pa: float = TUBE_MEAN_PRESSURE_PA,
    cells: int = TUBE_CELLS,
) -> dict:
    """(d) Outlet flow of a tube for a sinusoidal inlet flow h(t) = A sin(2 pi f t).

    ``outlet_eq31``: Eq. 31, h(t - tau) phi with phi of Eq. 30 at ``mean_pressure_pa`` and
    R_t by the Reynolds number of the delayed inlet flow (``physics.tube.tube_attenuation``).
    ``outlet_wave``: Eqs. 19-20 (linearised about ``mean_pressure_pa``, R_t by the local
    Reynolds number) solved by the method of characteristics on ``cells`` cells with the
    grid step c dt; the outlet is non-reflecting (no incoming wave), the inlet imposes h.
    With q = (A_t / c) P, the Riemann variables a = m + q, b = m - q obey
    da/dt + c da/ds = -(R_t / rho) m and db/dt - c db/ds = -(R_t / rho) m, integrated
    along the characteristics with Heun's method.
    """
    p = load_parameters(DEFAULT_CYLINDER) if params is None else params
    gas_rt = p["gas_constant_j_per_kg_k"] * p["temperature_k"]
    c = _sound_speed(p)
    tau = _tube_delay_s(length_m, p)
    diameter, mu = p["tube_inner_diameter_m"], p["air_viscosity_pa_s"]
    re_t = p["reynolds_turbulent"]
    omega = 2.0 * np.pi * frequency_hz

    def inlet(t):
        return amplitude_kg_s * np.sin(omega * t) * (np.asarray(t) >= 0.0)

    dt = length_m / cells / c
    n_steps = int(math.ceil(duration_s / dt))
    t = dt * np.arange(n_steps + 1)
    rho = mean_pressure_pa / gas_rt
    a = np.zeros(cells + 1)
    b = np.zeros(cells + 1)
    outlet = np.zeros(n_steps + 1)

    def source(a_, b_):
        m = 0.5 * (a_ + b_)
        return -_resistance(m, diameter, mu, re_t) / rho * m

    for n in range(n_steps):
        h_new = float(inlet(t[n + 1]))
        s0 = source(a, b)
        a1, b1 = np.empty_like(a), np.empty_like(b)
        a1[1:] = a[:-1] + dt * s0[:-1]
        b1[:-1] = b[1:] + dt * s0[1:]
        b1[-1] = 0.0
        a1[0] = 2.0 * h_new - b1[0]
        s1 = source(a1, b1)
        a[1:], b[:-1] = (
            a[:-1] + 0.5 * dt * (s0[:-1] + s1[1:]),
            b[1:] + 0.5 * dt * (s0[1:] + s1[:-1]),
        )
        b[-1] = 0.0
        a[0] = 2.0 * h_new - b[0]
        outlet[n + 1] = 0.5 * (a[-1] + b[-1])

    delayed = inlet(t - tau)
    phi = np.array(
        [tube_attenuation(m, mean_pressure_pa, gas_rt, tau, diameter, mu, re_t) for m in delayed]
    )
    phi_laminar = tube_attenuation(0.0, mean_pressure_pa, gas_rt, tau, diameter, mu, re_t)
    steady = t >= 2.0 * tau + 1.0 / frequency_hz  # after the first wave and one period
    return {
        "t": t,
        "inlet_kg_s": inlet(t),
        "outlet_eq31_kg_s": phi * delayed,
        "outlet_eq31_laminar_kg_s": phi_laminar * delayed,
        "outlet_wave_kg_s": outlet,
        "delay_s": tau,
        "phi_at_peak_flow": tube_attenuation(
            amplitude_kg_s, mean_pressure_pa, gas_rt, tau, diameter, mu, re_t
        ),
        "phi_laminar": phi_laminar,
        "amplitude_ratio_eq31": float(np.abs(phi * delayed)[steady].max() / amplitude_kg_s),
        "amplitude_ratio_wave": float(np.abs(outlet)[steady].max() / amplitude_kg_s),
        "mean_pressure_pa": mean_pressure_pa,
    }
