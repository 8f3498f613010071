"""The ppo_fast configuration and its training env (``agents/ppo.py``): config files with
``extends`` and overrides, the training and validation references, the policy's input
columns, the vector env a config trains on (features, references, residual wrapper, or a
generalist's mixture) and the pure action map's settings."""

from __future__ import annotations

import fnmatch
import json
from pathlib import Path

import gymnasium as gym
import numpy as np

from pneumatic_env.envs.tasks import scale_spec

from .base import valve_currents
from .config import ConfigError, agent_config_path, load_agent_config
from .generalist import MixtureVectorEnv
from .residual_env import ResidualVectorWrapper

__all__ = [
    "load_config",
    "references",
    "select_columns",
    "make_training_env",
    "action_scale_a",
    "deadband_smoothing",
    "row_deadband_a",
]

REFERENCES = "ppo_fast-references"  # configs/agents/ppo_fast-references.yaml
REFERENCE_FILE_KEYS = ("training", "validation")


# --------------------------------------------------------------------------- configuration


def _merge(base: dict, top: dict) -> dict:
    out = dict(base)
    for key, value in top.items():
        out[key] = (
            _merge(out[key], value)
            if isinstance(value, dict) and isinstance(out.get(key), dict)
            else value
        )
    return out


def _load_tree(config: str | Path, seen: tuple = ()) -> dict:
    """A config file; ``extends: NAME`` takes NAME's config and overrides what this sets."""
    path = agent_config_path(config)
    if path in seen:
        raise ConfigError(f"{path}: extends itself (through {[str(p) for p in seen]})")
    cfg = load_agent_config(path)
    parent = cfg.pop("extends", None)
    return _merge(_load_tree(parent, seen + (path,)), cfg) if parent else cfg


def load_config(config: str | Path | dict, overrides: dict | None = None) -> dict:
    """The ppo_fast config (entries resolved, ``extends`` followed) with ``overrides``
    {"section.key": value}."""
    cfg = _load_tree(config) if not isinstance(config, dict) else json.loads(json.dumps(config))
    if cfg.get("algo") != "ppo_fast":
        raise ConfigError(
            f"config {config if not isinstance(config, dict) else '<dict>'}: "
            f"algo = {cfg.get('algo')!r}, expected 'ppo_fast'"
        )
    for key, value in (overrides or {}).items():
        section, _, name = key.rpartition(".")
        node = cfg
        for part in filter(None, section.split(".")):
            node = node.setdefault(part, {})
        node[name] = value
    if cfg.get("mode") not in ("residual", "pure"):
        raise ConfigError(f"mode = {cfg.get('mode')!r} is not allowed: 'residual' or 'pure'")
    for key in ("env_kwargs", "policy_inputs", "reward", "hyperparameters", "training"):
        if key not in cfg:
            raise ConfigError(f"ppo_fast config is missing {key!r}")
    variants = cfg.get("variants")
    if variants is not None:
        ids = list(gym.registry)
        if not isinstance(variants, list) or len(variants) < 2:
            raise ConfigError(f"variants = {variants!r} is not allowed: a list of >= 2 env ids")
        for v in variants:
            if v not in ids:
                raise ConfigError(f"variants: {v!r} is not a registered env id")
    return cfg


def references(cfg: dict) -> tuple[dict | None, list]:
    """(training reference spec in scale units, or None for the task's default; the
    validation references) of the config's ``reference`` file (``task``: the default
    file's validation)."""
    name = cfg.get("reference", REFERENCES)
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


def make_training_env(cfg: dict, env_id: str, seed: int = 0, num_envs: int | None = None):
    """The vector env of a config: features, training references, residual wrapper; with
    ``variants`` (a generalist) an ``agents.generalist.MixtureVectorEnv`` of one such env
    per variant id, ``num_envs`` split evenly, plant columns ``plant_inputs``."""
    hp, tr = cfg["hyperparameters"], cfg["training"]
    n_envs = int(hp["num_envs"]) if num_envs is None else int(num_envs)
    variants = cfg.get("variants")
    if variants:
        if n_envs % len(variants):
            raise ConfigError(
                f"num_envs = {n_envs} is not allowed with {len(variants)} variants: "
                "must be a multiple of their number"
            )
        single = {k: v for k, v in cfg.items() if k != "variants"}
        envs = [make_training_env(single, v, seed, n_envs // len(variants)) for v in variants]
        return MixtureVectorEnv(envs, cfg.get("plant_inputs", ("tube_length_m", "bore_diameter_m")))
    episode = int(tr["episode_steps"])
    kwargs = dict(cfg["env_kwargs"])
    ref, _ = references(cfg)
    if ref is not None:
        probe = gym.make_vec(env_id, num_envs=1, **kwargs)
        kwargs["reference"] = scale_spec(ref, probe.unwrapped.reference_scale)
        probe.close()
    env = gym.make_vec(
        env_id,
        num_envs=n_envs,
        max_episode_steps=episode,
        reference_steps=max(episode, 2000),
        **kwargs,
    )
    if cfg["mode"] == "residual":
        env = ResidualVectorWrapper(env, **cfg["residual"])
    return env


# --------------------------------------------------------------------------- pure actions


def action_scale_a(cfg: dict) -> float:
    """Pure mode: amperes per unit action (default 1.3 A, just above full valve opening)."""
    return float((cfg.get("pure") or {}).get("action_scale_a", 1.3))


def deadband_smoothing(cfg: dict) -> float:
    """Pure mode: the action width of the dead-band step (``learned.pure_current``; 0: off)."""
    return float((cfg.get("pure") or {}).get("deadband_smoothing", 0.0))


def row_deadband_a(env) -> np.ndarray | float:
    """The valve's dead-band current of each env row (a mixture's variants differ)."""
    top = env.unwrapped
    if isinstance(top, MixtureVectorEnv):
        return np.concatenate(
            [np.full(e.num_envs, valve_currents(e.unwrapped.base_params)[0]) for e in top.envs]
        )
    return valve_currents(top.base_params)[0]
