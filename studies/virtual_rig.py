"""The virtual rig: synthetic recordings from a plant of higher fidelity than the fit model.

``pneumatic-env rig --effect NAME --strength S --out DIR --seed N`` writes
``DIR/NAME.csv`` + ``.json`` (:func:`pneumatic_env.recording.write_recording`) and
``DIR/NAME.truth.json`` (what the plant really was, for evaluation only; the diagnosis
never reads it, nor the sidecar's notes). The sidecar's notes say "synthetic (virtual
rig)". Several effects at once: :mod:`.rig_multi_effect` (``--effects``); the rig's draw,
sample grid and sensors: :mod:`.rig_sampling`.

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
                                    (``segmented_line``; any rod) instead of the kernel
                                    (a transmission line, friction lumped at its ends)
  valve_null_leak, tube_volume,     the rig's own forms (:mod:`.rig_forms`: a laminar
  iso_flow_law,                     clearance flow, tube volumes as states of their own, ISO
  exhaust_discharge, stribeck       6358-2 with m = 0.6, a ratio-dependent exhaust C_f, a
                                    Lorentzian Stribeck curve); ``own_forms=False`` puts the
                                    kernel's parameter (the candidate's form) in the plant
  ================================  ==========================================================
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pneumatic_env.identification.config import IdentificationConfig, load_config
from pneumatic_env.params import load_parameters, parameter_array
from pneumatic_env.physics import layout as L
from pneumatic_env.recording import PISTON_MODES, write_recording
from pneumatic_env.simulator import BatchSimulator

from .rig_excitation import UserExcitation, excitation
from .rig_forms import OWN_FORM_EFFECTS, own_form
from .rig_plants import _coil_plant, _plant_form, _stick_slip_play
from .rig_sampling import _SampleGrid, _sensor_channels, rig_drive
from .segmented_line import line_constants, segmented_line_rollout

__all__ = [
    "KERNEL_EFFECTS",
    "LINE_EFFECTS",
    "MOVING_EFFECTS",
    "RIG_EFFECTS",
    "SPLIT_EFFECTS",
    "RigResult",
    "excitation",
    "make_recording",
    "run_rig",
    "write_rig_result",
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


# --------------------------------------------------------------------------- plant


@dataclass
class RigResult:
    """A synthetic recording and the truth behind it."""

    t: np.ndarray
    channels: dict[str, np.ndarray]
    rig: dict
    truth: dict = field(default_factory=dict)


def run_rig(
    effect: str = "none",
    strength: float = 1.0,
    seed: int = 0,
    duration_s: float | None = None,
    cylinder: str = "numatics",
    tube_length_m: float = 0.5,
    piston: str = "fixed",
    excitation_kind: str | UserExcitation = "identification",
    perturb: bool = True,
    experiment: int | None = None,
    spring_rest_position_m: float = 0.0,
    own_forms: bool = True,
    config: IdentificationConfig | None = None,
    spring_stiffness_n_per_m: float | None = None,
    load_mass_kg: float | None = None,
) -> RigResult:
    """Simulate the virtual rig; returns the recording's samples, sidecar and truth.

    ``seed`` draws the rig (its perturbed parameters); with ``experiment`` (an integer)
    the excitation and the noise come from their own stream ``(seed, experiment)``, so
    several experiments on the same rig have independent draws (a campaign,
    :mod:`.rig_campaign`); without it they come from the rig's stream, after the rig.
    ``spring_rest_position_m`` (``piston="spring"``): the spring's rest position; the rod
    starts at 0 with both chambers sealed at ambient, so a rest position off 0 pulls it
    and expands one chamber below ambient (a physical sub-ambient pressure).
    ``own_forms``: the effects of :data:`.rig_forms.OWN_FORM_EFFECTS` in the rig's own form
    (default); False puts the kernel's parameter (the candidate's form) in the plant.
    ``spring_stiffness_n_per_m``, ``load_mass_kg`` (a moving rod): the experiment's own
    spring and load instead of the config's (``virtual_rig.spring_*``; free: no load).

    Stages: the rig (piston, perturbed parameters), the effect on its parameters, the
    excitation and the coil drive, the plant, the sensors (:func:`_sensor_channels`).
    """
    cfg = config or load_config()
    _check_rig_arguments(effect, strength, piston)
    drive = rig_drive(
        seed,
        duration_s,
        cylinder,
        tube_length_m,
        piston,
        excitation_kind,
        perturb,
        experiment,
        spring_rest_position_m,
        cfg,
        spring_stiffness_n_per_m,
        load_mass_kg,
    )
    cylinder, true, rng, grid, i_c = drive.cylinder, drive.true, drive.rng, drive.grid, drive.i_c
    ref = float(cfg.number("virtual_rig", "effects", effect)) if effect != "none" else 0.0
    s = float(strength)
    own = own_forms and effect in OWN_FORM_EFFECTS and s > 0.0
    true, own_truth = _effect_parameters(effect, s, ref, true, own, cylinder, cfg)
    truth_parameters = dict(true)
    fine = _coil_drive(effect, s, ref, i_c, grid, true, truth_parameters, cfg)
    rows, plant = _plant_rows(
        effect, s, ref, fine, grid, true, truth_parameters, own, own_truth, cylinder, piston, cfg
    )
    t, channels = _sensor_channels({effect: s * ref}, rows, i_c, grid, piston, rng, cfg)
    rig = drive.sidecar
    truth = {
        "effect": effect,
        "strength": s,
        "seed": int(seed),
        "experiment": experiment,
        "excitation": excitation_kind,
        "duration_s": grid.duration_s,
        "perturbed": bool(perturb),
        "effect_reference": ref,
        "plant": plant,
        "parameters": {k: float(v) for k, v in truth_parameters.items()},
    }
    if isinstance(excitation_kind, tuple):  # a UserExcitation: its settings by name
        truth["excitation"] = excitation_kind._asdict()
    return RigResult(t=t, channels=channels, rig=rig, truth=truth)


def _check_rig_arguments(effect: str, strength: float, piston: str) -> None:
    """Refuse, by name, an unknown effect, a bad strength or piston, or a pair the rig
    cannot make."""
    if effect not in RIG_EFFECTS:
        raise ValueError(
            f"effect {effect!r} is not known to the virtual rig; allowed: {', '.join(RIG_EFFECTS)}"
        )
    if not (isinstance(strength, (int, float)) and math.isfinite(strength) and strength >= 0):
        raise ValueError(f"strength = {strength!r} is not allowed: must be a finite number >= 0")
    if piston not in PISTON_MODES:
        raise ValueError(f"piston = {piston!r} is not allowed: must be one of {list(PISTON_MODES)}")
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


def _effect_parameters(
    effect: str,
    s: float,
    ref: float,
    true: dict,
    own: bool,
    cylinder: str,
    cfg: IdentificationConfig,
) -> tuple[dict, dict]:
    """(the plant's parameters with a kernel-form effect or the load cell in them, the
    nearest kernel form of the effect for the truth)."""
    own_truth: dict = {}
    if effect in KERNEL_EFFECTS:
        name, rule = KERNEL_EFFECTS[effect]
        own_truth[name] = rule(s, ref)  # the nearest kernel form, stated in the truth
        if effect == "iso_flow_law":
            own_truth["flow_law"] = 1
        if effect == "tube_volume":
            own_truth["tube_air_model"] = 1  # the candidate's form: isothermal tube air
        if not own:  # the kernel's own form (the candidate's): an inverse crime
            true.update(own_truth)
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
    return true, own_truth


def _coil_drive(
    effect: str,
    s: float,
    ref: float,
    i_c: np.ndarray,
    grid: _SampleGrid,
    true: dict,
    truth_parameters: dict,
    cfg: IdentificationConfig,
) -> np.ndarray:
    """The current the plant sees per plant step: the sampled command held, through the
    coil's amplifier and lags or the spool's stick-slip if the effect is there (the
    nearest kernel form goes into ``truth_parameters``)."""
    plant_dt = grid.plant_dt_s
    fine = np.repeat(i_c[:-1], grid.plant_steps_per_sample)
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
    return fine


def _plant_rows(
    effect: str,
    s: float,
    ref: float,
    fine: np.ndarray,
    grid: _SampleGrid,
    true: dict,
    truth_parameters: dict,
    own: bool,
    own_truth: dict,
    cylinder: str,
    piston: str,
    cfg: IdentificationConfig,
) -> tuple[np.ndarray, str]:
    """(the plant's outputs at every plant step from t = 0, the plant's description):
    the kernel, the kernel with the rig's own form of the effect, or segmented lines."""
    plant_dt = grid.plant_dt_s
    plant_substeps = int(cfg.number("virtual_rig", "plant_substeps", positive=True))
    form = None
    if s > 0.0 and effect in SPLIT_EFFECTS:
        form = _plant_form(effect, s, ref, true, truth_parameters, cfg, piston)
    if own:
        truth_parameters.update(own_truth)
        form = own_form(
            effect,
            own_truth[KERNEL_EFFECTS[effect][0]],
            true,
            cfg.number("virtual_rig", "tube_air_thermal_time_constant_s", positive=True),
        )
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
        rows = np.tile(first, (fine.size, 1))  # its velocity column is not recorded
        rows[:, [L.O_P1, L.O_P2, L.O_F, L.O_X]] = line[1:]
        plant = f"segmented line, {segments} volumes per tube"
    elif form is None:
        rows = sim.rollout(fine[:, None])[:, :, 0]
        plant = "kernel and the rig's own form" if own else "kernel"
    else:
        rows = np.empty((fine.size, L.N_OUTPUT))
        h = plant_dt / steps_per_plant_step
        for k in range(fine.size):
            for _ in range(steps_per_plant_step):
                form.before_step(sim, k, h)
                rows[k] = sim.step(fine[k : k + 1])[:, 0]
            form.correct_output(rows[k])
        plant = "kernel and the rig's own form" if own else "kernel"
    return np.vstack([first[None, :], rows]), plant  # rows[j] = state at j * plant_dt


def make_recording(out_dir, name: str | None = None, overwrite: bool = False, **kwargs) -> Path:
    """Run the rig and write ``out_dir/NAME.csv``, ``.json`` and ``NAME.truth.json``."""
    result = run_rig(**kwargs)
    if name is None:
        tr = result.truth
        name = f"rig_{tr['effect']}_s{tr['strength']:g}_seed{tr['seed']}"
    return write_rig_result(out_dir, name, result, overwrite)


def write_rig_result(out_dir, name: str, result: RigResult, overwrite: bool = False) -> Path:
    """Write ``out_dir/NAME.csv``, ``.json`` (the recording) and ``NAME.truth.json``."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    path = write_recording(
        out_dir / name, result.t, result.channels, result.rig, overwrite=overwrite
    )
    truth_path = out_dir / f"{name}.truth.json"
    if truth_path.exists() and not overwrite:
        raise FileExistsError(f"{truth_path} exists; pass overwrite=True to replace it")
    truth_path.write_text(json.dumps(result.truth, indent=2) + "\n", encoding="utf-8")
    return path
