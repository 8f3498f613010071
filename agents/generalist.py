"""One policy for several variants: a vector env that runs each variant on its own share of
the envs, with the nominal plant the controller may know in the observation.

``MixtureVectorEnv([env_a, env_b, ...])`` steps the per-variant vector envs (native, or
residual-wrapped) as one: rows ``0..n_a-1`` are ``env_a``'s, the next ``n_b`` ``env_b``'s,
and so on. Every update's batch mixes the variants in fixed proportions, the same
distribution of (variant, episode) pairs as drawing the variant per episode. Each variant
keeps its own observation scales (a normalised force is a fraction of *its* force scale),
reward scale and references. After each variant's columns the mixture appends the plant
columns ``param:<name>``: the nominal value of the base parameter ``<name>`` of that row's
variant (e.g. ``param:tube_length_m``, ``param:bore_diameter_m``), what a controller on a
rig may know about it. :class:`~pneumatic_env.agents.learned.LearnedController` rebuilds
them from its context's ``base_params``, so a generalist runs on one variant like any
actor.

Used by ``pneumatic-env train --algo ppo_fast`` when the config lists ``variants``
(``configs/agents/ppo_fast-generalist.yaml``).
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium.vector.utils import batch_space

from .residual import RESIDUAL_COLUMNS, env_variant

__all__ = ["PARAM_PREFIX", "param_columns", "param_values", "MixtureVectorEnv"]

PARAM_PREFIX = "param:"


def param_columns(names) -> list[str]:
    """``["param:tube_length_m", ...]`` for base-parameter names."""
    return [PARAM_PREFIX + n for n in names]


def param_values(base_params, columns) -> np.ndarray:
    """The values of the ``param:`` columns among ``columns`` (others are an error)."""
    values = []
    for c in columns:
        name = c[len(PARAM_PREFIX) :] if c.startswith(PARAM_PREFIX) else None
        if name is None or name not in base_params:
            raise ValueError(
                f"plant column = {c!r} is not allowed: use 'param:<name>' with a base "
                f"parameter name, e.g. 'param:tube_length_m'"
            )
        values.append(float(base_params[name]))
    return np.array(values)


class _BaseTime:
    """The residual base controllers' summed time (``ResidualCore.base_time_s``)."""

    def __init__(self, cores):
        self.cores = cores

    @property
    def base_time_s(self) -> float:
        return float(sum(c.base_time_s for c in self.cores))


class MixtureVectorEnv(gym.vector.VectorEnv):
    """Per-variant vector envs stepped as one, with plant columns ``param:<name>`` for
    ``plant_params`` appended to the observation.

    Spaces: each env's observation width must agree (same options); the action space is
    theirs. ``info`` holds the keys every env gives (concatenated) and ``final_obs`` with
    the plant columns appended. ``reference_scale`` and ``variants`` are per row.
    """

    def __init__(self, envs, plant_params=("tube_length_m", "bore_diameter_m")):
        if len(envs) < 2:
            raise ValueError(f"envs has {len(envs)} entries: a mixture needs at least 2")
        widths = {e.single_observation_space.shape for e in envs}
        if len(widths) != 1:
            raise ValueError(
                f"envs' observation shapes {sorted(widths)} differ: the variants must "
                "be made with the same options"
            )
        limits = {float(e.unwrapped.coil_current_max_a) for e in envs}
        if len(limits) != 1:
            raise ValueError(f"coil_current_max_a differs between the variants: {limits}")
        self.envs = list(envs)
        self.sizes = [e.num_envs for e in envs]
        self.bounds = np.cumsum([0] + self.sizes)
        self.num_envs = int(self.bounds[-1])
        self.plant_columns = param_columns(plant_params)
        self.variants = [env_variant(e) for e in envs]
        self._plant = np.concatenate(
            [
                np.tile(param_values(e.unwrapped.base_params, self.plant_columns), (n, 1))
                for e, n in zip(envs, self.sizes)
            ]
        ).astype(np.float32)
        first = envs[0]
        residual = hasattr(first, "residual")
        self.columns = (
            list(first.unwrapped.observation_columns)
            + (list(RESIDUAL_COLUMNS) if residual else [])
            + self.plant_columns
        )
        self.residual = _BaseTime([e.residual for e in envs]) if residual else None
        space, n_plant = first.single_observation_space, len(self.plant_columns)
        self.single_observation_space = gym.spaces.Box(
            np.concatenate([space.low, np.full(n_plant, -np.inf)]).astype(np.float32),
            np.concatenate([space.high, np.full(n_plant, np.inf)]).astype(np.float32),
            dtype=np.float32,
        )
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.single_action_space = first.single_action_space
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.reference_scale = np.concatenate(
            [np.full(n, e.unwrapped.reference_scale) for e, n in zip(envs, self.sizes)]
        )
        self.coil_current_max_a = limits.pop()
        self.metadata = dict(first.metadata)

    @property
    def unwrapped(self):
        return self

    def _rows(self, k: int) -> slice:
        return slice(int(self.bounds[k]), int(self.bounds[k + 1]))

    def _with_plant(self, obs_parts) -> np.ndarray:
        return np.concatenate([np.concatenate(obs_parts), self._plant], axis=1)

    def reset(self, *, seed=None, options=None):
        parts = []
        for k, env in enumerate(self.envs):
            sub_options = options
            if options and "start_step" in options:
                steps = np.broadcast_to(options["start_step"], (self.num_envs,))
                sub_options = {**options, "start_step": np.asarray(steps[self._rows(k)])}
            sub_seed = None if seed is None else int(seed) + int(self.bounds[k])
            obs, _ = env.reset(seed=sub_seed, options=sub_options)
            parts.append(obs)
        return self._with_plant(parts), {}

    def step(self, actions):
        actions = np.asarray(actions)
        if actions.shape[0] != self.num_envs:
            raise ValueError(
                f"actions has {actions.shape[0]} rows, expected num_envs = {self.num_envs}"
            )
        results = [env.step(actions[self._rows(k)]) for k, env in enumerate(self.envs)]
        obs = self._with_plant([r[0] for r in results])
        reward, terminated, truncated = (np.concatenate([r[i] for r in results]) for i in (1, 2, 3))
        infos = [r[4] for r in results]
        common = set.intersection(*(set(i) for i in infos)) - {"final_obs", "_final_obs"}
        info = {key: np.concatenate([i[key] for i in infos]) for key in sorted(common)}
        if any("final_obs" in i for i in infos):
            final = np.full(self.num_envs, None, dtype=object)
            for k, i in enumerate(infos):
                rows = self._rows(k)
                for j, o in enumerate(i.get("final_obs", [])):
                    if o is not None:
                        final[rows.start + j] = np.concatenate([o, self._plant[rows.start + j]])
            info["final_obs"] = final
            info["_final_obs"] = np.array([o is not None for o in final])
        return obs, reward, terminated, truncated, info

    def close(self, **kwargs):
        for env in self.envs:
            env.close(**kwargs)
