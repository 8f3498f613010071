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
  than the others shows;
- the kernel's cost per substep with each candidate switched on (its ``set`` values and
  its parameters' initial values, on every lane of a chunk, one core) against the base
  model's, measured interleaved: what a candidate's simulations cost beside the base.

``--candidate`` takes a comma-separated list (default: leakage, rod_seal_leak, coil_lag,
spool_friction, heat_transfer, tube_volume, iso_flow_law, valve_null_leak,
exhaust_backpressure, tube_waves); ``--no-jacobians``
prints only the kernel figures (a few minutes instead of many).

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

__all__ = ["candidate_kernel_costs", "jacobian_timing", "kernel_throughput", "main"]

DEFAULT_CANDIDATES = (
    "leakage,rod_seal_leak,coil_lag,spool_friction,heat_transfer,tube_volume,iso_flow_law,"
    "valve_null_leak,exhaust_backpressure,tube_waves"
)


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
    from pneumatic_env.identification.stage_costs import kernel_substeps_per_s
    from pneumatic_env.params import parameter_array
    from pneumatic_env.physics.constants import CHUNK_ENVS
    from pneumatic_env.simulator import BatchSimulator

    cfg = load_config()
    recordings = [read_checked(p) for p in sorted(folder.glob("*.csv"))]
    datasets, _ = prepare_datasets(recordings, None, cfg)
    ds = next(d for d in datasets if d.rod_mode == "fixed")
    one_core = kernel_substeps_per_s(ds, samples=None, repeats=repeats)
    lanes = 2 * CHUNK_ENVS  # two chunks, stepped by step_parallel
    sim = BatchSimulator(parameter_array([ds.values] * lanes), ds.dt_s, ds.substeps)
    block = np.repeat(ds.recording.i_c[:-1, None], lanes, axis=1)
    seconds = []
    for _ in range(repeats + 1):  # the first run compiles
        sim.reset(initial=ds.initial)
        t0 = time.perf_counter()
        for row in block:
            sim.step(row)
        seconds.append(time.perf_counter() - t0)
    return one_core, block.size * ds.substeps / statistics.median(seconds[1:])


def _candidate_values(values: dict, candidate: str) -> dict:
    """``values`` (a recording's kernel parameters) with ``candidate`` switched on: its
    ``set`` values (a text value names the parameter whose value it takes) and its
    parameters' initial values."""
    from pneumatic_env.identification.candidates import candidate_table

    cand = candidate_table()[candidate]
    out = dict(values)
    out.update({k: float(values[v]) if isinstance(v, str) else v for k, v in cand.set.items()})
    out.update({p.name: p.initial for p in cand.parameters if p.initial is not None})
    return out


def candidate_kernel_costs(
    folder: Path, candidates: Sequence[str], repeats: int
) -> dict[str, tuple[float, float]]:
    """Seconds per substep of a full chunk on one core (``rollout``) of the rig's first
    clamped and first moving recording, for the base model ('base') and each plant
    candidate switched on, the runs interleaved (base, candidates, base, ...; median):
    name -> (clamped, moving)."""
    from pneumatic_env.identification.candidates import candidate_table
    from pneumatic_env.identification.checks import read_checked
    from pneumatic_env.identification.config import load_config
    from pneumatic_env.identification.datasets import prepare_datasets
    from pneumatic_env.params import parameter_array
    from pneumatic_env.physics.constants import CHUNK_ENVS
    from pneumatic_env.simulator import BatchSimulator

    cfg = load_config()
    table = candidate_table(cfg)
    plant = [c for c in candidates if table[c].kind == "plant"]
    recordings = [read_checked(p) for p in sorted(folder.glob("*.csv"))]
    datasets, _ = prepare_datasets(recordings, None, cfg)
    clamped = next(d for d in datasets if d.rod_mode == "fixed")
    moving = next((d for d in datasets if d.rod_mode != "fixed"), clamped)
    runs = []  # (name, column, simulator, currents, initial state)
    for column, ds in enumerate((clamped, moving)):
        block = np.repeat(ds.recording.i_c[:-1, None], CHUNK_ENVS, axis=1)
        for name in ("base", *plant):
            values = ds.values if name == "base" else _candidate_values(ds.values, name)
            sim = BatchSimulator(parameter_array([values] * CHUNK_ENVS), ds.dt_s, ds.substeps)
            runs.append((name, column, sim, block, ds.initial, block.size * ds.substeps))
    seconds: dict[tuple[str, int], list[float]] = {(r[0], r[1]): [] for r in runs}
    for repeat in range(repeats + 1):  # the first round compiles
        for name, column, sim, block, initial, substeps in runs:
            sim.reset(initial=initial)
            t0 = time.perf_counter()
            sim.rollout(block)
            if repeat:
                seconds[name, column].append((time.perf_counter() - t0) / substeps)
    return {
        name: (statistics.median(seconds[name, 0]), statistics.median(seconds[name, 1]))
        for name in ("base", *plant)
    }


def _cost_table(costs: dict[str, tuple[float, float]]) -> list[str]:
    base_clamped, base_moving = costs["base"]
    lines = [
        "| kernel, one core | ns/substep clamped | x base | ns/substep moving | x base |",
        "|---|---|---|---|---|",
    ]
    for name, (clamped, moving) in costs.items():
        lines.append(
            f"| {name} | {clamped * 1e9:.0f} | {clamped / base_clamped:.1f} | "
            f"{moving * 1e9:.0f} | {moving / base_moving:.1f} |"
        )
    return lines


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
        "--candidate",
        default=DEFAULT_CANDIDATES,
        help="comma-separated candidates to time ('none': no candidate)",
    )
    parser.add_argument(
        "--no-jacobians", action="store_true", help="only the kernel's per-substep costs"
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
    candidates = [c for c in args.candidate.split(",") if c and c != "none"]
    print("\n".join(_cost_table(candidate_kernel_costs(folders[0], candidates, args.repeats))))
    print(flush=True)
    if args.no_jacobians:
        return 0
    one, both = kernel_throughput(folders[0], args.repeats)
    print(
        f"kernel (base model, clamped rod): {one / 1e6:.2f} M substeps/s on one core, "
        f"{both / 1e6:.2f} M on both\n"
    )
    print("| Jacobian | columns | M substeps | s (median) | kernel s (both cores) | ratio |")
    print("|---|---|---|---|---|---|")
    for folder in folders:
        for cand in (None, *candidates):
            timing = jacobian_timing(_problem(folder, cand), args.repeats)
            name = f"{folder.name}: {cand or 'base'}"
            print("\n".join(_table(name, timing, both)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
