"""The observation: its layout, its normalisation and the inverse, in one place.

A row is ``[p1, p2, x, f, ref(k), ref(k+1), ..., ref(k+H)]``: the measured chamber
pressures (Pa), piston position (m) and load-cell force (N), then the reference of the
tracked channel now and ``H = preview_steps`` control periods ahead. With
``normalize_observation`` every entry is mapped by the :class:`ObservationScales` of the
env: ``(p - P_a) / (P_s - P_a)``, ``x / (L/2)``, ``f / force_scale``,
``ref / reference_scale``. The env applies the map in the jitted
:func:`fill_observation_row`; :func:`observation_to_si` undoes it for controllers.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import NamedTuple

import numpy as np
from numba import njit

__all__ = [
    "OBSERVED_CHANNELS",
    "OBS_P1",
    "OBS_P2",
    "OBS_X",
    "OBS_F",
    "OBS_REF",
    "ObservationScales",
    "observation_scales",
    "observation_dim",
    "fill_observation",
    "observation_to_si",
]

OBSERVED_CHANNELS = ("p1", "p2", "x", "f")  # measured channels, in observation order
OBS_P1 = OBSERVED_CHANNELS.index("p1")
OBS_P2 = OBSERVED_CHANNELS.index("p2")
OBS_X = OBSERVED_CHANNELS.index("x")
OBS_F = OBSERVED_CHANNELS.index("f")
OBS_REF = len(OBSERVED_CHANNELS)  # ref(k); the preview ref(k+1..k+H) follows


class ObservationScales(NamedTuple):
    """What ``normalize_observation`` divides by (passed to the jitted task step as is)."""

    normalize: bool  # False: the observation is in SI units and the scales are unused
    ambient_pa: float  # P_a: the pressures' zero
    supply_pa: float  # P_s: (P_s - P_a) is the pressures' unit
    half_stroke_m: float  # L/2: the position's unit
    force_scale_n: float  # (P_s - P_a) min(A1, A2): the force's unit
    reference_scale: float  # the tracked channel's unit (tasks.scale_of): N or m


def observation_scales(
    params: Mapping[str, float], force_scale_n: float, reference_scale: float, normalize: bool
) -> ObservationScales:
    """The scales of an env with parameters ``params`` (a ``load_parameters`` mapping)."""
    return ObservationScales(
        bool(normalize),
        float(params["ambient_pressure_pa"]),
        float(params["supply_pressure_pa"]),
        float(0.5 * params["stroke_m"]),
        float(force_scale_n),
        float(reference_scale),
    )


def observation_dim(preview_steps: int) -> int:
    """Entries of an observation row with ``preview_steps`` preview samples."""
    return OBS_REF + 1 + int(preview_steps)


@njit(cache=True, inline="always")
def fill_observation_row(env, measured, references, step_count, scales, obs):
    """obs[env] = [p1, p2, x, f, ref(k), ..., ref(k+H)] in SI units or normalised by
    ``scales`` (an :class:`ObservationScales`); the references are held at their end."""
    n_ref = references.shape[1]
    n_channels = measured.shape[1]
    normalize = scales.normalize
    if normalize:
        ambient_pa = scales.ambient_pa
        span = scales.supply_pa - ambient_pa
        obs[env, 0] = (measured[env, 0] - ambient_pa) / span
        obs[env, 1] = (measured[env, 1] - ambient_pa) / span
        obs[env, 2] = measured[env, 2] / scales.half_stroke_m
        obs[env, 3] = measured[env, 3] / scales.force_scale_n
    else:
        for ch in range(n_channels):
            obs[env, ch] = measured[env, ch]
    reference_scale = scales.reference_scale
    for j in range(obs.shape[1] - n_channels):
        value = references[env, min(step_count[env] + j, n_ref - 1)]
        obs[env, n_channels + j] = value / reference_scale if normalize else value


@njit(cache=True)
def fill_observation(measured, references, step_count, scales, obs):
    """Every env's observation row (:func:`fill_observation_row`), on one thread."""
    for env in range(obs.shape[0]):
        fill_observation_row(env, measured, references, step_count, scales, obs)


def observation_to_si(obs: np.ndarray, scales: ObservationScales) -> np.ndarray:
    """The inverse of :func:`fill_observation_row`'s normalisation: rows ``(n, obs_dim)`` in
    SI units (float64; ``obs`` itself when ``scales.normalize`` is False)."""
    if not scales.normalize:
        return obs
    out = np.array(obs, dtype=np.float64)
    span = scales.supply_pa - scales.ambient_pa
    out[:, [OBS_P1, OBS_P2]] = scales.ambient_pa + out[:, [OBS_P1, OBS_P2]] * span
    out[:, OBS_X] = out[:, OBS_X] * scales.half_stroke_m
    out[:, OBS_F] = out[:, OBS_F] * scales.force_scale_n
    out[:, OBS_REF:] = out[:, OBS_REF:] * scales.reference_scale
    return out
