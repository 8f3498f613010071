"""The virtual rig: synthetic recordings from a plant of higher fidelity than the fit model.

``pneumatic-env rig --effect NAME --strength S --out DIR --seed N`` writes
``DIR/NAME.csv`` + ``.json`` (:func:`pneumatic_env.recording.write_recording`) and
``DIR/NAME.truth.json`` (what the plant really was, for evaluation only; the diagnosis
never reads it, nor the sidecar's notes). The sidecar's notes say "synthetic (virtual
rig)".

How the plant differs from the fitting model:

- its base parameters are drawn around the configs' defaults (log-normal, relative
  standard deviations under ``virtual_rig.perturbation``); the sidecar states only the
  nominal rig (cylinder, tube, nominal supply pressure, rod mode);
- it is simulated 10x finer (``plant_dt_s``, ``plant_substeps``) and sampled at
  ``sample_dt_s`` (decimation: every 10th plant sample, the coil current held over each
  sample period as a digital controller would);
- sensor noise (white, Gaussian) and ADC quantisation on every measured channel;
- an optional extra effect at a strength S (strength 1 = ``virtual_rig.effects``).
  Where feasible the plant's form of the effect differs from the candidate model's:

  ================================  ==========================================================
  effect                            plant form (candidate form in brackets)
  ================================  ==========================================================
  leakage, rod_seal_leak            laminar leak, flow proportional to the pressure
                                    difference, applied between plant steps (orifice, Eq. 39)
  coil_lag                          the amplifier holds the current over its 0.2 ms period,
                                    then a current lag and a force lag of 0.65 T and 0.35 T
                                    (two cascaded lags of total T, no hold)
  pressure_sensor_lag               two cascaded lags of tau/2 at the plant rate (one lag at
                                    the sample rate)
  pressure_sensor_offset            offsets that drift by 10 % over the recording (constant)
  channel_time_skew                 exact shift at the plant rate (interpolated shift)
  load_cell_compliance              rod held by a spring of stiffness k_ref / S at the clamp,
                                    sliding friction off (pre-sliding), the cell's moving mass
                                    on the rod (the same spring mode; the candidate refits the
                                    mass, so this is close to an inverse crime)
  spool_friction                    stick-slip play on the current: the spool breaks away at
                                    1.3 x the Coulomb band and then slides at it (a play of
                                    the Coulomb band, ``spool_coulomb_friction_n``)
  supply_ripple                     not in the catalog: 3 Hz supply-pressure oscillation
  lugre                             LuGre friction on the Stribeck curve with a bristle damping
                                    that falls with speed, sigma1 exp(-(v/v_d)^2) (Canudas de
                                    Wit et al. 1995), a load force every 10 us plant substep
                                    (the kernel's LuGre: a constant sigma1, once per substep)
  supply_droop                      a supply line of volume V fed through the regulator's
                                    resistance R (a lag of R V / (R_gas T), 20 ms at S = 1),
                                    drained by the valve (R alone: the droop is immediate)
  exhaust_muffler                   an exhaust muffler: a volume of 10 cm^3 (a state: the
                                    back-pressure lags the flow) vented through an orifice of
                                    about the valve's opening at the excitation's steps / S,
                                    explicit steps at the plant rate fed by the valve's flow
                                    at the spool's present opening (the kernel's muffler node:
                                    a backward-Euler step per substep at the delayed opening,
                                    held over it; close to an inverse crime)
  heat_transfer                     wall exchange per chamber with hA proportional to the gas
                                    density to the 2/3 (natural convection), applied between
                                    plant steps on the full energy equation (one constant hA)
  tube_waves                        each tube a segmented line of finite volumes with the
                                    air's inertia and the friction along the line
                                    (``segmented_line``; rod clamped) instead of the kernel
                                    (a transmission line, friction lumped at its ends)
  valve_null_leak, tube_volume,     **same form** as the candidate (the kernel's parameter):
  iso_flow_law,                     an inverse crime, softened only by the finer step, the
  exhaust_discharge (orifice)       perturbed base and the noise
  stribeck
  ================================  ==========================================================
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.signal import cont2discrete, lfilter, lfilter_zi

from pneumatic_env.identification.config import IdentificationConfig, load_config
from pneumatic_env.params import load_parameters, parameter_array
from pneumatic_env.physics import layout as L
from pneumatic_env.physics.chamber import chamber_volumes
from pneumatic_env.physics.effects import lugre_bristle_step, stribeck_friction
from pneumatic_env.physics.flow import flow_constants, orifice_mass_flow, subsonic_reduced_flow
from pneumatic_env.physics.valve import orifice_area
from pneumatic_env.recording import PISTON_MODES, canonical_cylinder, write_recording
from pneumatic_env.references import ChirpReference, MultisineReference
from pneumatic_env.simulator import BatchSimulator

from .segmented_line import line_constants, segmented_line_rollout

__all__ = [
    "KERNEL_EFFECTS",
    "LINE_EFFECTS",
    "RIG_EFFECTS",
    "SPLIT_EFFECTS",
    "MOVING_EFFECTS",
    "RigResult",
    "excitation",
    "make_recording",
    "run_rig",
    "add_arguments",
    "run",
]

#: Rig effects realised by a kernel parameter (same form as the candidate): name ->
#: (kernel parameter, value at strength S given the strength-1 reference r).
KERNEL_EFFECTS = {
    "valve_null_leak": ("valve_null_leak_area_m2", lambda s, r: s * r),
    "tube_volume": ("tube_volume_fraction", lambda s, r: min(1.0, s * r)),
    "iso_flow_law": ("iso_critical_ratio_b", lambda s, r: 0.528 - s * (0.528 - r)),
    "stribeck": ("stribeck_velocity_m_per_s", lambda s, r: s * r),
    "exhaust_discharge": ("exhaust_discharge_ratio", lambda s, r: 1.0 - s * (1.0 - r)),
    "tube_waves": ("tube_waves", lambda s, r: r if s > 0.0 else 0.0),  # a switch
}
#: Every effect the rig can add.
RIG_EFFECTS = (
    "none",
    "leakage",
    "rod_seal_leak",
    "coil_lag",
    "spool_friction",
    "pressure_sensor_offset",
    "pressure_sensor_lag",
    "channel_time_skew",
    "load_cell_compliance",
    "supply_ripple",
    "heat_transfer",
    "supply_droop",
    "exhaust_muffler",
    "lugre",
    *KERNEL_EFFECTS,
)
#: Rig effects whose plant is not the kernel: the tubes as segmented lines
#: (``segmented_line``); their ``KERNEL_EFFECTS`` entry states the nearest kernel form in
#: the truth.
LINE_EFFECTS = ("tube_waves",)
#: Rig effects applied by operator splitting between steps of the kernel.
SPLIT_EFFECTS = (
    "leakage",
    "rod_seal_leak",
    "supply_ripple",
    "heat_transfer",
    "supply_droop",
    "exhaust_muffler",
    "lugre",
)
#: Rig effects of the piston's friction: they need a moving piston (``spring`` or ``free``).
MOVING_EFFECTS = ("stribeck", "lugre")
EXCITATIONS = ("identification", "steps", "prbs", "multisine", "chirp", "triangle")
_SEGMENTS = ("rest", "step_pos", "step_neg", "prbs", "multisine", "chirp", "triangle")


# --------------------------------------------------------------------------- excitation


def _segment(
    kind: str, n: int, dt: float, rng: np.random.Generator, cfg: IdentificationConfig
) -> np.ndarray:
    ex = lambda name: cfg.value("virtual_rig", "excitation", name)  # noqa: E731
    if n <= 0:
        return np.zeros(0)
    if kind == "rest":
        return np.zeros(n)
    if kind in ("step_pos", "step_neg"):
        return np.full(n, float(ex("step_a")) * (1.0 if kind == "step_pos" else -1.0))
    if kind == "prbs":
        hold = max(1, int(round(float(ex("prbs_hold_s")) / dt)))
        levels = rng.choice([-1.0, 1.0], size=n // hold + 1)
        return float(ex("prbs_a")) * np.repeat(levels, hold)[:n]
    if kind == "multisine":
        f_lo, f_hi = (float(f) for f in ex("multisine_band_hz"))
        period = n * dt
        k = np.arange(max(1, math.ceil(f_lo * period)), max(2, math.floor(f_hi * period)) + 1)
        spec = MultisineReference(
            amplitude=float(ex("multisine_a")), frequencies_hz=tuple(k / period), phases="random"
        )
        return spec.generate(n, dt, rng)
    if kind == "chirp":
        f0, f1 = (float(f) for f in ex("chirp_band_hz"))
        return ChirpReference(
            amplitude=float(ex("chirp_a")), f0_hz=f0, f1_hz=f1, duration_s=n * dt
        ).generate(n, dt)
    if kind == "triangle":
        a = float(ex("triangle_a"))
        phase = np.arange(n) / n  # one period: 0 -> +a -> -a -> 0
        return a * np.where(
            phase < 0.25, 4 * phase, np.where(phase < 0.75, 2 - 4 * phase, 4 * phase - 4)
        )
    raise ValueError(f"excitation segment {kind!r} is not known; allowed: {', '.join(_SEGMENTS)}")


def excitation(
    kind: str,
    n_samples: int,
    dt_s: float,
    rng: np.random.Generator,
    config: IdentificationConfig | None = None,
) -> np.ndarray:
    """Coil current (A) for identification, ``n_samples`` at ``dt_s``.

    ``identification``: two blocks of ``virtual_rig.excitation.block_layout`` (rest
    periods, steps of both signs, PRBS, multisine, chirp, slow triangle) sized
    ``train_fraction`` and the rest of the recording, so a time split holds out the same
    kinds of segment. The other kinds are one segment type over the whole recording
    (``steps`` alternates +/- steps with rests).
    """
    cfg = config or load_config()
    if kind not in EXCITATIONS:
        raise ValueError(f"excitation {kind!r} is not known; allowed: {', '.join(EXCITATIONS)}")
    if kind == "identification":
        split = int(round(cfg.number("fit", "train_fraction") * n_samples))
        layout = cfg.value("virtual_rig", "excitation", "block_layout")
        parts = []
        for n_block in (split, n_samples - split):
            shares = np.array([float(s) for _, s in layout])
            bounds = np.round(np.concatenate([[0], np.cumsum(shares) / shares.sum()]) * n_block)
            for (seg, _), a, b in zip(layout, bounds[:-1], bounds[1:]):
                parts.append(_segment(seg, int(b - a), dt_s, rng, cfg))
        return np.concatenate(parts)
    if kind == "steps":
        quarter = n_samples // 4
        out = np.concatenate(
            [_segment(s, quarter, dt_s, rng, cfg) for s in ("step_pos", "rest", "step_neg", "rest")]
        )
        return np.concatenate([out, np.zeros(n_samples - out.size)])
    return _segment(kind, n_samples, dt_s, rng, cfg)


# --------------------------------------------------------------------------- plant


@dataclass
class RigResult:
    """A synthetic recording and the truth behind it."""

    t: np.ndarray
    channels: dict[str, np.ndarray]
    rig: dict
    truth: dict = field(default_factory=dict)


def _two_lags(y: np.ndarray, total_tau_s: float, dt_s: float) -> np.ndarray:
    """Two cascaded first-order lags of ``total_tau_s / 2`` (exact for a held input)."""
    if total_tau_s <= 0:
        return y
    a = math.exp(-dt_s / (0.5 * total_tau_s))
    for _ in range(2):
        y, _ = lfilter([1.0 - a], [1.0, -a], y, zi=[a * y[0]])
    return y


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
    den = np.polymul([(1.0 - force_share) * total_tau_s, 1.0], [force_share * total_tau_s, 1.0])
    num, den = cont2discrete(([1.0], np.trim_zeros(den, "f")), dt_s, method="zoh")[:2]
    num = np.ravel(num)
    # lfilter's y[n] is the value at sample n with the input held over the step before it
    padded = np.append(held, held[-1])
    y, _ = lfilter(num, den, padded, zi=lfilter_zi(num, den) * held[0])
    return y[1:]


def _stick_slip_play(current_a: np.ndarray, band_a: float, breakaway_a: float) -> np.ndarray:
    """The current a spool with Coulomb and static friction follows (quasi-static).

    Stuck, the spool holds its current ``h`` until the command leaves ``h +/- breakaway_a``
    (static friction); it then slides, held ``band_a`` behind the command (Coulomb
    friction), for as long as the command keeps moving that way. With ``breakaway_a =
    band_a`` this is the candidate's play (``effects.spool_play_current``).
    """
    out = np.empty_like(current_a)
    held, sliding = 0.0, 0.0
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
    return out


def _orifice_gas(p: dict) -> tuple:
    """The gas's arguments of ``orifice_mass_flow`` (Eqs. 39, 40, 52) for parameters ``p``,
    computed once: 1/sqrt(T), k, C1, C2, P_cr, the linear ratio and its slope."""
    c1, c2, pcr = flow_constants(p["heat_capacity_ratio"], p["gas_constant_j_per_kg_k"])
    lin = p["flow_linear_ratio"]
    slope = subsonic_reduced_flow(lin, p["heat_capacity_ratio"], c2) / (1.0 - lin)
    return (1.0 / math.sqrt(p["temperature_k"]), p["heat_capacity_ratio"], c1, c2, pcr, lin, slope)


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
        self.cap_area = 0.25 * math.pi * true["bore_diameter_m"] ** 2
        self.rod_side_area = self.cap_area - 0.25 * math.pi * true["rod_diameter_m"] ** 2
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


def _perturbed(
    cylinder: str, base: dict, rng: np.random.Generator, cfg: IdentificationConfig
) -> dict:
    """``base`` with each parameter under ``virtual_rig.perturbation`` multiplied by
    ``exp(sigma z)``, z standard normal; validated by the loader."""
    out = dict(base)
    for name in cfg.raw["virtual_rig"]["perturbation"]:
        sigma = cfg.number("virtual_rig", "perturbation", name, minimum=0.0)
        out[name] = base[name] * math.exp(sigma * rng.standard_normal())
    return load_parameters(cylinder, params=out)


def run_rig(
    effect: str = "none",
    strength: float = 1.0,
    seed: int = 0,
    duration_s: float | None = None,
    cylinder: str = "numatics",
    tube_length_m: float = 0.5,
    piston: str = "fixed",
    excitation_kind: str = "identification",
    perturb: bool = True,
    config: IdentificationConfig | None = None,
) -> RigResult:
    """Simulate the virtual rig; returns the recording's samples, sidecar and truth."""
    cfg = config or load_config()
    if effect not in RIG_EFFECTS:
        raise ValueError(
            f"effect {effect!r} is not known to the virtual rig; allowed: {', '.join(RIG_EFFECTS)}"
        )
    if not (isinstance(strength, (int, float)) and math.isfinite(strength) and strength >= 0):
        raise ValueError(f"strength = {strength!r} is not allowed: must be a finite number >= 0")
    if piston not in PISTON_MODES:
        raise ValueError(f"piston = {piston!r} is not allowed: must be one of {list(PISTON_MODES)}")
    if effect in LINE_EFFECTS and strength > 0 and piston != "fixed":
        raise ValueError(
            f"effect {effect!r} needs piston = 'fixed' (the segmented line plant "
            f"has a clamped rod); got piston = {piston!r}"
        )
    if effect == "load_cell_compliance" and piston != "fixed":
        raise ValueError(
            f"effect 'load_cell_compliance' needs piston = 'fixed' (a clamped rod "
            f"held through a load cell); got piston = {piston!r}"
        )
    if effect in MOVING_EFFECTS and strength > 0 and piston == "fixed":
        raise ValueError(
            f"effect {effect!r} needs a moving piston ('spring' or 'free'); got piston = 'fixed'"
        )
    if effect in KERNEL_EFFECTS and KERNEL_EFFECTS[effect][0] not in L.PARAMETER_NAMES:
        raise ValueError(
            f"effect {effect!r} needs the kernel parameter "
            f"{KERNEL_EFFECTS[effect][0]!r}, which this kernel does not have"
        )
    rng = np.random.default_rng(seed)
    dt = cfg.number("virtual_rig", "sample_dt_s", positive=True)
    plant_dt = cfg.number("virtual_rig", "plant_dt_s", positive=True)
    ratio = int(round(dt / plant_dt))
    if ratio < 1 or abs(ratio * plant_dt - dt) > 1e-9 * dt:
        raise ValueError("virtual_rig.sample_dt_s must be a whole multiple of plant_dt_s")
    duration = float(
        duration_s if duration_s is not None else cfg.number("virtual_rig", "duration_s")
    )
    n = int(round(duration / dt)) + 1
    cylinder = canonical_cylinder(cylinder)

    piston_rig = {"mode": piston}
    overrides = {"tube_length_m": tube_length_m, "piston_mode": PISTON_MODES[piston][0]}
    if piston == "fixed":
        piston_rig["position_m"] = 0.0
        overrides["fixed_position_m"] = 0.0
    elif piston == "free":
        piston_rig.update(load_mass_kg=0.0, load_force_n=0.0)
        overrides.update(load_mass_kg=0.0, load_force_n=0.0)
    else:
        k_env = cfg.number("virtual_rig", "spring_stiffness_n_per_m", positive=True)
        m_env = cfg.number("virtual_rig", "spring_load_mass_kg", minimum=0.0)
        piston_rig.update(stiffness_n_per_m=k_env, rest_position_m=0.0, load_mass_kg=m_env)
        overrides.update(
            spring_stiffness_n_per_m=k_env, spring_rest_position_m=0.0, load_mass_kg=m_env
        )
    nominal = load_parameters(cylinder, **overrides)
    true = _perturbed(cylinder, nominal, rng, cfg) if perturb else dict(nominal)

    i_c = excitation(excitation_kind, n, dt, rng, cfg)
    ref = float(cfg.number("virtual_rig", "effects", effect)) if effect != "none" else 0.0
    s = float(strength)
    if effect in KERNEL_EFFECTS:
        name, rule = KERNEL_EFFECTS[effect]
        true[name] = rule(s, ref)
        if effect == "iso_flow_law":
            true["flow_law"] = 1
        true = load_parameters(cylinder, params=true)  # validate
    if effect == "load_cell_compliance" and s > 0.0:
        # the clamp is a spring (the cell) at the clamp position; strength scales the
        # compliance 1/k; the cell's moving part adds its mass to the rod; the rod's
        # micrometre motion stays in the seal's pre-sliding range: no sliding friction
        true.update(
            piston_mode=PISTON_MODES["spring"][0],
            spring_stiffness_n_per_m=ref / s,
            static_friction_n=0.0,
            dynamic_friction_n=0.0,
            spring_rest_position_m=true["fixed_position_m"],
            load_mass_kg=cfg.number("virtual_rig", "load_cell_moving_mass_kg", minimum=0.0),
        )
        true = load_parameters(cylinder, params=true)

    fine = np.repeat(i_c[:-1], ratio)
    truth_parameters = dict(true)
    if effect == "coil_lag" and s > 0.0:
        share = cfg.number("virtual_rig", "coil_force_lag_share", minimum=0.0)
        fine = _coil_plant(
            fine,
            s * ref,
            plant_dt,
            cfg.number("virtual_rig", "coil_amplifier_period_s", positive=True),
            share,
        )
        # the nearest kernel coil (the amplifier's hold has no kernel parameter)
        truth_parameters.update(coil_time_constant_s=s * ref, coil_lag_shape=share * (1.0 - share))
    if effect == "spool_friction":
        truth_parameters["spool_coulomb_friction_n"] = s * ref
        band = s * ref / true["coil_force_n_per_a"]
        breakaway = cfg.number("virtual_rig", "spool_breakaway_ratio", minimum=1.0)
        fine = _stick_slip_play(fine, band, breakaway * band)
    plant_substeps = int(cfg.number("virtual_rig", "plant_substeps", positive=True))
    form = None
    if s > 0.0 and effect in SPLIT_EFFECTS:
        form = _plant_form(effect, s, ref, true, truth_parameters, cfg, piston)
    # a stiff form acts before every plant substep (the kernel steps one substep at a time)
    steps_per_plant_step = plant_substeps if form is not None and form.every_substep else 1
    sim = BatchSimulator(
        parameter_array([load_parameters(cylinder, params=true)]),
        plant_dt / steps_per_plant_step,
        plant_substeps // steps_per_plant_step,
    )
    first = sim.outputs[:, 0].copy()
    if effect in LINE_EFFECTS and s > 0.0:
        segments = max(
            2,
            int(
                round(
                    true["tube_length_m"]
                    / cfg.number("virtual_rig", "line_segment_length_m", positive=True)
                )
            ),
        )
        truth_parameters.update(tube_volume_fraction=0.0)  # the line holds its own air
        line = segmented_line_rollout(
            line_constants(true, segments),
            segments,
            fine,
            plant_dt,
            int(cfg.number("virtual_rig", "line_substeps", positive=True)),
        )
        rows = np.tile(first, (fine.size, 1))  # the rod stays at the clamp
        rows[:, [L.O_P1, L.O_P2, L.O_F]] = line[1:]
    elif form is None:
        rows = sim.rollout(fine[:, None])[:, :, 0]
    else:
        rows = np.empty((fine.size, L.N_OUTPUT))
        h = plant_dt / steps_per_plant_step
        for k in range(fine.size):
            for _ in range(steps_per_plant_step):
                form.before_step(sim, k, h)
                rows[k] = sim.step(fine[k : k + 1])[:, 0]
            form.correct_output(rows[k])
    rows = np.vstack([first[None, :], rows])  # rows[j] = state at j * plant_dt

    names = {"p1": L.O_P1, "p2": L.O_P2, "f": L.O_F, "x": L.O_X}
    measured = ("p1", "p2", "f") if piston == "fixed" else ("p1", "p2", "x")
    t = dt * np.arange(n)
    channels = {"i_c": i_c}
    skew_steps = int(round(s * ref / plant_dt)) if effect == "channel_time_skew" else 0
    for ch in measured:
        y = rows[:, names[ch]].copy()
        if effect == "pressure_sensor_lag" and ch in ("p1", "p2"):
            y = _two_lags(y, s * ref, plant_dt)
        idx = np.arange(n) * ratio - skew_steps
        y = y[np.clip(idx, 0, None)]
        if effect == "pressure_sensor_offset" and ch in ("p1", "p2"):
            y = y + s * ref * (1.0 if ch == "p1" else -2.0 / 3.0) * (1.0 + 0.1 * t / t[-1])
        sigma = cfg.number("virtual_rig", "noise", ch, minimum=0.0)
        q = cfg.number("virtual_rig", "quantisation", ch, minimum=0.0)
        y = y + sigma * rng.standard_normal(n)
        if q > 0:
            y = q * np.round(y / q)
        channels[ch] = y

    rig = {
        "cylinder": cylinder,
        "tube_length_m": float(tube_length_m),
        "supply_pressure_pa": float(nominal["supply_pressure_pa"]),
        "ambient_pressure_pa": float(nominal["ambient_pressure_pa"]),
        "temperature_k": float(nominal["temperature_k"]),
        "piston": piston_rig,
        "notes": "synthetic (virtual rig) recording made by pneumatic_env.studies.virtual_rig",
    }
    truth = {
        "effect": effect,
        "strength": s,
        "seed": int(seed),
        "excitation": excitation_kind,
        "duration_s": duration,
        "perturbed": bool(perturb),
        "effect_reference": ref,
        "plant": (
            f"segmented line, {segments} volumes per tube"
            if effect in LINE_EFFECTS and s > 0.0
            else "kernel"
        ),
        "parameters": {k: float(v) for k, v in truth_parameters.items()},
    }
    return RigResult(t=t, channels=channels, rig=rig, truth=truth)


def make_recording(out_dir, name: str | None = None, overwrite: bool = False, **kwargs) -> Path:
    """Run the rig and write ``out_dir/NAME.csv``, ``.json`` and ``NAME.truth.json``."""
    result = run_rig(**kwargs)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    if name is None:
        tr = result.truth
        name = f"rig_{tr['effect']}_s{tr['strength']:g}_seed{tr['seed']}"
    path = write_recording(
        out_dir / name, result.t, result.channels, result.rig, overwrite=overwrite
    )
    truth_path = out_dir / f"{name}.truth.json"
    if truth_path.exists() and not overwrite:
        raise FileExistsError(f"{truth_path} exists; pass overwrite=True to replace it")
    truth_path.write_text(json.dumps(result.truth, indent=2) + "\n", encoding="utf-8")
    return path


# --------------------------------------------------------------------------- CLI


def add_arguments(p) -> None:
    p.add_argument(
        "--effect",
        default="none",
        choices=RIG_EFFECTS,
        help="extra effect in the plant (default: none)",
    )
    p.add_argument(
        "--strength",
        type=float,
        default=1.0,
        help="effect strength; 1 = the realistic value of configs/identification.yaml",
    )
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.add_argument("--seed", type=int, default=0, help="seed of perturbation, excitation and noise")
    p.add_argument("--name", default=None, help="recording name (default: rig_EFFECT_sS_seedN)")
    p.add_argument(
        "--duration",
        type=float,
        default=None,
        metavar="S",
        help="recording length in s (default: virtual_rig.duration_s)",
    )
    p.add_argument("--cylinder", default="numatics")
    p.add_argument("--tube-length", type=float, default=0.5, metavar="M")
    p.add_argument("--piston", default="fixed", choices=tuple(PISTON_MODES))
    p.add_argument("--excitation", default="identification", choices=EXCITATIONS)
    p.add_argument(
        "--no-perturb", action="store_true", help="use the configs' default base parameters exactly"
    )
    p.add_argument("--overwrite", action="store_true")


def run(args) -> int:
    import sys

    try:
        path = make_recording(
            args.out,
            name=args.name,
            overwrite=args.overwrite,
            effect=args.effect,
            strength=args.strength,
            seed=args.seed,
            duration_s=args.duration,
            cylinder=args.cylinder,
            tube_length_m=args.tube_length,
            piston=args.piston,
            excitation_kind=args.excitation,
            perturb=not args.no_perturb,
        )
    except (FileExistsError, ValueError) as exc:
        print(f"pneumatic-env rig: {exc}", file=sys.stderr)
        return 2
    print(
        f"{path}: synthetic (virtual rig) recording, effect {args.effect} "
        f"strength {args.strength:g}, seed {args.seed}"
    )
    return 0
