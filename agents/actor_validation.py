"""Model selection in training: an actor's closed-loop score on validation references.

The trainer's side of the benchmark (``agents.ppo`` calls it on each saved actor); the
inference modules (``agents.learned``, ``agents.policy``) do not need it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .base import ControllerContext
from .bench import closed_loop, make_env, task_metrics
from .registry import learned_spec

__all__ = ["validate_actor"]


def validate_actor(
    actor_path: str | Path,
    variant: str,
    validation: list,
    n_steps: int,
    env_options: dict | None = None,
) -> dict:
    """Mean RMS error (% of the scale) and chatter of an actor on ``validation`` references
    (``[{"seed": s, "reference": spec in scale units}, ...]``) over ``n_steps``, through the
    benchmark's closed loop (``agents.bench.closed_loop``); model selection in training.
    ``env_options``: more env keyword arguments (e.g. ``domain_randomization``: each
    episode's plant drawn from the env's generator, seeded by the reference's seed)."""
    spec = learned_spec(actor_path, variant)
    env = make_env(variant, len(validation), n_steps, **{**spec.env_options, **(env_options or {})})
    ctrl = spec.build(ControllerContext.from_env(env))
    tr = closed_loop(
        env, ctrl, [v["reference"] for v in validation], [v["seed"] for v in validation], n_steps
    )
    scale = env.unwrapped.reference_scale
    env.close()
    ms = [
        task_metrics(
            tr["force_n"][:, i],
            tr["reference_n"][:, i],
            tr["current_a"][:, i],
            tr["exhaust_kg"][:, i],
            scale,
        )
        for i in range(len(validation))
    ]
    return {
        "val_rms_pct": float(np.mean([m["rms_error_pct"] for m in ms])),
        "val_chatter_a": float(np.mean([m["chatter_rms_a"] for m in ms])),
    }
