"""The classical controllers' reference smoothing (``Controller.smoothed_reference``,
``reference_smoothing_steps``): the centred mean of the reference over k - W .. k + W from
the controller's own past references and the preview."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import pneumatic_env
from conftest import PID_TEST_GAINS
from pneumatic_env.agents.base import OBS_REF, ControllerContext
from pneumatic_env.agents.pid import PIDController
from pneumatic_env.agents.registry import resolve_controller

ID_05 = pneumatic_env.env_id("ForceTrack", "Numatics", "0.5")
H = 20  # preview steps


def _context() -> ControllerContext:
    env = gym.make(ID_05, max_episode_steps=10, preview_steps=H, normalize_observation=False)
    ctx = ControllerContext.from_env(env)
    env.close()
    return ctx


def _pid(ctx, steps):
    return PIDController(ctx, **PID_TEST_GAINS, reference_smoothing_steps=steps)


def _by_hand(reference: np.ndarray, k: int, w: int) -> np.ndarray:
    """Mean of the reference over k + j - w .. k + j + w for j = 0..H, written out: before
    the episode the first reference, beyond the preview its last sample."""
    seen = reference[: k + H + 1]
    out = []
    for j in range(H + 1):
        window = [seen[min(max(t, 0), k + H)] for t in range(k + j - w, k + j + w + 1)]
        out.append(sum(window) / len(window))
    return np.array(out)


def _observations(refs: list[np.ndarray], k: int, ks: list[int]) -> np.ndarray:
    obs = np.zeros((len(refs), OBS_REF + H + 1))
    obs[:, :OBS_REF] = [4e5, 3e5, 0.0, 10.0]
    for i, (r, ki) in enumerate(zip(refs, ks)):
        obs[i, OBS_REF:] = r[ki : ki + H + 1]
    return obs


def test_the_smoothed_reference_is_the_centred_mean_of_past_and_preview():
    rng = np.random.default_rng(5)
    widths = np.array([0, 2, 3])
    refs = [rng.normal(size=80).cumsum() for _ in widths]
    ctrl = _pid(_context(), widths)
    ctrl.reset()
    start = [0, 0, 0]
    for k in range(40):
        if k == 25:  # row 1 starts a new episode on another reference
            ctrl.reset([1])
            refs[1], start[1] = rng.normal(size=80).cumsum(), k
        ks = [k - s for s in start]
        obs = _observations(refs, k, ks)
        smoothed = ctrl.smoothed_reference(obs) if k else obs  # allocated at the first act
        if k:
            assert np.array_equal(smoothed[0], obs[0])  # W = 0: the observation itself
            for i in (1, 2):
                want = _by_hand(refs[i], ks[i], int(widths[i]))
                np.testing.assert_allclose(smoothed[i, OBS_REF:], want, rtol=0, atol=1e-12)
                assert np.array_equal(smoothed[i, :OBS_REF], obs[i, :OBS_REF])
        ctrl.act(obs)


@pytest.mark.parametrize("w", [1, 2, 4])
def test_a_step_becomes_a_ramp_centred_on_it(w):
    ctrl = _pid(_context(), w)
    reference = np.r_[np.zeros(10), np.ones(40)]  # the step 10 periods ahead
    obs = _observations([reference], 0, [0])
    ctrl.act(obs)
    ramp = ctrl.smoothed_reference(obs)[0, OBS_REF:]
    j = np.arange(H + 1)
    want = np.clip((j - (10 - w) + 1) / (2 * w + 1), 0.0, 1.0)
    np.testing.assert_allclose(ramp, want, rtol=0, atol=1e-12)
    assert ramp[10] == pytest.approx((w + 1) / (2 * w + 1))  # half-way up at the step


@pytest.mark.parametrize("bad", [-1, 1.5, H + 1, True, np.nan])
def test_a_bad_smoothing_width_is_refused_naming_the_field(bad):
    with pytest.raises(
        ValueError, match="reference_smoothing_steps = .* is not allowed: an integer"
    ):
        _pid(_context(), bad)


def test_the_sliding_modes_peek_sees_the_same_smoothed_reference_as_act():
    venv = gym.make_vec(ID_05, num_envs=2, preview_steps=H, normalize_observation=False)
    spec = resolve_controller("sliding_mode", "Numatics-0.5m")
    ctx = ControllerContext.from_env(venv)
    sm, plain = spec.build(ctx), spec.build(ctx)
    sm.set_reference_smoothing("test", 3)
    obs, _ = venv.reset(
        seed=0, options={"reference": {"kind": "step", "amplitude": 40.0, "step_time_s": 0.01}}
    )
    u_sm, u_plain = [], []
    for _ in range(15):
        u = sm.act(obs)
        u_sm.append(u)
        u_plain.append(plain.act(obs))
        obs, *_ = venv.step(u.reshape(2, 1))
    peeked, error = sm.peek(obs, np.arange(2))
    assert np.array_equal(peeked, sm.act(obs)) and np.array_equal(error, sm.last_error)
    # the step 10 ms ahead: the smoothed reference moves the current earlier
    assert not np.array_equal(np.array(u_sm), np.array(u_plain))
    venv.close()
