"""Jitted per-step task logic (clip, simulate, measure, reward, observe) for a batch of envs.

One call per control step does everything ``TaskCore.step`` needs, the observation
included, so a single env pays one Numba dispatch instead of dozens of NumPy calls on
one-element arrays, and the vector env loops over environments in compiled code, in one
parallel region per step (each chunk observed while its rows are in cache).

The step takes a few named tuples of arrays (gymnax style: parameters apart from state):
``layout.SimArrays`` (the simulator's ``arrays``), :class:`TaskParams` and the observation's
``ObservationScales`` (fixed for the env's life), :class:`TaskState` (updated in place) and
:class:`StepOutputs` (written by the step). Flat tuples: a parallel loop cannot take a
tuple nested in a tuple. The entry points take them as plain tuples (``tuple(named)``)
and name them again inside (free): Numba's dispatcher types a plain tuple of arrays in C
but a named tuple in Python, which would add some 7 us to each single-env step.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit, prange

from ..physics.batch_path import advance_chunk
from ..physics.constants import CHUNK_ENVS
from ..physics.layout import SimArrays
from .observation import ObservationScales, fill_observation_row

__all__ = [
    "TaskParams",
    "TaskState",
    "StepOutputs",
    "task_step_serial",
    "task_step_parallel",
]


class TaskParams(NamedTuple):
    """What a task step needs beyond the simulator, fixed for the env's life."""

    coil_current_max_a: float  # actions are clipped to +-this
    effort_weight: float  # reward -= effort_weight (i / i_max)^2
    chatter_weight: float  # reward -= chatter_weight ((i - i_prev) / (2 i_max))^2
    lag: float  # first-order sensor lag per control period: exp(-dt / sensor_lag_s), or 0
    out_rows: np.ndarray  # layout.O_* row of each observed channel (p1, p2, x, f)
    tracked_row: int  # layout.O_* row of the tracked channel


class TaskState(NamedTuple):
    """The episodes' state, updated in place by the step (one row per env)."""

    references: np.ndarray  # (n_envs, n_ref) float64, held at the last sample
    step_count: np.ndarray  # (n_envs,) int64: steps since reset
    prev_action: np.ndarray  # (n_envs,): the previous applied current (chatter term)
    measured: np.ndarray  # (n_envs, 4): sensor readings (noise and lag included)


class StepOutputs(NamedTuple):
    """Per-env results the step writes."""

    reward: np.ndarray  # (n_envs,)
    error: np.ndarray  # (n_envs,): tracked output - reference
    reference: np.ndarray  # (n_envs,): the reference of this step
    applied: np.ndarray  # (n_envs,): the clipped coil current (A)
    obs: np.ndarray  # (n_envs, obs_dim) float32: the next observation


@njit(cache=True)
def _chunk_step(first, stop, sim, task, scales, state, action, noise, out):
    """One control step of envs ``first .. stop-1``: clip, simulate (``advance_chunk``),
    measure (noise, first-order sensor lag), reward, observe."""
    i_max = task.coil_current_max_a
    applied = out.applied
    for env in range(first, stop):
        applied[env] = min(max(action[env], -i_max), i_max)
    outputs = sim.outputs
    advance_chunk(sim, first, stop, applied)
    out_rows, lag, scale = task.out_rows, task.lag, scales.reference_scale
    references, step_count, measured = state.references, state.step_count, state.measured
    prev_action = state.prev_action
    for env in range(first, stop):
        a = applied[env]
        step_count[env] += 1
        for ch in range(out_rows.shape[0]):
            fresh = outputs[out_rows[ch], env] + noise[env, ch]
            measured[env, ch] = lag * measured[env, ch] + (1.0 - lag) * fresh
        k = min(step_count[env], references.shape[1] - 1)
        ref = references[env, k]
        e = outputs[task.tracked_row, env] - ref
        r = -min(abs(e) / scale, 1.0)
        r -= task.effort_weight * (a / i_max) ** 2
        r -= task.chatter_weight * ((a - prev_action[env]) / (2.0 * i_max)) ** 2
        prev_action[env] = a
        out.reward[env], out.error[env], out.reference[env] = r, e, ref
        fill_observation_row(env, measured, references, step_count, scales, out.obs)


@njit(cache=True)
def task_step_serial(sim, task, scales, state, action, noise, out):
    """One control step of every env of the batch, on one thread.

    ``sim``: ``layout.SimArrays``; ``task``: :class:`TaskParams`; ``scales``: the
    observation's :class:`ObservationScales` (``reference_scale`` also scales the reward's
    error); ``state``: :class:`TaskState`; ``action``: coil currents (n_envs,) in A;
    ``noise``: sensor noise (n_envs, 4) added this step; ``out``: :class:`StepOutputs`; the
    named tuples as plain tuples (``tuple(named)``).
    """
    sim, task, scales = SimArrays(*sim), TaskParams(*task), ObservationScales(*scales)
    state, out = TaskState(*state), StepOutputs(*out)  # named again (see the module doc)
    n_envs = sim.state.shape[1]
    for first in range(0, n_envs, CHUNK_ENVS):
        _chunk_step(
            first, min(first + CHUNK_ENVS, n_envs), sim, task, scales, state, action, noise, out
        )


@njit(cache=True, parallel=True)
def task_step_parallel(sim, task, scales, state, action, noise, out):
    """One control step of every env of the batch, chunks of envs spread over threads
    (arguments as :func:`task_step_serial`)."""
    sim, task, scales = SimArrays(*sim), TaskParams(*task), ObservationScales(*scales)
    state, out = TaskState(*state), StepOutputs(*out)  # named again (see the module doc)
    n_envs = sim.state.shape[1]
    for chunk in prange((n_envs + CHUNK_ENVS - 1) // CHUNK_ENVS):
        first = chunk * CHUNK_ENVS
        _chunk_step(
            first, min(first + CHUNK_ENVS, n_envs), sim, task, scales, state, action, noise, out
        )
