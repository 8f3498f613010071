"""A fit's Jacobians beside the batched kernel's throughput (issue 34, target 2).

``python -m pneumatic_env.studies.identification_speed --out runs/ident-speed`` records
two ``user13`` campaigns of the virtual rig (synthetic data: a clean rig and a
``tube_waves`` rig, seed 1, 1 m and 2 m of tube) unless they are there, then prints, in
one run on this machine:

- the kernel's throughput: substeps per second of the base model on a full chunk
  (``CHUNK_ENVS`` lanes) of the first clamped recording's current, on one core (the
  serial rollout the fit uses) and on both (``step_parallel``, two chunks);
- a base Jacobian of ``pneumatic-env identify``'s base fit at its start (the training
  split, the default base parameters) on each campaign, and the Jacobian of a candidate
  (``--candidate``, default ``tube_waves``) on top of it: the median time of
  ``--repeats`` runs, the substeps they simulate, and the ratio of that time to the
  kernel's own time for those substeps (issue target: base <= 3, candidate <= 5);
- each Jacobian's time per recording, so a recording that costs far more per substep
  than the others shows.

``--campaign DIR`` (repeatable) times the recordings in DIR instead. Ratios within one
invocation are what count on a shared machine.
"""

from __future__ import annotations

import argparse
import io
import statistics
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

__all__ = ["jacobian_timing", "kernel_throughput", "main"]


def _record(out: Path, effect: str, tube_length_m: float) -> Path:
    """The ``user13`` campaign of the rig ``effect`` (seed 1), recorded once into ``out``."""
    from .rig_campaign import CAMPAIGNS, make_campaign

    folder = out / f"user13-{effect}-seed1"
    if not all((folder / f"{ex.name}.csv").is_file() for ex in CAMPAIGNS["user13"]):
        make_campaign(
            folder,
            effect=effect,
            seed=1,
            campaign="user13",
            tube_length_m=tube_length_m,
            overwrite=True,
        )
    return folder


def _problem(folder: Path, candidate: str | None):
    """The fit problem of the base fit (or of ``candidate`` on top of the base) at its
    start, on the training split of the recordings in ``folder``."""
    from pneumatic_env.identification.candidates import candidate_table
    from pneumatic_env.identification.checks import read_checked
    from pneumatic_env.identification.config import load_config
    from pneumatic_env.identification.datasets import base_fit_parameters, prepare_datasets
    from pneumatic_env.identification.holdout import Holdout

    cfg = load_config()
    recordings = [read_checked(p) for p in sorted(folder.glob("*.csv"))]
    datasets, _ = prepare_datasets(recordings, None, cfg)
    split = Holdout(datasets, "auto", cfg)
    free = base_fit_parameters(datasets, None, cfg)
    if candidate is None:
        return split.training_problem(free, {}, "base")
    cand = candidate_table(cfg)[candidate]
    extra = [p for p in (*cand.refit_base, *cand.parameters) if p not in free]
    return split.training_problem(free + extra, cand.scoped_set(), candidate, cand.scopes())


def jacobian_timing(problem, repeats: int) -> dict:
    """Median seconds of ``problem.jacobian`` at its start, the substeps it simulates, and
    the seconds of each training recording's share (its rollout pieces' seconds summed
    over the threads they ran on, per Jacobian)."""
    from pneumatic_env.identification import problem as fit_problem
    from pneumatic_env.identification import progress

    u = problem.initial_u()
    problem.residual(u)  # the unperturbed simulation (cached), compiled and out of the way
    per_recording = {ds.name: 0.0 for ds in problem.datasets}
    rollout_piece = fit_problem._rollout_piece

    def timed(ds, *args):
        t0 = time.perf_counter()
        out = rollout_piece(ds, *args)
        per_recording[ds.name] += time.perf_counter() - t0
        return out

    seconds = []
    fit_problem._rollout_piece = timed
    try:
        for _ in range(repeats):
            problem._jac_cache.clear()
            meter = progress.Progress(bar=False, stream=io.StringIO())
            with progress.tracking(meter):
                t0 = time.perf_counter()
                problem.jacobian(u)
                seconds.append(time.perf_counter() - t0)
            substeps = meter.done
    finally:
        fit_problem._rollout_piece = rollout_piece
    return {
        "seconds": statistics.median(seconds),
        "substeps": substeps,
        "columns": len(problem.free),
        "per_recording": {k: v / repeats for k, v in per_recording.items() if v},
    }


def kernel_throughput(folder: Path, repeats: int) -> tuple[float, float]:
    """Substeps per second of the base model on one core and on both: a full chunk (two
    on both cores) of the rig's first clamped recording (its sidecar's parameters)."""
    from pneumatic_env.identification.checks import read_checked
    from pneumatic_env.identification.config import load_config
    from pneumatic_env.identification.datasets import prepare_datasets
    from pneumatic_env.params import parameter_array
    from pneumatic_env.physics.constants import CHUNK_ENVS
    from pneumatic_env.simulator import BatchSimulator

    cfg = load_config()
    recordings = [read_checked(p) for p in sorted(folder.glob("*.csv"))]
    datasets, _ = prepare_datasets(recordings, None, cfg)
    ds = next(d for d in datasets if d.rod_mode == "fixed")
    currents = ds.recording.i_c[:-1]
    rates = []
    for lanes, parallel in ((CHUNK_ENVS, False), (2 * CHUNK_ENVS, True)):
        sim = BatchSimulator(parameter_array([ds.values] * lanes), ds.dt_s, ds.substeps)
        block = np.repeat(currents[:, None], lanes, axis=1)
        best = []
        for _ in range(repeats + 1):  # the first run compiles
            sim.reset(initial=ds.initial)
            t0 = time.perf_counter()
            if parallel:
                for row in block:
                    sim.step(row)
            else:
                sim.rollout(block)
            best.append(time.perf_counter() - t0)
        rates.append(block.size * ds.substeps / statistics.median(best[1:]))
    return rates[0], rates[1]


def _table(name: str, timing: dict, rate_both: float) -> list[str]:
    kernel_s = timing["substeps"] / rate_both
    lines = [
        f"| {name} | {timing['columns']} | {timing['substeps'] / 1e6:.1f} | "
        f"{timing['seconds']:.2f} | {kernel_s:.2f} | {timing['seconds'] / kernel_s:.1f} |"
    ]
    shares = ", ".join(f"{k} {v:.2f}" for k, v in timing["per_recording"].items())
    lines.append(f"|  | per recording (s): {shares} | | | | |")
    return lines


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m pneumatic_env.studies.identification_speed", description=__doc__
    )
    parser.add_argument("--out", default="runs/ident-speed", help="where campaigns are recorded")
    parser.add_argument(
        "--campaign", action="append", metavar="DIR", help="time these recordings instead"
    )
    parser.add_argument(
        "--candidate", default="tube_waves", help="the candidate to time ('none': no candidate)"
    )
    parser.add_argument("--repeats", type=int, default=3, help="runs per figure (median)")
    args = parser.parse_args(argv)
    if args.repeats < 1:
        parser.error("--repeats must be at least 1")
    if args.campaign:
        folders = [Path(c) for c in args.campaign]
    else:
        out = Path(args.out)
        folders = [_record(out, "none", 1.0), _record(out, "tube_waves", 2.0)]
    for folder in folders:
        if not any(folder.glob("*.csv")):
            parser.error(f"{folder}: no recordings (*.csv)")
    one, both = kernel_throughput(folders[0], args.repeats)
    print(
        f"kernel (base model, clamped rod): {one / 1e6:.2f} M substeps/s on one core, "
        f"{both / 1e6:.2f} M on both\n"
    )
    print("| Jacobian | columns | M substeps | s (median) | kernel s (both cores) | ratio |")
    print("|---|---|---|---|---|---|")
    for folder in folders:
        for cand in (None, args.candidate) if args.candidate != "none" else (None,):
            timing = jacobian_timing(_problem(folder, cand), args.repeats)
            name = f"{folder.name}: {cand or 'base'}"
            print("\n".join(_table(name, timing, both)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
