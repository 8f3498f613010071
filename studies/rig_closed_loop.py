"""Closed loop on the virtual rig's own plant (issue 35): the benchmark suite, not on the
fitted model but on the rig's independent plant forms.

A controller (``agents.registry.resolve_controller``: pid, sliding_mode, a shipped policy,
a policy file) is stepped at the control rate (the env's ``control_dt_s``) against the
plant of :mod:`.rig_plants_closed_loop`: the virtual rig's base parameters drawn off nominal
(``virtual_rig.perturbation``, seeded), its finer plant step, one or several effects in the
rig's own forms, and optionally its sensor noise and quantisation. The controller sees only
the base observation ``[p1, p2, x, f, ref(k..k+H)]``, filled by the env's own
``fill_observation`` with the env's scales and references (the suite's env for the
variant, reset with each task's seed and reference as ``agents.bench.closed_loop`` does).
Metrics per task are ``agents.bench.task_metrics`` of the true force.

``python -m studies.rig_closed_loop --controller pid sliding_mode ppo_residual --effects
tube_waves,heat_transfer,spool_friction --cylinder Numatics --tube 2`` prints a table.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass

import numpy as np

from pneumatic_env import ids
from pneumatic_env.agents.base import ControllerContext
from pneumatic_env.agents.bench import make_env, task_metrics
from pneumatic_env.agents.registry import resolve_controller
from pneumatic_env.agents.suite import Suite, load_suite
from pneumatic_env.envs.observation import OBSERVED_CHANNELS, fill_observation
from pneumatic_env.envs.tasks import _CHANNEL_OUTPUT, scale_spec
from pneumatic_env.identification.config import load_config
from pneumatic_env.params import load_numerics
from pneumatic_env.physics import layout as L

from .rig_plants_closed_loop import CLOSED_LOOP_EFFECTS, rig_plant
from .rig_sampling import _perturbed

__all__ = ["RigSpec", "rig_closed_loop", "rig_suite", "summary", "main"]


@dataclass(frozen=True)
class RigSpec:
    """A virtual rig: its effects ({name: strength}, 1 = ``virtual_rig.effects``), the seed
    of its base parameters' draw (None: nominal), sensor noise on or off, and its plant step
    (None: ``virtual_rig.plant_dt_s`` and ``plant_substeps``)."""

    effects: tuple[tuple[str, float], ...] = ()
    seed: int | None = 0
    noise: bool = False
    plant_dt_s: float | None = None
    plant_substeps: int | None = None

    @classmethod
    def parse_effects(cls, text: str) -> tuple[tuple[str, float], ...]:
        """``"tube_waves,heat_transfer:0.5"`` -> ((tube_waves, 1.0), (heat_transfer, 0.5))."""
        out = []
        for item in filter(None, (t.strip() for t in text.split(","))):
            name, _, strength = item.partition(":")
            if name not in CLOSED_LOOP_EFFECTS:
                raise ValueError(
                    f"effect {name!r} is not allowed: use {', '.join(CLOSED_LOOP_EFFECTS)}"
                )
            out.append((name, float(strength) if strength else 1.0))
        return tuple(out)

    @property
    def label(self) -> str:
        effects = "+".join(f"{e}:{s:g}" for e, s in self.effects) or "none"
        params = "nominal" if self.seed is None else f"seed {self.seed}"
        return f"{effects}, {params}" + (", noise" if self.noise else "")


class _Sensors:
    """The rig's measured channels (observation order) from plant outputs (rows: tasks):
    exact, or with the rig's white noise and ADC quantisation (``virtual_rig.noise``,
    ``virtual_rig.quantisation``), drawn per task from ``(rig seed, task seed)``."""

    def __init__(self, rig: RigSpec, task_seeds: list[int], cfg):
        self.noisy = rig.noise
        self.rows = [_CHANNEL_OUTPUT[c] for c in OBSERVED_CHANNELS]
        self.rngs = [np.random.default_rng([rig.seed or 0, s]) for s in task_seeds]
        number = cfg.number
        self.sigma = np.array([number("virtual_rig", "noise", c) for c in OBSERVED_CHANNELS])
        self.quantum = np.array(
            [number("virtual_rig", "quantisation", c, positive=True) for c in OBSERVED_CHANNELS]
        )

    def __call__(self, outputs: np.ndarray) -> np.ndarray:
        measured = outputs[:, self.rows].copy()
        if self.noisy:
            measured += self.sigma * np.array(
                [rng.standard_normal(len(self.rows)) for rng in self.rngs]
            )
            measured = self.quantum * np.round(measured / self.quantum)
        return measured


def _suite_episodes(controller: str, variant: str, suite: Suite, config: str | None):
    """The controller, its context and the suite's episodes on ``variant`` as the env makes
    them: (controller, env's base parameters, observation scales, references (n_tasks,
    n_ref), control period, force scale, steps)."""
    cspec = resolve_controller(controller, variant, config, suite.preview_steps)
    dt = load_numerics()["control_dt_s"]  # the env's control period (as run_suite)
    steps = [int(round(t.duration_s / dt)) for t in suite.tasks]
    env = make_env(variant, len(suite.tasks), max(steps), suite.task, **cspec.env_options)
    scale = env.unwrapped.reference_scale
    env.reset(
        seed=[t.seed for t in suite.tasks],
        options={"reference": [scale_spec(t.reference, scale) for t in suite.tasks]},
    )
    u = env.unwrapped
    episodes = (
        cspec.build(ControllerContext.from_env(env)),
        cspec.name,
        dict(u.base_params),
        u.observation_scales,
        np.array(u.references),
        u.control_dt_s,
        scale,
        steps,
    )
    env.close()
    return episodes


def rig_closed_loop(
    controller: str,
    rig: RigSpec,
    variant: str = "Numatics-2m",
    suite: Suite | None = None,
    config: str | None = None,
) -> dict:
    """Run the suite's tasks in closed loop on ``rig``'s plant for ``variant``.

    Returns ``{"controller", "rows": [task_metrics + task name per task], "traces":
    {force_n, reference_n, current_a, exhaust_kg: (n_steps, n_tasks)}}``.
    """
    suite = suite or load_suite()
    cfg = load_config()
    ctrl, name, base, scales, references, dt, scale, steps = _suite_episodes(
        controller, variant, suite, config
    )
    cylinder = ids.split_variant(variant)[0].lower()
    true = (
        base
        if rig.seed is None
        else _perturbed(cylinder, base, np.random.default_rng(rig.seed), cfg)
    )
    plant_dt = rig.plant_dt_s or cfg.number("virtual_rig", "plant_dt_s", positive=True)
    substeps = rig.plant_substeps or int(cfg.number("virtual_rig", "plant_substeps", positive=True))
    n_tasks, n_steps = len(suite.tasks), max(steps)
    plants = [
        rig_plant(true, cylinder, dict(rig.effects), dt, plant_dt, substeps, cfg)
        for _ in range(n_tasks)
    ]
    measure = _Sensors(rig, [t.seed for t in suite.tasks], cfg)
    i_max = float(base["coil_current_max_a"])
    out = {
        k: np.empty((n_steps, n_tasks))
        for k in ("force_n", "reference_n", "current_a", "exhaust_kg")
    }
    obs = np.empty((n_tasks, ctrl.context.obs_dim), np.float32)
    step_count = np.zeros(n_tasks, dtype=np.int64)
    ctrl.reset()
    for k in range(n_steps):
        sensed = np.array([p.measured() for p in plants])  # through a sensor lag, if any
        fill_observation(measure(sensed), references, step_count, scales, obs)
        action = np.asarray(ctrl.act(obs), dtype=np.float64).reshape(n_tasks)
        applied = np.minimum(np.maximum(action, -i_max), i_max)
        outputs = np.array([p.advance(a) for p, a in zip(plants, applied)])
        step_count += 1
        out["reference_n"][k] = references[:, min(k + 1, references.shape[1] - 1)]
        out["force_n"][k] = outputs[:, L.O_F]
        out["current_a"][k] = applied
        out["exhaust_kg"][k] = outputs[:, L.O_EXHAUST]
    metrics = []
    for i, task in enumerate(suite.tasks):
        k = steps[i]
        metrics.append(
            {
                "task": task.name,
                **task_metrics(
                    out["force_n"][:k, i],
                    out["reference_n"][:k, i],
                    out["current_a"][:k, i],
                    out["exhaust_kg"][:k, i],
                    scale,
                ),
            }
        )
    return {"controller": name, "rows": metrics, "traces": out}


def summary(rows: list[dict]) -> dict:
    """The suite's figures of a run (as the leaderboard): mean RMS error (% of the force
    scale), mean chatter (A), total air (mg)."""
    return {
        "rms_error_pct": float(np.mean([r["rms_error_pct"] for r in rows])),
        "chatter_rms_a": float(np.mean([r["chatter_rms_a"] for r in rows])),
        "air_mg": float(np.sum([r["air_mg"] for r in rows])),
    }


def rig_suite(
    controller: str, rig: RigSpec, variant: str = "Numatics-2m", suite: Suite | None = None
) -> dict:
    """Metrics per task and their suite figures (:func:`summary`) on ``rig``."""
    run = rig_closed_loop(controller, rig, variant, suite)
    return {"controller": run["controller"], "tasks": run["rows"], **summary(run["rows"])}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m studies.rig_closed_loop", description=__doc__)
    p.add_argument("--controller", nargs="+", default=["pid", "sliding_mode"])
    p.add_argument(
        "--effects",
        default="tube_waves,heat_transfer,spool_friction",
        help="comma list of EFFECT[:STRENGTH]; '' for none",
    )
    p.add_argument("--cylinder", default="Numatics")
    p.add_argument("--tube", default="2", help="tube length as in the variant (0.5, 2)")
    p.add_argument("--seed", type=int, default=0, help="base parameters' draw")
    p.add_argument("--nominal", action="store_true", help="nominal base parameters")
    p.add_argument("--noise", action="store_true", help="the rig's sensor noise")
    args = p.parse_args(argv)
    rig = RigSpec(
        RigSpec.parse_effects(args.effects), None if args.nominal else args.seed, args.noise
    )
    variant = f"{args.cylinder}-{args.tube}m"
    print(f"suite on the virtual rig's plant, {variant}: {rig.label}\n")
    print("| controller | mean RMS err (%) | mean chatter (A) | air (mg) | time (s) |")
    print("|---|---|---|---|---|")
    for name in args.controller:
        start = time.perf_counter()
        r = rig_suite(name, rig, variant)
        seconds = time.perf_counter() - start
        print(
            f"| {r['controller']} | {r['rms_error_pct']:.2f} | {r['chatter_rms_a']:.4f} | "
            f"{r['air_mg']:.0f} | {seconds:.0f} |",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
