"""The ppo_fast config (``configs/agents/ppo_fast-*.yaml``) as typed dataclasses.

A file may ``extends: NAME`` another and override what it sets; numbers are entries
``{value, unit, source}`` (``agents.config``). :func:`load_config` checks each file's keys
(a typo is refused, naming the key, the file and the allowed keys), merges the files,
applies overrides ``{"section.key": value}`` and converts every setting to its field's
type (a wrong type is refused, naming the field and the value). The merged tree with its
units and sources stays in :attr:`PPOFastConfig.tree` (``to_tree``, ``unit``).
"""

from __future__ import annotations

import copy
import numbers
from collections.abc import Mapping
from dataclasses import MISSING, dataclass, field, fields
from pathlib import Path
from typing import Any, TypeVar

import gymnasium as gym
import numpy as np

from pneumatic_env.config_files import read_yaml

from .config import ConfigError, agent_config_path, is_entry, load_agent_config

__all__ = [
    "REFERENCES",
    "Hyperparameters",
    "TrainingSettings",
    "RewardWeights",
    "PureSettings",
    "PPOFastConfig",
    "load_config",
]

REFERENCES = "ppo_fast-references"  # configs/agents/ppo_fast-references.yaml
OVERRIDE_SOURCE = "override (agents.ppo_config.load_config)"

_S = TypeVar("_S", bound="_Section")


def _values(node: Any) -> Any:
    """``node`` with every entry replaced by its value."""
    if is_entry(node):
        return node["value"]
    if isinstance(node, Mapping):
        return {str(k): _values(v) for k, v in node.items()}
    return node


def _convert(value: Any, kind: str, where: str) -> Any:
    """``value`` as the field type ``kind`` (an annotation string), or a named error."""
    if kind.endswith(" | None"):
        if value is None:
            return None
        kind = kind.removesuffix(" | None")
    if kind.startswith("tuple["):
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{where} = {value!r} is not allowed: must be a list")
        item = kind.removeprefix("tuple[").split(",")[0]
        return tuple(_convert(v, item, f"{where}[{i}]") for i, v in enumerate(value))
    number = isinstance(value, numbers.Real) and not isinstance(value, bool)
    if kind == "int" and number and float(value).is_integer():
        value = int(value)
    allowed = {
        "float": number,
        "int": number and isinstance(value, numbers.Integral),
        "bool": isinstance(value, bool),
        "str": isinstance(value, str),
        "dict": isinstance(value, Mapping),
    }
    if not allowed[kind]:
        raise ConfigError(f"{where} = {value!r} is not allowed: must be of type {kind}")
    return {"float": float, "int": int, "bool": bool, "str": str, "dict": dict}[kind](value)


@dataclass(frozen=True)
class _Section:
    """A YAML section whose keys are the dataclass's fields."""

    @classmethod
    def keys(cls) -> list[str]:
        return [f.name for f in fields(cls)]

    @classmethod
    def from_tree(cls: type[_S], tree: Mapping, where: str) -> _S:
        """The section from its (merged) tree; entries or bare values."""
        unknown = sorted(set(map(str, tree)) - set(cls.keys()))
        if unknown:
            raise ConfigError(f"{where}.{unknown[0]} is not a key: allowed {cls.keys()}")
        kwargs = {}
        for f in fields(cls):
            if f.name in tree:
                kwargs[f.name] = _convert(_values(tree[f.name]), str(f.type), f"{where}.{f.name}")
            elif f.default is MISSING and f.default_factory is MISSING:
                raise ConfigError(f"{where}.{f.name} is missing")
        return cls(**kwargs)


@dataclass(frozen=True)
class Hyperparameters(_Section):
    """``hyperparameters``: PPO's (CleanRL names) and the networks'."""

    num_envs: int
    rollout_steps: int  # env steps per env and update
    minibatches: int  # per epoch
    epochs: int
    learning_rate: float
    learning_rate_final_fraction: float  # of learning_rate, at the end of the budget
    gamma: float  # per control period
    gae_lambda: float
    clip_range: float
    ent_coef: float
    vf_coef: float
    max_grad_norm: float
    target_kl: float | None  # 0 or None: no early stop of an update's epochs
    hidden_pi: tuple[int, ...]  # neurons per hidden layer
    hidden_v: tuple[int, ...]
    log_std_init: float
    log_std_min: float
    clip_obs: float  # running std


@dataclass(frozen=True)
class TrainingSettings(_Section):
    """``training``: budget, episodes, validation, checkpoints."""

    episode_steps: int  # control periods
    minutes: float  # wall-time budget
    eval_every_s: float  # wall time between validations
    validation_steps: int  # control periods per validation reference
    checkpoint_every: int  # updates
    torch_threads: int
    stagger: bool  # episodes start at random steps
    eval_every_steps: float = 0.0  # env steps between validations; 0: by wall time only
    total_steps: float | None = None  # env-step budget; None: wall time only
    validation_variants: tuple[str, ...] | None = None  # default: the trained variants
    residual_gains: tuple[float, ...] | None = None  # after training (agents.residual_gain)
    residual_gain_draws: int = 0  # drawn plants per validation reference in that choice
    validation_draws: int = 0  # drawn plants per validation reference in choosing the best
    critic_plant_inputs: tuple[str, ...] = ()  # drawn plant parameters the critic sees
    actor_plant_prediction: float = 0.0  # weight of the actor's head predicting them; 0: none


@dataclass(frozen=True)
class RewardWeights(_Section):
    """``reward``: r = -(e/(u_e Fs))^2 - w_l1 |e/(u_e Fs)| - w_c (du/u_c)^2 - w_u (u/u_u)^2
    - w_r a^2."""

    error_unit_fraction: float  # of the force scale
    l1_weight: float
    chatter_weight: float
    chatter_unit_a: float
    effort_weight: float
    effort_unit_a: float
    residual_weight: float  # residual mode only


@dataclass(frozen=True)
class PureSettings(_Section):
    """``pure``: the action map of a pure policy and its teacher (``agents.teacher``)."""

    action_scale_a: float = 1.3  # A per unit action, just above full valve opening
    deadband_smoothing: float = 0.0  # action width of the dead-band step; 0: off
    teacher: str | None = None  # a classical controller, or None
    teacher_weight: float = 1.0  # imitation loss weight at the start
    teacher_unit: float = 0.02  # action difference that costs teacher_weight
    teacher_fraction: float = 0.5  # share of the budget over which the weight falls to 0


SECTIONS: dict[str, type[_Section]] = {
    "hyperparameters": Hyperparameters,
    "training": TrainingSettings,
    "reward": RewardWeights,
    "pure": PureSettings,
}


@dataclass(frozen=True)
class PPOFastConfig:
    """A ppo_fast config; ``env_kwargs`` and ``residual`` are passed on as keyword
    arguments (``gym.make_vec``, ``agents.residual.ResidualVectorWrapper``)."""

    algo: str
    env: str  # the env id trained on unless another is given
    mode: str  # "residual" or "pure"
    env_kwargs: dict
    policy_inputs: tuple[str, ...]  # observation columns (fnmatch patterns), in order
    reward: RewardWeights
    hyperparameters: Hyperparameters
    training: TrainingSettings
    pure: PureSettings = PureSettings()
    residual: dict | None = None
    reference: str = REFERENCES  # training references' file; "task": the env's default
    variants: tuple[str, ...] | None = None  # a generalist's env ids
    plant_inputs: tuple[str, ...] = ("tube_length_m", "bore_diameter_m")
    tree: dict = field(default_factory=dict, repr=False, compare=False)  # entries as read

    @classmethod
    def keys(cls) -> list[str]:
        return [f.name for f in fields(cls) if f.name != "tree"]

    @classmethod
    def from_tree(cls, tree: Mapping) -> PPOFastConfig:
        """The config from a merged tree (entries or bare values)."""
        _check_keys(tree, "config")
        kwargs: dict[str, Any] = {"tree": copy.deepcopy(dict(tree))}
        for f in fields(cls):
            if f.name == "tree":
                continue
            if f.name in tree and f.name in SECTIONS:
                kwargs[f.name] = SECTIONS[f.name].from_tree(tree[f.name] or {}, f.name)
            elif f.name in tree:
                kwargs[f.name] = _convert(_values(tree[f.name]), str(f.type), f.name)
            elif f.default is MISSING:
                raise ConfigError(f"ppo_fast config is missing {f.name!r}")
        return cls(**kwargs)

    def to_tree(self) -> dict:
        """The config's tree: numbers as entries with their units and sources."""
        return copy.deepcopy(self.tree)

    def unit(self, key: str) -> str | None:
        """The unit of ``"section.key"`` (None for a bare value)."""
        node: Any = self.tree
        for part in key.split("."):
            node = node[part]
        return node["unit"] if is_entry(node) else None


def _check_keys(tree: Mapping, where: str) -> None:
    """Refuse a key that is not a config's or its section's (a typo), naming it."""
    allowed = PPOFastConfig.keys() + ["extends"]
    for key in map(str, tree):
        if key not in allowed:
            raise ConfigError(f"{where}: unknown key {key!r}: allowed {allowed}")
    for name, section in SECTIONS.items():
        node = tree.get(name)
        if not isinstance(node, Mapping):
            continue
        for key in map(str, node):
            if key not in section.keys():
                raise ConfigError(
                    f"{where}: unknown key {name}.{key}: allowed in {name} {section.keys()}"
                )


def _merge(base: dict, top: Mapping) -> dict:
    out = dict(base)
    for key, value in top.items():
        out[key] = (
            _merge(out[key], value)
            if isinstance(value, Mapping) and not is_entry(value) and isinstance(out.get(key), dict)
            else value
        )
    return out


def _load_tree(config: str | Path, seen: tuple = ()) -> dict:
    """A config file's tree, entries as read; ``extends: NAME`` takes NAME's tree and
    overrides what this file sets."""
    path = agent_config_path(config)
    if path in seen:
        raise ConfigError(f"{path}: extends itself (through {[str(p) for p in seen]})")
    load_agent_config(path)  # checks every number is an entry
    tree = copy.deepcopy(dict(read_yaml(path)))
    _check_keys(tree, str(path))
    parent = tree.pop("extends", None)
    return _merge(_load_tree(parent, seen + (path,)), tree) if parent else tree


def _override(tree: dict, key: str, value: Any) -> None:
    """Set ``"section.key"``; a number keeps its entry's unit, its source says override."""
    *sections, name = key.split(".")
    node = tree
    for part in sections:
        node = node.setdefault(part, {})
    old = node.get(name)
    if is_entry(old):
        node[name] = {"value": value, "unit": old["unit"], "source": OVERRIDE_SOURCE}
    elif isinstance(value, (bool, str)) or value is None or isinstance(value, (list, dict)):
        node[name] = value
    else:
        node[name] = {"value": value, "unit": "-", "source": OVERRIDE_SOURCE}


def drawn_plants(cfg: PPOFastConfig, key: str) -> tuple[int, dict | None]:
    """(``training.<key>``, a count of plants drawn per validation reference, and the
    config's randomisation they are drawn from), or a named error: the count is 0, or
    positive with ``env_kwargs.domain_randomization`` set."""
    draws = getattr(cfg.training, key)
    randomization = cfg.env_kwargs.get("domain_randomization")
    if draws < 0 or (draws and not randomization):
        raise ConfigError(
            f"training.{key} = {draws!r} is not allowed: 0, or a positive count "
            "with env_kwargs.domain_randomization set"
        )
    return int(draws), randomization


def load_config(
    config: str | Path | Mapping | PPOFastConfig, overrides: Mapping | None = None
) -> PPOFastConfig:
    """The ppo_fast config of a file (``extends`` followed), a tree or a config, with
    ``overrides`` {"section.key": value}."""
    if isinstance(config, PPOFastConfig):
        config = config.tree
    tree = _load_tree(config) if not isinstance(config, Mapping) else copy.deepcopy(dict(config))
    if tree.get("algo") != "ppo_fast":
        raise ConfigError(
            f"config {config if not isinstance(config, Mapping) else '<dict>'}: "
            f"algo = {tree.get('algo')!r}, expected 'ppo_fast'"
        )
    for key, value in (overrides or {}).items():
        _override(tree, key, value)
    _check_keys(tree, "config with overrides")
    if tree.get("mode") not in ("residual", "pure"):
        raise ConfigError(f"mode = {tree.get('mode')!r} is not allowed: 'residual' or 'pure'")
    cfg = PPOFastConfig.from_tree(tree)
    drawn_plants(cfg, "validation_draws")
    weight = cfg.training.actor_plant_prediction
    if not (np.isfinite(weight) and weight >= 0) or (
        weight > 0 and not cfg.training.critic_plant_inputs
    ):
        raise ConfigError(
            f"training.actor_plant_prediction = {weight!r} is not allowed: a finite number "
            ">= 0, and 0 unless training.critic_plant_inputs names the plant to predict"
        )
    if cfg.variants is not None:
        if len(cfg.variants) < 2:
            raise ConfigError(
                f"variants = {list(cfg.variants)!r} is not allowed: a list of >= 2 env ids"
            )
        for v in cfg.variants:
            if v not in gym.registry:
                raise ConfigError(f"variants: {v!r} is not a registered env id")
    return cfg
