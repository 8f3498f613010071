"""Shared fixtures and helpers of the physics and environment tests.

``python -m pytest -q`` runs every test on two pytest-xdist workers (``-n 2
--dist loadfile`` in pyproject.toml; about 5 minutes on two cores, ``-n 0`` runs
them in one process); tests that take over about 15 s carry ``@pytest.mark.slow``, so
``python -m pytest -q -m "not slow"`` is the quick run.
"""

from __future__ import annotations

import functools

import numba
import numpy as np
import pytest

from pneumatic_env.numba_cache import clear_stale_numba_cache

# Numba does not see an edit of a jitted callee in another module: clear what is stale
# before any jitted function is loaded from the cache (pneumatic_env.numba_cache).
clear_stale_numba_cache()

from pneumatic_env.params import load_numerics, load_parameters, parameter_array  # noqa: E402
from pneumatic_env.simulator import BatchSimulator  # noqa: E402

#: PID gains of the agents' tests (hand-set, not the benchmark's tuned ones)
PID_TEST_GAINS = dict(
    kp_a_per_n=0.008,
    ki_a_per_n_s=0.1,
    kd_a_s_per_n=1e-5,
    derivative_filter_s=0.002,
    rate_feedforward_a_s_per_n=0.0,
    reference_lead_s=0.005,
    antiwindup_tracking_s=0.02,
    deadband_ramp_a=0.01,
    deadband_compensation=True,
)

# Gymnasium's checker recommends a normalised action space and finite observation bounds;
# the action is a coil current in A and sensor noise makes the observation unbounded.
KNOWN_CHECKER_WARNINGS = (
    "Box observation space minimum value is -infinity",
    "Box observation space maximum value is infinity",
    "we recommend using a symmetric and normalized space",
)


def assert_check_env_passes(env) -> None:
    """Gymnasium's ``check_env`` on ``env.unwrapped`` warns of nothing but the known."""
    import gc
    import warnings

    from gymnasium.utils.env_checker import check_env

    gc.collect()  # another test's garbage (e.g. an unclosed file) must not warn in here
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped)
    unexpected = [
        str(w.message)
        for w in caught
        if not any(k in str(w.message) for k in KNOWN_CHECKER_WARNINGS)
    ]
    assert not unexpected


NO_VALUE = object()  # ``assert_error_names``: the message names no offending value


def assert_error_names(error, field, value=NO_VALUE, rule=()) -> str:
    """Assert that an error message names the field, the offending value and the rule it
    breaks, without fixing the sentence around them; returns the message.

    ``error`` is a ``pytest.raises`` result, an exception or a message. ``field`` is a text
    (or several) the message must contain (a parameter, key, column or option name, or its
    file); ``value`` must appear as its ``repr`` (``'heavy'``, ``-3.0``, ``True``), unless
    it is ``NO_VALUE``; ``rule`` is one fragment or several of what is allowed (a range, the
    allowed names, a limit). A few tests keep whole sentences as guards of the wording.
    """
    exc = getattr(error, "value", error)
    message = str(exc)
    fragments = [
        *([field] if isinstance(field, str) else field),
        *([] if value is NO_VALUE else [repr(value)]),
        *([rule] if isinstance(rule, str) else rule),
    ]
    missing = [f for f in fragments if f not in message]
    assert not missing, f"the error {message!r} does not name {missing}"
    return message


@pytest.fixture
def default_params() -> dict:
    """The reference parameter set: Numatics cylinder, 0.5 m tubes, rod clamped at mid-stroke."""
    return load_parameters()


@pytest.fixture
def numba_threads() -> int:
    """The Numba threads a parallel step runs on; skips the test on one thread, where
    ``BatchSimulator.call_step_kernel`` runs the serial kernel instead."""
    if numba.get_num_threads() < 2:
        pytest.skip("one Numba thread: the parallel step kernels are not used")
    return numba.get_num_threads()


def run_batch(
    param_sets, currents, control_dt_s=None, substeps=None, initial=None, parallel=False
) -> np.ndarray:
    """Open-loop run of one BatchSimulator over ``param_sets`` (one env each).

    ``currents`` is (n_steps,) for a current common to all envs or (n_steps, n_envs);
    returns ``outputs[step, O_*, env]`` after each control period. ``control_dt_s`` and
    ``substeps`` default to ``load_numerics()``.
    """
    num = load_numerics()
    sim = BatchSimulator(
        parameter_array(list(param_sets)),
        control_dt_s or num["control_dt_s"],
        substeps or num["substeps"],
        parallel=parallel,
    )
    if initial is not None:
        sim.reset(initial=initial)
    currents = np.asarray(currents, dtype=float)
    if currents.ndim == 1:
        currents = np.repeat(currents[:, None], sim.n_envs, axis=1)
    return sim.rollout(currents)


def areas(param: dict) -> tuple[float, float, float]:
    """Cap area A1, annulus A2 = A1 - A_r and rod area A_r (m^2) from the diameters."""
    a1 = np.pi * param["bore_diameter_m"] ** 2 / 4.0
    ar = np.pi * param["rod_diameter_m"] ** 2 / 4.0
    return a1, a1 - ar, ar


def volumes(param: dict, x) -> tuple[np.ndarray, np.ndarray]:
    """Chamber volumes of Eq. 15, written out independently of physics/chamber.py."""
    a1, a2, _ = areas(param)
    half = 0.5 * param["stroke_m"]
    x = np.asarray(x, dtype=float)
    return (
        param["dead_volume_cap_m3"] + a1 * (half + x),
        param["dead_volume_rod_m3"] + a2 * (half - x),
    )


def first_crossing_time(t_s: np.ndarray, values: np.ndarray, threshold: float) -> float:
    """Time at which ``values`` (sampled at ``t_s``) first reaches ``threshold``, linearly
    interpolated between the two samples around the crossing."""
    above = np.flatnonzero(values >= threshold)
    if not above.size:
        raise AssertionError(f"never reached {threshold}")
    k = int(above[0])
    if k == 0:
        return float(t_s[0])
    v0, v1 = values[k - 1], values[k]
    return float(t_s[k - 1] + (threshold - v0) / (v1 - v0) * (t_s[k] - t_s[k - 1]))


@functools.cache
def suite_rms_pct(controller: str, variant: str) -> dict[str, float]:
    """{task: RMS error (% of the scale)} of a named controller on suite v1 for one variant
    (``agents.bench.run_suite``; deterministic, so computed once per session)."""
    from pneumatic_env.agents.bench import run_suite

    return {r["task"]: r["rms_error_pct"] for r in run_suite(controller, [variant])[0]}


def small_run(config, out, updates: int, seed: int = 1, **overrides):
    """A fast trainer's run of ``updates`` updates with ``SMALL`` and ``overrides``
    ({"section.key": value}); returns its ``train.json`` summary."""
    from pneumatic_env.agents.ppo import train

    return train(
        config,
        seed=seed,
        out=out,
        minutes=10.0,  # ends by steps, not by the machine's load
        total_steps=updates
        * SMALL["hyperparameters.num_envs"]
        * SMALL["hyperparameters.rollout_steps"],
        overrides={**SMALL, **overrides},
        log=lambda *a, **k: None,
    )


# a fast trainer's run in seconds (agents.ppo.train overrides): tests of the trainer's files
SMALL = {
    "hyperparameters.num_envs": 32,
    "hyperparameters.rollout_steps": 8,
    "hyperparameters.minibatches": 2,
    "training.eval_every_s": 1.0,
    "training.validation_steps": 60,
    "training.checkpoint_every": 2,
    "training.episode_steps": 50,
}
