"""Residual control as Gymnasium envs: the wrappers and the registered ids.

The correction, its bound and its observation columns are :mod:`agents.residual`'s
(``ResidualCore``); here the base controller is built by name (``agents.registry``).
Three ways in, all with the same numbers:

* ``ResidualWrapper(gym.make(id, preview_steps=20), base="sliding_mode")``: a
  ``gym.Wrapper`` for any single-env algorithm (SB3: ``make_vec_env`` over it);
* ``ResidualVectorWrapper(gym.make_vec(id, num_envs=n, preview_steps=20))`` over the
  native vector env (the final observation of a truncated episode gets its columns too);
* registered ids: ``gym.make("pneumatic_env.agents.residual_env:pneumatic_env/ResidualForce
  Track-Numatics-2m-v0", correction_fraction=0.15)`` and the same id with ``gym.make_vec``
  (the module prefix imports this module, which registers them); the residual keywords
  (:class:`ResidualConfig`) and the env's are given together.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium.vector.utils import batch_space

from pneumatic_env import ids

from .base import Controller, ControllerContext
from .registry import make_base_controller
from .residual import (
    RESIDUAL_COLUMNS,
    ResidualConfig,
    ResidualCore,
    base_context,
    env_variant,
)
from .suite import suite_preview_steps

__all__ = [
    "ResidualWrapper",
    "ResidualVectorWrapper",
    "residual_core",
    "residual_env_id",
]


def residual_core(env, base: str | Controller, config: ResidualConfig) -> ResidualCore:
    """The residual core of ``env``: over ``base`` if a controller, else over the benchmark's
    ``base`` controller with ``config.gains``, else the gains of ``config.variant`` or of
    the env's variant; built on ``config.base_model_params`` if given (``base_context``)."""
    ctx = ControllerContext.from_env(env)
    if isinstance(base, Controller):
        controller = base
    else:
        config = ResidualConfig(**{**config.as_dict(), "base": base})
        config.validate()
        variant = config.variant or env_variant(env)
        controller = make_base_controller(base, base_context(ctx, config), variant, config.gains)
    return ResidualCore(controller, config)


def _box(dim: int) -> gym.spaces.Box:
    return gym.spaces.Box(-np.inf, np.inf, shape=(dim,), dtype=np.float32)


ACTION_SPACE = gym.spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32)


class ResidualWrapper(gym.Wrapper):
    """A single env with residual actions in [-1, 1] and the two residual columns.

    ``base``: ``"sliding_mode"`` or ``"pid"`` (``gains``, else the benchmark's gains for the
    env's variant or ``variant``) or a ``Controller``; the other keywords: :class:`ResidualConfig`.
    ``info["base_current_a"]``: the classical controller's current of the step.
    """

    def __init__(self, env: gym.Env, base: str | Controller = "sliding_mode", **config):
        super().__init__(env)
        self.residual = residual_core(env, base, ResidualConfig(**config))
        self.action_space = ACTION_SPACE
        self.observation_space = _box(
            gym.spaces.flatdim(env.observation_space) + len(RESIDUAL_COLUMNS)
        )

    def reset(self, *, seed=None, options=None):
        obs, info = self.env.reset(seed=seed, options=options)
        self.residual.reset()
        return self._observe(obs), info

    def _observe(self, obs):
        return np.concatenate([obs, self.residual.observe(obs[None])[0]])

    def step(self, action):
        u = self.residual.current(action)
        self.residual.applied(u)
        obs, reward, terminated, truncated, info = self.env.step(u)
        info["base_current_a"] = float(self.residual.u_base[0])
        return self._observe(obs), reward, terminated, truncated, info


class ResidualVectorWrapper(gym.vector.VectorWrapper):
    """The native vector env with residual actions (``(num_envs, 1)`` in [-1, 1]) and the
    two residual columns; arguments as :class:`ResidualWrapper`. Needs same-step
    autoreset (``info["final_obs"]`` gets the columns of the final observations)."""

    def __init__(
        self, env: gym.vector.VectorEnv, base: str | Controller = "sliding_mode", **config
    ):
        super().__init__(env)
        self.residual = residual_core(env, base, ResidualConfig(**config))
        self.single_action_space = ACTION_SPACE
        self.action_space = batch_space(ACTION_SPACE, env.num_envs)
        self.single_observation_space = _box(
            gym.spaces.flatdim(env.single_observation_space) + len(RESIDUAL_COLUMNS)
        )
        self.observation_space = batch_space(self.single_observation_space, env.num_envs)

    def reset(self, *, seed=None, options=None):
        obs, info = self.env.reset(seed=seed, options=options)
        self.residual.reset()
        return np.concatenate([obs, self.residual.observe(obs)], axis=1), info

    def step(self, actions):
        u = self.residual.current(actions)
        self.residual.applied(u)
        obs, reward, terminated, truncated, info = self.env.step(u[:, None])
        done = np.flatnonzero(np.logical_or(terminated, truncated))
        if done.size:
            final = info["final_obs"]
            cols = self.residual.peek(np.stack([final[i] for i in done]), done)
            final = final.copy()
            for j, i in enumerate(done):
                final[i] = np.concatenate([final[i], cols[j]])
            info["final_obs"] = final
            self.residual.reset(done)
        info["base_current_a"] = self.residual.u_base.copy()
        obs = np.concatenate([obs, self.residual.observe(obs)], axis=1)
        return obs, reward, terminated, truncated, info


# --------------------------------------------------------------------------- registered ids


def residual_env_id(env_id: str) -> str:
    """``pneumatic_env/ForceTrack-Numatics-2m-v0`` -> ``pneumatic_env/ResidualForceTrack-
    Numatics-2m-v0`` (registered when ``agents.residual_env`` is imported)."""
    e = ids.parse_env_id(env_id)
    return f"{ids.ENV_NAMESPACE}/Residual{e.task}-{e.variant}-v{ids.ENV_VERSION}"


def _make_single(env_id: str, **kwargs) -> gym.Env:
    config, env_kwargs = ResidualConfig.split(kwargs)
    env_kwargs.pop("max_episode_steps", None)  # gym.make's TimeLimit wraps the outside
    return ResidualWrapper(gym.make(env_id, **env_kwargs).unwrapped, **config.as_dict())


def _make_vector(env_id: str, num_envs: int = 1, **kwargs) -> gym.vector.VectorEnv:
    config, env_kwargs = ResidualConfig.split(kwargs)
    return ResidualVectorWrapper(
        gym.make_vec(env_id, num_envs=num_envs, **env_kwargs), **config.as_dict()
    )


def _register() -> None:
    preview = suite_preview_steps()
    for env_id in ids.registered_ids():
        if ids.parse_env_id(env_id).task != ids.FORCE_TRACK:
            continue
        rid = residual_env_id(env_id)
        if rid in gym.registry:
            continue
        gym.register(
            rid,
            entry_point=f"{__name__}:_make_single",
            vector_entry_point=f"{__name__}:_make_vector",
            max_episode_steps=ids.EPISODE_STEPS,
            kwargs={"env_id": env_id, "preview_steps": preview},
        )


_register()
