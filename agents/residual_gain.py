"""The residual's gain: the bound of a trained residual's correction, scaled after training
and chosen on validation data.

    python -m pneumatic_env.agents.residual_gain RUN_DIR [--config CONFIG.yaml]

A residual trained over a mixture of plants can push harder than a given plant needs: on
Numatics-2m the first shipped ``ppo_adaptive`` overshot the suite's 5 Hz sine by 7 %
where the PID alone undershoots by 6 %. Scaling the bound of its correction
(``agents.learned.scale_the_residual``: 0 is the base controller alone, 1 the actor as
trained) spans a one-parameter family between the two. Each gain of the config's
``training.residual_gains`` is scored on the trainer's validation references (never the
benchmark's) on the nominal plant and on ``training.residual_gain_draws`` plants per
reference drawn from the config's ``domain_randomization`` (the reference's seed shifted
by 1000 per draw, the same plants for every gain). The score is the mean RMS error over
all those episodes; the lowest wins.

The trainer runs this at the end of a residual run whose config lists gains: the run's
``actor_best.npz`` becomes the chosen gain's, ``actor_best_unscaled.npz`` keeps the actor
as trained, and ``train.json`` gets the scores (``residual_gain``). On a finished run the
command above does the same (``--config``: a config with the gains, for a run trained
before its config had them; default the config in the run's ``train.json``); run again,
it chooses again from the unscaled actor.
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path

from .actor_validation import DRAW_SEED_STRIDE, validate_on_draws
from .config import ConfigError
from .learned import LearnedActor, scale_the_residual
from .ppo_config import PPOFastConfig, drawn_plants, load_config
from .ppo_setup import references

__all__ = ["DRAW_SEED_STRIDE", "gain_scores", "apply_residual_gain", "main"]


def gain_scores(
    actor_path: str | Path,
    variant: str,
    validation: list,
    n_steps: int,
    randomization: dict | None,
    draws: int,
    gains: Sequence[float],
) -> list[dict]:
    """Per gain: the actor's mean RMS error (% of the scale) on ``validation`` on the
    nominal plant, on ``draws`` plants per reference drawn from ``randomization``, and
    over all those episodes (``score_rms_pct``)."""
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for gain in gains:
            path = scale_the_residual(actor_path, Path(tmp) / "scaled.npz", gain, "scored")
            score = validate_on_draws(path, variant, validation, n_steps, randomization, draws)
            rows.append(
                {
                    "gain": float(gain),
                    "nominal_rms_pct": score["nominal_rms_pct"],
                    "mixture_rms_pct": score["mixture_rms_pct"],
                    "score_rms_pct": score["val_rms_pct"],
                }
            )
    return rows


def _settings(cfg: PPOFastConfig) -> tuple[tuple[float, ...], int, dict | None]:
    """(gains, draws per reference, randomisation) of a residual config, or a named error."""
    tr = cfg.training
    if cfg.mode != "residual" or not tr.residual_gains:
        raise ConfigError(
            f"training.residual_gains = {tr.residual_gains!r} in a {cfg.mode} config: the gain "
            "is chosen for a residual config that lists gains (e.g. [1.0, 0.8, 0.6])"
        )
    if cfg.variants:
        raise ConfigError(
            f"training.residual_gains with variants = {list(cfg.variants)!r}: the gain is "
            "chosen for a residual of one variant"
        )
    if any(not (math.isfinite(g) and g >= 0) for g in tr.residual_gains):
        raise ConfigError(
            f"training.residual_gains = {list(tr.residual_gains)!r} is not allowed: "
            "finite numbers >= 0"
        )
    draws, randomization = drawn_plants(cfg, "residual_gain_draws")
    return tuple(tr.residual_gains), draws, randomization


def apply_residual_gain(run_dir: str | Path, cfg: PPOFastConfig, log: Callable = print) -> dict:
    """Choose the gain of the run's best actor (``actor_best_unscaled.npz``, made from
    ``actor_best.npz`` the first time) and write its scaled copy to ``actor_best.npz``;
    returns ``{"gain", "scores"}``."""
    gains, draws, randomization = _settings(cfg)
    run_dir = Path(run_dir)
    unscaled = run_dir / "actor_best_unscaled.npz"
    if not unscaled.is_file():
        shutil.copyfile(run_dir / "actor_best.npz", unscaled)
    variant = LearnedActor(unscaled).meta["variant"]
    _, validation = references(cfg)
    steps = cfg.training.validation_steps
    rows = gain_scores(unscaled, variant, validation, steps, randomization, draws, gains)
    for r in rows:
        log(
            f"  residual gain {r['gain']:.2f}: validation RMS {r['nominal_rms_pct']:.3f} % "
            f"nominal, {r['mixture_rms_pct']:.3f} % on {draws} drawn plants per reference, "
            f"{r['score_rms_pct']:.3f} % over both"
        )
    best = min(rows, key=lambda r: r["score_rms_pct"])
    source = (
        f"agents.residual_gain: of the gains {list(gains)}, the lowest mean validation RMS "
        f"on the nominal plant and {draws} drawn plants per reference"
    )
    scale_the_residual(unscaled, run_dir / "actor_best.npz", best["gain"], source)
    log(f"  residual gain {best['gain']:.2f} chosen: {run_dir / 'actor_best.npz'}")
    return {"gain": best["gain"], "scores": rows}


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m pneumatic_env.agents.residual_gain", description=__doc__.split("\n")[0]
    )
    p.add_argument("run", type=Path, help="a training run's directory (actor_best.npz)")
    p.add_argument(
        "--config", help="ppo_fast config with the gains (default: the run's train.json)"
    )
    args = p.parse_args(argv)
    summary_path = args.run / "train.json"
    if args.config is None and not summary_path.is_file():
        p.error(f"run = {str(args.run)!r} has no train.json: pass --config")
    summary = json.loads(summary_path.read_text()) if summary_path.is_file() else None
    cfg = load_config(args.config if args.config or summary is None else summary["config"])
    chosen = apply_residual_gain(args.run, cfg)
    if summary is not None:
        summary["residual_gain"] = chosen
        summary_path.write_text(json.dumps(summary, indent=2), encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
