"""Replay a recording: drive the model with its coil current and predict its channels.

``pneumatic-env simulate REC -o OUT.csv`` reads ``REC`` (``docs/measurement-format.md``),
builds the parameter set its sidecar describes, holds each ``i_c`` sample over one sample
step (zero-order hold: sample k applies from ``t[k]`` to ``t[k+1]``), and writes the
predicted ``p1, p2, x, f, v, x_s`` as a new recording with the same rig. Predicted
sample k is the state at ``t[k]``; row 0 is the initial state (the sidecar's
``initial``, else both chambers at ambient, at rest, spool centred).

The control period of the simulation is the recording's sample step; the number of RK4
substeps per step is chosen so that the substep is no longer than the default one
(``control_dt_s / substeps`` of ``configs/numerics.yaml``), unless given.
"""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from .ids import PACKAGE_VERSION
from .params import load_numerics, load_parameters, parameter_array
from .physics import layout as L
from .recording import (
    Recording,
    read_recording,
    recording_paths,
    rig_to_parameter_overrides,
    write_recording,
)
from .simulator import BatchSimulator

__all__ = [
    "PREDICTED_CHANNELS",
    "default_substep_s",
    "predict_to_recording",
    "recording_parameters",
    "simulate_currents",
    "simulate_recording",
    "substeps_for",
]

#: Channels a replay predicts, with their output rows in the kernel's layout.
PREDICTED_CHANNELS = {
    "p1": L.O_P1,
    "p2": L.O_P2,
    "x": L.O_X,
    "f": L.O_F,
    "v": L.O_V,
    "x_s": L.O_X_S,
}
_UNITS = {"p1": "Pa", "p2": "Pa", "x": "m", "f": "N", "v": "m/s", "x_s": "m"}
# A sample step within this relative distance of a whole number of default substeps
# counts as that whole number (float noise of t[-1] - t[0] over n - 1 steps).
_WHOLE_TOLERANCE = 1e-9


def default_substep_s() -> float:
    """The default RK4 substep: ``control_dt_s / substeps`` of ``configs/numerics.yaml``."""
    numerics = load_numerics()
    return float(numerics["control_dt_s"]) / int(numerics["substeps"])


def substeps_for(control_dt_s: float, max_substep_s: float | None = None) -> int:
    """Fewest substeps per control period that keep the substep <= ``max_substep_s``.

    ``max_substep_s`` defaults to :func:`default_substep_s`.
    """
    if not (
        isinstance(control_dt_s, (int, float)) and math.isfinite(control_dt_s) and control_dt_s > 0
    ):
        raise ValueError(
            f"control_dt_s = {control_dt_s!r} is not allowed: must be a finite number > 0 s"
        )
    h = default_substep_s() if max_substep_s is None else float(max_substep_s)
    if not (math.isfinite(h) and h > 0):
        raise ValueError(f"max_substep_s = {max_substep_s!r} is not allowed: must be > 0 s")
    ratio = control_dt_s / h
    return max(1, math.ceil(ratio * (1.0 - _WHOLE_TOLERANCE)))


def _check_substeps(substeps) -> int:
    if (
        isinstance(substeps, bool)
        or not isinstance(substeps, (int, np.integer, float))
        or not float(substeps).is_integer()
        or substeps < 1
    ):
        raise ValueError(f"substeps = {substeps!r} is not allowed: must be a whole number >= 1")
    return int(substeps)


def simulate_currents(
    params: Mapping[str, float],
    coil_current_a,
    control_dt_s: float,
    substeps: int | None = None,
    initial: Mapping[str, float] | None = None,
    t0_s: float = 0.0,
) -> dict[str, np.ndarray]:
    """Open-loop run of one actuator; the common core of replay and the paper's experiments.

    ``coil_current_a[k]`` is held from ``t_k`` to ``t_{k+1}`` (``t_k = t0_s + k dt``).
    Returns ``t`` and the channels of :data:`PREDICTED_CHANNELS`, each of length
    ``len(coil_current_a) + 1``: row 0 is the initial state, row k the state at ``t_k``.
    ``substeps`` defaults to :func:`substeps_for` ``(control_dt_s)``.
    """
    currents = np.asarray(coil_current_a, dtype=np.float64).ravel()
    if not np.all(np.isfinite(currents)):
        k = int(np.flatnonzero(~np.isfinite(currents))[0])
        raise ValueError(f"coil_current_a[{k}] = {currents[k]} is not allowed: must be finite")
    n_sub = substeps_for(control_dt_s) if substeps is None else _check_substeps(substeps)
    sim = BatchSimulator(
        parameter_array([dict(params)]), control_dt_s=control_dt_s, n_substeps=n_sub
    )
    sim.reset(initial=dict(initial) if initial else None)
    first = sim.outputs[:, 0].copy()
    out = sim.rollout(currents[:, None])[:, :, 0]
    rows = np.vstack([first[None, :], out])
    result = {"t": t0_s + control_dt_s * np.arange(len(currents) + 1)}
    for name, row in PREDICTED_CHANNELS.items():
        result[name] = rows[:, row].copy()
    return result


def recording_parameters(
    recording: Recording, params: str | os.PathLike | Mapping | None = None
) -> dict[str, float]:
    """The parameter set of a recording's rig.

    Layers: the configs for the sidecar's cylinder, then ``params`` (e.g. a fitted
    parameter YAML written by ``save_parameters``), then what the sidecar states (tube,
    pressures, temperature, rod mode and load), which describes this particular rig and
    therefore wins over a parameter file.
    """
    overrides = rig_to_parameter_overrides(recording.rig)
    cylinder = overrides.pop("cylinder")
    return load_parameters(cylinder, params=params, **overrides)


def simulate_recording(
    recording: Recording | str | os.PathLike,
    params: str | os.PathLike | Mapping | None = None,
    substeps: int | None = None,
) -> dict[str, np.ndarray]:
    """Predicted channels (``t, p1, p2, x, f, v, x_s``) of a recording, same sample times.

    ``recording`` is a :class:`Recording` or a path for :func:`read_recording`.
    The recording's ``i_c`` drives the model (sample k held from ``t[k]`` to ``t[k+1]``;
    the last sample's command acts after the recording and is not used); the control
    period is the sample step; the initial state is the sidecar's ``initial`` if given.
    """
    if not isinstance(recording, Recording):
        recording = read_recording(recording)
    values = recording_parameters(recording, params)
    dt = recording.dt
    predicted = simulate_currents(
        values,
        recording.i_c[:-1],
        dt,
        substeps=substeps,
        initial=recording.rig.get("initial"),
        t0_s=float(recording.t[0]),
    )
    predicted["t"] = recording.t.copy()
    return predicted


def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def _check_not_input(output, source: Path) -> None:
    out_csv, out_json = recording_paths(output)
    in_csv, in_json = recording_paths(source)
    for out_p, in_p in ((out_csv, in_csv), (out_json, in_json)):
        if out_p.resolve() == in_p.resolve() or _same_file(out_p, in_p):
            raise ValueError(
                f"output {out_p} is the input recording's file; the input is never "
                "overwritten: choose another output name"
            )


def predict_to_recording(
    recording: Recording | str | os.PathLike,
    output: str | os.PathLike,
    params: str | os.PathLike | None = None,
    substeps: int | None = None,
    overwrite: bool = False,
) -> tuple[Path, dict[str, np.ndarray], Recording]:
    """Replay ``recording`` and write the prediction as a recording at ``output``.

    The output has the input's ``t`` and ``i_c``, the predicted ``p1, p2, x, f, v, x_s``
    and the input's sidecar with ``notes`` saying what made it. Refuses to write to the
    input's files (even with ``overwrite=True``); other existing files are kept unless
    ``overwrite``. Returns (CSV path written, predicted channels, input recording).
    """
    if not isinstance(recording, Recording):
        recording = read_recording(recording)
    if recording.path is None:
        raise ValueError(
            "recording.path is None: predict_to_recording needs a recording read "
            "from a file (to name it in the notes and to protect it)"
        )
    _check_not_input(output, recording.path)
    predicted = simulate_recording(recording, params=params, substeps=substeps)
    channels = {"i_c": recording.i_c}
    channels.update((name, predicted[name]) for name in PREDICTED_CHANNELS)
    rig = dict(recording.rig)
    notes = f"simulated by pneumatic_env {PACKAGE_VERSION} from {recording.path}"
    if params is not None:
        notes += f" with parameters {params}"
    rig["notes"] = notes
    path = write_recording(output, recording.t, channels, rig, overwrite=overwrite)
    return path, predicted, recording


def rms_errors(recording: Recording, predicted: Mapping[str, np.ndarray]) -> dict[str, float]:
    """RMS of measured minus predicted for every predicted channel the recording has."""
    return {
        name: float(np.sqrt(np.mean((recording.channels[name] - predicted[name]) ** 2)))
        for name in PREDICTED_CHANNELS
        if name in recording.channels
    }


# --------------------------------------------------------------------------- CLI


def add_arguments(p) -> None:
    p.add_argument(
        "recording", metavar="REC", help="recording to replay: NAME.csv, NAME.json or the stem NAME"
    )
    p.add_argument(
        "-o",
        "--output",
        metavar="OUT.csv",
        required=True,
        help="where to write the predicted recording (never the input)",
    )
    p.add_argument(
        "--params",
        metavar="FILE",
        default=None,
        help="parameter YAML (e.g. fitted by identify) on top of the cylinder's "
        "configs; the recording's sidecar still sets the rig",
    )
    p.add_argument(
        "--substeps",
        metavar="N",
        type=int,
        default=None,
        help="RK4 substeps per sample step (default: enough to keep the default "
        "substep of configs/numerics.yaml)",
    )
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="replace OUT if it exists (the input is never replaced)",
    )


def run(args) -> int:
    """Replay REC into OUT; print a one-line summary. Bad input: message on stderr, exit 2."""
    try:
        path, predicted, recording = predict_to_recording(
            args.recording,
            args.output,
            params=args.params,
            substeps=args.substeps,
            overwrite=args.overwrite,
        )
    except (ValueError, FileExistsError) as exc:  # RecordingError, ConfigError are ValueErrors
        print(f"pneumatic-env simulate: error: {exc}", file=sys.stderr)
        return 2
    errors = rms_errors(recording, predicted)
    rms = ", ".join(f"{k} {v:.4g} {_UNITS[k]}" for k, v in errors.items()) or "none"
    print(
        f"{path}: {recording.n_samples} rows, {recording.duration:.6g} s; "
        f"RMS measured - predicted: {rms}"
    )
    return 0
