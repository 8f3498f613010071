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

__all__ = ["DRAW_SEED_STRIDE", "validate_actor", "validate_on_draws"]

DRAW_SEED_STRIDE = 1000  # a draw's episode seed: the reference's seed + this x the draw


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


def validate_on_draws(
    actor_path: str | Path,
    variant: str,
    validation: list,
    n_steps: int,
    randomization: dict | None,
    draws: int,
) -> dict:
    """``validate_actor`` on the nominal plant and on ``draws`` plants per reference drawn
    from ``randomization`` (the reference's seed shifted by ``DRAW_SEED_STRIDE`` per draw,
    so every actor meets the same plants). ``val_rms_pct`` and ``val_chatter_a`` are the
    means over all those episodes; ``nominal_rms_pct`` and ``mixture_rms_pct`` (NaN
    without draws) are the two parts."""
    nominal = validate_actor(actor_path, variant, validation, n_steps)
    out = {
        **nominal,
        "nominal_rms_pct": nominal["val_rms_pct"],
        "mixture_rms_pct": float("nan"),
    }
    if draws <= 0:
        return out
    drawn = [
        {**v, "seed": int(v["seed"]) + DRAW_SEED_STRIDE * k}
        for k in range(1, draws + 1)
        for v in validation
    ]
    options = {"domain_randomization": randomization}
    mixture = validate_actor(actor_path, variant, drawn, n_steps, options)
    n, m = len(validation), len(drawn)
    for key in nominal:
        out[key] = (nominal[key] * n + mixture[key] * m) / (n + m)
    out["mixture_rms_pct"] = mixture["val_rms_pct"]
    return out
