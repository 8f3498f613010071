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

from pneumatic_env.config_files import (  # YAML 1.2 floats, cached; the entry rule
    ConfigError,
    check_entry,
    config_dir,
    is_entry,
    read_yaml,
)

__all__ = [
    "ConfigError",
    "agent_config_dir",
    "agent_config_path",
    "load_agent_config",
    "write_agent_config",
    "is_entry",
]


def _strip(node: Any, where: str) -> Any:
    if is_entry(node):
        return check_entry(where, node)["value"]
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
