"""Inputs for long random rollouts, shared by the physics tests."""

from __future__ import annotations

import numpy as np


def random_currents(rng, n_steps: int, n_envs: int, i_max: float = 2.0) -> np.ndarray:
    """Piecewise-constant currents in [-i_max, i_max] A, each held 5-150 steps."""
    out = np.empty((n_steps, n_envs))
    for j in range(n_envs):
        k = 0
        while k < n_steps:
            hold = int(rng.integers(5, 150))
            out[k : k + hold, j] = rng.uniform(-i_max, i_max)
            k += hold
    return out


def assert_batch_matches_general_path(sets, currents: np.ndarray) -> bool:
    """Step ``sets`` (parameter sets) through ``currents`` (steps x envs) with
    ``BatchSimulator.step`` (the batch path) and env by env with ``kernel.advance_env``
    (the general path alone); outputs after every step, and the final state and history,
    must be equal bit for bit. Returns whether a rod other than the first env's moved."""
    from pneumatic_env.params import load_numerics, parameter_array
    from pneumatic_env.physics import kernel
    from pneumatic_env.physics import layout as L
    from pneumatic_env.simulator import BatchSimulator

    num = load_numerics()
    batch = BatchSimulator(parameter_array(sets), num["control_dt_s"], num["substeps"])
    general = BatchSimulator(parameter_array(sets), num["control_dt_s"], num["substeps"])
    moved = False
    for step_currents in currents:
        batch.step(np.ascontiguousarray(step_currents))
        for env in range(len(sets)):
            kernel.advance_env(general.arrays, env, float(step_currents[env]))
        general.advance_clock()
        np.testing.assert_array_equal(batch.outputs, general.outputs)
        moved |= bool(np.any(batch.outputs[L.O_V, 1:] != 0.0))
    np.testing.assert_array_equal(batch.state, general.state)
    np.testing.assert_array_equal(batch.history, general.history)
    return moved
