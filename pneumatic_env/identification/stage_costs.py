"""What each stage of a diagnosis cost beside the kernel's own throughput (issue 34).

Every simulation reports its work to :mod:`.progress` in lane-substeps (simulated samples x
substeps x parameter columns), and each stage's start goes to its ledger. The kernel's
throughput is measured once per diagnosis on the data itself: the base model on a full
batch chunk (``CHUNK_ENVS`` lanes) of a training recording's current, one core. A stage's
kernel time is its lane-substeps at that rate on every thread the fits use; its ratio to
the kernel is its wall time over that: 1 would be the kernel alone, fully vectorised on
every core, with nothing else to do. A candidate whose form costs more per substep than
the paper's model (a pressure node, the transmission line) shows as a higher ratio.
"""

from __future__ import annotations

import statistics
import time

import numpy as np

from pneumatic_env.params import parameter_array
from pneumatic_env.physics.constants import CHUNK_ENVS
from pneumatic_env.simulator import BatchSimulator

from .datasets import Dataset

__all__ = ["kernel_substeps_per_s", "stage_cost_lines", "stage_costs"]

KERNEL_SAMPLES = 1000  # samples of the current the throughput is timed on
KERNEL_REPEATS = 2  # timed runs after a first one (which may compile); their median counts


def kernel_substeps_per_s(
    ds: Dataset, samples: int | None = KERNEL_SAMPLES, repeats: int = KERNEL_REPEATS
) -> float:
    """Lane-substeps per second of the base model at ``ds``'s substep on one core: a
    full chunk of ``ds``'s parameters over its first ``samples`` samples (None: all),
    the median of ``repeats`` runs after a first one (``studies.identification_speed``
    takes its one-core figure from here too)."""
    n_all = len(ds.recording.i_c)
    n = n_all if samples is None else max(2, min(samples, n_all))
    params = np.ascontiguousarray(np.repeat(parameter_array([ds.values]), CHUNK_ENVS, axis=1))
    currents = np.repeat(ds.recording.i_c[: n - 1, None], CHUNK_ENVS, axis=1)
    seconds = []
    for _ in range(repeats + 1):
        sim = BatchSimulator(params, ds.dt_s, ds.substeps)
        sim.reset(initial=ds.initial)
        t0 = time.perf_counter()
        sim.rollout(currents)
        seconds.append(time.perf_counter() - t0)
    return (n - 1) * ds.substeps * CHUNK_ENVS / max(statistics.median(seconds[1:]), 1e-9)


def stage_costs(ledger: list[dict], substeps_per_s: float, threads: int) -> list[dict]:
    """Per stage of ``progress.ledger()``: seconds, lane-substeps, the kernel's time for
    them on ``threads`` cores at ``substeps_per_s`` each, and the ratio of the two (None
    for a stage that simulated nothing)."""
    rows = []
    for entry in ledger:
        kernel_s = entry["work"] / (substeps_per_s * max(threads, 1)) if substeps_per_s else 0.0
        rows.append(
            {
                "stage": entry["stage"],
                "seconds": entry["seconds"],
                "lane_substeps": entry["work"],
                "kernel_seconds": kernel_s,
                "ratio_to_kernel": entry["seconds"] / kernel_s if kernel_s > 0 else None,
            }
        )
    return rows


def stage_cost_lines(rows: list[dict], substeps_per_s: float, threads: int) -> list[str]:
    """The report's "Time" section: each stage's seconds, simulated lane-substeps and
    its ratio to the kernel."""
    if not rows:
        return []
    lines = [
        "",
        "## Time",
        "",
        f"Each stage's wall time beside the kernel's own for the substeps it simulated "
        f"({substeps_per_s / 1e6:.1f} M lane-substeps/s per core, measured on this data, "
        f"x {threads} threads; 1 x would be the kernel alone on every core):",
        "",
        "| stage | s | simulated (M lane-substeps) | x the kernel |",
        "|---|---|---|---|",
    ]
    for r in rows:
        ratio = "-" if r["ratio_to_kernel"] is None else f"{r['ratio_to_kernel']:.1f}"
        lines.append(
            f"| {r['stage']} | {r['seconds']:.1f} | {r['lane_substeps'] / 1e6:.1f} | {ratio} |"
        )
    return lines
