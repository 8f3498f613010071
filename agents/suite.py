"""The benchmark suite (``configs/benchmark.yaml``): its tasks, variants and settings.

``load_suite`` reads and checks the file; ``parse_variant`` turns a variant
(``Numatics-2m``) into its env id. The suite's ``preview_steps`` (20) is the benchmark's
observation layout, a different fact from the env's default (``ids.ENV_PREVIEW_STEPS``, 10).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from pneumatic_env import ids
from pneumatic_env.config_files import ConfigError, config_dir, read_yaml
from pneumatic_env.references import make_reference

__all__ = [
    "BenchTask",
    "Suite",
    "default_suite_path",
    "load_suite",
    "parse_variant",
    "suite_preview_steps",
]


@dataclass(frozen=True)
class BenchTask:
    name: str
    seed: int
    duration_s: float
    reference: dict  # amplitudes/offsets in units of the force scale


@dataclass(frozen=True)
class Suite:
    version: str
    task: str
    variants: tuple
    preview_steps: int
    tasks: tuple
    bandwidth_task: str
    bins_per_octave: float
    bandwidth_level: float
    plot_tasks: dict = field(default_factory=dict)
    path: str = ""

    def task_named(self, name: str) -> BenchTask:
        for t in self.tasks:
            if t.name == name:
                return t
        raise KeyError(name)


def default_suite_path() -> Path:
    return config_dir() / "benchmark.yaml"


def load_suite(path: str | Path | None = None) -> Suite:
    """Read and validate the suite file (default ``configs/benchmark.yaml``)."""
    path = Path(path) if path is not None else default_suite_path()
    data = read_yaml(path)
    where = str(path)

    def need(mapping, key, kind, owner):
        if not isinstance(mapping, dict) or key not in mapping:
            raise ConfigError(f"{where}: {owner} is missing {key!r}")
        value = mapping[key]
        if not isinstance(value, kind) or isinstance(value, bool) and kind is not bool:
            raise ConfigError(
                f"{where}: {owner}.{key} = {value!r} is not allowed: must be "
                f"{getattr(kind, '__name__', kind)}"
            )
        return value

    version = str(need(data, "version", (str, int, float), "suite"))
    task = need(data, "task", str, "suite")
    variants = tuple(need(data, "variants", list, "suite"))
    for v in variants:
        parse_variant(v, task)
    preview = need(need(data, "env", dict, "suite"), "preview_steps", int, "env")
    metrics = need(data, "metrics", dict, "suite")
    tasks, names = [], set()
    for i, t in enumerate(need(data, "tasks", list, "suite")):
        owner = f"tasks[{i}]"
        name = need(t, "name", str, owner)
        if name in names:
            raise ConfigError(f"{where}: {owner}.name = {name!r} is used twice")
        names.add(name)
        seed = need(t, "seed", int, owner)
        duration = float(need(t, "duration_s", (int, float), owner))
        if not (math.isfinite(duration) and duration > 0):
            raise ConfigError(
                f"{where}: {owner}.duration_s = {duration!r} is not allowed: "
                "must be a finite number > 0"
            )
        ref = need(t, "reference", dict, owner)
        try:
            make_reference(ref)
        except (ValueError, TypeError) as exc:
            raise ConfigError(f"{where}: {owner}.reference: {exc}") from None
        tasks.append(BenchTask(name, seed, duration, dict(ref)))
    bw_task = need(metrics, "bandwidth_task", str, "metrics")
    if bw_task not in names:
        raise ConfigError(
            f"{where}: metrics.bandwidth_task = {bw_task!r} is not a task: allowed {sorted(names)}"
        )
    if tasks[[t.name for t in tasks].index(bw_task)].reference.get("kind") != "chirp":
        raise ConfigError(f"{where}: metrics.bandwidth_task = {bw_task!r} must be a chirp task")
    plots = data.get("plots", {}) or {}
    for key, name in plots.items():
        if name not in names:
            raise ConfigError(
                f"{where}: plots.{key} = {name!r} is not a task: allowed {sorted(names)}"
            )
    return Suite(
        version=version,
        task=task,
        variants=variants,
        preview_steps=preview,
        tasks=tuple(tasks),
        bandwidth_task=bw_task,
        bins_per_octave=float(need(metrics, "bandwidth_bins_per_octave", (int, float), "metrics")),
        bandwidth_level=float(need(metrics, "bandwidth_level", float, "metrics")),
        plot_tasks=dict(plots),
        path=str(path),
    )


def parse_variant(variant: str, task: str = ids.FORCE_TRACK) -> str:
    """``"Numatics-2m"`` -> ``"pneumatic_env/ForceTrack-Numatics-2m-v0"`` (checked)."""
    return ids.env_id(task, *ids.split_variant(variant))


def suite_preview_steps(path: str | Path | None = None) -> int:
    """The suite's ``env.preview_steps``: the preview the benchmark's controllers get."""
    return load_suite(path).preview_steps
