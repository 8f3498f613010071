"""How close to the plant's own limit is a controller on a perturbed plant? (issue 35,
target 3: the robustness table's tube-air cell.)

Two tables for one variant, its nominal plant and one perturbation of
``configs/agents/robustness.yaml``:

- the suite's error per task for each controller (names or files as ``pneumatic-env
  bench`` takes them; ``pid_retuned_per_plant``: the PID's tuning grid searched again on
  each plant, as the robustness table runs it), so one sees which tasks make a cell's mean;
- the step tasks' floor under the fastest constant current: the valve held at one current
  from ``lead`` before the step (at most the suite's preview) until the force first reaches
  the target, the tracking then taken as perfect. The RMS error of that, minimised over a
  grid of currents and leads, estimates what any controller can reach on a step (not a
  proof: a current that varies during the rise could be faster). The current is searched,
  not set to the coil's maximum: the paper's tube (Eq. 31, turbulent R_t of Eq. 35)
  attenuates a large flow more than in proportion, so on a 2 m tube a fully open valve
  fills the chamber more slowly than a half-open one.

``python -m pneumatic_env.studies.step_floor --variant Numatics-2m --perturbation "tube air
volume" --controllers pid pid_retuned_per_plant ppo_adaptive``
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence

import numpy as np

from pneumatic_env.agents.bench import make_env, run_suite
from pneumatic_env.agents.bench_results import markdown_table
from pneumatic_env.agents.config import load_agent_config
from pneumatic_env.agents.robustness import (
    NOMINAL,
    PER_PLANT_PID,
    perturbed_plants,
    spec_on_plant,
)
from pneumatic_env.agents.suite import Suite, load_suite
from pneumatic_env.envs.tasks import scale_spec
from pneumatic_env.params import load_numerics

__all__ = ["step_floor", "task_errors", "main"]

CURRENTS_A = np.round(np.arange(0.15, 1.51, 0.05), 2)  # the valve opens fully near 1.2 A


def step_floor(
    variant: str, plant: dict, task, suite: Suite, currents_a=CURRENTS_A
) -> dict[str, float]:
    """The step ``task``'s RMS error (% of the force scale) under the best constant current:
    ``{"rms_pct", "current_a", "lead_steps", "rise_steps"}`` (rise: from the step to the
    force first at the target)."""
    options = {"plant": plant} if plant else {}
    dt = load_numerics()["control_dt_s"]
    grid = [(c, lead) for c in currents_a for lead in range(0, suite.preview_steps + 1, 2)]
    current = np.array([c for c, _ in grid])
    lead = np.array([lead for _, lead in grid])
    n, m = int(round(task.duration_s / dt)), len(grid)
    env = make_env(variant, m, n, suite.task, **options)
    scale = env.unwrapped.reference_scale
    env.reset(seed=[task.seed] * m, options={"reference": [scale_spec(task.reference, scale)] * m})
    k_step = int(round(task.reference["step_time_s"] / dt))
    sign = float(np.sign(task.reference["amplitude"]))
    force, reference = np.empty((n, m)), np.empty((n, m))
    for k in range(n):
        u = np.where(k >= k_step - lead, sign * current, 0.0)
        *_, info = env.step(u.reshape(-1, 1))
        reference[k], force[k] = info["reference"], info["reference"] + info["tracking_error"]
    env.close()
    at_target = sign * (force - reference[-1]) >= 0.0
    reached = np.where(at_target.any(0), np.argmax(at_target, axis=0), n)
    k = np.arange(n)[:, None]
    live = (k >= k_step - lead) & (k < reached)  # held at rest before, tracked after
    error = np.where(live, force - reference, 0.0)
    rms = 100.0 * np.sqrt((error**2).mean(0)) / scale
    best = int(np.argmin(rms))
    return {
        "rms_pct": float(rms[best]),
        "current_a": float(current[best]),
        "lead_steps": int(lead[best]),
        "rise_steps": int(reached[best] - k_step),
    }


def task_errors(controller: str, variant: str, plant: dict, suite: Suite) -> dict[str, float]:
    """``{task: RMS error %}`` of the suite for ``controller`` on ``plant``."""
    spec, _ = spec_on_plant(controller, variant, plant, suite.preview_steps)
    rows, _ = run_suite(spec, [variant], suite, env_options={"plant": plant} if plant else None)
    return {r["task"]: float(r["rms_error_pct"]) for r in rows}


def _markdown(variant: str, errors: dict, floors: dict) -> str:
    tasks = list(next(iter(errors.values())))
    rows = [
        [name, plant, *(f"{row[t]:.2f}" for t in tasks), f"{np.mean(list(row.values())):.2f}"]
        for (name, plant), row in errors.items()
    ]
    floor_rows = [
        [
            plant,
            task,
            f"{f['rms_pct']:.2f}",
            f"{f['current_a']:.2f}",
            f["lead_steps"],
            f["rise_steps"],
        ]
        for (plant, task), f in floors.items()
    ]
    floor_header = ["plant", "task", "RMS %", "current (A)", "lead (periods)", "rise (periods)"]
    return "\n\n".join(
        [
            f"**{variant}**: RMS error per task (% of the nominal force scale)",
            markdown_table(["controller", "plant", *tasks, "mean"], rows),
            "Step floor under the best constant current:",
            markdown_table(floor_header, floor_rows),
        ]
    )


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m pneumatic_env.studies.step_floor")
    ap.add_argument("--variant", default="Numatics-2m")
    ap.add_argument("--perturbation", default="tube air volume", help="robustness.yaml's name")
    ap.add_argument("--controllers", nargs="+", default=["pid", PER_PLANT_PID, "ppo_adaptive"])
    args = ap.parse_args(argv)
    plants = perturbed_plants(load_agent_config("robustness"), args.variant)
    if args.perturbation not in plants:
        raise SystemExit(
            f"--perturbation {args.perturbation!r} is not allowed: one of {sorted(plants)}"
        )
    suite = load_suite()
    pair = {NOMINAL: plants[NOMINAL], args.perturbation: plants[args.perturbation]}
    errors = {
        (c, name): task_errors(c, args.variant, plant, suite)
        for c in args.controllers
        for name, plant in pair.items()
    }
    steps = [t for t in suite.tasks if t.reference.get("kind") == "step"]
    floors = {
        (name, t.name): step_floor(args.variant, plant, t, suite)
        for name, plant in pair.items()
        for t in steps
    }
    print(_markdown(args.variant, errors, floors))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
