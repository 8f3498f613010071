"""Grid-search tuning of the classical controllers (PID by default; also the sliding mode).

    python -m pneumatic_env.agents.tune_pid [--controller pid|sliding_mode] [--variants V ...]
        [--dry-run]

The procedure lives in ``configs/agents/tuning.yaml``: a grid of gains, fixed values, tuning
references (seeds and signals distinct from the benchmark's) and the objective
``J = mean RMS error (% of scale) + chatter_penalty * mean chatter (A)``. Every combination x
reference runs as one env of a single native vector env per variant; the best combination is
written to ``configs/agents/<controller>-<variant>.yaml``.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import sys
import time
from pathlib import Path

import numpy as np

from pneumatic_env.config_files import make_entry, read_yaml
from pneumatic_env.params import load_numerics

from .base import ControllerContext
from .bench import closed_loop, load_suite, make_env, parse_variant
from .config import agent_config_path, load_agent_config, write_agent_config
from .pid import PIDController
from .sliding_mode import SlidingModeController

__all__ = ["CONTROLLERS", "grid_search", "tuned_config", "main"]

CONTROLLERS = {"pid": PIDController, "sliding_mode": SlidingModeController}


def grid_search(
    controller: str,
    variant: str,
    tuning: dict,
    env_options: dict | None = None,
    base_params: dict | None = None,
) -> dict:
    """Run the grid of ``tuning[controller]`` on ``variant``; returns scores and the best combo.

    ``tuning`` is ``load_agent_config("tuning", raw=("references",))``; ``env_options``:
    more env keyword arguments (e.g. a fitted rig's ``params``, ``agents.rig``);
    ``base_params``: the model the controller runs on, if not the env's (the sliding mode
    on the nominal model of a fitted rig).
    """
    if controller not in CONTROLLERS:
        raise ValueError(
            f"controller = {controller!r} is not allowed: use one of {sorted(CONTROLLERS)}"
        )
    parse_variant(variant)
    grid, fixed = tuning[controller]["grid"], tuning[controller]["fixed"]
    names = list(grid)
    combos = list(itertools.product(*(grid[n] for n in names)))
    refs = tuning["references"]
    n_ref = len(refs)
    n_steps = int(round(tuning["duration_s"] / load_numerics()["control_dt_s"]))
    env = make_env(
        variant,
        len(combos) * n_ref,
        n_steps,
        preview_steps=tuning["preview_steps"],
        normalize_observation=False,
        **(env_options or {}),
    )
    ctx = ControllerContext.from_env(env)
    if base_params is not None:
        ctx = dataclasses.replace(ctx, base_params=dict(base_params))
    gains = {n: np.repeat(np.array([c[j] for c in combos]), n_ref) for j, n in enumerate(names)}
    ctrl = CONTROLLERS[controller](ctx, **{**fixed, **gains})
    t0 = time.perf_counter()
    tr = closed_loop(
        env,
        ctrl,
        [r["reference"] for r in refs] * len(combos),
        [r["seed"] for r in refs] * len(combos),
        n_steps,
    )
    wall = time.perf_counter() - t0
    scale = env.unwrapped.reference_scale
    env.close()
    e = tr["force_n"] - tr["reference_n"]
    rms_pct = (100 * np.sqrt(np.mean(e**2, axis=0)) / scale).reshape(len(combos), n_ref)
    chatter = np.sqrt(np.mean(np.diff(tr["current_a"], axis=0) ** 2, axis=0)).reshape(
        len(combos), n_ref
    )
    score = rms_pct.mean(axis=1) + tuning["chatter_penalty_pct_per_a"] * chatter.mean(axis=1)
    score = np.where(np.isfinite(score), score, np.inf)
    best = int(np.argmin(score))
    return {
        "names": names,
        "combos": combos,
        "score": score,
        "rms_pct": rms_pct,
        "chatter_a": chatter,
        "best": best,
        "wall_s": wall,
        "n_envs": len(combos) * n_ref,
        "n_steps": n_steps,
    }


def tuned_config(
    controller: str, variant: str, result: dict, tuning_path: Path, command: str
) -> dict:
    """The config tree for ``configs/agents/<controller>-<variant>.yaml`` (entries kept)."""
    raw = read_yaml(tuning_path)
    section = raw[controller]
    best = result["combos"][result["best"]]
    gains = {}
    for name, value in zip(result["names"], best):
        e = section["grid"][name]
        how = f"tuned: best of {e['value']} by `{command}` (configs/agents/tuning.yaml)"
        gains[name] = make_entry(value, e["unit"], how)
    for name, e in section["fixed"].items():
        gains[name] = make_entry(
            e["value"], e["unit"], f"fixed in configs/agents/tuning.yaml: {e['source']}"
        )
    order = np.argsort(result["score"])
    return {
        "controller": controller,
        "variant": variant,
        "preview_steps": make_entry(
            raw["preview_steps"]["value"],
            "control periods",
            "configs/agents/tuning.yaml preview_steps (observation layout "
            "the gains were tuned with)",
        ),
        "gains": gains,
        "tuning": {
            "objective": make_entry(
                round(float(result["score"][result["best"]]), 4),
                "%",
                "J on the tuning set (configs/agents/tuning.yaml)",
            ),
            "runner_up_objective": make_entry(
                round(float(result["score"][order[1]]), 4) if len(order) > 1 else None,
                "%",
                "second-best J of the grid (how flat the optimum is)",
            ),
            "combinations": make_entry(len(result["combos"]), "-", "size of the grid searched"),
        },
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m pneumatic_env.agents.tune_pid", description=__doc__.split("\n")[0]
    )
    parser.add_argument("--controller", default="pid", choices=sorted(CONTROLLERS))
    parser.add_argument("--variants", nargs="+", help="default: the benchmark suite's variants")
    parser.add_argument("--tuning", default="tuning", help="tuning config (configs/agents/...)")
    parser.add_argument("--dry-run", action="store_true", help="print, do not write configs")
    args = parser.parse_args(argv)
    tuning_path = agent_config_path(args.tuning)
    tuning = load_agent_config(tuning_path, raw=("references",))
    variants = args.variants or list(load_suite().variants)
    command = "python -m pneumatic_env.agents.tune_pid --controller " + args.controller
    for variant in variants:
        res = grid_search(args.controller, variant, tuning)
        best = res["best"]
        desc = ", ".join(f"{n}={v}" for n, v in zip(res["names"], res["combos"][best]))
        print(
            f"{args.controller} {variant}: {len(res['combos'])} combinations x "
            f"{res['rms_pct'].shape[1]} references ({res['n_envs']} envs, "
            f"{res['wall_s']:.1f} s): best J = {res['score'][best]:.3f} % ({desc}); RMS % per "
            f"reference {np.round(res['rms_pct'][best], 2).tolist()}",
            flush=True,
        )
        if not args.dry_run:
            path = agent_config_path(f"{args.controller}-{variant.lower()}")
            cfg = tuned_config(
                args.controller, variant, res, tuning_path, f"{command} --variants {variant}"
            )
            write_agent_config(
                path,
                cfg,
                header=(
                    f"{args.controller} gains for {variant}: written by\n"
                    f"  {command} --variants {variant}\n"
                    "Do not edit by hand; change configs/agents/tuning.yaml and re-run."
                ),
            )
            print(f"  wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
