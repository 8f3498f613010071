"""Robustness table: every controller on perturbed plants, with its nominal tuning.

    python -m pneumatic_env.agents.robustness [--variants Numatics-2m ...]
        [--controllers pid sliding_mode ppo_residual] [--config robustness] [--out FILE.md]
    python -m pneumatic_env.agents.robustness --variants Numatics-2m \
        --seed-runs runs/a-s1 runs/a-s2 runs/a-s3 [--actor actor_best.npz] [--baseline pid]
        [--residual-gain 0.9]

Each perturbation of ``configs/agents/robustness.yaml`` changes the simulated plant only
(the env option ``plant``): the task, its force scale and what a controller knows
(``base_params``) stay nominal, so the controllers run exactly as tuned. Every cell is the
benchmark suite's mean RMS error (% of the nominal force scale, ``agents.bench.run_suite``)
and, in brackets, its ratio to the same controller on the nominal plant; the last column
is each controller's worst ratio. A controller without an actor for a variant (a shipped
policy trained on another variant) is left out of that variant's table.

With ``--seed-runs`` (one training run or actor file per seed) each cell is instead the
interquartile mean over the seeds with its 95 % bootstrap interval (``agents.stats``) and
the number of seeds below the baseline there; the last row is the worst ratio, per seed,
against the baseline's. ``--residual-gain G`` runs each seed's residual actor with its
correction's bound at G times the trained one (``agents.learned.scale_the_residual``; a
file already scaled is rescaled from its trained bound), to see how the gain trades the
nominal error against the degradation.

``--controllers`` also takes ``pid_retuned_per_plant``: the PID with its gains searched
again on each perturbed plant itself (``agents.tune_pid``'s grid and references, not the
benchmark's). It is not a controller one could ship (it knows the plant it is tuned for):
it shows how much of a cell's error comes from not adapting to that plant.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path

import gymnasium as gym
import numpy as np

from pneumatic_env.params import DEFAULT_CYLINDER, load_parameters

from .base import ControllerSpec
from .bench import run_suite
from .bench_results import markdown_table
from .config import load_agent_config
from .evaluate_seeds import actor_paths, estimate_text
from .learned import scale_the_residual
from .registry import classical_spec, resolve_controller
from .stats import iqm_estimate
from .suite import load_suite, parse_variant
from .tune_pid import grid_search

__all__ = [
    "perturbed_plants",
    "robustness_rows",
    "robustness_markdown",
    "seed_markdown",
    "worst_ratio",
    "PER_PLANT_PID",
    "pid_retuned_for",
    "spec_on_plant",
    "actors_at_gain",
    "main",
]

NOMINAL = "nominal"
PER_PLANT_PID = "pid_retuned_per_plant"  # the PID's grid searched on each plant itself


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


def pid_retuned_for(variant: str, plant: dict, tuning: dict | None = None) -> dict:
    """The PID's gains best on ``plant`` over the tuning grid (``agents.tune_pid``: its
    references and objective; ``tuning`` default ``configs/agents/tuning.yaml``), with the
    grid's fixed values."""
    tuning = tuning or load_agent_config("tuning", raw=("references",))
    res = grid_search("pid", variant, tuning, {"plant": plant} if plant else None)
    best = zip(res["names"], res["combos"][res["best"]])
    return {**tuning["pid"]["fixed"], **{n: float(v) for n, v in best}}


def spec_on_plant(
    controller: str, variant: str, plant: dict, preview_steps: int
) -> tuple[str | ControllerSpec, dict | None]:
    """(what runs ``controller`` on ``plant``, the gains searched for it or None): the
    name itself, or for ``PER_PLANT_PID`` the PID with its grid searched on that plant."""
    if controller != PER_PLANT_PID:
        return controller, None
    gains = pid_retuned_for(variant, plant)
    return classical_spec("pid", gains, preview_steps, PER_PLANT_PID), gains


def _has_actor(controller: str, variant: str) -> bool:
    if controller == PER_PLANT_PID:
        return True
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
            spec, gains = spec_on_plant(controller, variant, plant, suite.preview_steps)
            if gains is not None:
                progress(f"{PER_PLANT_PID} {variant} {name}: {gains}")
            rows, _ = run_suite(
                spec, [variant], suite, env_options={"plant": plant} if plant else None
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


def worst_ratio(cells: dict[str, float]) -> float:
    """The largest ratio of a row's cells to its nominal one."""
    return max(v / cells[NOMINAL] for v in cells.values())


def seed_markdown(variant: str, baseline: str, table: dict[str, dict[str, float]]) -> str:
    """Per perturbation: the baseline's error, the seeds' IQM [95 % interval] and how many
    seeds are below the baseline; last, the worst ratios. ``table`` is
    ``robustness_rows`` of the baseline and one controller per seed."""
    base = table[baseline]
    seeds = [cells for name, cells in table.items() if name != baseline]
    lines = []
    for name, value in base.items():
        est = iqm_estimate([cells[name] for cells in seeds]).as_dict()
        below = sum(cells[name] < value for cells in seeds)
        lines.append([name, f"{value:.2f}", estimate_text(est), f"{below} of {len(seeds)}"])
    worst, base_worst = [worst_ratio(cells) for cells in seeds], worst_ratio(base)
    lines.append(
        [
            "worst ratio",
            f"{base_worst:.2f}",
            estimate_text(iqm_estimate(worst).as_dict()),
            f"{sum(w <= base_worst for w in worst)} of {len(seeds)} at most",
        ]
    )
    header = ["plant", baseline, f"IQM over {len(seeds)} seeds [95 % CI]", f"below {baseline}"]
    return f"**{variant}** (mean RMS % of the nominal force scale)\n\n" + markdown_table(
        header, lines
    )


def actors_at_gain(paths: Sequence[Path], gain: float, directory: Path) -> list[Path]:
    """Each residual actor of ``paths`` written to ``directory`` with its correction's
    bound at ``gain`` x the trained one (``seed<k>-gain<gain>.npz``)."""
    source = f"agents.robustness --residual-gain {gain:g}"
    return [
        scale_the_residual(path, directory / f"seed{k}-gain{gain:g}.npz", gain, source)
        for k, path in enumerate(paths, 1)
    ]


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m pneumatic_env.agents.robustness")
    p.add_argument("--variants", nargs="+", default=["Numatics-2m"])
    p.add_argument("--controllers", nargs="+", help="default: the config's")
    p.add_argument("--config", default="robustness", help="configs/agents/<name>.yaml")
    p.add_argument("--out", type=Path, help="write the tables to this Markdown file")
    p.add_argument("--seed-runs", nargs="+", help="training runs (or actors), one per seed")
    p.add_argument("--actor", default="actor.npz", help="with --seed-runs: each run's file")
    p.add_argument("--baseline", default="pid", help="with --seed-runs: the compared controller")
    p.add_argument(
        "--residual-gain",
        type=float,
        help="with --seed-runs: each residual actor's correction bound x this (0: its base)",
    )
    args = p.parse_args(argv)
    config = load_agent_config(args.config)
    controllers = args.controllers or config["controllers"]
    if args.seed_runs and args.controllers:
        p.error("--controllers and --seed-runs exclude each other: the seeds are the rows")
    if args.residual_gain is not None and not args.seed_runs:
        p.error(f"--residual-gain {args.residual_gain:g} needs --seed-runs (the actors to scale)")
    with tempfile.TemporaryDirectory() as scaled:
        if args.seed_runs:
            paths = actor_paths(args.seed_runs, args.actor)
            if args.residual_gain is not None:
                paths = actors_at_gain(paths, args.residual_gain, Path(scaled))
            controllers = [args.baseline, *map(str, paths)]
        blocks = []
        for variant in args.variants:
            table = robustness_rows(variant, controllers, perturbed_plants(config, variant))
            if table and args.seed_runs:
                blocks.append(seed_markdown(variant, args.baseline, table))
            elif table:
                blocks.append(robustness_markdown(variant, table))
    command = "python -m pneumatic_env.agents.robustness " + " ".join(sys.argv[1:])
    text = f"Generated by `{command.strip()}`.\n\n" + "\n\n".join(blocks) + "\n"
    print(text)
    if args.out:
        args.out.write_text(text, encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
