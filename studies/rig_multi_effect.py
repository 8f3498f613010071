"""The virtual rig with several effects at once: recordings from the closed-loop plant.

:func:`run_rig_effects` records like :func:`.virtual_rig.run_rig` (the same rig draw,
excitation, sample grid, sensors with their noise and quantisation, sidecar) but drives
the plant of :mod:`.rig_plants_closed_loop` open loop with the excitation: one plant for
the recordings and for the closed-loop evaluation, holding several effects
(:data:`RECORDING_EFFECTS`). The sensor effects act on the recorded channels as in the
single-effect rig (``rig_sampling._sensor_channels``). A single-effect recording stays
``run_rig``'s (its own code path, byte for byte as before); where both hold the same
effect the two plants agree (``tests/test_rig_multi_effect.py``).
"""

from __future__ import annotations

import numpy as np

from pneumatic_env.identification.config import IdentificationConfig, load_config

from .rig_excitation import UserExcitation
from .rig_plants_closed_loop import CLOSED_LOOP_EFFECTS, SENSOR_EFFECTS, rig_plant
from .rig_sampling import _sensor_channels, rig_drive
from .virtual_rig import RigResult, _check_rig_arguments

__all__ = ["RECORDING_EFFECTS", "RECORDED_SENSOR_EFFECTS", "parse_effects", "run_rig_effects"]

#: Effects on the recorded channels, applied by the rig's sensors (not the plant).
RECORDED_SENSOR_EFFECTS = (*SENSOR_EFFECTS, "pressure_sensor_offset", "channel_time_skew")
#: Every effect a multi-effect recording can hold.
RECORDING_EFFECTS = tuple(dict.fromkeys((*CLOSED_LOOP_EFFECTS, *RECORDED_SENSOR_EFFECTS)))


def parse_effects(text: str) -> dict[str, float]:
    """``"tube_waves,heat_transfer=0.5"`` -> {tube_waves: 1.0, heat_transfer: 0.5} (strength 1
    = ``virtual_rig.effects``); ``+`` separates as ``,`` does; unknown names are refused."""
    out: dict[str, float] = {}
    for item in filter(None, (t.strip() for t in text.replace("+", ",").split(","))):
        name, _, strength = item.partition("=")
        if name not in RECORDING_EFFECTS:
            raise ValueError(
                f"effect {name!r} is not allowed in a multi-effect rig: use "
                f"{', '.join(RECORDING_EFFECTS)}"
            )
        if name in out:
            raise ValueError(f"effect {name!r} is named twice")
        out[name] = float(strength) if strength else 1.0
    return out


def run_rig_effects(
    effects: dict[str, float],
    seed: int = 0,
    duration_s: float | None = None,
    cylinder: str = "numatics",
    tube_length_m: float = 0.5,
    piston: str = "fixed",
    excitation_kind: str | UserExcitation = "identification",
    perturb: bool = True,
    experiment: int | None = None,
    spring_rest_position_m: float = 0.0,
    config: IdentificationConfig | None = None,
    spring_stiffness_n_per_m: float | None = None,
    load_mass_kg: float | None = None,
) -> RigResult:
    """Record the virtual rig ``seed`` with ``effects`` ({name: strength}) all at once;
    the other arguments as :func:`.virtual_rig.run_rig`'s. The truth lists every effect
    (``effects``, their strength-1 references) and the nearest kernel forms."""
    cfg = config or load_config()
    for effect, strength in effects.items():
        _check_rig_arguments(effect, strength, piston)
        if effect not in RECORDING_EFFECTS:
            raise ValueError(
                f"effect {effect!r} has no multi-effect plant; allowed: "
                f"{', '.join(RECORDING_EFFECTS)}"
            )
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
    grid = drive.grid
    reference = {e: float(cfg.number("virtual_rig", "effects", e)) for e in effects}
    plant = rig_plant(
        drive.true,
        drive.cylinder,
        {e: s for e, s in effects.items() if e not in RECORDED_SENSOR_EFFECTS},
        grid.dt_s,
        grid.plant_dt_s,
        int(cfg.number("virtual_rig", "plant_substeps", positive=True)),
        cfg,
    )
    first = plant.outputs().copy()
    fine = np.repeat(drive.i_c[:-1], grid.plant_steps_per_sample)
    rows = np.vstack([first[None, :], plant.rollout(fine)])  # rows[j]: at j * plant_dt
    sensors = {
        e: float(s) * reference[e]
        for e, s in effects.items()
        if e in RECORDED_SENSOR_EFFECTS and s > 0.0
    }
    t, channels = _sensor_channels(sensors, rows, drive.i_c, grid, piston, drive.rng, cfg)
    active = {e: float(s) for e, s in effects.items() if s > 0.0}
    truth = {
        "effect": "+".join(active) or "none",
        "effects": active,
        "effect_reference": {e: reference[e] for e in active},
        "seed": int(seed),
        "experiment": experiment,
        "excitation": excitation_kind._asdict()
        if isinstance(excitation_kind, tuple)
        else excitation_kind,
        "duration_s": grid.duration_s,
        "perturbed": bool(perturb),
        "plant": "closed-loop plant (studies/rig_plants_closed_loop.py), driven open loop",
        "parameters": {k: float(v) for k, v in plant.truth.items()},
    }
    return RigResult(t=t, channels=channels, rig=drive.sidecar, truth=truth)
