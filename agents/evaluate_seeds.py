"""Multi-seed evaluation of a learned controller against a classical one (Agarwal et al., 2021).

    python -m pneumatic_env.agents.evaluate_seeds runs/res-s0 runs/res-s1 ... \\
        [--actor actor.npz] [--variants Numatics-2m ...] [--baseline sliding_mode] \\
        [--out runs/res-seeds.md]

Each argument is a training run directory (its ``--actor`` file, default ``actor.npz``) or
an actor ``.npz``; each is one seed. Every seed runs the benchmark suite on each variant
(default: the variant the first actor was trained on) through ``agents.bench.run_suite``,
and so does the baseline once (deterministic). Per variant, with ``agents.stats``:

* the interquartile mean over seeds of the mean RMS error (% of the force scale), with a
  95 % bootstrap interval;
* the paired ratio to the baseline (per seed, the mean over tasks of RMS / baseline RMS)
  with its interval; "beats" needs the whole interval below 1 and at least
  ``MIN_SEEDS_FOR_A_CLAIM`` (3) seeds;
* the probability of improvement P(seed's RMS < baseline's RMS), averaged over tasks;
* the ratio on ``sine_10hz``, ``sine_20hz`` and ``chirp`` (issue 19's fast tasks);
* the worst task's chatter and air ratios (mean over seeds / baseline).

Output: a Markdown table (printed, and written to ``--out`` with a ``.json`` beside it).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from . import stats
from .bench import run_suite
from .bench_results import markdown_table
from .learned import LearnedActor
from .suite import Suite, load_suite

__all__ = [
    "FAST_TASKS",
    "actor_paths",
    "evaluate_seeds",
    "summarize_variant",
    "seeds_markdown",
    "main",
]

FAST_TASKS = ("sine_10hz", "sine_20hz", "chirp")
#: fewest seeds for a "beats" verdict (issue 19 asks for 5, or 10 on the headline rows)
MIN_SEEDS_FOR_A_CLAIM = 3


def actor_paths(runs: Sequence[str | Path], actor: str = "actor.npz") -> list[Path]:
    """The actor file of each run (a directory holding ``actor``, or an ``.npz``)."""
    paths = []
    for r in runs:
        p = Path(r)
        p = p / actor if p.is_dir() else p
        if not p.is_file():
            raise FileNotFoundError(
                f"no actor at {str(p)!r}: give run directories holding {actor!r} or .npz files"
            )
        paths.append(p)
    return paths


def _matrix(rows: list[dict], tasks: list[str], key: str) -> np.ndarray:
    by_task = {r["task"]: float(r[key]) for r in rows}
    return np.array([by_task[t] for t in tasks])


def summarize_variant(
    seed_rows: list[list[dict]], baseline_rows: list[dict], reps: int = stats.DEFAULT_REPS
) -> dict:
    """The statistics of one variant from each seed's suite rows and the baseline's."""
    tasks = [r["task"] for r in baseline_rows]
    rms = np.stack([_matrix(rows, tasks, "rms_error_pct") for rows in seed_rows])
    base = _matrix(baseline_rows, tasks, "rms_error_pct")[None]
    out = {
        "n_seeds": len(seed_rows),
        "tasks": tasks,
        "mean_rms_pct": stats.iqm_estimate(rms.mean(axis=1), reps).as_dict(),
        "baseline_mean_rms_pct": float(base.mean()),
        "paired_ratio": stats.paired_ratio_estimate(rms, base, reps).as_dict(),
        "probability_of_improvement": stats.improvement_estimate(rms, base, reps).as_dict(),
        "per_seed_mean_rms_pct": rms.mean(axis=1).tolist(),
    }
    # a bootstrap interval over fewer seeds than MIN_SEEDS_FOR_A_CLAIM says nothing
    enough = len(seed_rows) >= MIN_SEEDS_FOR_A_CLAIM
    out["beats"] = bool(out["paired_ratio"]["high"] < 1.0) if enough else None
    out["task_ratios"] = {
        t: stats.paired_ratio_estimate(
            rms[:, [tasks.index(t)]], base[:, [tasks.index(t)]], reps
        ).as_dict()
        for t in FAST_TASKS
        if t in tasks
    }
    for key, name in (("chatter_rms_a", "chatter"), ("air_mg", "air")):
        mine = np.stack([_matrix(rows, tasks, key) for rows in seed_rows]).mean(axis=0)
        ref = _matrix(baseline_rows, tasks, key)
        ratio = np.where(ref > 0, mine / np.where(ref > 0, ref, 1.0), np.inf)
        j = int(np.argmax(ratio))
        out[f"worst_{name}_ratio"] = {"ratio": float(ratio[j]), "task": tasks[j]}
    return out


def evaluate_seeds(
    actors: Sequence[Path],
    variants: Sequence[str] | None = None,
    baseline: str = "sliding_mode",
    suite: Suite | None = None,
    reps: int = stats.DEFAULT_REPS,
    progress=None,
) -> dict:
    """Run the suite for every actor (seed) and the baseline; statistics per variant."""
    suite = suite or load_suite()
    if not variants:
        variants = [LearnedActor(actors[0]).meta["variant"]]
    result: dict[str, Any] = {
        "baseline": baseline,
        "suite_version": suite.version,
        "actors": [str(a) for a in actors],
        "variants": {},
    }
    for variant in variants:
        base_rows, _ = run_suite(baseline, [variant], suite)
        seed_rows = []
        for actor in actors:
            if progress:
                progress(f"{actor} on {variant}")
            rows, _ = run_suite(str(actor), [variant], suite)
            seed_rows.append(rows)
        result["variants"][variant] = summarize_variant(seed_rows, base_rows, reps)
    return result


def estimate_text(e: dict, digits: int = 2) -> str:
    """``value [low, high]`` of an estimate (``Estimate.as_dict()``)."""
    return f"{e['value']:.{digits}f} [{e['low']:.{digits}f}, {e['high']:.{digits}f}]"


def seeds_markdown(result: dict) -> str:
    """One row per variant (values with 95 % intervals in brackets)."""
    base = result["baseline"]
    header = [
        "variant",
        "seeds",
        "IQM mean RMS (%)",
        f"{base} (%)",
        "paired ratio",
        "P(improvement)",
        *[f"{t} ratio" for t in FAST_TASKS],
        "worst chatter ratio",
        "worst air ratio",
        "beats",
    ]
    rows = []
    for variant, s in result["variants"].items():
        rows.append(
            [
                variant,
                str(s["n_seeds"]),
                estimate_text(s["mean_rms_pct"]),
                f"{s['baseline_mean_rms_pct']:.2f}",
                estimate_text(s["paired_ratio"], 3),
                estimate_text(s["probability_of_improvement"], 2),
                *[
                    estimate_text(s["task_ratios"][t], 3) if t in s["task_ratios"] else ""
                    for t in FAST_TASKS
                ],
                f"{s['worst_chatter_ratio']['ratio']:.2f} ({s['worst_chatter_ratio']['task']})",
                f"{s['worst_air_ratio']['ratio']:.2f} ({s['worst_air_ratio']['task']})",
                {True: "yes", False: "no", None: f"- (< {MIN_SEEDS_FOR_A_CLAIM} seeds)"}[
                    s["beats"]
                ],
            ]
        )
    return (
        f"Suite {result['suite_version']}, {len(result['actors'])} seed(s) against "
        f"{base}\n\n" + markdown_table(header, rows)
    )


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m pneumatic_env.agents.evaluate_seeds", description=__doc__.split("\n")[0]
    )
    ap.add_argument("runs", nargs="+", help="run directories or actor .npz files (one a seed)")
    ap.add_argument("--actor", default="actor.npz", help="actor file inside a run directory")
    ap.add_argument("--variants", nargs="+", help="default: the first actor's variant")
    ap.add_argument("--baseline", default="sliding_mode")
    ap.add_argument("--suite", help="suite file (default configs/benchmark.yaml)")
    ap.add_argument("--reps", type=int, default=stats.DEFAULT_REPS, help="bootstrap resamples")
    ap.add_argument("--out", help="Markdown file to write (a .json beside it)")
    args = ap.parse_args(argv)
    result = evaluate_seeds(
        actor_paths(args.runs, args.actor),
        args.variants,
        args.baseline,
        load_suite(args.suite),
        args.reps,
        progress=lambda m: print(m, file=sys.stderr, flush=True),
    )
    text = seeds_markdown(result)
    print(text)
    if args.out:
        out = Path(args.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(text + "\n", encoding="utf-8")
        out.with_suffix(".json").write_text(json.dumps(result, indent=2), encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
