"""The measurements of ``pneumatic-env speed``: single envs, the native vector env and the
bare kernel, SyncVectorEnv and the SciPy reference solution."""

from __future__ import annotations

import time

import numpy as np

from .ceiling import CEILING_PAIRS, ceiling_pair, sample_regimes
from .plan import (
    ACCURACY_FULL_SCALE,
    ENV_ID,
    SCALING_MIN_N,
    STEP_TUBE_M,
    WINDOWS_PER_REPEAT,
    YARDSTICK_ID,
    Plan,
    kernel_rate,
    median,
    set_threads,
    with_cpu_share,
)


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


def _amortized_rate(
    steady_rate: float, autoreset_s: float, n_envs: int, episode_steps: int
) -> float:
    """Env-steps per second over whole episodes: ``episode_steps`` steps, one autoreset."""
    return n_envs * episode_steps / (n_envs * episode_steps / steady_rate + autoreset_s)


def _array_bytes(*objects) -> int:
    """Bytes of the NumPy arrays held as attributes of ``objects``."""
    return sum(v.nbytes for obj in objects for v in vars(obj).values() if isinstance(v, np.ndarray))


def measure_single(plan: Plan, log) -> dict:
    """steps/s of Pendulum-v1 and of our single env, both through gym.make."""
    import gymnasium as gym
    from gymnasium.utils.performance import benchmark_step

    import pneumatic_env  # noqa: F401  (registers the ids)

    envs = {YARDSTICK_ID: gym.make(YARDSTICK_ID), ENV_ID: gym.make(ENV_ID)}
    rates = {k: [] for k in envs}
    cpu = {k: [] for k in envs}
    for env in envs.values():  # warm-up (loads the jitted kernels)
        benchmark_step(env, target_duration=0.01, seed=0)
    for rep in range(plan.repeats):
        for name, env in envs.items():
            env.action_space.seed(rep)
            rate, share = with_cpu_share(
                1, benchmark_step, env, target_duration=plan.single_s, seed=rep
            )
            rates[name].append(rate)
            cpu[name].append(share)
    for env in envs.values():
        env.close()
    log(
        f"single envs: Pendulum {median(rates[YARDSTICK_ID]):.0f} steps/s, "
        f"ours {median(rates[ENV_ID]):.0f} steps/s"
    )
    return {"rates": rates, "cpu": cpu}


def measure_vector(plan: Plan, log) -> dict:
    """Native vector env (gym.make_vec) and the bare kernel at every N and thread count."""
    env_rows, kernel_rows, regimes, mismatch, pairs = [], [], None, [], []
    regime_n = max(n for n in plan.vector_sizes if n <= SCALING_MIN_N)
    for n in plan.vector_sizes:
        env, core, sims, configs = _warmed_env_and_kernels(plan, n, mismatch, log)
        env_rows += _time_vector_env(plan, env, core, n)
        i_max, n_substeps = core.i_max, core.sim.n_substeps
        env.close()

        currents = np.random.default_rng(0).uniform(-i_max, i_max, (16, n))
        kernel_rows += _time_kernels(plan, sims, configs, currents, n, n_substeps)
        if n == regime_n:
            set_threads(1)
            pairs = [
                ceiling_pair(plan, sims["serial"], currents)
                for _ in range(max(plan.repeats, CEILING_PAIRS))
            ]
            regimes = sample_regimes(sims["serial"], currents)
        log(
            f"vector N={n}: "
            + ", ".join(
                f"{r['threads']} thread(s) {median(r['rates']):.0f}"
                for r in env_rows
                if r["n"] == n
            )
            + " env-steps/s"
        )
        sims.clear()  # free the batches before the next N
    set_threads(plan.threads[-1])
    return {
        "env": env_rows,
        "kernel": kernel_rows,
        "regimes": regimes,
        "regime_n": regime_n,
        "mismatch": mismatch,
        "ceiling_pairs": pairs,
    }


def _warmed_env_and_kernels(plan: Plan, n: int, mismatch: list, log):
    """(vector env, its core, {kind: BatchSimulator}, [(kind, threads)]) of ``n`` envs,
    warmed up and in the env's state; ``n`` joins ``mismatch`` when the env's step does
    not reproduce the serial kernel's bit for bit."""
    import gymnasium as gym

    from pneumatic_env.simulator import PARALLEL_MIN_ENVS, BatchSimulator

    env = gym.make_vec(ENV_ID, num_envs=n)
    core = getattr(env, "unwrapped", env).core
    env.action_space.seed(0)
    env.reset(seed=0)
    for threads in plan.threads:  # warm-up: jitted kernels and thread pool
        set_threads(threads)
        env.step(env.action_space.sample())
    for _ in range(plan.warmup_steps):
        env.step(env.action_space.sample())

    n_substeps, dt = core.sim.n_substeps, core.sim.control_dt_s
    configs = [("serial", 1)]
    if n >= PARALLEL_MIN_ENVS:
        configs += [("parallel", t) for t in plan.threads if t > 1]
    sims = {
        kind: BatchSimulator(
            np.repeat(core.sim.params[:, :1], n, axis=1),
            dt,
            n_substeps,
            parallel=kind == "parallel",
        )
        for kind, _ in configs
    }
    for kind, threads in configs:  # warm-up, then the env's warmed state
        set_threads(threads)
        sims[kind].step(np.zeros(n))
        _copy_batch(core.sim, sims[kind])
    # the env's own kernel must be the BatchSimulator's: a stale Numba cache of a module
    # that inlines the physics (cache=True does not track other files) breaks this
    action = env.action_space.sample()
    env.step(action)
    sims["serial"].step(np.asarray(action, dtype=np.float64).reshape(n))
    if not np.array_equal(core.sim.state, sims["serial"].state):
        mismatch.append(n)
        log(
            f"WARNING N={n}: the env's step does not reproduce BatchSimulator.step "
            "(stale Numba cache? clear the __pycache__ folders of pneumatic_env)"
        )
    for sim in sims.values():
        _copy_batch(core.sim, sim)
    return env, core, sims, configs


def _time_vector_env(plan: Plan, env, core, n: int) -> list[dict]:
    """One row per thread count: the vector env's rates between autoresets, its
    autoreset time and the rates over whole episodes (timing windows interleaved)."""
    steady: dict[int, list] = {t: [] for t in plan.threads}
    autoreset: dict[int, list] = {t: [] for t in plan.threads}
    cpu: dict[int, list] = {t: [] for t in plan.threads}
    episode_steps = getattr(env, "unwrapped", env).max_episode_steps
    for _ in range(plan.repeats):
        for window in range(WINDOWS_PER_REPEAT):
            for threads in plan.threads:
                set_threads(threads)
                rate, share = with_cpu_share(
                    threads if core.sim.parallel else 1,
                    _vector_rate,
                    env,
                    plan.vector_s / WINDOWS_PER_REPEAT,
                    plan.min_steps,
                )
                steady[threads].append(rate)
                cpu[threads].append(share)
                if window == WINDOWS_PER_REPEAT - 1:
                    autoreset[threads].append(
                        _autoreset_s(env, core, rate, plan.warmup_steps, episode_steps)
                    )
    return [
        {
            "n": n,
            "threads": threads,
            "kernel": ("parallel" if core.sim.parallel and threads > 1 else "serial"),
            "rates": [
                _amortized_rate(r, median(autoreset[threads]), n, episode_steps)
                for r in steady[threads]
            ],
            "steady_rates": steady[threads],
            "autoreset_s": autoreset[threads],
            "episode_steps": episode_steps,
            "cpu": cpu[threads],
            "substeps": core.sim.n_substeps,
            "bytes_per_env": _array_bytes(core, core.sim) / n,
        }
        for threads in plan.threads
    ]


def _time_kernels(plan: Plan, sims: dict, configs: list, currents, n: int, n_substeps: int):
    """One row per (kernel, threads): the bare kernel's rates (windows interleaved)."""
    krates: dict[tuple, list] = {cfg: [] for cfg in configs}
    kcpu: dict[tuple, list] = {cfg: [] for cfg in configs}
    for _ in range(plan.repeats * WINDOWS_PER_REPEAT):
        for kind, threads in configs:
            set_threads(threads)
            rate, share = with_cpu_share(
                threads,
                kernel_rate,
                sims[kind],
                currents,
                plan.vector_s / WINDOWS_PER_REPEAT,
                plan.min_steps,
            )
            krates[(kind, threads)].append(rate)
            kcpu[(kind, threads)].append(share)
    return [
        {
            "n": n,
            "kernel": cfg[0],
            "threads": cfg[1],
            "rates": krates[cfg],
            "cpu": kcpu[cfg],
            "substeps": n_substeps,
        }
        for cfg in configs
    ]


def _copy_batch(source, target) -> None:
    """Put ``target`` (a BatchSimulator of the same size) in ``source``'s state."""
    target.state[:] = source.state
    target.history[:] = source.history
    target.outputs[:] = source.outputs
    target.head = source.head


def measure_sync(plan: Plan, log) -> dict:
    """Gymnasium's SyncVectorEnv over N single envs (make_vec(..., vectorization_mode="sync"))."""
    import gymnasium as gym
    from gymnasium.utils.performance import benchmark_vector_step

    set_threads(1)
    rows = []
    for n in plan.sync_sizes:
        env = gym.make_vec(ENV_ID, num_envs=n, vectorization_mode="sync")
        measured = [
            with_cpu_share(1, benchmark_vector_step, env, target_duration=plan.vector_s, seed=rep)
            for rep in range(plan.repeats)
        ]
        env.close()
        rates = [m[0] for m in measured]
        rows.append({"n": n, "rates": rates, "cpu": [m[1] for m in measured]})
        log(f"SyncVectorEnv N={n}: {median(rates):.0f} env-steps/s")
    set_threads(plan.threads[-1])
    return {"rows": rows}


def measure_scipy(plan: Plan, log) -> dict:
    """Simulated seconds per wall second on the paper's clamped step (2 m tube, command
    coupling): our kernel (one env, one thread) and the SciPy reference solution at the
    loosest tolerance whose error meets the accuracy target of the convergence study."""
    from pneumatic_env.params import load_numerics, parameter_array
    from pneumatic_env.replay import simulate_currents
    from pneumatic_env.simulator import BatchSimulator

    from ..paper import clamped_step_scenario

    numerics = load_numerics()
    dt, n_substeps = numerics["control_dt_s"], numerics["substeps"]
    scenario = clamped_step_scenario(STEP_TUBE_M, "command", plan.step_scenario_steps * dt, dt)
    params, currents = scenario.parameters(), scenario.coil_current_a
    simulated_s = scenario.duration_s

    set_threads(1)
    sim = BatchSimulator(parameter_array([params]), dt, n_substeps, parallel=False)
    sim.rollout(currents[:1, None])  # warm-up
    ours_rates = [
        _rollout_rate(sim, currents, simulated_s, plan.vector_s) for _ in range(plan.repeats)
    ]
    set_threads(plan.threads[-1])
    ours = simulate_currents(params, currents, dt, substeps=n_substeps)
    result = {
        "scenario": scenario.name,
        "ours_rates": ours_rates,
        "substeps": n_substeps,
        "control_dt_s": dt,
        "simulated_s": simulated_s,
        "rows": [],
        "message": None,
    }
    try:
        from ..reference_solution import simulate_reference
    except ImportError as exc:
        result["message"] = (
            f"skipped: pneumatic_env.studies.reference_solution is not available ({exc})"
        )
        log(result["message"])
        return result
    return _compare_scipy(plan, log, result, simulate_reference, params, currents, dt, ours)


def _compare_scipy(plan: Plan, log, result: dict, simulate_reference, params, currents, dt, ours):
    """``result`` with the SciPy reference solution's rates and errors at each tolerance
    and the loosest one that meets the accuracy target (``chosen``), or a ``message``."""
    from ..convergence import _scales, errors

    simulated_s = result["simulated_s"]

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
    result["chosen"] = max(ok, key=lambda r: median(r["rates"])) if ok else None
    if result["chosen"] is None:
        result["message"] = (
            f"failed: no tolerance in {plan.scipy_rtols} reached "
            f"{ACCURACY_FULL_SCALE:.1%} of full scale"
        )
        log(result["message"])
        return result
    log(
        f"SciPy: {median(result['chosen']['rates']):.3g} simulated s per wall s at rtol "
        f"{result['chosen']['rtol']:g}; ours {median(result['ours_rates']):.3g}"
    )
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
