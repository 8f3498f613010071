"""Stable-Baselines3 adapter for the native Gymnasium vector env.

``SB3VecEnv(venv)`` wraps a ``gymnasium.vector.VectorEnv`` with same-step autoreset (our
``PneumaticTrackingVectorEnv`` from ``gym.make_vec``) as an SB3 ``VecEnv``: ``step_wait``
returns (obs, rewards, dones, infos) with the last observation of a finished episode in
``infos[i]["terminal_observation"]`` and ``infos[i]["TimeLimit.truncated"]`` set on
truncation, exactly as SB3's ``DummyVecEnv`` over the single envs would. Seeds given by
``seed(s)`` apply at the next ``reset()``: env i gets ``s + i`` (the vector env's own rule,
which reproduces the single env seeded ``s + i``).

With ``normalize_action=True`` (default) the policy acts in [-1, 1] and the adapter scales
to the env's current range; SAC's squashing and PPO's clipping both work in that box.

``action_repeat=k`` holds each action for k control periods (the agent's step is k env
steps, its reward their sum, its observation the last): an agent then decides every k ms
and its discount spans k times the time, the fix tried for SAC at a 1 ms control period
(value methods degrade as the time step shrinks, Tallec et al. 2019). The episode length
must be a multiple of k so that every episode ends on an agent step. The adapter also
times the env (``env_time_s``) for throughput reports.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode
from stable_baselines3.common.vec_env import VecEnv

__all__ = ["SB3VecEnv", "make_sb3_vec_env"]


class SB3VecEnv(VecEnv):
    """An SB3 ``VecEnv`` over a Gymnasium vector env with ``AutoresetMode.SAME_STEP``."""

    def __init__(
        self, venv: gym.vector.VectorEnv, normalize_action: bool = True, action_repeat: int = 1
    ):
        mode = venv.metadata.get("autoreset_mode")
        if mode != AutoresetMode.SAME_STEP:
            raise ValueError(
                f"SB3VecEnv needs a vector env with autoreset_mode = SAME_STEP "
                f"(final observation in info['final_obs']); got {mode!r}"
            )
        space = venv.single_action_space
        if not isinstance(space, gym.spaces.Box):
            raise ValueError(f"SB3VecEnv supports Box action spaces, got {space!r}")
        if (
            isinstance(action_repeat, bool)
            or not isinstance(action_repeat, int)
            or action_repeat < 1
        ):
            raise ValueError(
                f"SB3VecEnv: action_repeat = {action_repeat!r} is not allowed: an integer >= 1"
            )
        self.venv = venv
        self.normalize_action = bool(normalize_action)
        self.action_repeat = action_repeat
        self._low, self._high = space.low.astype(np.float64), space.high.astype(np.float64)
        action_space = (
            gym.spaces.Box(-1.0, 1.0, shape=space.shape, dtype=np.float32)
            if self.normalize_action
            else space
        )
        self.env_time_s = 0.0
        self.env_steps = 0
        self._actions: np.ndarray | None = None
        super().__init__(venv.num_envs, venv.single_observation_space, action_space)

    # -- actions -----------------------------------------------------------------------------
    def to_env_action(self, actions: np.ndarray) -> np.ndarray:
        """Policy actions (n, dim) -> env actions (coil currents in A)."""
        a = np.asarray(actions, dtype=np.float64).reshape(
            (self.num_envs,) + self.venv.single_action_space.shape
        )
        if self.normalize_action:
            a = self._low + 0.5 * (np.clip(a, -1.0, 1.0) + 1.0) * (self._high - self._low)
        return a

    # -- VecEnv API ----------------------------------------------------------------------------
    def reset(self):
        seeds = self._seeds
        if all(s is None for s in seeds):
            seed = None
        elif any(s is None for s in seeds):
            raise ValueError(
                f"SB3VecEnv.reset: seeds {seeds} mix None and integers; give all "
                "or none (seed(s) sets all)"
            )
        else:
            seed = [int(s) for s in seeds]
        options = self._options[0] if self._options and self._options[0] else None
        t0 = time.perf_counter()
        obs, info = self.venv.reset(seed=seed, options=options)
        self.env_time_s += time.perf_counter() - t0
        self.reset_infos = self._split_info(info)
        self._reset_seeds()
        self._reset_options()
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = actions

    def step_wait(self):
        if self._actions is None:
            raise RuntimeError("SB3VecEnv.step_wait called without step_async")
        actions = self.to_env_action(self._actions)
        self._actions = None
        rewards = np.zeros(self.num_envs, dtype=np.float64)
        dones = np.zeros(self.num_envs, dtype=bool)
        ends: dict[int, dict] = {}
        for _ in range(self.action_repeat):
            t0 = time.perf_counter()
            obs, reward, terminated, truncated, info = self.venv.step(actions)
            self.env_time_s += time.perf_counter() - t0
            self.env_steps += self.num_envs
            rewards += np.where(dones, 0.0, reward)  # an ended episode earns no more
            final_obs = info.get("final_obs")
            final_info = info.get("final_info")
            for i in np.flatnonzero(np.logical_or(terminated, truncated) & ~dones):
                end = {
                    "terminal_observation": final_obs[i],
                    "TimeLimit.truncated": bool(truncated[i] and not terminated[i]),
                }
                if isinstance(final_info, dict):
                    end.update(self._split_info(final_info)[i])
                ends[int(i)] = end
            dones |= np.logical_or(terminated, truncated)
        infos = self._split_info(info)
        for i in range(self.num_envs):  # as DummyVecEnv: the flag on every step
            infos[i]["TimeLimit.truncated"] = False
            infos[i].update(ends.get(i, {}))
        return obs, np.asarray(rewards, dtype=np.float32), dones, infos

    def _split_info(self, info: dict) -> list[dict]:
        """Gymnasium's dict of arrays (with ``_key`` masks) -> one dict per env."""
        out: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        for key, value in info.items():
            if key.startswith("_") or key in ("final_obs", "final_info"):
                continue
            mask = info.get("_" + key)
            for i in range(self.num_envs):
                if mask is None or mask[i]:
                    v = value[i]
                    out[i][key] = v.item() if isinstance(v, np.generic) else v
        return out

    def close(self) -> None:
        self.venv.close()

    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        return super().seed(seed)

    def _indices(self, indices) -> list[int]:
        if indices is None:
            return list(range(self.num_envs))
        if isinstance(indices, int):
            return [indices]
        return list(indices)

    # The native vector env is one object for all envs: attributes are shared.
    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        value = getattr(self.venv, attr_name)
        return [value for _ in self._indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        if indices is not None and sorted(self._indices(indices)) != list(range(self.num_envs)):
            raise ValueError(
                f"SB3VecEnv.set_attr({attr_name!r}): the native vector env shares "
                "its attributes; set them for all envs (indices=None)"
            )
        setattr(self.venv, attr_name, value)

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs):
        result = getattr(self.venv, method_name)(*method_args, **method_kwargs)
        return [result for _ in self._indices(indices)]

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [False for _ in self._indices(indices)]

    def get_images(self):
        return [None for _ in range(self.num_envs)]


def make_sb3_vec_env(
    env_id: str,
    num_envs: int,
    episode_steps: int | None = None,
    normalize_action: bool = True,
    action_repeat: int = 1,
    **env_kwargs,
) -> SB3VecEnv:
    """``gym.make_vec(env_id, num_envs)`` (native vector env) wrapped for SB3.

    ``episode_steps`` sets the episode length (default the registered ``ids.EPISODE_STEPS``);
    it must be a multiple of ``action_repeat``.
    """
    if episode_steps is not None:
        env_kwargs["max_episode_steps"] = int(episode_steps)
    venv = gym.make_vec(env_id, num_envs=num_envs, **env_kwargs)
    steps = int(venv.unwrapped.max_episode_steps)
    if isinstance(action_repeat, int) and action_repeat >= 1 and steps % action_repeat:
        raise ValueError(
            f"episode_steps = {steps} is not allowed with action_repeat = {action_repeat}: "
            "it must be a multiple of it (every episode ends on an agent step)"
        )
    return SB3VecEnv(venv, normalize_action=normalize_action, action_repeat=action_repeat)
