"""Issue 35's evaluation: from a virtual rig's campaign to a controller trained for it,
judged in closed loop on the rig's own plant.

For each evaluation rig (:data:`EVAL_RIGS`: single effects and combinations of two or
three, base parameters drawn off nominal by the rig's seed):

1. record a ``user13`` campaign (:func:`.rig_campaign.make_campaign`; several effects at
   once through :mod:`.rig_multi_effect`);
2. ``pneumatic-env identify CAMPAIGN/*.csv --report REPORT``;
3. the baselines in closed loop on the rig's own plant (:func:`.rig_closed_loop.rig_suite`
   with the recording's effects, strengths and seed): PID and the sliding mode at nominal
   tuning, the shipped learned controllers (``LEARNED_BASELINES``);
4. per training seed: ``pneumatic-env train --rig REPORT --out OUT --seed S [--minutes M]``
   (``agents/rig_training.py``), then
   ``OUT/controller.npz`` in the same closed loop.

The summary per rig: the trained controllers' IQM of the suite's mean RMS error over the
seeds with its 95 % bootstrap interval (``agents.stats.iqm_estimate``), and its ratio to
the best classical controller; over rigs the median and the worst ratio.

Every rig's stages 1-3 and every (rig, seed) result is written to its own JSON as it
finishes (``OUT/RIG/rig.json``, ``OUT/RIG/seed_S.json``); a rerun skips the finished ones.
Local processes by default, Ray tasks with ``--ray-address`` (Ray imported only then).

``python -m pneumatic_env.studies.rig_eval --out runs/rig-eval [--rigs NAME ...] [--seeds
1,2,3] [--minutes M] [--processes 2] [--train-processes 1] [--ray-address ADDR]``;
``--quick``: one rig, tiny budgets (:meth:`Plan.quick`); ``--summary``: the table of what
is finished, running nothing (:func:`finished`). Measured on 2 shared cores beside an identify run:
``--quick`` took 156 s (recording 1.4 s, identify --quick 151 s, the baselines 1.2 s; on
the three-effect rig 398 s: recording 156 s, identify 199 s, baselines 34 s), too long
for a test; the bookkeeping is tested on stubs.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import shutil
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import numpy as np

__all__ = [
    "CLASSICAL",
    "EVAL_RIGS",
    "LEARNED_BASELINES",
    "EvalRig",
    "Plan",
    "finished",
    "prepare_rig",
    "run_evaluation",
    "summarise",
    "train_and_evaluate",
    "main",
]

#: Classical controllers at nominal tuning, and the shipped learned ones (trained on the
#: nominal model, ppo_residual_dr and ppo_adaptive over randomised plants around it).
CLASSICAL = ("pid", "sliding_mode")
LEARNED_BASELINES = (
    "ppo_residual",
    "ppo_pure",
    "ppo_generalist",
    "ppo_residual_dr",
    "ppo_adaptive",
)


class EvalRig(NamedTuple):
    """An evaluation rig: name, effects ((name, strength), 1 = ``virtual_rig.effects``),
    the tube (a variant's tube key: the shipped policies exist for 0.5 and 2 m) and the
    seed of its base parameters' draw (off nominal)."""

    name: str
    effects: tuple[tuple[str, float], ...]
    tube: str
    seed: int

    @property
    def variant(self) -> str:
        return f"Numatics-{self.tube}m"


def _rig(name: str, effects: str, tube: str, seed: int) -> EvalRig:
    return EvalRig(name, tuple((e, 1.0) for e in effects.split("+")), tube, seed)


#: The evaluation rigs (issue 35: at least 8; single effects and combinations).
EVAL_RIGS = (
    _rig("tube_heat_spool", "tube_waves+heat_transfer+spool_friction", "2", 11),
    _rig("leak_coil", "leakage+coil_lag", "0.5", 12),
    _rig("supply_sensor", "supply_droop+pressure_sensor_lag", "0.5", 13),
    _rig("heat_spool", "heat_transfer+spool_friction", "2", 14),
    _rig("tube", "tube_waves", "2", 15),
    _rig("heat", "heat_transfer", "2", 16),
    _rig("spool", "spool_friction", "0.5", 17),
    _rig("coil", "coil_lag", "0.5", 18),
    _rig("leak", "leakage", "2", 19),
)


@dataclasses.dataclass(frozen=True)
class Plan:
    """What to run: rigs, training seeds, training minutes (None: the trainer's default),
    identify's ``--quick``, and the suite's tasks cut to ``task_duration_s`` / the first
    ``n_tasks`` (None: the whole suite)."""

    rigs: tuple[EvalRig, ...] = EVAL_RIGS
    seeds: tuple[int, ...] = (1, 2, 3)
    minutes: float | None = None
    identify_quick: bool = False
    n_tasks: int | None = None
    task_duration_s: float | None = None

    @classmethod
    def quick(cls) -> Plan:
        """One rig whose plant is the kernel's own rollout (the cheapest to record), 2
        seeds of 0.2 min, identify ``--quick``, 2 tasks of 0.3 s."""
        return cls(tuple(r for r in EVAL_RIGS if r.name == "spool"), (1, 2), 0.2, True, 2, 0.3)


# --------------------------------------------------------------------------- stages


def _suite(plan: dict):
    from pneumatic_env.agents.suite import load_suite

    suite = load_suite()
    tasks = suite.tasks[: plan["n_tasks"]] if plan["n_tasks"] else suite.tasks
    if plan["task_duration_s"]:
        tasks = tuple(dataclasses.replace(t, duration_s=plan["task_duration_s"]) for t in tasks)
    return dataclasses.replace(suite, tasks=tuple(tasks))


def _closed_loop(controller: str, job: dict) -> dict:
    """The suite on the rig's own plant, measured through its sensors (noise, quantisation):
    per-task RMS errors and the suite's figures."""
    from .rig_closed_loop import RigSpec, rig_suite

    rig = EvalRig(*job["rig"])
    spec = RigSpec(tuple(map(tuple, rig.effects)), seed=rig.seed, noise=True)  # its sensors
    run = rig_suite(controller, spec, rig.variant, _suite(job["plan"]))
    run["rms_error_pct_per_task"] = [t["rms_error_pct"] for t in run.pop("tasks")]
    return run


def _cli(*args: str) -> subprocess.CompletedProcess:
    """``pneumatic-env ARGS`` in a process of its own (it may start processes itself)."""
    command = [sys.executable, "-m", "pneumatic_env.cli", *args]
    return subprocess.run(command, capture_output=True, text=True, check=False)


def prepare_rig(job: dict) -> dict:
    """Stages 1-3 of one rig: record, identify, the baselines in closed loop."""
    from .rig_campaign import make_campaign

    rig = EvalRig(*job["rig"])
    out = Path(job["dir"])
    t0 = time.time()
    paths = make_campaign(
        out / "campaign",
        effects=dict(rig.effects),
        seed=rig.seed,
        campaign="user13",
        overwrite=True,
        tube_length_m=float(rig.tube),
    )
    t1 = time.time()
    report = out / "report"
    quick = ["--quick"] if job["plan"]["identify_quick"] else []
    done = _cli("identify", *map(str, paths), "--report", str(report), *quick)
    t2 = time.time()
    baselines: dict = {}
    for name in (*CLASSICAL, *LEARNED_BASELINES):
        try:
            baselines[name] = _closed_loop(name, job)
        except (FileNotFoundError, ValueError, KeyError) as exc:  # no shipped policy here
            baselines[name] = {"skipped": f"{type(exc).__name__}: {exc}"}
    return {
        "rig": rig.name,
        "report": str(report),
        "identify_returncode": done.returncode,
        "identify_tail": done.stdout[-2000:] + done.stderr[-2000:],
        "baselines": baselines,
        "seconds": {"record": t1 - t0, "identify": t2 - t1, "baselines": time.time() - t2},
    }


def train_and_evaluate(job: dict) -> dict:
    """Stage 4 of one (rig, seed): ``train --rig``, then its controller on the rig's plant."""
    rig, seed = EvalRig(*job["rig"]), job["seed"]
    out = Path(job["dir"]) / f"train_seed{seed}"
    minutes = job["plan"]["minutes"]
    budget = [] if minutes is None else ["--minutes", f"{minutes:g}"]
    t0 = time.time()
    report = str(Path(job["dir"]) / "report")
    done = _cli("train", "--rig", report, "--out", str(out), "--seed", str(seed), *budget)
    controller = out / "controller.npz"
    if done.returncode != 0 or not controller.is_file():
        return {
            "rig": rig.name,
            "seed": seed,
            "failed": f"train --rig exited {done.returncode}: {done.stderr[-2000:]}",
        }
    t1 = time.time()
    training = json.loads((out / "rig_training.json").read_text(encoding="utf-8"))
    return {
        "rig": rig.name,
        "seed": seed,
        "controller": str(controller),
        "residual_base": training.get("base"),
        **_closed_loop(str(controller), job),
        "base_alone_rms_error_pct": base_alone(controller, job),
        "seconds": {"train": t1 - t0, "closed_loop": time.time() - t1},
    }


def base_alone(controller: Path, job: dict) -> float | None:
    """The suite's mean RMS error (%) on the rig's plant of the controller file's base alone
    (a copy with its residual zeroed, ``agents.learned.zero_the_residual``): the learned
    correction's own share is the difference. None for a pure actor (``train --rig`` may
    adopt a shipped one)."""
    from pneumatic_env.agents.learned import LearnedActor, zero_the_residual

    if LearnedActor(controller).residual_config is None:
        return None
    copy = Path(shutil.copy(controller, controller.with_name("base_alone.npz")))
    zero_the_residual(copy, "rig_eval: the base alone")
    return _closed_loop(str(copy), job)["rms_error_pct"]


# --------------------------------------------------------------------------- bookkeeping


def _checkpointed(task: tuple[Callable[[dict], dict], dict]) -> dict:
    """``function(job)``, read back from ``job["result"]`` if a run of the same job wrote
    it, else run and written there as it finishes."""
    function, job = task
    path = Path(job["result"])
    key = {k: v for k, v in job.items() if k != "result"}
    if path.is_file():
        saved = _saved(path)
        if saved.get("job") == json.loads(json.dumps(key)):
            return saved["result"]
    result = function(job)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps({"job": key, "result": result}, indent=1) + "\n", encoding="utf-8")
    tmp.replace(path)  # a result file is whole or absent
    return result


def _run(tasks: list, processes: int, ray_address: str | None):
    """Checkpointed results of ``tasks`` as they finish: inline with one process, else
    local processes or Ray tasks (``identification_eval``'s runner)."""
    if processes <= 1 and not ray_address:
        yield from map(_checkpointed, tasks)
        return
    from .identification_eval import _run_all

    yield from _run_all(_checkpointed, tasks, processes, ray_address)


_log = functools.partial(print, flush=True)  # a log of a run in the background shows at once


def run_evaluation(
    plan: Plan,
    out: Path,
    processes: int = 2,
    ray_address: str | None = None,
    prepare: Callable[[dict], dict] = prepare_rig,
    train: Callable[[dict], dict] = train_and_evaluate,
    log: Callable[[str], None] = _log,
    train_processes: int = 1,
) -> dict:
    """Every rig's stages (``processes`` at a time), then every (rig, seed)
    (``train_processes`` at a time: one, as a user runs ``train --rig`` on the machine;
    two trainings side by side on 2 cores made about 16 500 env steps/s each against
    80 000-88 000 alone, so a wall-time budget bought a fifth of the samples); returns
    :func:`summarise`'s summary (also written to ``out/summary.json``)."""
    plan_dict = {k: v for k, v in dataclasses.asdict(plan).items() if k not in ("rigs", "seeds")}
    common = {"plan": plan_dict}
    rig_jobs = [
        {"rig": list(r), "dir": str(out / r.name), "result": str(result_file(out, r.name))}
        for r in plan.rigs
    ]
    rigs = {}
    for result in _run([(prepare, {**j, **common}) for j in rig_jobs], processes, ray_address):
        rigs[result["rig"]] = result
        log(f"rig {result['rig']}: recorded, identified, baselines run")
    seed_jobs = [
        {**j, **common, "seed": s, "result": str(result_file(out, j["rig"][0], s))}
        for j in rig_jobs
        for s in plan.seeds
    ]
    trained: dict[str, list] = {r.name: [] for r in plan.rigs}
    for result in _run([(train, j) for j in seed_jobs], train_processes, ray_address):
        trained[result["rig"]].append(result)
        state = result.get("skipped") or result.get("failed") or "trained and run"
        log(f"rig {result['rig']} seed {result['seed']}: {state}")
    summary = summarise(rigs, trained)
    (out / "summary.json").write_text(json.dumps(summary, indent=1) + "\n", encoding="utf-8")
    return summary


def summarise(rigs: dict[str, dict], trained: dict[str, list[dict]]) -> dict:
    """Per rig: the baselines' suite RMS, the trained controllers' IQM over seeds with its
    bootstrap interval, the ratio to the best classical; over rigs: median and worst."""
    from pneumatic_env.agents.stats import iqm_estimate

    per_rig = {}
    for name, prepared in rigs.items():
        base = {
            k: v["rms_error_pct"] for k, v in prepared["baselines"].items() if "skipped" not in v
        }
        best = min((base[c], c) for c in CLASSICAL if c in base)
        runs = [r for r in trained.get(name, []) if "rms_error_pct" in r]
        entry: dict = {"baselines_rms_pct": base, "best_classical": best[1], "n_seeds": len(runs)}
        if runs:
            scores = np.array([[r["rms_error_pct"]] for r in sorted(runs, key=lambda r: r["seed"])])
            estimate = iqm_estimate(scores)
            entry["trained_iqm_rms_pct"] = estimate.as_dict()
            entry["ratio_to_best_classical"] = {
                k: estimate.as_dict()[k] / best[0] for k in ("value", "low", "high")
            }
        per_rig[name] = entry
    ratios = [e["ratio_to_best_classical"]["value"] for e in per_rig.values() if e["n_seeds"]]
    skipped = sorted({r["skipped"] for runs in trained.values() for r in runs if "skipped" in r})
    return {
        "rigs": per_rig,
        "ratio_median": float(np.median(ratios)) if ratios else None,
        "ratio_worst": float(max(ratios)) if ratios else None,
        "n_rigs_trained": len(ratios),
        "skipped": skipped,
    }


def result_file(out: Path, rig: str, seed: int | None = None) -> Path:
    """Where a rig's stages 1-3 (``seed`` None) or one seed's stage 4 are checkpointed."""
    return out / rig / ("rig.json" if seed is None else f"seed_{seed}.json")


def _saved(path: Path) -> dict:
    """A checkpoint as :func:`_checkpointed` writes it: ``{"job": ..., "result": ...}``."""
    return json.loads(path.read_text(encoding="utf-8"))


def finished(plan: Plan, out: Path) -> tuple[dict[str, dict], dict[str, list[dict]]]:
    """The stages of ``plan``'s rigs already written under ``out`` (``prepare_rig``'s and
    ``train_and_evaluate``'s results, as :func:`summarise` takes them), whatever their
    plan: a running or stopped evaluation's figures so far."""
    rigs: dict[str, dict] = {}
    trained: dict[str, list[dict]] = {}
    for rig in plan.rigs:
        path = result_file(out, rig.name)
        if not path.is_file():
            continue
        rigs[rig.name] = _saved(path)["result"]
        seeds = [result_file(out, rig.name, s) for s in plan.seeds]
        trained[rig.name] = [_saved(p)["result"] for p in seeds if p.is_file()]
    return rigs, trained


def _seed_lines(rigs: dict[str, dict], trained: dict[str, list[dict]]) -> list[str]:
    """Per (rig, seed): the trained controller's error and its base's alone, its chatter
    and air against the sliding mode's on the rig's plant (issue 35: within 1.5 x), its
    base (and whether ``train --rig`` zeroed its residual), its time."""
    lines = ["", "| rig | seed | RMS % | base alone % | chatter / SM | air / SM | base | train s |"]
    lines.append("|---|---|---|---|---|---|---|---|")
    for name, runs in trained.items():
        sm = rigs[name]["baselines"].get("sliding_mode", {})
        for r in sorted(runs, key=lambda r: r["seed"]):
            if "rms_error_pct" not in r:
                lines.append(f"| {name} | {r['seed']} | {r.get('failed', 'skipped')} ||||||")
                continue
            nan = float("nan")
            chatter = r.get("chatter_rms_a", nan) / sm.get("chatter_rms_a", nan)
            air = r.get("air_mg", nan) / sm.get("air_mg", nan)
            record = r.get("residual_base") or {}
            base = record.get("controller", record.get("kind", "-"))  # a name since 2026-11-28
            base += " (residual zeroed)" if record.get("residual_zeroed") else ""
            if record.get("shipped"):  # since 2026-12-07: a shipped actor won on the fitted rig
                base = f"shipped {record['shipped']['adopted']} (trained: {base})"
            seconds = r.get("seconds", {}).get("train", nan)
            alone = r.get("base_alone_rms_error_pct")
            lines.append(
                f"| {name} | {r['seed']} | {r['rms_error_pct']:.2f} | "
                + ("-" if alone is None else f"{alone:.2f}")
                + f" | {chatter:.2f} | "
                f"{air:.2f} | {base} | {seconds:.0f} |"
            )
    return lines


def _table(summary: dict) -> str:
    lines = [
        "| rig | PID | sliding mode | best shipped learned | trained, IQM [95 % CI] | "
        "ratio to best classical |",
        "|---|---|---|---|---|---|",
    ]
    for name, e in summary["rigs"].items():
        base = e["baselines_rms_pct"]
        t = e.get("trained_iqm_rms_pct")
        r = e.get("ratio_to_best_classical")
        learned = min(((base[k], k) for k in LEARNED_BASELINES if k in base), default=None)
        lines.append(
            f"| {name} | {base.get('pid', float('nan')):.2f} | "
            f"{base.get('sliding_mode', float('nan')):.2f} | "
            + (f"{learned[0]:.2f} (`{learned[1]}`)" if learned else "-")
            + " | "
            + (f"{t['value']:.2f} [{t['low']:.2f}, {t['high']:.2f}]" if t else "-")
            + " | "
            + (f"{r['value']:.2f} [{r['low']:.2f}, {r['high']:.2f}]" if r else "-")
            + " |"
        )
    if summary["ratio_median"] is not None:
        lines.append(
            f"\nratio over rigs: median {summary['ratio_median']:.2f}, "
            f"worst {summary['ratio_worst']:.2f}"
        )
    lines += [f"\n{s}" for s in summary["skipped"]]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m pneumatic_env.studies.rig_eval")
    p.add_argument("--out", type=Path, default=Path("runs/rig-eval"))
    p.add_argument("--rigs", nargs="+", default=None, choices=[r.name for r in EVAL_RIGS])
    p.add_argument("--seeds", type=lambda s: tuple(int(x) for x in s.split(",")), default=None)
    p.add_argument("--minutes", type=float, default=None, help="training budget per seed")
    p.add_argument("--processes", type=int, default=2, help="recording, identify, baselines")
    p.add_argument(
        "--train-processes",
        type=int,
        default=1,
        help="trainings at a time (default 1: each gets the machine, as a user's)",
    )
    p.add_argument(
        "--ray-address",
        default=None,
        metavar="ADDR",
        help="run the stages as Ray tasks (auto, ray://host:10001, or local; needs the "
        "'distributed' extra); default: local processes",
    )
    p.add_argument("--quick", action="store_true", help="one rig, tiny budgets (a test)")
    p.add_argument(
        "--summary",
        action="store_true",
        help="run nothing: the table of the stages already finished under --out",
    )
    args = p.parse_args(argv)
    plan = Plan.quick() if args.quick else Plan()
    if args.rigs:
        plan = dataclasses.replace(plan, rigs=tuple(r for r in EVAL_RIGS if r.name in args.rigs))
    if args.seeds:
        plan = dataclasses.replace(plan, seeds=args.seeds)
    if args.minutes is not None:
        plan = dataclasses.replace(plan, minutes=args.minutes)
    if args.summary:
        rigs, trained = finished(plan, args.out)
        print(_table(summarise(rigs, trained)))
        print("\n".join(_seed_lines(rigs, trained)))
        return 0
    args.out.mkdir(parents=True, exist_ok=True)
    try:
        summary = run_evaluation(
            plan, args.out, args.processes, args.ray_address, train_processes=args.train_processes
        )
    except ModuleNotFoundError as exc:
        if (exc.name or "").split(".")[0] != "ray":
            raise
        print("--ray-address needs Ray: pip install 'pneumatic_env[distributed]'", file=sys.stderr)
        return 2
    print(_table(summary))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
