"""``pneumatic-env speed``: how fast the simulation runs on this machine, against yardsticks.

One run measures, on the same machine and in the same process:

1. Gymnasium's ``Pendulum-v1`` through ``gym.make`` (the yardstick), steps/s;
2. our single env through ``gym.make`` (all wrappers on), steps/s;
3. our native vector env from ``gym.make_vec`` at several N, on 1 thread and on all cores
   (``numba.set_num_threads``), and the bare ``BatchSimulator`` kernel; env-steps/s,
   env-substeps/s, wall ns per right-hand-side evaluation (4 RK4 stages per substep) and
   the bytes of state, parameter, history and task arrays per environment;
4. Gymnasium's ``SyncVectorEnv`` over N single envs;
5. the independent SciPy solution (``reference_solution.simulate_reference``) on the
   clamped 0.5 A step, at the loosest tolerance that reaches the accuracy target;
6. a ceiling for the kernel: the SIMD instructions of the compiled vectorised loops (read
   from their assembly, ``vector_loop_instructions``) and the scalar work per lane counted
   in ``KERNEL_WORK``, each at its throughput measured in a Numba loop on this machine;
   the measured / ceiling ratio is the median over pairs, each the fastest of a few short
   kernel timings and the fastest of as many operation-cost samples, interleaved (both
   halves see the same window of load from other processes);

and prints a table of ratios against the targets. Medians over ``--repeats``;
measurements of different configurations are interleaved so that load from other
processes spreads over all of them. No number here is a test assertion.
"""
from __future__ import annotations

import argparse
import math
import os
import platform
import re
import subprocess
import sys
import time
from dataclasses import dataclass, field

import numpy as np
from numba import njit, types

from .convergence import TOLERANCE_PERCENT
from pneumatic_env.physics import kernel as K
from pneumatic_env.physics import layout as L
from pneumatic_env.physics.kernel import N_RK, OUTPUT_STATE_ROWS

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
CEILING_PAIRS = 7  # kernel / operation-cost pairs behind the measured / ceiling ratio
# each pair interleaves this many kernel timings (of vector_s / PAIR_BURSTS each) with as
# many operation-cost samples and keeps the fastest of each: a shared machine slows a
# window at random (other processes), and the ceiling is a rate without that load
PAIR_BURSTS = 5
# Batches are timed after this many control steps with random currents, so the delayed
# spool has left its initial position (2 m tube: 5.8 ms) and the pressures have moved off
# ambient: the regime of an episode, not of its first milliseconds.
WARMUP_STEPS = 50
OPS = ("exp", "log", "sqrt", "div", "flop", "imod")  # scalar operations (KERNEL_WORK)
VECTOR_OPS = ("vdiv", "vsqrt", "vother")  # SIMD instructions of the vectorised loops

# The batch path (kernel.advance_chunk) advances an environment in two parts.
# 1. The vectorised loops (VECTOR_LOOPS, every branch computed and selected): per
#    substep, kernel._begin_substeps (start state, piston direction, stiffness test),
#    kernel._interpolate_row (the delayed spool position at the substep's start, middle
#    and end, from the ring buffer's rows: the benchmark's lanes share one tube delay),
#    kernel._base_substeps_vectorised (one RK4 substep of kernel.base_derivatives for every
#    lane), kernel._end_substeps (event test, end stops) and kernel._copy_fast_lanes (the
#    delay history, once per channel); per control period, kernel._fast_commands (the spool
#    play) and the state and outputs (kernel._copy_fast_lanes per row,
#    kernel._fast_output_forces). Their work is not counted by hand:
#    vector_loop_instructions() reads the SIMD instructions of the compiled loops
#    (divisions, square roots, the rest).
# 2. Scalar work per lane, counted here by reading pneumatic_env/physics/kernel.py with
#    the rod clamped (no piston events) and no stiff substep. "flop" is an add, subtract,
#    multiply, compare, select, min, max, abs, floor or conversion; "div" a floating-point
#    division; "imod" an integer modulo; pow (``**``) counts as one exp and one log.
#    Expressions of the per-environment constants alone, and the work done once per chunk
#    (e.g. kernel._delay_slots for lanes that share their delay), are not counted. Update
#    this table when advance_chunk changes.
KERNEL_WORK = {
    # per lane and substep: advance_chunk's two tests of the lane's path (general path or
    # redone)
    "lane_substep:fixed": {"flop": 2},
    # per lane and control period: kernel.refresh_constants testing the key (the substep
    # the constants were derived for; kernel.env_constants runs only when it differs),
    # kernel._same_delay's compare and advance_chunk's test of the lane's path
    "control_step:cache": {"flop": 3},
}
# the vectorised loops in kernel: calls per substep and per control period
VECTOR_LOOPS = {"_begin_substeps": (1, 0), "_interpolate_row": (3, 0),
                "_base_substeps_vectorised": (1, 0),
                "_end_substeps": (1, 0),
                "_fast_commands": (0, 1), "_fast_output_forces": (0, 1),
                # 3 history channels per substep; per period the RK4 state rows, the two
                # coil rows and the outputs that are state rows
                "_copy_fast_lanes": (3, N_RK + 2 + len(OUTPUT_STATE_ROWS))}


# --------------------------------------------------------------------------- options

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


def _positive_int(name):
    def parse(text):
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None or value < 1:
            raise argparse.ArgumentTypeError(f"{name} = {text!r} is not allowed: "
                                             "must be an integer >= 1")
        return value
    return parse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--quick", action="store_true",
                        help="a smoke run: tiny N (up to --max-n, default 8), one repeat, "
                             "short measurements")
    parser.add_argument("--max-n", type=_positive_int("--max-n"), default=None,
                        help=f"largest number of vector environments (default "
                             f"{VECTOR_SIZES[-1]}; SyncVectorEnv stops at {SYNC_MAX_N})")
    parser.add_argument("--repeats", type=_positive_int("--repeats"), default=None,
                        help="repeats of every measurement; medians are reported "
                             "(default 3, --quick 1)")
    parser.add_argument("--out", metavar="FILE.md", default=None,
                        help="also write the report (tables, command, machine) as Markdown")


def make_plan(quick: bool, max_n: int | None, repeats: int | None) -> Plan:
    max_n = max_n or (8 if quick else VECTOR_SIZES[-1])
    sizes = sorted({n for n in VECTOR_SIZES if n <= max_n} | {max_n})
    sync = tuple(n for n in sizes if n <= SYNC_MAX_N)
    import numba
    all_threads = int(numba.config.NUMBA_NUM_THREADS)
    threads = (1,) if all_threads == 1 else (1, all_threads)
    if quick:
        return Plan(True, repeats or 1, tuple(sizes), sync, 0.02, 0.02, 1, 5, (1e-4,), 1e-8,
                    1024, 2, 1, threads)
    return Plan(False, repeats or 3, tuple(sizes), sync, 1.0, 0.5, 2, 100, SCIPY_RTOLS,
                SCIPY_REFERENCE_RTOL, 4096, 100, WARMUP_STEPS, threads)


# --------------------------------------------------------------------------- measurements

def _median(values) -> float:
    values = [v for v in values if v is not None]
    return float(np.median(values)) if values else float("nan")


def _vector_rate(env, seconds: float, min_steps: int) -> float:
    """Env-steps per second of a vector env between autoresets: ``benchmark_vector_step``'s
    loop (sample, step, count ``num_envs``) without its two resets, which cost seconds at
    N = 16384; a step that reset episodes is left out (``_autoreset_s`` times it)."""
    steps, stepping_s = 0, 0.0
    start = time.perf_counter()
    while True:
        before = time.perf_counter()
        _, _, _, truncated, _ = env.step(env.action_space.sample())
        if not truncated.any():
            stepping_s += time.perf_counter() - before
            steps += 1
        if time.perf_counter() - start >= seconds and steps >= min_steps:
            return steps * env.num_envs / stepping_s


def _autoreset_s(env, core, steady_rate: float, warmup_steps: int, episode_steps: int) -> float:
    """Seconds an autoreset of all ``num_envs`` episodes adds to the step that ends them:
    one step timed with every episode at its last step, less the step time at
    ``steady_rate``; then ``warmup_steps`` untimed steps (past the tube delay again)."""
    core.step_count[:] = episode_steps - 1
    before = time.perf_counter()
    _, _, _, truncated, _ = env.step(env.action_space.sample())
    elapsed = time.perf_counter() - before
    assert truncated.all(), "the timed step did not end every episode"
    for _ in range(warmup_steps):
        env.step(env.action_space.sample())
    return max(elapsed - env.num_envs / steady_rate, 0.0)


def _amortized_rate(steady_rate: float, autoreset_s: float, n_envs: int,
                    episode_steps: int) -> float:
    """Env-steps per second over whole episodes: ``episode_steps`` steps, one autoreset."""
    return n_envs * episode_steps / (n_envs * episode_steps / steady_rate + autoreset_s)


def _paired_ratio(numerators, denominators) -> float:
    """Median of the ratios of windows measured one after the other (same index)."""
    return _median([a / b for a, b in zip(numerators, denominators)])


def _with_cpu_share(measure, threads: int):
    """Run ``measure()``; return its value and the process CPU time over wall time x threads
    (below 1 when other processes took the cores during the measurement)."""
    wall0, cpu0 = time.perf_counter(), time.process_time()
    value = measure()
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    return value, cpu / (wall * threads) if wall > 0 else float("nan")


def _array_bytes(*objects) -> int:
    """Bytes of the NumPy arrays held as attributes of ``objects``."""
    return sum(v.nbytes for obj in objects for v in vars(obj).values()
               if isinstance(v, np.ndarray))


def _set_threads(n: int) -> None:
    import numba
    numba.set_num_threads(n)


def measure_single(plan: Plan, log) -> dict:
    """steps/s of Pendulum-v1 and of our single env, both through gym.make."""
    import gymnasium as gym
    from gymnasium.utils.performance import benchmark_step

    import pneumatic_env  # noqa: F401  (registers the ids)
    envs = {YARDSTICK_ID: gym.make(YARDSTICK_ID), ENV_ID: gym.make(ENV_ID)}
    rates = {k: [] for k in envs}
    cpu = {k: [] for k in envs}
    for name, env in envs.items():  # warm-up (loads the jitted kernels)
        benchmark_step(env, target_duration=0.01, seed=0)
    for rep in range(plan.repeats):
        for name, env in envs.items():
            env.action_space.seed(rep)
            rate, share = _with_cpu_share(
                lambda: benchmark_step(env, target_duration=plan.single_s, seed=rep), 1)
            rates[name].append(rate)
            cpu[name].append(share)
    for env in envs.values():
        env.close()
    log(f"single envs: Pendulum {_median(rates[YARDSTICK_ID]):.0f} steps/s, "
        f"ours {_median(rates[ENV_ID]):.0f} steps/s")
    return {"rates": rates, "cpu": cpu}


def measure_vector(plan: Plan, log) -> dict:
    """Native vector env (gym.make_vec) and the bare kernel at every N and thread count."""
    import gymnasium as gym

    from pneumatic_env.simulator import PARALLEL_MIN_ENVS, BatchSimulator

    env_rows, kernel_rows, regimes, mismatch, pairs = [], [], None, [], []
    regime_n = max(n for n in plan.vector_sizes if n <= SCALING_MIN_N)
    for n in plan.vector_sizes:
        env = gym.make_vec(ENV_ID, num_envs=n)
        vector_env = getattr(env, "unwrapped", env)
        core = vector_env.core
        env.action_space.seed(0)
        env.reset(seed=0)
        for threads in plan.threads:  # warm-up: jitted kernels and thread pool
            _set_threads(threads)
            env.step(env.action_space.sample())
        for _ in range(plan.warmup_steps):
            env.step(env.action_space.sample())

        n_substeps, dt = core.sim.n_substeps, core.sim.control_dt_s
        configs = [("serial", 1)]
        if n >= PARALLEL_MIN_ENVS:
            configs += [("parallel", t) for t in plan.threads if t > 1]
        sims = {kind: BatchSimulator(np.repeat(core.sim.params[:, :1], n, axis=1), dt,
                                     n_substeps, parallel=kind == "parallel")
                for kind, _ in configs}
        for kind, threads in configs:  # warm-up, then the env's warmed state
            _set_threads(threads)
            sims[kind].step(np.zeros(n))
            _copy_batch(core.sim, sims[kind])
        # the env's own kernel must be the BatchSimulator's: a stale Numba cache of a module
        # that inlines the physics (cache=True does not track other files) breaks this
        action = env.action_space.sample()
        env.step(action)
        sims["serial"].step(np.asarray(action, dtype=np.float64).reshape(n))
        if not np.array_equal(core.sim.state, sims["serial"].state):
            mismatch.append(n)
            log(f"WARNING N={n}: the env's step does not reproduce BatchSimulator.step "
                "(stale Numba cache? clear the __pycache__ folders of pneumatic_env)")
        for sim in sims.values():
            _copy_batch(core.sim, sim)

        steady = {t: [] for t in plan.threads}
        autoreset = {t: [] for t in plan.threads}
        cpu = {t: [] for t in plan.threads}
        episode_steps = vector_env.max_episode_steps
        for _ in range(plan.repeats):
            for window in range(WINDOWS_PER_REPEAT):
                for threads in plan.threads:
                    _set_threads(threads)
                    rate, share = _with_cpu_share(
                        lambda: _vector_rate(env, plan.vector_s / WINDOWS_PER_REPEAT,
                                             plan.min_steps),
                        threads if core.sim.parallel else 1)
                    steady[threads].append(rate)
                    cpu[threads].append(share)
                    if window == WINDOWS_PER_REPEAT - 1:
                        autoreset[threads].append(_autoreset_s(
                            env, core, rate, plan.warmup_steps, episode_steps))
        for threads in plan.threads:
            env_rows.append({"n": n, "threads": threads,
                             "kernel": ("parallel" if core.sim.parallel and threads > 1
                                        else "serial"),
                             "rates": [_amortized_rate(r, _median(autoreset[threads]), n,
                                                       episode_steps)
                                       for r in steady[threads]],
                             "steady_rates": steady[threads],
                             "autoreset_s": autoreset[threads],
                             "episode_steps": episode_steps, "cpu": cpu[threads],
                             "substeps": n_substeps,
                             "bytes_per_env": _array_bytes(core, core.sim) / n})
        i_max = core.i_max
        env.close()

        currents = np.random.default_rng(0).uniform(-i_max, i_max, (16, n))
        krates = {cfg: [] for cfg in configs}
        kcpu = {cfg: [] for cfg in configs}
        for _ in range(plan.repeats * WINDOWS_PER_REPEAT):
            for kind, threads in configs:
                _set_threads(threads)
                rate, share = _with_cpu_share(
                    lambda: _kernel_rate(sims[kind], currents,
                                         plan.vector_s / WINDOWS_PER_REPEAT, plan.min_steps),
                    threads)
                krates[(kind, threads)].append(rate)
                kcpu[(kind, threads)].append(share)
        for cfg in configs:
            kernel_rows.append({"n": n, "kernel": cfg[0], "threads": cfg[1],
                                "rates": krates[cfg], "cpu": kcpu[cfg],
                                "substeps": n_substeps})
        if n == regime_n:
            _set_threads(1)
            pairs = [_ceiling_pair(plan, sims["serial"], currents)
                     for _ in range(max(plan.repeats, CEILING_PAIRS))]
            regimes = _sample_regimes(sims["serial"], currents)
        log(f"vector N={n}: " + ", ".join(
            f"{r['threads']} thread(s) {_median(r['rates']):.0f}" for r in env_rows
            if r["n"] == n) + " env-steps/s")
        del sims
    _set_threads(plan.threads[-1])
    return {"env": env_rows, "kernel": kernel_rows, "regimes": regimes, "regime_n": regime_n,
            "mismatch": mismatch, "ceiling_pairs": pairs}


def _ceiling_pair(plan: Plan, sim, currents: np.ndarray) -> tuple:
    """One (kernel ns per env-substep, operation costs, RK4 loop ns per env-substep) triple
    behind the measured / ceiling ratio: ``PAIR_BURSTS`` short kernel timings interleaved
    with as many operation-cost samples (``op_cost_sample``) and timings of the RK4 loop
    alone (``_rk4_loop_ns``), the fastest of each (per operation)."""
    kernel_ns, samples, rk4_ns = [], [], []
    for _ in range(PAIR_BURSTS):
        rate = _kernel_rate(sim, currents, plan.vector_s / PAIR_BURSTS, plan.min_steps)
        kernel_ns.append(1e9 / (rate * sim.n_substeps))
        samples.append(op_cost_sample(plan))
        rk4_ns.append(_rk4_loop_ns(sim, currents[0], plan.vector_s / PAIR_BURSTS))
    return (min(kernel_ns), {op: min(s[op] for s in samples) for op in samples[0]},
            min(rk4_ns))


@njit(cache=True)
def _repeat_rk4_loop(constants, work, start, n_lanes, h, reps, run_loop):
    """``reps`` times: restore the work array from ``start``, then (with ``run_loop``) one
    call of the batch path's RK4 loop."""
    for _ in range(reps):
        work[:] = start
        if run_loop:
            K._base_substeps_vectorised(constants, work, n_lanes, h)


def _rk4_loop_ns(sim, currents: np.ndarray, seconds: float) -> float:
    """ns per env-substep of the RK4 loop alone (``kernel._base_substeps_vectorised``) on
    the batch's first chunk, its inputs set up as ``kernel.advance_chunk`` does (start
    state, direction, delayed spool positions), minus the time of restoring them."""
    n = min(K.CHUNK_ENVS, sim.n_envs)
    h = sim.control_dt_s / sim.n_substeps
    constants = sim.constants[0]
    work = K.chunk_work(sim.state, 0, n)
    work[K.W_CURRENT * K.CHUNK_ENVS:K.W_CURRENT * K.CHUNK_ENVS + n] = currents[:n]
    K.prepare_substep(constants, work, sim.history, 0, n,
                      K.ring_slot(sim.head, sim.history.shape[0]), K._same_delay(constants, n), h)
    start = work.copy()
    reps = 16
    while True:  # calls that take about ``seconds``
        t0 = time.perf_counter()
        _repeat_rk4_loop(constants, work, start, n, h, reps, True)
        loop_s = time.perf_counter() - t0
        if loop_s >= seconds or reps >= 1 << 24:
            break
        reps *= 2
    t0 = time.perf_counter()
    _repeat_rk4_loop(constants, work, start, n, h, reps, False)
    restore_s = time.perf_counter() - t0
    return max(loop_s - restore_s, 0.0) / (reps * n) * 1e9


def _copy_batch(source, target) -> None:
    """Put ``target`` (a BatchSimulator of the same size) in ``source``'s state."""
    target.state[:] = source.state
    target.history[:] = source.history
    target.outputs[:] = source.outputs
    target.head = source.head


def _kernel_rate(sim, currents: np.ndarray, seconds: float, min_steps: int) -> float:
    steps = 0
    start = time.perf_counter()
    while True:
        sim.step(currents[steps % len(currents)])
        steps += 1
        elapsed = time.perf_counter() - start
        if elapsed >= seconds and steps >= min_steps:
            return steps * sim.n_envs / elapsed


def measure_sync(plan: Plan, log) -> dict:
    """Gymnasium's SyncVectorEnv over N single envs (make_vec(..., vectorization_mode="sync"))."""
    import gymnasium as gym
    from gymnasium.utils.performance import benchmark_vector_step

    _set_threads(1)
    rows = []
    for n in plan.sync_sizes:
        env = gym.make_vec(ENV_ID, num_envs=n, vectorization_mode="sync")
        measured = [_with_cpu_share(
            lambda: benchmark_vector_step(env, target_duration=plan.vector_s, seed=rep), 1)
            for rep in range(plan.repeats)]
        env.close()
        rates = [m[0] for m in measured]
        rows.append({"n": n, "rates": rates, "cpu": [m[1] for m in measured]})
        log(f"SyncVectorEnv N={n}: {_median(rates):.0f} env-steps/s")
    _set_threads(plan.threads[-1])
    return {"rows": rows}


def measure_scipy(plan: Plan, log) -> dict:
    """Simulated seconds per wall second on the paper's clamped step (2 m tube, command
    coupling): our kernel (one env, one thread) and the SciPy reference solution at the
    loosest tolerance whose error meets the accuracy target of the convergence study."""
    from .convergence import _scales, errors
    from pneumatic_env.params import load_numerics, parameter_array
    from .paper import clamped_step_scenario
    from pneumatic_env.replay import simulate_currents
    from pneumatic_env.simulator import BatchSimulator

    numerics = load_numerics()
    dt, n_substeps = numerics["control_dt_s"], numerics["substeps"]
    scenario = clamped_step_scenario(STEP_TUBE_M, "command", plan.step_scenario_steps * dt, dt)
    params, currents = scenario.parameters(), scenario.coil_current_a
    simulated_s = scenario.duration_s

    _set_threads(1)
    sim = BatchSimulator(parameter_array([params]), dt, n_substeps, parallel=False)
    sim.rollout(currents[:1, None])  # warm-up
    ours_rates = [_rollout_rate(sim, currents, simulated_s, plan.vector_s)
                  for _ in range(plan.repeats)]
    _set_threads(plan.threads[-1])
    ours = simulate_currents(params, currents, dt, substeps=n_substeps)
    result = {"scenario": scenario.name, "ours_rates": ours_rates, "substeps": n_substeps,
              "control_dt_s": dt, "simulated_s": simulated_s, "rows": [], "message": None}
    try:
        from .reference_solution import simulate_reference
    except ImportError as exc:
        result["message"] = f"skipped: pneumatic_env.studies.reference_solution is not available ({exc})"
        log(result["message"])
        return result

    def run(rtol):
        t0 = time.perf_counter()
        solution = simulate_reference(params, currents, dt, rtol=rtol)
        return solution, simulated_s / (time.perf_counter() - t0)

    def error(solution, reference, scales):
        return max(errors(solution, 1, reference, scales).values()) / 100.0

    try:
        reference, reference_rate = run(plan.reference_rtol)
        reference = {k: np.asarray(v) for k, v in reference.items()}
        scales = _scales(params, reference)
        result["ours_error"] = error(ours, reference, scales)
        rows = [{"rtol": r, "error": None, "rates": []} for r in plan.scipy_rtols]
        for _ in range(plan.repeats):
            for row in rows:
                solution, rate = run(row["rtol"])
                row["error"] = error(solution, reference, scales)
                row["rates"].append(rate)
    except Exception as exc:  # the reference is developed separately; report, don't crash
        result["message"] = f"failed: simulate_reference raised {type(exc).__name__}: {exc}"
        log(result["message"])
        return result
    result["reference"] = {"rtol": plan.reference_rtol, "error": 0.0, "rates": [reference_rate]}
    result["rows"] = rows
    ok = [r for r in rows if r["error"] <= ACCURACY_FULL_SCALE]
    result["chosen"] = max(ok, key=lambda r: _median(r["rates"])) if ok else None
    if result["chosen"] is None:
        result["message"] = (f"failed: no tolerance in {plan.scipy_rtols} reached "
                             f"{ACCURACY_FULL_SCALE:.1%} of full scale")
        log(result["message"])
        return result
    log(f"SciPy: {_median(result['chosen']['rates']):.3g} simulated s per wall s at rtol "
        f"{result['chosen']['rtol']:g}; ours {_median(ours_rates):.3g}")
    return result


def _rollout_rate(sim, currents, simulated_s, seconds) -> float:
    """Simulated s per wall s over repeated rollouts from reset (resets not timed)."""
    spent, done = 0.0, 0
    while spent < seconds or done < 1:
        sim.reset()
        t0 = time.perf_counter()
        sim.rollout(currents[:, None])
        spent += time.perf_counter() - t0
        done += 1
    return done * simulated_s / spent


# --------------------------------------------------------------------------- ceiling

@njit(cache=True)
def _micro_base(a, out, idx, sweeps):
    for _ in range(sweeps):
        for i in range(idx.shape[0]):
            j = idx[i]
            out[j] = a[j]


@njit(cache=True)
def _micro_exp(a, out, idx, sweeps):
    for _ in range(sweeps):
        for i in range(idx.shape[0]):
            j = idx[i]
            out[j] = math.exp(a[j])


@njit(cache=True)
def _micro_log(a, out, idx, sweeps):
    for _ in range(sweeps):
        for i in range(idx.shape[0]):
            j = idx[i]
            out[j] = math.log(a[j])


@njit(cache=True)
def _micro_sqrt(a, out, idx, sweeps):
    for _ in range(sweeps):
        for i in range(idx.shape[0]):
            j = idx[i]
            out[j] = math.sqrt(a[j])


@njit(cache=True)
def _micro_div(a, out, idx, sweeps):
    for _ in range(sweeps):
        for i in range(idx.shape[0]):
            j = idx[i]
            out[j] = 1.0 / a[j]


@njit(cache=True)
def _micro_flop(a, out, idx, sweeps):  # 9 flops in two independent chains
    for _ in range(sweeps):
        for i in range(idx.shape[0]):
            j = idx[i]
            v = a[j]
            out[j] = ((1.1 * v + 0.3) * v + 0.7) + ((0.9 * v - 0.2) * v - 0.4)


@njit(cache=True)
def _micro_imod(a, out, idx, sweeps):
    n = idx.shape[0]
    for s in range(sweeps):
        for i in range(n):
            j = idx[i]
            out[j] = a[(j + s) % n]


@njit(cache=True)
def _micro_imod_base(a, out, idx, sweeps):
    n = idx.shape[0]
    for s in range(sweeps):
        for i in range(n):
            j = idx[i]
            out[j] = a[min(j + s, n - 1)]


# The same operations in contiguous loops the compiler vectorises (``idx`` unused), each
# with enough independent work per element that the arithmetic, not the memory traffic,
# sets the time: ns per element is the cost of one SIMD instruction divided by its lanes.
@njit(cache=True, error_model="numpy")
def _vmicro_base(a, out, idx, sweeps):
    for _ in range(sweeps):
        for j in range(a.shape[0]):
            out[j] = a[j]


@njit(cache=True, error_model="numpy")
def _vmicro_div(a, out, idx, sweeps):  # 8 divisions and 15 adds, independent
    for _ in range(sweeps):
        for j in range(a.shape[0]):
            v = a[j]
            out[j] = (((1.0 / (v + 1.0) + 1.0 / (v + 2.0)) + (1.0 / (v + 3.0) + 1.0 / (v + 4.0)))
                      + ((1.0 / (v + 5.0) + 1.0 / (v + 6.0))
                         + (1.0 / (v + 7.0) + 1.0 / (v + 8.0))))


@njit(cache=True, error_model="numpy")
def _vmicro_sqrt(a, out, idx, sweeps):  # 8 square roots and 15 adds, independent
    for _ in range(sweeps):
        for j in range(a.shape[0]):
            v = a[j]
            out[j] = (((math.sqrt(v + 1.0) + math.sqrt(v + 2.0))
                       + (math.sqrt(v + 3.0) + math.sqrt(v + 4.0)))
                      + ((math.sqrt(v + 5.0) + math.sqrt(v + 6.0))
                         + (math.sqrt(v + 7.0) + math.sqrt(v + 8.0))))


@njit(cache=True, error_model="numpy")
def _vmicro_flop(a, out, idx, sweeps):  # four independent degree-4 Horner chains: 35 flops
    for _ in range(sweeps):
        for j in range(a.shape[0]):
            v = a[j]
            c1 = (((0.11 * v + 0.3) * v + 0.7) * v + 0.2) * v + 0.1
            c2 = (((0.12 * v - 0.2) * v + 0.4) * v - 0.3) * v + 0.2
            c3 = (((0.13 * v + 0.5) * v - 0.6) * v + 0.1) * v - 0.4
            c4 = (((0.14 * v - 0.1) * v + 0.8) * v - 0.5) * v + 0.3
            out[j] = (c1 + c2) + (c3 + c4)


# op -> (loop, its baseline, operations per element, other flops per element (subtracted
# at the cost of "flop" or "vother"))
_MICRO = {"exp": (_micro_exp, _micro_base, 1, 0), "log": (_micro_log, _micro_base, 1, 0),
          "sqrt": (_micro_sqrt, _micro_base, 1, 0), "div": (_micro_div, _micro_base, 1, 0),
          "flop": (_micro_flop, _micro_base, 9, 0),
          "imod": (_micro_imod, _micro_imod_base, 1, 0),
          "vother": (_vmicro_flop, _vmicro_base, 35, 0),
          "vdiv": (_vmicro_div, _vmicro_base, 8, 15), "vsqrt": (_vmicro_sqrt, _vmicro_base, 8, 15)}


def op_cost_sample(plan: Plan) -> dict:
    """ns per operation, one sample (single thread): the extra time of a Numba loop
    applying it to each element over the same loop copying the element. Scalar operations
    visit the elements in a random order (not vectorised); the ``v*`` ones run contiguous
    loops that compile to SIMD code, so their cost is per element (per SIMD instruction /
    lanes). Independent elements: this is throughput, not latency."""
    rng = np.random.default_rng(0)
    a = rng.uniform(0.1, 0.9, plan.micro_elements)
    out = np.empty_like(a)
    idx = rng.permutation(plan.micro_elements)
    funcs = {f for entry in _MICRO.values() for f in entry[:2]}
    for f in funcs:  # compiled or loaded from the cache, and warm
        f(a, out, idx, 1)
    per_sweep = plan.micro_elements * plan.micro_sweeps
    timed = {}
    for f in funcs:
        t0 = time.perf_counter()
        f(a, out, idx, plan.micro_sweeps)
        timed[f] = (time.perf_counter() - t0) / per_sweep * 1e9
    extra = {op: max(timed[f] - timed[base], 0.0) for op, (f, base, *_) in _MICRO.items()}
    sample = {}
    for op, (_, _, count, other) in _MICRO.items():  # minus the other flops' share
        flop_op = "vother" if op.startswith("v") else "flop"
        flop_ns = extra[flop_op] / _MICRO[flop_op][2]
        sample[op] = max(extra[op] - other * flop_ns, 0.0) / count
    return sample


def measure_op_costs(plan: Plan, samples: list | None = None) -> dict:
    """Median ns per operation over ``max(repeats, 3)`` samples of ``op_cost_sample``
    (``samples`` taken elsewhere in the run, e.g. paired with the kernel, count too)."""
    _set_threads(1)
    samples = list(samples or []) + [op_cost_sample(plan)
                                     for _ in range(max(plan.repeats, 3))]
    _set_threads(plan.threads[-1])
    return {op: _median([sample[op] for sample in samples]) for op in _MICRO}


def _sample_regimes(sim, currents: np.ndarray, steps: int = 8, envs: int = 128) -> dict:
    """How often the batch path leaves its vectorised loop: the mean number of parts
    ``kernel.refinement`` splits a substep into, and the share of substeps it splits (those
    the general path redoes), sampled at the control-step boundaries of a few more steps
    of the benchmark run."""
    from pneumatic_env.physics import kernel

    picks = np.linspace(0, sim.n_envs - 1, min(envs, sim.n_envs)).astype(int)
    h = sim.control_dt_s / sim.n_substeps
    constants = {int(e): kernel.env_constants(sim.params, int(e), h) for e in picks}
    parts, split, samples = 0, 0, 0
    for step in range(steps):
        sim.step(currents[step % len(currents)])
        for env in picks:
            state = tuple(float(v) for v in sim.state[:L.S_T2 + 1, env])
            n_parts = kernel.refinement(constants[int(env)], state, h)
            parts += n_parts
            split += n_parts > 1
            samples += 1
    return {"samples": samples, "parts": parts / samples, "redone": split / samples}


SIMD_REGISTERS = (("%zmm", 8), ("%ymm", 4), ("%xmm", 2))  # register name, float64 lanes


# the Numba type of each argument of the VECTOR_LOOPS, by name
_ROW = types.float64[::1]
_LOOP_ARGUMENT_TYPES = {"constants": _ROW, "work": _ROW, "target_row": _ROW,
                        "lower_row": _ROW, "upper_row": _ROW, "row": types.int64,
                        "weight": types.float64, "at_start": types.boolean,
                        "force_row": _ROW, "command_row": _ROW, "play_row": _ROW,
                        "values": _ROW, "key_values": _ROW, "differing_bits": types.int64[::1],
                        "n_lanes": types.int64, "work_row": types.int64,
                        "keep_redone": types.boolean, "h": types.float64}


_ASM_LABEL = re.compile(r"^(\.LBB\d+_\d+):")
_ASM_JUMP = re.compile(r"^\tj\w+\t(\.LBB\d+_\d+)$")
_ASM_INDEX_STEP = re.compile(r"^\taddq?\t\$(\d+), (%r\w+)$")


def _vector_body(asm: str, register: str) -> tuple[list, int]:
    """The SIMD instructions (on ``register``) of a function's vector loop body and the
    float64 elements one pass of it serves.

    The body is the single-block loop (a label, then a jump back to it with no other label
    between) with the most such instructions; the elements per pass are its index step
    (``add $K, %reg`` with ``%reg`` scaling a SIMD operand's address by 8). LLVM interleaves
    small loops, so one pass may serve several vectors; prologue, remainder loop and the
    Python wrapper are not counted.
    """
    lines = asm.splitlines()
    best, label = ([], []), None
    for i, line in enumerate(lines):
        found = _ASM_LABEL.match(line)
        if found:
            label = (found.group(1), i)
            continue
        found = _ASM_JUMP.match(line)
        if found and label and found.group(1) == label[0]:
            body = lines[label[1] + 1:i]
            simd = [b for b in body if register in b]
            if len(simd) > len(best[1]):
                best = (body, simd)
    body, simd = best
    steps = {int(m.group(1)) for m in map(_ASM_INDEX_STEP.match, body)
             if m and any(f",{m.group(2)},8)" in line for line in simd)}
    return simd, (steps.pop() if len(steps) == 1 else 0)


def vector_loop_instructions() -> dict:
    """SIMD instructions of the batch path's vectorised loops, by class (from their assembly).

    The functions of ``VECTOR_LOOPS`` in ``kernel`` are compiled afresh (Numba does not
    show the assembly of cached code) with the argument types the kernel passes. The
    instructions of each one's vector loop body (``_vector_body``) on the widest vector
    registers present count, scaled to one vector of lanes (on x86 with AVX2, 4 lanes: a
    body LLVM interleaved to serve 16 elements counts a quarter). Returns the counts per
    class of each loop, the lanes per vector and whether every loop was vectorised.
    """
    from pneumatic_env.physics import kernel
    loops = {}
    found = []
    for name in VECTOR_LOOPS:
        counts = loops[name] = dict.fromkeys(VECTOR_OPS, 0.0)
        py_func = getattr(kernel, name).py_func
        fn = njit(error_model="numpy")(py_func)
        arguments = py_func.__code__.co_varnames[:py_func.__code__.co_argcount]
        signature = tuple(_LOOP_ARGUMENT_TYPES[a] for a in arguments)
        fn.compile(signature)
        asm = fn.inspect_asm(signature)
        lanes, body, elements = 1, [], 0
        for register, register_lanes in SIMD_REGISTERS:
            body, elements = _vector_body(asm, register)
            if register == "%xmm":  # 128-bit: only the packed double instructions are SIMD
                body = [line for line in body if line.split()[0].endswith("pd")]
            if body and elements:
                lanes = register_lanes
                break
        found.append(lanes)
        for line in body if lanes > 1 else []:
            op = line.split()[0]
            counts["vdiv" if op.startswith("vdivp") or op == "divpd" else
                   "vsqrt" if op.startswith("vsqrtp") or op == "sqrtpd" else
                   "vother"] += lanes / elements
    return {"loops": loops, "lanes": min(found), "vectorised": min(found) > 1}


def kernel_ceiling(instructions: dict, op_ns: dict, n_substeps: int) -> dict:
    """Work per environment and substep and the time it takes at the measured cost per
    operation: a floor on the kernel's ns per substep (rod clamped, no stiff substep).

    The vectorised loops' SIMD instructions (``vector_loop_instructions``, times the
    loops' calls per substep of ``VECTOR_LOOPS``) at their cost per element, plus the
    scalar work per lane of ``KERNEL_WORK`` at the scalar costs.
    """
    ops = dict.fromkeys(VECTOR_OPS + OPS, 0.0)
    for name, (per_substep, per_period) in VECTOR_LOOPS.items():
        for op, count in instructions["loops"][name].items():
            ops[op] += count * (per_substep + per_period / n_substeps)
    for op, count in KERNEL_WORK["lane_substep:fixed"].items():
        ops[op] += count
    for op, count in KERNEL_WORK["control_step:cache"].items():
        ops[op] += count / n_substeps
    ns = {op: ops[op] * op_ns[op] for op in ops}
    return {"ops": ops, "ns": ns, "total_ns": sum(ns.values())}


# --------------------------------------------------------------------------- report

def _fmt(x, digits=3) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "n/a"
    if abs(x) >= 1e3:
        return f"{x:,.0f}"
    return f"{x:.{digits}g}"


def _pct(shares) -> str:
    return f"{100 * _median(shares):.0f}%"


def _table(headers, rows) -> list[str]:
    lines = ["| " + " | ".join(headers) + " |", "|" + "|".join("---" for _ in headers) + "|"]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return lines


def machine_description() -> dict:
    import gymnasium
    import numba
    import scipy
    model = platform.processor() or platform.machine()
    try:
        text = subprocess.run(["lscpu"], capture_output=True, text=True, timeout=10).stdout
        for line in text.splitlines():
            if line.startswith("Model name:"):
                model = line.split(":", 1)[1].strip()
    except (OSError, subprocess.SubprocessError):
        pass
    return {"cpu": model, "cores": os.cpu_count(), "numba_threads": numba.config.NUMBA_NUM_THREADS,
            "python": platform.python_version(), "numpy": np.__version__,
            "numba": numba.__version__, "gymnasium": gymnasium.__version__,
            "scipy": scipy.__version__, "os": platform.platform()}


def _ratio_rows(res: dict, plan: Plan) -> list[tuple]:
    """(quantity, value, target text, met) for the ratio table."""
    rows = []
    pend = _median(res["single"]["rates"][YARDSTICK_ID])
    single = _median(res["single"]["rates"][ENV_ID])

    def row(name, value, target, bigger_is_better=True, unit="x"):
        if value is None or not math.isfinite(value):
            rows.append((name, "n/a", target and f"{'>=' if bigger_is_better else '<='} "
                         f"{_fmt(target)}{unit}", "n/a"))
            return
        met = "n/a" if target is None else (
            "yes" if (value >= target if bigger_is_better else value <= target) else "no")
        tgt = "-" if target is None else f"{'>=' if bigger_is_better else '<='} {_fmt(target)}{unit}"
        rows.append((name, f"{_fmt(value)}{unit}", tgt, met))

    row("single env / Pendulum", single / pend, TARGET_SINGLE_OVER_PENDULUM)
    env = {(r["n"], r["threads"]): _median(r["rates"]) for r in res["vector"]["env"]}
    kern = {(r["n"], r["kernel"], r["threads"]): _median(r["rates"])
            for r in res["vector"]["kernel"]}
    sync = {r["n"]: _median(r["rates"]) for r in res["sync"]["rows"]}
    big = [n for n in plan.vector_sizes if n >= SCALING_MIN_N] or [max(plan.vector_sizes)]
    many = plan.threads[-1]
    for n in big:
        row(f"vector env N={n}, 1 thread / Pendulum", env[(n, 1)] / pend,
            TARGET_VECTOR_OVER_PENDULUM)
        row(f"vector env N={n}, 1 thread, env-steps/s", env[(n, 1)], TARGET_VECTOR_STEPS_PER_S,
            unit="")
    n_sync = max(sync) if sync else None
    if n_sync is not None:
        row(f"vector env / SyncVectorEnv, N={n_sync}, 1 thread", env[(n_sync, 1)] / sync[n_sync],
            TARGET_VECTOR_OVER_SYNC)
    scipy_res = res["scipy"]
    ours = _median(scipy_res["ours_rates"])
    if scipy_res.get("chosen") and not scipy_res.get("message"):
        theirs = _median(scipy_res["chosen"]["rates"])
        row("ours / SciPy, 0.5 A step (kernel, 1 env, 1 thread)", ours / theirs,
            TARGET_OURS_OVER_SCIPY)
        row("ours / SciPy, 0.5 A step (single env via gym.make)",
            single * scipy_res["control_dt_s"] / theirs, None)
    else:
        row("ours / SciPy, 0.5 A step", None, TARGET_OURS_OVER_SCIPY)
    ceiling = res.get("ceiling")
    if ceiling:
        row(f"kernel measured / ceiling, N={res['vector']['regime_n']}, 1 thread",
            _median(ceiling["pair_ratios"]), TARGET_MEASURED_OVER_CEILING, False)
    env_windows = {(r["n"], r["threads"]): r["rates"] for r in res["vector"]["env"]}
    kern_windows = {(r["n"], r["kernel"], r["threads"]): r["rates"]
                    for r in res["vector"]["kernel"]}
    for n in big:
        if many > 1 and (n, many) in env:
            row(f"vector env N={n}, {many} threads / 1 thread",
                _paired_ratio(env_windows[(n, many)], env_windows[(n, 1)]),
                TARGET_THREAD_SCALING)
        if (n, "parallel", many) in kern and many > 1:
            row(f"kernel N={n}, {many} threads / serial 1 thread",
                _paired_ratio(kern_windows[(n, "parallel", many)],
                              kern_windows[(n, "serial", 1)]), TARGET_THREAD_SCALING)
    return rows


RATIO_HEADERS = ("ratio", "value", "target", "met")


def report(res: dict, plan: Plan, command: str, machine: dict, started: float) -> str:
    from pneumatic_env.params import load_numerics
    numerics = load_numerics()
    pend = _median(res["single"]["rates"][YARDSTICK_ID])
    lines = ["# Speed", "",
             f"Generated by `{command}` ({'quick smoke run' if plan.quick else 'full run'}; "
             f"{plan.repeats} repeat(s), medians; {time.time() - started:.0f} s).", "",
             "## Machine", ""]
    lines += [f"- CPU: {machine['cpu']}, {machine['cores']} cores "
              f"(Numba threads available: {machine['numba_threads']})",
              f"- Python {machine['python']}, NumPy {machine['numpy']}, Numba {machine['numba']}, "
              f"Gymnasium {machine['gymnasium']}, SciPy {machine['scipy']}",
              f"- {machine['os']}",
              f"- load average (1 min) at start / end: {res['load'][0]:.2f} / {res['load'][1]:.2f} "
              "(other processes share the cores; rates scale down with it)", "",
              "## Numerics", "",
              f"Default numerics (`load_numerics()`): control period "
              f"{numerics['control_dt_s'] * 1e3:g} ms, {numerics['substeps']} RK4 substeps per "
              f"control period ({RK4_STAGES} right-hand-side evaluations each); environment "
              f"`{ENV_ID}`.", ""]
    mismatch = res["vector"]["mismatch"]
    lines += [("**Warning: at N = " + ", ".join(map(str, mismatch)) + " the env's step did not "
               "reproduce `BatchSimulator.step` bit for bit: its jitted task kernel is not "
               "the current physics (stale Numba cache?). Its rates are not valid.**")
              if mismatch else "The env's step reproduced `BatchSimulator.step` bit for bit "
              "at every N (its jitted task kernel runs the current physics).", "",
              "## Ratios", ""]
    lines += _table(RATIO_HEADERS, _ratio_rows(res, plan))
    lines += ["", "## Single environments (gym.make, `gymnasium.utils.performance.benchmark_step`)",
              ""]
    rows = []
    for name in (YARDSTICK_ID, ENV_ID):
        r = res["single"]["rates"][name]
        rows.append((name, _fmt(_median(r)), _fmt(min(r)), _fmt(max(r)),
                     _fmt(_median(r) / pend), _pct(res["single"]["cpu"][name])))
    lines += _table(("env", "steps/s (median)", "min", "max", "/ Pendulum", "CPU busy"), rows)

    lines += ["", "## Native vector env (gym.make_vec) and the bare kernel (BatchSimulator.step)",
              ""]
    rows = []
    for r in res["vector"]["env"]:
        rate = _median(r["rates"])
        rhs = rate * r["substeps"] * RK4_STAGES
        rows.append((r["n"], r["threads"], f"env ({r['kernel']})", _fmt(rate),
                     _fmt(_median(r["steady_rates"])), _fmt(_median(r["autoreset_s"]) * 1e3),
                     _fmt(rate * r["substeps"]), _fmt(1e9 / rhs), _fmt(r["bytes_per_env"]),
                     _pct(r["cpu"])))
    for r in res["vector"]["kernel"]:
        rate = _median(r["rates"])
        rhs = rate * r["substeps"] * RK4_STAGES
        rows.append((r["n"], r["threads"], f"kernel ({r['kernel']})", _fmt(rate), "", "",
                     _fmt(rate * r["substeps"]), _fmt(1e9 / rhs), "", _pct(r["cpu"])))
    rows.sort(key=lambda row: (row[0], row[2].startswith("kernel"), row[1]))
    episode_steps = res["vector"]["env"][0]["episode_steps"]
    lines += [f"An env's env-steps/s are over whole episodes ({episode_steps} steps and one "
              "autoreset of all N episodes); the steps between autoresets and the time an "
              "autoreset adds are in their own columns.", ""]
    lines += _table(("N", "threads", "what", "env-steps/s", "between autoresets",
                     "autoreset (ms)", "env-substeps/s", "wall ns per RHS", "bytes per env",
                     "CPU busy"), rows)

    lines += ["", "## SyncVectorEnv (gym.make_vec(..., vectorization_mode=\"sync\"), "
              "`benchmark_vector_step`)", ""]
    env = {(r["n"], r["threads"]): _median(r["rates"]) for r in res["vector"]["env"]}
    rows = [(r["n"], _fmt(_median(r["rates"])), _fmt(env.get((r["n"], 1))),
             _fmt(env.get((r["n"], 1), float("nan")) / _median(r["rates"])), _pct(r["cpu"]))
            for r in res["sync"]["rows"]]
    lines += _table(("N", "Sync env-steps/s", "native, 1 thread", "native / Sync",
                     "CPU busy (Sync)"), rows)

    s = res["scipy"]
    lines += ["", f"## SciPy reference: {s['scenario']}, {s['simulated_s'] * 1e3:g} ms simulated",
              ""]
    if s.get("rows"):
        lines += [f"Errors as in docs/convergence.md (largest over the control-period samples: "
                  f"p1, p2 of supply - ambient, f of the force range, x of half the stroke) "
                  f"against the SciPy solution at rtol {plan.reference_rtol:g}; accuracy target "
                  f"{ACCURACY_FULL_SCALE:.1%} of full scale.", ""]
        rows = [(f"ours ({s['substeps']} RK4 substeps, kernel, 1 env, 1 thread)", "-",
                 f"{s['ours_error']:.2g}", _fmt(_median(s["ours_rates"])))]
        ref = s["reference"]
        rows.append(("SciPy reference_solution (reference, timed once)", f"{ref['rtol']:g}",
                     "0", _fmt(_median(ref["rates"]))))
        for r in s["rows"]:
            mark = " (compared)" if r is s.get("chosen") else ""
            rows.append((f"SciPy reference_solution{mark}", f"{r['rtol']:g}",
                         f"{r['error']:.2g}", _fmt(_median(r["rates"]))))
        lines += _table(("solver", "rtol", "max error (fraction of full scale)",
                         "simulated s per wall s"), rows)
    if s.get("message"):
        lines += ["", f"SciPy comparison {s['message']}.", "",
                  f"Ours ({s['substeps']} RK4 substeps, kernel, 1 env): "
                  f"{_fmt(_median(s['ours_rates']))} simulated s per wall s."]

    c = res.get("ceiling")
    if c:
        how = (f"one vector serves {c['lanes']} environments" if c["vectorised"] else
               "**a loop was not vectorised on this machine**")
        lines += ["", f"## Kernel ceiling (N={res['vector']['regime_n']}, 1 thread, serial kernel)",
                  "", "Work per environment and substep: the SIMD instructions of the compiled "
                  "vectorised loops' bodies (" + ", ".join(
                      f"`kernel.{f}`" for f in VECTOR_LOOPS) + ", each times its calls per "
                  "substep in `VECTOR_LOOPS`; per vector of lanes, a body LLVM interleaved to "
                  "serve several vectors counting its share; prologues, remainder loops and "
                  f"wrappers not counted; {how}), divided by their lanes, and the scalar work "
                  "per lane counted "
                  "in `KERNEL_WORK` "
                  "(`studies/speed.py`); each at its throughput measured in a Numba loop "
                  "on this machine (a SIMD instruction: the cost per element of a vectorised "
                  "loop times its lanes, `vother` at the cost of an add or multiply; a scalar "
                  "operation: in a loop that is not vectorised).", ""]
        lanes = {op: c["lanes"] if op in VECTOR_OPS else 1 for op in VECTOR_OPS + OPS}
        rows = [(op, _fmt(c["op_ns"][op] * lanes[op]), _fmt(c["ops"][op] / lanes[op]),
                 _fmt(c["ns"][op])) for op in VECTOR_OPS + OPS]
        rows.append(("**ceiling**", "", "", _fmt(c["total_ns"])))
        rows.append(("**measured**", "", "", _fmt(c["measured_ns"])))
        lines += _table(("operation", "ns each", "per substep and env", "ns per substep"),
                        rows)
        ratios = c["pair_ratios"]
        lines += ["", f"The ratio in the first table is the median over {len(ratios)} pairs: "
                  + ", ".join(f"{r:.2f}" for r in sorted(ratios)) + f". Each pair is the fastest "
                  f"of {PAIR_BURSTS} kernel timings ({plan.vector_s / PAIR_BURSTS:g} s each) "
                  f"over the fastest of {PAIR_BURSTS} samples of each operation cost, "
                  "interleaved, so that both halves see the same window of load from other "
                  "processes and neither carries a burst of it (the ceiling is a rate without "
                  "such load). The table above uses the medians over the pairs (and further "
                  "operation samples).", "",
                  f"Where the gap is: the RK4 loop alone (`kernel._base_substeps_vectorised` "
                  f"on the batch's first chunk, its inputs as `advance_chunk` sets them up, "
                  f"timed in the same pairs) takes {_fmt(c['rk4_ns'])} ns per env-substep "
                  f"against its own ceiling of {_fmt(c['rk4_ceiling_ns'])} ns (median ratio "
                  f"{_median(c['rk4_ratios']):.2f}); the rest of the kernel (the loops around "
                  f"it, the delay reads, the constants cache, the calls per chunk) takes "
                  f"{_fmt(c['measured_ns'] - c['rk4_ns'])} ns against "
                  f"{_fmt(c['total_ns'] - c['rk4_ceiling_ns'])} ns."]
        lines += ["", f"Parts per substep (`kernel.refinement`, sampled): {c['parts']:.2f}; "
                  f"substeps the general path redid: {c['redone']:.1%}."]
    lines += ["", "## How it is measured", "",
              "- Single envs: `gymnasium.utils.performance.benchmark_step` (a random action per "
              "step, resets included), through `gym.make` with its default wrappers.",
              "- Native vector env: the loop of `benchmark_vector_step` (a random action per "
              "step, N env-steps per step) after one reset, without that helper's two resets "
              "per call (seconds at N = 16384), timing the steps between autoresets; then one "
              "step with every episode at its last step (`max_episode_steps`), whose extra "
              "time is the autoreset of all N episodes. env-steps/s = N x episode steps / "
              "(their time + one autoreset). The env chooses its kernel: the parallel one for "
              "N >= 256 (`simulator.PARALLEL_MIN_ENVS`) on more than one thread.",
              "- Bare kernel: `BatchSimulator.step` with random currents, serial (1 thread) "
              "and parallel (more threads) kernels chosen explicitly. Wall ns per RHS = "
              "1e9 / (env-steps/s x substeps x 4).",
              f"- Vector env and kernel: each repeat is {WINDOWS_PER_REPEAT} timing windows of "
              f"{plan.vector_s / WINDOWS_PER_REPEAT:.3g} s per configuration, interleaved over "
              "the configurations (the autoreset timed once per repeat); rates are medians over "
              "the windows, and a thread-scaling ratio is the median over the windows of the "
              "ratio of two neighbouring windows (both see nearly the same load from other "
              "processes).",
              "- Bytes per env: all NumPy arrays of the env's `TaskCore` and `BatchSimulator` "
              "(parameters, state, outputs, delay history, references, ...) divided by N.",
              "- SciPy: `reference_solution.simulate_reference` at each rtol; the fastest one "
              "whose error meets the accuracy target is compared with our kernel's rollout "
              "of the same scenario (resets not timed).",
              "- CPU busy: process CPU time / (wall time x threads) during the measurement, "
              "median; well below 100% means other processes held the cores and the rates "
              "are low by about that factor.",
              f"- Batches are timed after {plan.warmup_steps} control steps with random currents "
              "from reset (the kernel copies the env's warmed state), past the tube delay and "
              "the first pressure rise; single envs run whole episodes."]
    return "\n".join(lines) + "\n"


def _command(args) -> str:
    parts = ["pneumatic-env speed"]
    if args.quick:
        parts.append("--quick")
    if args.max_n is not None:
        parts.append(f"--max-n {args.max_n}")
    if args.repeats is not None:
        parts.append(f"--repeats {args.repeats}")
    if args.out:
        parts.append(f"--out {args.out}")
    return " ".join(parts)


def run(args) -> int:
    import numba
    started = time.time()
    plan = make_plan(args.quick, args.max_n, args.repeats)
    threads_before = numba.get_num_threads()

    def log(msg):
        print(f"[speed] {msg}", file=sys.stderr, flush=True)

    res = {"load": [os.getloadavg()[0]]}
    try:
        res["single"] = measure_single(plan, log)
        res["vector"] = measure_vector(plan, log)
        res["sync"] = measure_sync(plan, log)
        res["scipy"] = measure_scipy(plan, log)
        pairs = res["vector"]["ceiling_pairs"]
        op_ns = measure_op_costs(plan, [ops for _, ops, _ in pairs])
        regimes = res["vector"]["regimes"]
        n_ref = res["vector"]["regime_n"]
        serial = [r for r in res["vector"]["kernel"]
                  if r["n"] == n_ref and r["kernel"] == "serial"][0]
        instructions = vector_loop_instructions()
        ceiling = kernel_ceiling(instructions, op_ns, serial["substeps"])
        # measured / ceiling of each pair (kernel, operation costs and the RK4 loop alone,
        # timed interleaved); the ratios reported are their medians
        ratios = [ns / kernel_ceiling(instructions, ops, serial["substeps"])["total_ns"]
                  for ns, ops, _ in pairs]
        rk4 = instructions["loops"]["_base_substeps_vectorised"]
        rk4_ceilings = [sum(count * ops[op] for op, count in rk4.items())
                        for _, ops, _ in pairs]
        ceiling.update(op_ns=op_ns, lanes=instructions["lanes"],
                       vectorised=instructions["vectorised"], parts=regimes["parts"],
                       redone=regimes["redone"], pair_ratios=ratios,
                       measured_ns=_median([ns for ns, _, _ in pairs]),
                       rk4_ns=_median([ns for _, _, ns in pairs]),
                       rk4_ceiling_ns=sum(count * op_ns[op] for op, count in rk4.items()),
                       rk4_ratios=[ns / c for (_, _, ns), c in zip(pairs, rk4_ceilings)])
        res["ceiling"] = ceiling
    finally:
        numba.set_num_threads(threads_before)
    res["load"].append(os.getloadavg()[0])
    text = report(res, plan, _command(args), machine_description(), started)
    print(text)
    if args.out:
        with open(args.out, "w", encoding="utf-8") as fh:
            fh.write(text)
    return 0
