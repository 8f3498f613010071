"""Robustness table: every controller on perturbed plants, with its nominal tuning.

    python -m pneumatic_env.agents.robustness [--variants Numatics-2m ...]
        [--controllers pid sliding_mode ppo_residual] [--config robustness] [--out FILE.md]

Each perturbation of ``configs/agents/robustness.yaml`` changes the simulated plant only
(the env option ``plant``): the task, its force scale and what a controller knows
(``base_params``) stay nominal, so the controllers run exactly as tuned. Every cell is the
benchmark suite's mean RMS error (% of the nominal force scale, ``agents.bench.run_suite``)
and, in brackets, its ratio to the same controller on the nominal plant; the last column
is each controller's worst ratio. A controller without an actor for a variant (a shipped
policy trained on another variant) is left out of that variant's table.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

import gymnasium as gym
import numpy as np

from pneumatic_env.params import DEFAULT_CYLINDER, load_parameters

from .bench import run_suite
from .bench_results import markdown_table
from .config import load_agent_config
from .registry import resolve_controller
from .suite import load_suite, parse_variant

__all__ = ["perturbed_plants", "robustness_rows", "robustness_markdown", "main"]

NOMINAL = "nominal"


def perturbed_plants(config: dict, variant: str) -> dict[str, dict[str, float]]:
    """``{perturbation: plant parameters}`` for ``variant`` (nominal first, empty)."""
    env = gym.make(parse_variant(variant))
    nominal = dict(env.get_wrapper_attr("base_params"))
    env.close()
    plants: dict[str, dict[str, float]] = {NOMINAL: {}}
    for name, spec in config["perturbations"].items():
        unknown = sorted(set(spec) - {"factor", "set"})
        if unknown:
            raise ValueError(
                f"perturbation {name!r} has key {unknown[0]!r}: allowed keys are factor, set"
            )
        plant = {k: float(f) * float(nominal[k]) for k, f in spec.get("factor", {}).items()}
        plant.update(spec.get("set", {}))
        load_parameters(DEFAULT_CYLINDER, None, nominal, **plant)  # names, units, ranges checked
        plants[name] = plant
    return plants


def _has_actor(controller: str, variant: str) -> bool:
    try:
        resolve_controller(controller, variant)
    except (ValueError, FileNotFoundError):
        return False
    return True


def robustness_rows(
    variant: str, controllers: Sequence[str], plants: dict[str, dict], progress=print
) -> dict[str, dict[str, float]]:
    """``{controller: {perturbation: mean RMS %}}`` on one variant."""
    suite = load_suite()
    table: dict[str, dict[str, float]] = {}
    for controller in controllers:
        if not _has_actor(controller, variant):
            progress(f"{controller}: no actor for {variant}, left out")
            continue
        for name, plant in plants.items():
            rows, _ = run_suite(
                controller, [variant], suite, env_options={"plant": plant} if plant else None
            )
            mean = float(np.mean([r["rms_error_pct"] for r in rows]))
            table.setdefault(controller, {})[name] = mean
            progress(f"{controller:14s} {variant} {name:18s} mean RMS {mean:.2f} %")
    return table


def robustness_markdown(variant: str, table: dict[str, dict[str, float]]) -> str:
    names = list(next(iter(table.values())))
    header = ["controller", *names, "worst ratio"]
    lines = []
    for controller, cells in table.items():
        nominal = cells[NOMINAL]
        ratios = {n: v / nominal for n, v in cells.items()}
        worst = max(ratios, key=lambda n: ratios[n])
        lines.append(
            [controller]
            + [
                f"{v:.2f}" if n == NOMINAL else f"{v:.2f} ({ratios[n]:.2f})"
                for n, v in cells.items()
            ]
            + [f"{ratios[worst]:.2f} ({worst})"]
        )
    return f"**{variant}** (mean RMS % of the nominal force scale; ratio to nominal)\n\n" + (
        markdown_table(header, lines)
    )


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m pneumatic_env.agents.robustness")
    p.add_argument("--variants", nargs="+", default=["Numatics-2m"])
    p.add_argument("--controllers", nargs="+", help="default: the config's")
    p.add_argument("--config", default="robustness", help="configs/agents/<name>.yaml")
    p.add_argument("--out", type=Path, help="write the tables to this Markdown file")
    args = p.parse_args(argv)
    config = load_agent_config(args.config)
    controllers = args.controllers or config["controllers"]
    blocks = []
    for variant in args.variants:
        table = robustness_rows(variant, controllers, perturbed_plants(config, variant))
        if table:
            blocks.append(robustness_markdown(variant, table))
    command = "python -m pneumatic_env.agents.robustness " + " ".join(sys.argv[1:])
    text = f"Generated by `{command.strip()}`.\n\n" + "\n\n".join(blocks) + "\n"
    print(text)
    if args.out:
        args.out.write_text(text, encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
