"""Recordings prepared for fitting: channels, residual scales, usable samples, substeps,
and the parameter overrides that reach each recording (scoped by rod mode)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from pneumatic_env.params import ConfigError
from pneumatic_env.physics.derived import circle_area_m2
from pneumatic_env.physics.layout import PARAMETER_INDEX
from pneumatic_env.recording import Recording
from pneumatic_env.replay import PREDICTED_CHANNELS, recording_parameters, substeps_for

from .checks import FITTED_CHANNELS, check_recordings, usable_masks
from .config import FitParameter, IdentificationConfig, load_config

__all__ = [
    "Dataset",
    "base_fit_parameters",
    "channel_scale",
    "dataset_overrides",
    "prepare_datasets",
]


def kernel_name(key: str) -> str:
    """The kernel parameter of an override key: ``name`` or a scoped ``name@mode|mode``
    (a value that applies only to recordings whose rod is in one of those modes)."""
    return key.partition("@")[0]


@dataclass
class Dataset:
    """One recording prepared for fitting."""

    name: str
    recording: Recording
    values: dict[str, float]  # the parameter set before fitting (configs + params + rig)
    channels: tuple[str, ...]  # channels that enter the residual
    scales: dict[str, float]  # residual scale of each channel
    usable: dict[str, np.ndarray]  # per channel: samples not clipped
    dt_s: float
    substeps: int  # RK4 substeps per sample for the recording's rod mode
    initial: dict | None
    moving: bool
    rod_mode: str = "fixed"  # the sidecar's piston.mode
    substeps_moving: int = 0  # substeps when the simulated rod moves (0: = substeps)

    @property
    def n_samples(self) -> int:
        return self.recording.n_samples

    def measured(self, channel: str) -> np.ndarray:
        return self.recording.channels[channel]


def channel_scale(channel: str, values: Mapping[str, float], config: IdentificationConfig) -> float:
    """Residual scale of a channel (see ``channel_scales`` in the config)."""
    span = values["supply_pressure_pa"] - values["ambient_pressure_pa"]
    if channel in ("p1", "p2"):
        return span
    if channel == "f":
        return span * circle_area_m2(values["bore_diameter_m"])
    if channel == "x":
        return config.number("channel_scales", "x", positive=True) * values["stroke_m"]
    if channel == "x_s":
        return config.number("channel_scales", "x_s", positive=True) * values["hole_radius_m"]
    if channel == "v":
        return config.number("channel_scales", "v", positive=True)
    raise ConfigError(f"channel {channel!r} has no residual scale; allowed: p1, p2, f, x, v, x_s")


def prepare_datasets(
    recordings: Sequence[Recording],
    params=None,
    config: IdentificationConfig | None = None,
    check: bool = True,
) -> tuple[list[Dataset], list]:
    """Datasets for ``recordings`` and the data issues found (errors raise ``BadDataError``).

    ``params`` is a parameter file or mapping layered under each recording's sidecar (see
    :func:`pneumatic_env.replay.recording_parameters`).
    """
    config = config or load_config()
    values = [recording_parameters(rec, params) for rec in recordings]
    issues = check_recordings(recordings, values, config=config) if check else []
    datasets = []
    for k, (rec, vals) in enumerate(zip(recordings, values)):
        name = rec.path.stem if rec.path is not None else f"recording{k}"
        dropped = {
            i.channel
            for i in issues
            if i.code == "constant" and i.recording in (rec.path.name if rec.path else "recording")
        }
        mode = rec.rig["piston"]["mode"]
        max_substep = config.number(
            "fit", "max_substep_s" if mode == "fixed" else "max_substep_moving_s", positive=True
        )
        moving_substep = config.number("fit", "max_substep_moving_s", positive=True)
        initial = rec.rig.get("initial")
        if mode == "fixed":  # the rod starts at the clamp, also when a candidate frees it
            initial = {"x": vals["fixed_position_m"], **(initial or {})}
        channels = tuple(
            c
            for c in FITTED_CHANNELS
            if c in rec.channels
            and c not in dropped
            and c in PREDICTED_CHANNELS
            and not (c == "x" and mode == "fixed")
        )
        datasets.append(
            Dataset(
                name=name,
                recording=rec,
                values=vals,
                channels=channels,
                scales={c: channel_scale(c, vals, config) for c in channels},
                usable=usable_masks(rec, channels),
                dt_s=rec.dt,
                substeps=substeps_for(rec.dt, max_substep),
                initial=initial,
                moving=mode in ("free", "spring") and "x" in channels,
                rod_mode=mode,
                substeps_moving=substeps_for(rec.dt, moving_substep),
            )
        )
    return datasets, issues


def base_fit_parameters(
    datasets: Sequence[Dataset],
    names: Sequence[str] | None = None,
    config: IdentificationConfig | None = None,
) -> list[FitParameter]:
    """The base parameters to fit: ``names``, else the config's default set for the data."""
    config = config or load_config()
    if names is None:
        names = list(config.base_fit_names("fit_always"))
        if any(ds.moving for ds in datasets):
            names += config.base_fit_names("fit_when_moving")
    out = []
    for name in names:
        if name not in config.base_parameters:
            raise ConfigError(
                f"cannot fit {name!r}: no entry under base_parameters in "
                f"{config.path}; fittable: {', '.join(config.base_parameters)}"
            )
        out.append(config.base_parameters[name])
    return out


def dataset_overrides(
    ds: Dataset,
    overrides: Mapping[str, float | str],
    scopes: Mapping[str, Sequence[str]] | None = None,
) -> dict[str, float]:
    """The kernel-parameter ``overrides`` that apply to ``ds``, as numbers.

    A name whose ``scopes`` entry (rod modes) does not include the recording's rod mode is
    dropped; a scoped key ``name@mode|mode`` (:func:`kernel_name`) applies only to
    recordings in those modes and there overrides ``name``'s plain value, which the other
    recordings keep (a load cell's zero sliding friction on clamped rods, the calibrated
    friction on moving ones); a text value names a kernel parameter whose value in
    ``ds``'s set is used.
    """
    scopes = scopes or {}
    out, scoped = {}, {}
    for key, v in overrides.items():
        name, _, modes = key.partition("@")
        if name not in PARAMETER_INDEX:
            continue
        value = float(ds.values[v]) if isinstance(v, str) else float(v)
        if modes:
            if ds.rod_mode in modes.split("|"):
                scoped[name] = value
        elif not (name in scopes and ds.rod_mode not in scopes[name]):
            out[name] = value
    out.update(scoped)
    return out
