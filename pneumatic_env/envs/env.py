"""Gymnasium environments: ``PneumaticTrackingEnv`` (single) and ``PneumaticTrackingVectorEnv``.

Both are thin shells over ``TaskCore``; the README's *Spaces and reward* describes the
spaces and the reward.
"""
from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from .tasks import DEFAULT_EPISODE_STEPS, TASKS, EnvOptions, TaskCore

_OPTION_NAMES = set(EnvOptions.__dataclass_fields__)


def _split_kwargs(kwargs: dict) -> tuple[EnvOptions, dict]:
    options = EnvOptions(**{k: v for k, v in kwargs.items() if k in _OPTION_NAMES})
    return options, {k: v for k, v in kwargs.items() if k not in _OPTION_NAMES}


def _check_render_mode(render_mode) -> None:
    if render_mode not in (None, "rgb_array"):
        raise ValueError(f"render_mode = {render_mode!r} is not allowed: use 'rgb_array' or None")


def _task(name: str):
    if name not in TASKS:
        raise ValueError(f"task = {name!r} is not known: allowed {sorted(TASKS)}")
    return TASKS[name]


class PneumaticTrackingEnv(gym.Env):
    """One actuator; action = coil current (A), observation = [p1, p2, x, f, ref, preview...].

    Keyword arguments: ``task``, ``cylinder``, ``tube_length_m``, ``params`` (a fitted
    parameter YAML or mapping), the ``EnvOptions`` fields, ``render_mode``, and any physical
    parameter by name (``supply_pressure_pa=5e5``), validated by the config loader.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 50}

    def __init__(self, task: str = "ForceTrack", cylinder: str = "numatics",
                 tube_length_m: float | None = None, params=None, render_mode: str | None = None,
                 **kwargs):
        options, overrides = _split_kwargs(kwargs)
        _check_render_mode(render_mode)
        self.core = TaskCore(_task(task), 1, cylinder, tube_length_m, params, options, **overrides)
        self.render_mode = render_mode
        i_max = np.float32(self.core.i_max)
        self.action_space = gym.spaces.Box(-i_max, i_max, shape=(1,), dtype=np.float32)
        low, high = self.core.observation_bounds()
        self.observation_space = gym.spaces.Box(low, high, dtype=np.float32)
        self.metadata = {**self.metadata, "render_fps": int(round(1 / self.core.dt / 20))}
        self._trace = None

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self._rngs = [self.np_random]
        self.core.reset_envs(np.array([0]), self._rngs)
        if self.render_mode is not None:
            from .render import Trace
            self._trace = Trace()
            self._trace.record(self.core, 0)
        return self.core.observation()[0], {}

    def step(self, action):
        current = self.core.check_action(action)
        obs, reward = self.core.step(current, self._rngs)
        if self._trace is not None:
            self._trace.record(self.core, 0)
        return obs[0], float(reward[0]), False, False, self.core.info(0)

    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() called without render_mode='rgb_array'")
            return None
        from .render import render_rgb
        return render_rgb(self.core, 0, self._trace)


class PneumaticTrackingVectorEnv(VectorEnv):
    """``num_envs`` actuators advanced in one jitted call per step (``gym.make_vec``).

    Episodes are truncated after ``max_episode_steps`` (the registered 2000 unless given)
    inside the env and reset in the same
    step (``AutoresetMode.SAME_STEP``): the returned observation is the new episode's first,
    the last one is in ``info["final_obs"]``. Env ``i`` seeded with ``seed + i`` reproduces the
    single env seeded with ``seed + i`` exactly.
    """

    metadata = {"render_modes": ["rgb_array"], "autoreset_mode": AutoresetMode.SAME_STEP}

    def __init__(self, num_envs: int = 1, task: str = "ForceTrack", cylinder: str = "numatics",
                 tube_length_m: float | None = None, params=None,
                 max_episode_steps: int | None = None, render_mode: str | None = None, **kwargs):
        if int(num_envs) != num_envs or num_envs < 1:
            raise ValueError(f"num_envs = {num_envs!r} is not allowed: must be an integer >= 1")
        options, overrides = _split_kwargs(kwargs)
        _check_render_mode(render_mode)
        self.num_envs = int(num_envs)
        self.core = TaskCore(_task(task), self.num_envs, cylinder, tube_length_m, params, options,
                             **overrides)
        if max_episode_steps is None:
            max_episode_steps = DEFAULT_EPISODE_STEPS
        if int(max_episode_steps) != max_episode_steps or max_episode_steps < 1:
            raise ValueError(f"max_episode_steps = {max_episode_steps!r} is not allowed: must be "
                             "an integer >= 1")
        self.max_episode_steps = int(max_episode_steps)
        self.render_mode = render_mode
        i_max = np.float32(self.core.i_max)
        self.single_action_space = gym.spaces.Box(-i_max, i_max, shape=(1,), dtype=np.float32)
        low, high = self.core.observation_bounds()
        self.single_observation_space = gym.spaces.Box(low, high, dtype=np.float32)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self._rngs = [np.random.default_rng() for _ in range(self.num_envs)]

    def reset(self, *, seed=None, options=None):
        if seed is not None:
            seeds = ([seed + i for i in range(self.num_envs)] if isinstance(seed, int)
                     else list(seed))
            if len(seeds) != self.num_envs:
                raise ValueError(f"seed has {len(seeds)} entries, expected {self.num_envs}")
            self._rngs = [gym.utils.seeding.np_random(s)[0] for s in seeds]
        self.core.reset_envs(np.arange(self.num_envs), self._rngs)
        return self.core.observation(), {}

    def step(self, actions):
        current = self.core.check_action(actions)
        obs, reward = self.core.step(current, self._rngs)
        reward = reward.copy()
        info = self.core.info()
        terminated = np.zeros(self.num_envs, dtype=bool)
        truncated = self.core.step_count >= self.max_episode_steps
        if truncated.any():
            done = np.flatnonzero(truncated)
            final_obs = np.full(self.num_envs, None, dtype=object)
            for env in done:
                final_obs[env] = obs[env].copy()
            info["final_obs"] = final_obs
            info["_final_obs"] = truncated.copy()
            self.core.reset_envs(done, self._rngs)
            obs = self.core.observation()
        return obs, reward, terminated, truncated, info

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        from .render import render_rgb
        return render_rgb(self.core, 0, None)
