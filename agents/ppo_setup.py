"""The training env of a ppo_fast config (``agents/ppo.py``; the config itself:
``agents.ppo_config``): the training and validation references, the policy's input
columns, the vector env a config trains on (features, references, residual wrapper, or a
generalist's mixture) and the valve dead band the pure action map needs."""

from __future__ import annotations

import dataclasses
import fnmatch

import gymnasium as gym
import numpy as np

import pneumatic_env.params as P
from pneumatic_env.envs.randomization import check_randomization
from pneumatic_env.envs.tasks import scale_spec
from pneumatic_env.ids import EPISODE_STEPS

from .base import valve_currents
from .config import ConfigError, load_agent_config
from .generalist import MixtureVectorEnv
from .ppo_config import REFERENCES, PPOFastConfig, load_config
from .residual_env import ResidualVectorWrapper

__all__ = [
    "load_config",  # its home is agents.ppo_config; kept here for callers of this module
    "references",
    "select_columns",
    "make_training_env",
    "row_deadband_a",
    "PlantInputs",
]

REFERENCE_FILE_KEYS = ("training", "validation")


def references(cfg: PPOFastConfig) -> tuple[dict | None, list]:
    """(training reference spec in scale units, or None for the task's default; the
    validation references) of the config's ``reference`` file (``task``: the default
    file's validation)."""
    name = cfg.reference
    data = load_agent_config(REFERENCES if name == "task" else name, raw=REFERENCE_FILE_KEYS)
    return (None if name == "task" else data["training"]), data["validation"]


def select_columns(columns: list[str], patterns: list[str]) -> list[str]:
    """Columns matching each pattern in turn (``fnmatch``; ``rel_ref+*``), in column order."""
    out = []
    for pattern in patterns:
        hits = [c for c in columns if fnmatch.fnmatchcase(c, pattern)]
        if not hits:
            raise ConfigError(
                f"policy_inputs: {pattern!r} matches no observation column: allowed {columns}"
            )
        out += [c for c in hits if c not in out]
    return out


def make_training_env(cfg: PPOFastConfig, env_id: str, seed: int = 0, num_envs: int | None = None):
    """The vector env of a config: features, training references, residual wrapper; with
    ``variants`` (a generalist) an ``agents.generalist.MixtureVectorEnv`` of one such env
    per variant id, ``num_envs`` split evenly, plant columns ``plant_inputs``."""
    n_envs = cfg.hyperparameters.num_envs if num_envs is None else int(num_envs)
    variants = cfg.variants
    if variants:
        if n_envs % len(variants):
            raise ConfigError(
                f"num_envs = {n_envs} is not allowed with {len(variants)} variants: "
                "must be a multiple of their number"
            )
        single = dataclasses.replace(cfg, variants=None)
        envs = [make_training_env(single, v, seed, n_envs // len(variants)) for v in variants]
        return MixtureVectorEnv(envs, cfg.plant_inputs)
    episode = cfg.training.episode_steps
    kwargs = dict(cfg.env_kwargs)
    ref, _ = references(cfg)
    if ref is not None:
        probe = gym.make_vec(env_id, num_envs=1, **kwargs)
        kwargs["reference"] = scale_spec(ref, probe.unwrapped.reference_scale)
        probe.close()
    env = gym.make_vec(
        env_id,
        num_envs=n_envs,
        max_episode_steps=episode,
        reference_steps=max(episode, EPISODE_STEPS),  # the env's default reference length
        **kwargs,
    )
    if cfg.mode == "residual":
        env = ResidualVectorWrapper(env, **(cfg.residual or {}))
    return env


def row_deadband_a(env) -> np.ndarray | float:
    """The valve's dead-band current of each env row (a mixture's variants differ)."""
    top = env.unwrapped
    if isinstance(top, MixtureVectorEnv):
        return np.concatenate(
            [np.full(e.num_envs, valve_currents(e.unwrapped.base_params)[0]) for e in top.envs]
        )
    return valve_currents(top.base_params)[0]


class PlantInputs:
    """The critic's privileged inputs (asymmetric actor-critic, Pinto et al. 2018): each
    lane's plant parameters ``training.critic_plant_inputs`` as drawn for its episode,
    scaled to [-1, 1] over the config's randomisation ranges (all alternatives). Training
    only: the actor, and so the exported policy, never sees them."""

    def __init__(self, env, names: tuple[str, ...]):
        core = env.unwrapped.core
        spec = core.options.domain_randomization
        base = P.load_parameters(core.cylinder, params=core.plant_params)
        rand = check_randomization(spec, base, core.cylinder)
        spans: dict[str, list[float]] = {}
        for ranges in (rand.ranges, *(r for _, r in rand.alternatives)):
            for n, (lo, hi) in ranges.items():
                spans.setdefault(n, [float(base[n])]).extend((lo, hi))
        missing = [n for n in names if n not in spans]
        if missing:
            raise ConfigError(
                f"training.critic_plant_inputs = {list(names)!r}: {missing} not drawn; "
                f"allowed: parameters of env_kwargs.domain_randomization {sorted(spans)}"
            )
        lo = np.array([min(spans[n]) for n in names])
        hi = np.array([max(spans[n]) for n in names])
        self.center, self.half = (hi + lo) / 2, np.maximum((hi - lo) / 2, 1e-30)
        self.rows = np.array([P.PARAMETER_INDEX[n] for n in names])
        self.sim = core.sim

    def __len__(self) -> int:
        return len(self.rows)

    def __call__(self) -> np.ndarray:
        """(N, inputs) float32: each lane's current plant, scaled."""
        values = self.sim.params[self.rows].T
        return ((values - self.center) / self.half).astype(np.float32)
