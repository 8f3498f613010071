"""Controllers by name: how ``pneumatic-env bench`` (and anything else) builds a controller
for a variant from its name, its config under ``configs/agents/`` or a trained policy file."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from pneumatic_env.params import ConfigError

from .base import Controller, ControllerContext, ControllerSpec, ZeroController
from .config import agent_config_path, load_agent_config
from .learned import (
    LearnedActor,
    LearnedController,
    is_learned,
    shipped_policies,
    shipped_policy_path,
)
from .policy import load_policy_spec
from .residual import BASE_CLASSES, BASE_CONTROLLERS, base_context
from .suite import suite_preview_steps

__all__ = [
    "resolve_controller",
    "classical_spec",
    "make_base_controller",
    "learned_spec",
    "controller_names",
    "tuned_config_path",
    "CLASSICAL",
    "classical_gains",
]

CLASSICAL = ("pid", "sliding_mode", "zero")


def tuned_config_path(name: str, variant: str) -> Path:
    """``configs/agents/<name>-<variant>.yaml``: the benchmark's gains of a classical
    controller for one variant (the file may not exist: no gains tuned there)."""
    return agent_config_path(f"{name}-{variant.lower()}")


def _classical_config(name: str, variant: str, config: str | Path | None = None) -> tuple:
    """(the config file, its tree, its gains) of a classical controller for ``variant``:
    ``config``, else ``tuned_config_path`` if it exists, else ``configs/agents/<name>.yaml``."""
    if config is None:
        per_variant = tuned_config_path(name, variant)
        config = per_variant if per_variant.is_file() else agent_config_path(name)
    cfg = load_agent_config(config)
    if cfg.get("controller") != name:
        raise ConfigError(f"{config}: controller = {cfg.get('controller')!r}, expected {name!r}")
    gains = cfg.get("gains")
    if not isinstance(gains, dict):
        raise ConfigError(f"{config}: missing the 'gains' mapping")
    return config, cfg, gains


def classical_gains(name: str, variant: str) -> dict:
    """The benchmark's gains of the classical controller ``name`` for ``variant``."""
    return dict(_classical_config(name, variant)[2])


def _classical(
    name: str, variant: str, config: str | None, preview_steps: int | None
) -> ControllerSpec:
    config, cfg, gains = _classical_config(name, variant, config)
    preview = int(
        cfg["preview_steps"]
        if "preview_steps" in cfg
        else suite_preview_steps()
        if preview_steps is None
        else preview_steps
    )
    return classical_spec(name, gains, preview, name, str(config))


def classical_spec(
    kind: str, gains: Mapping, preview_steps: int, name: str | None = None, source: str = ""
) -> ControllerSpec:
    """The classical controller ``kind`` (``pid``, ``sliding_mode``) with ``gains``, as the
    benchmark runs it (``preview_steps`` of the reference, raw observation)."""
    cls, gains = BASE_CLASSES[kind], dict(gains)
    return ControllerSpec(
        name or kind,
        {"preview_steps": int(preview_steps), "normalize_observation": False},
        lambda ctx: cls(ctx, **gains),
        source,
    )


def controller_names() -> list[str]:
    """Every name ``resolve_controller`` accepts besides file paths: the classical
    controllers, then the shipped policies (``agents/policies``)."""
    return list(CLASSICAL) + sorted(shipped_policies())


def resolve_controller(
    spec: str, variant: str, config: str | None = None, preview_steps: int | None = None
) -> ControllerSpec:
    """``pid``, ``sliding_mode``, ``zero``, a shipped policy's name (``controller_names``)
    or a trained policy file (``.npz`` export of ``pneumatic-env train``, SB3 ``.zip``).

    ``preview_steps``: the preview a classical controller gets unless its config sets one;
    default the benchmark suite's (``suite_preview_steps()``, not the env's default).
    """
    if spec in ("pid", "sliding_mode"):
        return _classical(spec, variant, config, preview_steps)
    if spec == "zero":
        preview_steps = suite_preview_steps() if preview_steps is None else preview_steps
        return ControllerSpec(
            "zero", {"preview_steps": preview_steps, "normalize_observation": False}, ZeroController
        )
    path = Path(spec)
    if path.suffix in (".npz", ".zip"):
        if path.suffix == ".npz" and path.is_file() and is_learned(path):
            return learned_spec(path, variant)
        return load_policy_spec(path)
    names = controller_names()
    if spec in names:
        return learned_spec(shipped_policy_path(spec, variant), variant, name=spec)
    raise ValueError(
        f"controller = {spec!r} is not allowed: use one of {names} or a path "
        "to a trained policy (.npz from pneumatic-env train or "
        "pneumatic_env.agents.policy.export_policy, or SB3 .zip)"
    )


def make_base_controller(
    name: str, context: ControllerContext, variant: str, gains: Mapping | None = None
) -> Controller:
    """The benchmark's ``name`` controller (one of ``residual.BASE_CONTROLLERS``) with
    ``gains`` if given, else the gains of ``variant``, for ``context``: the base of a
    residual policy or a teacher."""
    if name not in BASE_CONTROLLERS:
        raise ValueError(f"base = {name!r} is not allowed: use one of {list(BASE_CONTROLLERS)}")
    if gains is not None:
        return BASE_CLASSES[name](context, **gains)
    return resolve_controller(name, variant, preview_steps=context.preview_steps).build(context)


def learned_spec(path: str | Path, variant: str, name: str | None = None) -> ControllerSpec:
    """Bench controller spec of an actor file (``agents.learned``); a residual actor gets
    the base controller its file holds (self-contained, v2), else the benchmark's with the
    gains of its residual config (``ResidualConfig.gains``) or of ``variant``. A v2 file
    also brings its model (``LearnedActor.model_context``)."""
    actor = LearnedActor(path)
    opts = actor.meta["env_options"]
    label = name or actor.meta.get("name") or Path(path).stem
    residual = actor.residual_config

    def build(ctx: ControllerContext) -> Controller:
        ctx = actor.model_context(ctx)
        if residual is None:
            return LearnedController(ctx, actor, None)
        kind, gains = actor.base_controller or (residual.base, residual.gains)
        base = make_base_controller(kind, base_context(ctx, residual), variant, gains)
        return LearnedController(ctx, actor, base)

    return ControllerSpec(
        label,
        {"preview_steps": int(opts["preview_steps"]), "normalize_observation": False},
        build,
        str(path),
    )
