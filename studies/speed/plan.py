"""What one ``pneumatic-env speed`` run measures: the targets, the plan and the timing
helpers the measurements and the ceiling share."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..convergence import TOLERANCE_PERCENT

ENV_ID = "pneumatic_env/ForceTrack-Numatics-2m-v0"
YARDSTICK_ID = "Pendulum-v1"
VECTOR_SIZES = (1, 64, 1024, 16384)
SYNC_MAX_N = 1024  # SyncVectorEnv holds N full Python envs; beyond this it only costs time
SCALING_MIN_N = 1024  # thread scaling is reported for N >= this
STEP_TUBE_M = 2.0  # the paper's clamped 0.5 A step (Figs. 15-16) with the env's tube
# The SciPy solver must reach the accuracy the convergence study demands of the default
# substeps (errors as there: p1, p2 of supply - ambient, f of the force range, x of L/2).
ACCURACY_FULL_SCALE = TOLERANCE_PERCENT / 100.0
SCIPY_REFERENCE_RTOL = 1e-10  # the "exact" solution the errors are measured against
SCIPY_RTOLS = (1e-3, 1e-4, 1e-5, 1e-6, 1e-7)

# Targets (per core, medians), from the issue "Speed".
TARGET_VECTOR_STEPS_PER_S = 100_000
TARGET_VECTOR_OVER_PENDULUM = 1.0
TARGET_SINGLE_OVER_PENDULUM = 0.3
TARGET_VECTOR_OVER_SYNC = 20.0
TARGET_OURS_OVER_SCIPY = 200.0
TARGET_THREAD_SCALING = 1.6
TARGET_MEASURED_OVER_CEILING = 1.5

RK4_STAGES = 4
# A vector env's or kernel's repeat is this many windows (of vector_s / WINDOWS_PER_REPEAT),
# interleaved over the configurations: a ratio of two configurations (threads) is the median
# over the windows of the ratios of neighbouring windows, which see nearly the same load
# from other processes.
WINDOWS_PER_REPEAT = 3
# Batches are timed after this many control steps with random currents, so the delayed
# spool has left its initial position (2 m tube: 5.8 ms) and the pressures have moved off
# ambient: the regime of an episode, not of its first milliseconds.
WARMUP_STEPS = 50


@dataclass
class Plan:
    """What one run measures and for how long."""

    quick: bool
    repeats: int
    vector_sizes: tuple
    sync_sizes: tuple
    single_s: float  # seconds per single-env measurement
    vector_s: float  # seconds per vector-env / kernel measurement
    min_steps: int  # at least this many vector steps per measurement
    step_scenario_steps: int  # control steps of the SciPy step scenario
    scipy_rtols: tuple
    reference_rtol: float
    micro_elements: int
    micro_sweeps: int
    warmup_steps: int  # control steps run before timing a batch (past the tube delay)
    threads: tuple = field(default_factory=tuple)


def make_plan(quick: bool, max_n: int | None, repeats: int | None) -> Plan:
    max_n = max_n or (8 if quick else VECTOR_SIZES[-1])
    sizes = sorted({n for n in VECTOR_SIZES if n <= max_n} | {max_n})
    sync = tuple(n for n in sizes if n <= SYNC_MAX_N)
    import numba

    all_threads = int(numba.config.NUMBA_NUM_THREADS)
    threads = (1,) if all_threads == 1 else (1, all_threads)
    if quick:
        return Plan(
            True,
            repeats or 1,
            tuple(sizes),
            sync,
            0.02,
            0.02,
            1,
            5,
            (1e-4,),
            1e-8,
            1024,
            2,
            1,
            threads,
        )
    return Plan(
        False,
        repeats or 3,
        tuple(sizes),
        sync,
        1.0,
        0.5,
        2,
        100,
        SCIPY_RTOLS,
        SCIPY_REFERENCE_RTOL,
        4096,
        100,
        WARMUP_STEPS,
        threads,
    )


def median(values) -> float:
    values = [v for v in values if v is not None]
    return float(np.median(values)) if values else float("nan")


def with_cpu_share(threads: int, measure, *args, **kwargs):
    """Run ``measure(*args, **kwargs)``; return its value and the process CPU time over wall
    time x ``threads`` (below 1 when other processes took the cores during the
    measurement)."""
    wall0, cpu0 = time.perf_counter(), time.process_time()
    value = measure(*args, **kwargs)
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    return value, cpu / (wall * threads) if wall > 0 else float("nan")


def set_threads(n: int) -> None:
    import numba

    numba.set_num_threads(n)


def kernel_rate(sim, currents: np.ndarray, seconds: float, min_steps: int) -> float:
    """Env-steps per second of ``sim.step`` over ``currents`` (at least ``seconds`` and
    ``min_steps`` steps)."""
    steps = 0
    start = time.perf_counter()
    while True:
        sim.step(currents[steps % len(currents)])
        steps += 1
        elapsed = time.perf_counter() - start
        if elapsed >= seconds and steps >= min_steps:
            return steps * sim.n_envs / elapsed
