"""Agent configs under ``configs/agents/``: controller gains and RL hyperparameters.

Every number in these files is an *entry* with its value, unit and where it comes from::

    kp_a_per_n:
      value: 0.02
      unit: A/N
      source: "tuned: agents/tune_pid.py grid search (see docs/benchmark.md)"

Entries may sit inside plain mappings (``hyperparameters:``, ``env_kwargs:``); strings and
booleans may be given bare (``algo: ppo``). :func:`load_agent_config` returns the same tree
with every entry replaced by its value and refuses a bare number, so no tuning constant
enters the code without a unit and a source.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import yaml

from pneumatic_env.config_files import ConfigError, config_dir, read_yaml  # YAML 1.2 floats, cached

__all__ = [
    "ConfigError",
    "agent_config_dir",
    "agent_config_path",
    "load_agent_config",
    "write_agent_config",
    "is_entry",
]

_ENTRY_KEYS = {"value", "unit", "source"}


def is_entry(node: Any) -> bool:
    """A mapping with a ``value`` key is an entry (value, unit, source)."""
    return isinstance(node, Mapping) and "value" in node


def _strip(node: Any, where: str) -> Any:
    if is_entry(node):
        extra = sorted(set(map(str, node)) - _ENTRY_KEYS)
        if extra:
            raise ConfigError(
                f"{where} has unknown key {extra[0]!r}; an entry has exactly the "
                "keys value, unit, source"
            )
        for key in ("unit", "source"):
            if not isinstance(node.get(key), str) or not node[key].strip():
                raise ConfigError(
                    f"{where} is missing {key!r}: every value needs a non-empty {key} string"
                )
        return node["value"]
    if isinstance(node, Mapping):
        return {str(k): _strip(v, f"{where}.{k}") for k, v in node.items()}
    if isinstance(node, (bool, str)) or node is None:
        return node
    if isinstance(node, list) and all(isinstance(v, (str, bool)) for v in node):
        return list(node)
    raise ConfigError(
        f"{where} = {node!r} is not allowed: a number (or list of numbers) must be "
        "an entry with value, unit and source"
    )


def agent_config_dir() -> Path:
    """``configs/agents`` of the configs directory in use (``pneumatic_env.params.config_dir``)."""
    return config_dir() / "agents"


def agent_config_path(name: str | os.PathLike) -> Path:
    """``configs/agents/<name>.yaml`` for a bare name, else the path itself."""
    p = Path(name)
    if p.suffix in (".yaml", ".yml") or p.parent != Path("."):
        return p
    return agent_config_dir() / f"{name}.yaml"


def load_agent_config(path: str | os.PathLike, raw: tuple = ()) -> dict:
    """The config at ``path`` (or ``configs/agents/<path>.yaml``) with entries resolved.

    Top-level keys listed in ``raw`` are returned as read (e.g. reference specs, whose
    numbers are in the units their kind documents).
    """
    p = agent_config_path(path)
    if not p.is_file():
        raise ConfigError(f"agent config {str(p)!r} does not exist")
    data = read_yaml(p)
    if not isinstance(data, Mapping):
        raise ConfigError(f"{p}: must be a mapping, got {type(data).__name__}")
    return {str(k): (v if k in raw else _strip(v, f"{p}: {k}")) for k, v in data.items()}


def write_agent_config(path: str | os.PathLike, tree: Mapping[str, Any], header: str = "") -> None:
    """Write a config tree (entries as dicts) with an optional comment header."""
    text = "".join(f"# {line}\n" if line else "#\n" for line in header.splitlines())
    text += yaml.safe_dump(_plain(tree), sort_keys=False, width=100)
    Path(path).write_text(text, encoding="utf-8")


def _plain(node: Any) -> Any:
    if isinstance(node, Mapping):
        return {str(k): _plain(v) for k, v in node.items()}
    if isinstance(node, (list, tuple)):
        return [_plain(v) for v in node]
    if hasattr(node, "item"):  # numpy scalars
        return node.item()
    return node
