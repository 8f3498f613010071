"""Jitted per-step task logic (clip, simulate, measure, reward, observe) for a batch of envs.

One call per control step does everything ``TaskCore.step`` needs, the observation
included, so a single env pays one Numba dispatch instead of dozens of NumPy calls on
one-element arrays, and the vector env loops over environments in compiled code, in one
parallel region per step (each chunk observed while its rows are in cache).
"""
from numba import njit, prange

from ..physics.kernel import CHUNK_ENVS, advance_chunk


@njit(cache=True)
def _chunk_step(first, stop, params, state, history, head, action, control_dt_s, n_substeps,
                outputs, i_max, references, step_count, prev_action, measured, noise, lag,
                out_rows, tracked_row, scale, effort_weight, chatter_weight, reward, error,
                reference, applied, key, constants, observe, obs):
    """One control step of envs ``first .. stop-1``: clip, simulate (``advance_chunk``),
    measure (noise, first-order sensor lag), reward, observe (``observe`` holds the
    arguments of ``_fill_observation_row`` after ``step_count``)."""
    for env in range(first, stop):
        applied[env] = min(max(action[env], -i_max), i_max)
    advance_chunk(params, state, history, first, stop, head, applied, control_dt_s, n_substeps,
                  outputs, key, constants)
    for env in range(first, stop):
        a = applied[env]
        step_count[env] += 1
        for ch in range(out_rows.shape[0]):
            fresh = outputs[out_rows[ch], env] + noise[env, ch]
            measured[env, ch] = lag * measured[env, ch] + (1.0 - lag) * fresh
        k = min(step_count[env], references.shape[1] - 1)
        ref = references[env, k]
        e = outputs[tracked_row, env] - ref
        r = -min(abs(e) / scale, 1.0)
        r -= effort_weight * (a / i_max) ** 2
        r -= chatter_weight * ((a - prev_action[env]) / (2.0 * i_max)) ** 2
        prev_action[env] = a
        reward[env], error[env], reference[env] = r, e, ref
        _fill_observation_row(env, measured, references, step_count, observe[0], observe[1],
                              observe[2], observe[3], observe[4], observe[5], obs)


@njit(cache=True)
def task_step_serial(params, state, history, head, action, control_dt_s, n_substeps, outputs,
                     i_max, references, step_count, prev_action, measured, noise, lag, out_rows,
                     tracked_row, scale, effort_weight, chatter_weight, reward, error,
                     reference, applied, key, constants, observe, obs):
    """One control step of every env of the batch, on one thread."""
    n_envs = state.shape[1]
    for first in range(0, n_envs, CHUNK_ENVS):
        _chunk_step(first, min(first + CHUNK_ENVS, n_envs), params, state, history, head,
                    action, control_dt_s, n_substeps, outputs, i_max, references, step_count,
                    prev_action, measured, noise, lag, out_rows, tracked_row, scale,
                    effort_weight, chatter_weight, reward, error, reference, applied, key,
                    constants, observe, obs)


@njit(cache=True, parallel=True)
def task_step_parallel(params, state, history, head, action, control_dt_s, n_substeps, outputs,
                       i_max, references, step_count, prev_action, measured, noise, lag,
                       out_rows, tracked_row, scale, effort_weight, chatter_weight, reward,
                       error, reference, applied, key, constants, observe, obs):
    """One control step of every env of the batch, chunks of envs spread over threads."""
    n_envs = state.shape[1]
    for chunk in prange((n_envs + CHUNK_ENVS - 1) // CHUNK_ENVS):
        first = chunk * CHUNK_ENVS
        _chunk_step(first, min(first + CHUNK_ENVS, n_envs), params, state, history, head,
                    action, control_dt_s, n_substeps, outputs, i_max, references, step_count,
                    prev_action, measured, noise, lag, out_rows, tracked_row, scale,
                    effort_weight, chatter_weight, reward, error, reference, applied, key,
                    constants, observe, obs)


@njit(cache=True, inline="always")
def _fill_observation_row(env, measured, references, step_count, normalize, ambient_pa,
                          supply_pa, half_stroke_m, force_scale_n, reference_scale, obs):
    """obs[env] = [p1, p2, x, f, ref(k), ..., ref(k+H)] in SI units or normalised.

    Normalised: pressures (p - P_a)/(P_s - P_a), x/(L/2), f/force_scale, ref/reference_scale.
    """
    n_ref = references.shape[1]
    n_channels = measured.shape[1]
    if normalize:
        span = supply_pa - ambient_pa
        obs[env, 0] = (measured[env, 0] - ambient_pa) / span
        obs[env, 1] = (measured[env, 1] - ambient_pa) / span
        obs[env, 2] = measured[env, 2] / half_stroke_m
        obs[env, 3] = measured[env, 3] / force_scale_n
    else:
        for ch in range(n_channels):
            obs[env, ch] = measured[env, ch]
    for j in range(obs.shape[1] - n_channels):
        value = references[env, min(step_count[env] + j, n_ref - 1)]
        obs[env, n_channels + j] = value / reference_scale if normalize else value


@njit(cache=True)
def fill_observation(measured, references, step_count, normalize, ambient_pa, supply_pa,
                     half_stroke_m, force_scale_n, reference_scale, obs):
    """Every env's observation row (``_fill_observation_row``), on one thread."""
    for env in range(obs.shape[0]):
        _fill_observation_row(env, measured, references, step_count, normalize, ambient_pa,
                              supply_pa, half_stroke_m, force_scale_n, reference_scale, obs)
