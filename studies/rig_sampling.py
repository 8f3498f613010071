"""The virtual rig's draw, sample grid and sensors, shared by the single-effect rig
(:mod:`.virtual_rig`) and the multi-effect rig (:mod:`.rig_multi_effect`): the rig's base
parameters drawn around the configs' defaults, its nominal piston set-up and sidecar, the
excitation, and the recorded channels through the sensor effects, noise and quantisation.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from pneumatic_env.identification.config import IdentificationConfig
from pneumatic_env.params import load_parameters
from pneumatic_env.physics import layout as L
from pneumatic_env.recording import PISTON_MODES, canonical_cylinder

from .rig_excitation import UserExcitation, excitation
from .rig_plants import _two_lags

__all__ = ["RigDrive", "rig_drive"]


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


class RigDrive(NamedTuple):
    """A rig before its effects: the canonical cylinder, its parameters (perturbed), the
    stream of its noise draws, its sample grid, the sampled command and its sidecar."""

    cylinder: str
    true: dict
    rng: np.random.Generator
    grid: _SampleGrid
    i_c: np.ndarray
    sidecar: dict


def rig_drive(
    seed: int,
    duration_s: float | None,
    cylinder: str,
    tube_length_m: float,
    piston: str,
    excitation_kind: str | UserExcitation,
    perturb: bool,
    experiment: int | None,
    spring_rest_position_m: float,
    cfg: IdentificationConfig,
    spring_stiffness_n_per_m: float | None = None,
    load_mass_kg: float | None = None,
) -> RigDrive:
    """The rig ``seed`` (its perturbed parameters) and the excitation of its experiment
    (``run_rig``'s first stages, shared with the multi-effect rig)."""
    rng = np.random.default_rng(seed)
    grid = _sample_grid(cfg, duration_s)
    cylinder = canonical_cylinder(cylinder)
    piston_rig, nominal = _nominal_rig(
        cylinder,
        tube_length_m,
        piston,
        spring_rest_position_m,
        cfg,
        spring_stiffness_n_per_m,
        load_mass_kg,
    )
    true = _perturbed(cylinder, nominal, rng, cfg) if perturb else dict(nominal)
    if experiment is not None:
        rng = np.random.default_rng([int(seed), int(experiment)])
    i_c = excitation(excitation_kind, grid.n, grid.dt_s, rng, cfg)
    sidecar = {
        "cylinder": cylinder,
        "tube_length_m": float(tube_length_m),
        "supply_pressure_pa": float(nominal["supply_pressure_pa"]),
        "ambient_pressure_pa": float(nominal["ambient_pressure_pa"]),
        "temperature_k": float(nominal["temperature_k"]),
        "piston": piston_rig,
        "notes": "synthetic (virtual rig) recording made by pneumatic_env.studies.virtual_rig",
    }
    return RigDrive(cylinder, true, rng, grid, i_c, sidecar)


class _SampleGrid(NamedTuple):
    """The recording's sample period, the plant's step and the number of samples."""

    dt_s: float  # sample period
    plant_dt_s: float  # the plant's step
    plant_steps_per_sample: int
    n: int  # samples, the first at t = 0
    duration_s: float


def _sample_grid(cfg: IdentificationConfig, duration_s: float | None) -> _SampleGrid:
    dt = cfg.number("virtual_rig", "sample_dt_s", positive=True)
    plant_dt = cfg.number("virtual_rig", "plant_dt_s", positive=True)
    ratio = int(round(dt / plant_dt))
    if ratio < 1 or abs(ratio * plant_dt - dt) > 1e-9 * dt:
        raise ValueError("virtual_rig.sample_dt_s must be a whole multiple of plant_dt_s")
    duration = float(
        duration_s if duration_s is not None else cfg.number("virtual_rig", "duration_s")
    )
    return _SampleGrid(dt, plant_dt, ratio, int(round(duration / dt)) + 1, duration)


def _nominal_rig(
    cylinder: str,
    tube_length_m: float,
    piston: str,
    spring_rest_position_m: float,
    cfg: IdentificationConfig,
    spring_stiffness_n_per_m: float | None = None,
    load_mass_kg: float | None = None,
) -> tuple[dict, dict]:
    """(the sidecar's piston entry, the nominal parameters) of the rig's piston mode, with
    the experiment's own spring and load where given."""
    piston_rig: dict = {"mode": piston}
    overrides: dict = {"tube_length_m": tube_length_m, "piston_mode": PISTON_MODES[piston][0]}
    if piston == "fixed":
        piston_rig["position_m"] = 0.0
        overrides["fixed_position_m"] = 0.0
    elif piston == "free":
        piston_rig.update(load_mass_kg=0.0, load_force_n=0.0)
        overrides.update(load_mass_kg=0.0, load_force_n=0.0)
    else:
        k_env = cfg.number("virtual_rig", "spring_stiffness_n_per_m", positive=True)
        if spring_stiffness_n_per_m is not None:  # the experiment's own spring
            k_env = float(spring_stiffness_n_per_m)
        m_env = cfg.number("virtual_rig", "spring_load_mass_kg", minimum=0.0)
        rest = float(spring_rest_position_m)
        piston_rig.update(stiffness_n_per_m=k_env, rest_position_m=rest, load_mass_kg=m_env)
        overrides.update(
            spring_stiffness_n_per_m=k_env, spring_rest_position_m=rest, load_mass_kg=m_env
        )
    if load_mass_kg is not None and piston != "fixed":  # the experiment's own load
        piston_rig["load_mass_kg"] = overrides["load_mass_kg"] = float(load_mass_kg)
    return piston_rig, load_parameters(cylinder, **overrides)


def _sensor_channels(
    sensor_effects: dict[str, float],
    rows: np.ndarray,
    i_c: np.ndarray,
    grid: _SampleGrid,
    piston: str,
    rng: np.random.Generator,
    cfg: IdentificationConfig,
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """(sample times, the recorded channels): the plant's outputs sampled, through the
    sensor effects ({name: value at the rig's strength, s x reference}; others are
    ignored), with noise and quantisation."""
    n, dt, plant_dt = grid.n, grid.dt_s, grid.plant_dt_s
    names = {"p1": L.O_P1, "p2": L.O_P2, "f": L.O_F, "x": L.O_X}
    measured = ("p1", "p2", "f") if piston == "fixed" else ("p1", "p2", "x")
    t = dt * np.arange(n)
    channels = {"i_c": i_c}
    skew = sensor_effects.get("channel_time_skew")
    skew_steps = int(round(skew / plant_dt)) if skew is not None else 0
    lag = sensor_effects.get("pressure_sensor_lag")
    offset = sensor_effects.get("pressure_sensor_offset")
    for ch in measured:
        y = rows[:, names[ch]].copy()
        if lag is not None and ch in ("p1", "p2"):
            y = _two_lags(y, lag, plant_dt)
        idx = np.arange(n) * grid.plant_steps_per_sample - skew_steps
        y = y[np.clip(idx, 0, None)]
        if offset is not None and ch in ("p1", "p2"):
            y = y + offset * (1.0 if ch == "p1" else -2.0 / 3.0) * (1.0 + 0.1 * t / t[-1])
        sigma = cfg.number("virtual_rig", "noise", ch, minimum=0.0)
        q = cfg.number("virtual_rig", "quantisation", ch, minimum=0.0)
        y = y + sigma * rng.standard_normal(n)
        if q > 0:
            y = q * np.round(y / q)
        channels[ch] = y
    return t, channels
