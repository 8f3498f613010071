"""Where the YAML configs are and how they are read: one place for both.

:func:`config_dir` finds ``configs/`` (``$PNEUMATIC_ENV_CONFIG_DIR``, the source
checkout's, or the copy shipped in the package); :func:`read_yaml` parses a file with
YAML 1.2 floats (``1e-3`` is a float, which PyYAML alone reads as a string) and caches
it until the file changes; :func:`resolve_cylinder` maps a cylinder's name or alias to
its file under ``configs/cylinders/``. Every number in the configs is an *entry*
``{value, unit, source}``: :func:`check_entry` reads one, :func:`make_entry` writes one.
Errors are :class:`ConfigError`.
"""

from __future__ import annotations

import functools
import importlib.resources
import os
import re
from collections.abc import Collection, Mapping
from pathlib import Path
from typing import Any

import yaml

from pneumatic_env.ids import CYLINDERS
from pneumatic_env.text_format import value_text

__all__ = [
    "CONFIG_DIR_ENV",
    "ENTRY_KEYS",
    "ConfigError",
    "check_entry",
    "config_dir",
    "is_entry",
    "make_entry",
    "read_yaml",
    "resolve_cylinder",
]

CONFIG_DIR_ENV = "PNEUMATIC_ENV_CONFIG_DIR"


class ConfigError(ValueError):
    """A parameter file or value is malformed or not allowed."""


# --------------------------------------------------------------------------- YAML reading


class _Loader(yaml.SafeLoader):
    """SafeLoader that also reads YAML 1.2 floats such as ``1e-3`` and ``6.5e5``."""


_Loader.yaml_implicit_resolvers = {
    key: list(resolvers) for key, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()
}
_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
    list("-+0123456789"),
)


@functools.lru_cache(maxsize=64)
def _parse_yaml_cached(path: str, mtime_ns: int, size: int) -> Any:
    try:
        with open(path, encoding="utf-8") as fh:
            return yaml.load(fh, Loader=_Loader)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: invalid YAML: {exc}") from None


def _stamp(path: Path) -> tuple[str, int, int]:
    try:
        st = os.stat(path)
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read: {exc.strerror}") from None
    return str(path), st.st_mtime_ns, st.st_size


def read_yaml(path: Path) -> Any:
    """Parsed content of a YAML file (YAML 1.2 floats), cached until the file changes.

    Do not mutate the result."""
    return _parse_yaml_cached(*_stamp(path))


# --------------------------------------------------------------------------- entries

ENTRY_KEYS = ("value", "unit", "source")


def is_entry(node: Any) -> bool:
    """A mapping with a ``value`` key is an entry (value, unit, source)."""
    return isinstance(node, Mapping) and "value" in node


def check_entry(
    where: str,
    entry: Any,
    keys: Collection[str] = ENTRY_KEYS,
    required: Collection[str] = ENTRY_KEYS,
) -> Mapping:
    """``entry`` checked as a mapping with no key outside ``keys``, every key of
    ``required``, and a ``unit`` and ``source`` (where given) that are non-empty strings.
    Errors start with ``where`` (the file and the entry's name)."""
    if not isinstance(entry, Mapping):
        raise ConfigError(
            f"{where} must be a mapping with keys {', '.join(required)}; got {value_text(entry)}"
        )
    unknown = sorted(set(map(str, entry)) - set(keys))
    if unknown:
        raise ConfigError(
            f"{where} has unknown key {unknown[0]!r}; allowed keys: {', '.join(sorted(keys))}"
        )
    for key in required:
        if key not in entry:
            raise ConfigError(f"{where} is missing {key!r}")
    for key in ("unit", "source"):
        if key in entry and (not isinstance(entry[key], str) or not entry[key].strip()):
            raise ConfigError(f"{where}: {key!r} must be a non-empty string")
    return entry


def make_entry(value: Any, unit: str, source: str, **more: Any) -> dict[str, Any]:
    """An entry as the configs write it: ``{value, unit, source}`` and any ``more`` keys."""
    return {"value": value, "unit": unit, "source": source, **more}


# --------------------------------------------------------------------------- locations


def config_dir() -> Path:
    """The directory of the YAML configs.

    ``$PNEUMATIC_ENV_CONFIG_DIR`` if set; else ``configs/`` at the repository root (a
    source checkout); else the copy shipped inside the package (``pneumatic_env/configs``).
    """
    env = os.environ.get(CONFIG_DIR_ENV)
    if env:
        path = Path(env).expanduser()
        if not path.is_dir():
            raise ConfigError(f"{CONFIG_DIR_ENV}={env!r} is not a directory")
        return path.resolve()
    repo = Path(__file__).resolve().parent.parent / "configs"
    if (repo / "air.yaml").is_file():
        return repo
    packaged = None
    try:
        packaged = Path(str(importlib.resources.files("pneumatic_env") / "configs"))
    except (ModuleNotFoundError, TypeError, ValueError):
        pass
    if packaged is not None and packaged.is_dir():
        return packaged
    raise ConfigError(
        f"no configs directory found (looked in {repo} and in the installed "
        f"package); set {CONFIG_DIR_ENV}"
    )


def _known_cylinders(cfg: Path) -> dict[str, str]:
    """Lower-case name or alias -> canonical name (CYLINDERS plus any other file stems)."""
    known = {}
    for canonical, aliases in CYLINDERS.items():
        known[canonical.lower()] = canonical
        for alias in aliases:
            known[alias.lower()] = canonical
    cyl_dir = cfg / "cylinders"
    if cyl_dir.is_dir():
        for path in sorted(cyl_dir.glob("*.yaml")):
            known.setdefault(path.stem.lower(), path.stem)
    return known


def _describe_cylinders(cfg: Path) -> str:
    known = _known_cylinders(cfg)
    parts = []
    for canonical in dict.fromkeys(known.values()):
        aliases = CYLINDERS.get(canonical, ())
        alias_text = "".join(f" (alias {a!r})" for a in aliases)
        parts.append(f"{canonical!r}{alias_text}")
    return ", ".join(parts)


def resolve_cylinder(cylinder: str) -> str:
    """Canonical name of a cylinder given its name or alias (case-insensitive)."""
    key = str(cylinder).strip().lower()
    for canonical, aliases in CYLINDERS.items():
        if key == canonical.lower() or key in aliases:
            return canonical
    cfg = config_dir()
    found = _known_cylinders(cfg).get(key)
    if found is None:
        raise ConfigError(
            f"unknown cylinder {cylinder!r}; known cylinders: {_describe_cylinders(cfg)}"
        )
    return found


def _cylinder_path(cylinder: str | os.PathLike, cfg: Path) -> Path:
    if isinstance(cylinder, os.PathLike) or str(cylinder).lower().endswith((".yaml", ".yml")):
        path = Path(cylinder).expanduser()
        if not path.is_file():
            raise ConfigError(f"cylinder file {str(path)!r} does not exist")
        return path.resolve()
    if not isinstance(cylinder, str):
        raise ConfigError(f"cylinder must be a name or a path, got {cylinder!r}")
    canonical = resolve_cylinder(cylinder)
    return cfg / "cylinders" / f"{canonical}.yaml"
