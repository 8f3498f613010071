"""The report of ``pneumatic-env speed``: the machine, the ratio table against the targets
and the tables of every measurement, as Markdown."""

from __future__ import annotations

import math
import time

from pneumatic_env.text_format import number_text

from .ceiling import OPS, PAIR_BURSTS, VECTOR_LOOPS, VECTOR_OPS
from .plan import (
    ACCURACY_FULL_SCALE,
    ENV_ID,
    RK4_STAGES,
    SCALING_MIN_N,
    TARGET_MEASURED_OVER_CEILING,
    TARGET_OURS_OVER_SCIPY,
    TARGET_SINGLE_OVER_PENDULUM,
    TARGET_THREAD_SCALING,
    TARGET_VECTOR_OVER_PENDULUM,
    TARGET_VECTOR_OVER_SYNC,
    TARGET_VECTOR_STEPS_PER_S,
    WINDOWS_PER_REPEAT,
    YARDSTICK_ID,
    Plan,
    median,
)


def _fmt(x, digits=3) -> str:
    return number_text(x, digits, missing="n/a", not_finite="n/a", grouped_from=1e3)


def _pct(shares) -> str:
    return f"{100 * median(shares):.0f}%"


def _table(headers, rows) -> list[str]:
    lines = ["| " + " | ".join(headers) + " |", "|" + "|".join("---" for _ in headers) + "|"]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return lines


def _paired_ratio(numerators, denominators) -> float:
    """Median of the ratios of windows measured one after the other (same index)."""
    return median([a / b for a, b in zip(numerators, denominators)])


def _ratio_row(name, value, target, bigger_is_better=True, unit="x") -> tuple:
    """(quantity, value, target text, met) of one ratio against its target."""
    if value is None or not math.isfinite(value):
        return (
            name,
            "n/a",
            target and f"{'>=' if bigger_is_better else '<='} {_fmt(target)}{unit}",
            "n/a",
        )
    met = (
        "n/a"
        if target is None
        else ("yes" if (value >= target if bigger_is_better else value <= target) else "no")
    )
    tgt = "-" if target is None else f"{'>=' if bigger_is_better else '<='} {_fmt(target)}{unit}"
    return (name, f"{_fmt(value)}{unit}", tgt, met)


def _ratio_rows(res: dict, plan: Plan) -> list[tuple]:
    """(quantity, value, target text, met) for the ratio table."""
    rows = []
    pend = median(res["single"]["rates"][YARDSTICK_ID])
    single = median(res["single"]["rates"][ENV_ID])

    def row(*args, **kw):
        rows.append(_ratio_row(*args, **kw))

    row("single env / Pendulum", single / pend, TARGET_SINGLE_OVER_PENDULUM)
    env = {(r["n"], r["threads"]): median(r["rates"]) for r in res["vector"]["env"]}
    sync = {r["n"]: median(r["rates"]) for r in res["sync"]["rows"]}
    big = [n for n in plan.vector_sizes if n >= SCALING_MIN_N] or [max(plan.vector_sizes)]
    many = plan.threads[-1]
    for n in big:
        row(
            f"vector env N={n}, 1 thread / Pendulum",
            env[(n, 1)] / pend,
            TARGET_VECTOR_OVER_PENDULUM,
        )
        row(
            f"vector env N={n}, 1 thread, env-steps/s",
            env[(n, 1)],
            TARGET_VECTOR_STEPS_PER_S,
            unit="",
        )
    n_sync = max(sync) if sync else None
    if n_sync is not None:
        row(
            f"vector env / SyncVectorEnv, N={n_sync}, 1 thread",
            env[(n_sync, 1)] / sync[n_sync],
            TARGET_VECTOR_OVER_SYNC,
        )
    scipy_res = res["scipy"]
    ours = median(scipy_res["ours_rates"])
    if scipy_res.get("chosen") and not scipy_res.get("message"):
        theirs = median(scipy_res["chosen"]["rates"])
        row(
            "ours / SciPy, 0.5 A step (kernel, 1 env, 1 thread)",
            ours / theirs,
            TARGET_OURS_OVER_SCIPY,
        )
        row(
            "ours / SciPy, 0.5 A step (single env via gym.make)",
            single * scipy_res["control_dt_s"] / theirs,
            None,
        )
    else:
        row("ours / SciPy, 0.5 A step", None, TARGET_OURS_OVER_SCIPY)
    ceiling = res.get("ceiling")
    if ceiling:
        row(
            f"kernel measured / ceiling, N={res['vector']['regime_n']}, 1 thread",
            median(ceiling["pair_ratios"]),
            TARGET_MEASURED_OVER_CEILING,
            False,
        )
    return rows + _thread_scaling_rows(res, big, many)


def _thread_scaling_rows(res: dict, big: list[int], many: int) -> list[tuple]:
    """The ratio rows of ``many`` threads over one, vector env and kernel, at each N of
    ``big`` (paired windows)."""
    rows = []
    env_windows = {(r["n"], r["threads"]): r["rates"] for r in res["vector"]["env"]}
    kern_windows = {
        (r["n"], r["kernel"], r["threads"]): r["rates"] for r in res["vector"]["kernel"]
    }
    for n in big:
        if many > 1 and (n, many) in env_windows:
            rows.append(
                _ratio_row(
                    f"vector env N={n}, {many} threads / 1 thread",
                    _paired_ratio(env_windows[(n, many)], env_windows[(n, 1)]),
                    TARGET_THREAD_SCALING,
                )
            )
        if (n, "parallel", many) in kern_windows and many > 1:
            rows.append(
                _ratio_row(
                    f"kernel N={n}, {many} threads / serial 1 thread",
                    _paired_ratio(
                        kern_windows[(n, "parallel", many)], kern_windows[(n, "serial", 1)]
                    ),
                    TARGET_THREAD_SCALING,
                )
            )
    return rows


RATIO_HEADERS = ("ratio", "value", "target", "met")


def report(res: dict, plan: Plan, command: str, machine: dict, started: float) -> str:
    """The Markdown report of the measurements ``res``."""
    lines = _head_lines(res, plan, command, machine, started)
    lines += _table(RATIO_HEADERS, _ratio_rows(res, plan))
    lines += _single_lines(res) + _vector_lines(res) + _sync_lines(res)
    lines += _scipy_lines(res, plan) + _ceiling_lines(res, plan) + _method_lines(plan)
    return "\n".join(lines) + "\n"


def _head_lines(res: dict, plan: Plan, command: str, machine: dict, started: float) -> list:
    """The title, the machine, the numerics and whether the env's kernel is current."""
    from pneumatic_env.params import load_numerics

    numerics = load_numerics()
    lines = [
        "# Speed",
        "",
        f"Generated by `{command}` ({'quick smoke run' if plan.quick else 'full run'}; "
        f"{plan.repeats} repeat(s), medians; {time.time() - started:.0f} s).",
        "",
        "## Machine",
        "",
    ]
    lines += [
        f"- CPU: {machine['cpu']}, {machine['cores']} cores "
        f"(Numba threads available: {machine['numba_threads']})",
        f"- Python {machine['python']}, NumPy {machine['numpy']}, Numba {machine['numba']}, "
        f"Gymnasium {machine['gymnasium']}, SciPy {machine['scipy']}",
        f"- {machine['os']}",
        f"- load average (1 min) at start / end: {res['load'][0]:.2f} / {res['load'][1]:.2f} "
        "(other processes share the cores; rates scale down with it)",
        "",
        "## Numerics",
        "",
        f"Default numerics (`load_numerics()`): control period "
        f"{numerics['control_dt_s'] * 1e3:g} ms, {numerics['substeps']} RK4 substeps per "
        f"control period ({RK4_STAGES} right-hand-side evaluations each); environment "
        f"`{ENV_ID}`.",
        "",
    ]
    mismatch = res["vector"]["mismatch"]
    lines += [
        (
            "**Warning: at N = " + ", ".join(map(str, mismatch)) + " the env's step did not "
            "reproduce `BatchSimulator.step` bit for bit: its jitted task kernel is not "
            "the current physics (stale Numba cache?). Its rates are not valid.**"
        )
        if mismatch
        else "The env's step reproduced `BatchSimulator.step` bit for bit "
        "at every N (its jitted task kernel runs the current physics).",
        "",
        "## Ratios",
        "",
    ]
    return lines


def _single_lines(res: dict) -> list[str]:
    """The single envs' table."""
    pend = median(res["single"]["rates"][YARDSTICK_ID])
    lines = [
        "",
        "## Single environments (gym.make, `gymnasium.utils.performance.benchmark_step`)",
        "",
    ]
    rows = []
    for name in (YARDSTICK_ID, ENV_ID):
        r = res["single"]["rates"][name]
        rows.append(
            (
                name,
                _fmt(median(r)),
                _fmt(min(r)),
                _fmt(max(r)),
                _fmt(median(r) / pend),
                _pct(res["single"]["cpu"][name]),
            )
        )
    lines += _table(("env", "steps/s (median)", "min", "max", "/ Pendulum", "CPU busy"), rows)
    return lines


def _vector_lines(res: dict) -> list[str]:
    """The native vector env's and the bare kernel's table."""
    lines = [
        "",
        "## Native vector env (gym.make_vec) and the bare kernel (BatchSimulator.step)",
        "",
    ]
    rows = []
    for r in res["vector"]["env"]:
        rate = median(r["rates"])
        rhs = rate * r["substeps"] * RK4_STAGES
        rows.append(
            (
                r["n"],
                r["threads"],
                f"env ({r['kernel']})",
                _fmt(rate),
                _fmt(median(r["steady_rates"])),
                _fmt(median(r["autoreset_s"]) * 1e3),
                _fmt(rate * r["substeps"]),
                _fmt(1e9 / rhs),
                _fmt(r["bytes_per_env"]),
                _pct(r["cpu"]),
            )
        )
    for r in res["vector"]["kernel"]:
        rate = median(r["rates"])
        rhs = rate * r["substeps"] * RK4_STAGES
        rows.append(
            (
                r["n"],
                r["threads"],
                f"kernel ({r['kernel']})",
                _fmt(rate),
                "",
                "",
                _fmt(rate * r["substeps"]),
                _fmt(1e9 / rhs),
                "",
                _pct(r["cpu"]),
            )
        )
    rows.sort(key=lambda row: (row[0], row[2].startswith("kernel"), row[1]))
    episode_steps = res["vector"]["env"][0]["episode_steps"]
    lines += [
        f"An env's env-steps/s are over whole episodes ({episode_steps} steps and one "
        "autoreset of all N episodes); the steps between autoresets and the time an "
        "autoreset adds are in their own columns.",
        "",
    ]
    lines += _table(
        (
            "N",
            "threads",
            "what",
            "env-steps/s",
            "between autoresets",
            "autoreset (ms)",
            "env-substeps/s",
            "wall ns per RHS",
            "bytes per env",
            "CPU busy",
        ),
        rows,
    )
    return lines


def _sync_lines(res: dict) -> list[str]:
    """SyncVectorEnv against the native vector env."""
    lines = [
        "",
        '## SyncVectorEnv (gym.make_vec(..., vectorization_mode="sync"), `benchmark_vector_step`)',
        "",
    ]
    env = {(r["n"], r["threads"]): median(r["rates"]) for r in res["vector"]["env"]}
    rows = [
        (
            r["n"],
            _fmt(median(r["rates"])),
            _fmt(env.get((r["n"], 1))),
            _fmt(env.get((r["n"], 1), float("nan")) / median(r["rates"])),
            _pct(r["cpu"]),
        )
        for r in res["sync"]["rows"]
    ]
    lines += _table(
        ("N", "Sync env-steps/s", "native, 1 thread", "native / Sync", "CPU busy (Sync)"), rows
    )
    return lines


def _scipy_lines(res: dict, plan: Plan) -> list[str]:
    """Our kernel against the SciPy reference solution."""
    s = res["scipy"]
    lines = [
        "",
        f"## SciPy reference: {s['scenario']}, {s['simulated_s'] * 1e3:g} ms simulated",
        "",
    ]
    if s.get("rows"):
        lines += [
            f"Errors as in docs/convergence.md (largest over the control-period samples: "
            f"p1, p2 of supply - ambient, f of the force range, x of half the stroke) "
            f"against the SciPy solution at rtol {plan.reference_rtol:g}; accuracy target "
            f"{ACCURACY_FULL_SCALE:.1%} of full scale.",
            "",
        ]
        rows = [
            (
                f"ours ({s['substeps']} RK4 substeps, kernel, 1 env, 1 thread)",
                "-",
                f"{s['ours_error']:.2g}",
                _fmt(median(s["ours_rates"])),
            )
        ]
        ref = s["reference"]
        rows.append(
            (
                "SciPy reference_solution (reference, timed once)",
                f"{ref['rtol']:g}",
                "0",
                _fmt(median(ref["rates"])),
            )
        )
        for r in s["rows"]:
            mark = " (compared)" if r is s.get("chosen") else ""
            rows.append(
                (
                    f"SciPy reference_solution{mark}",
                    f"{r['rtol']:g}",
                    f"{r['error']:.2g}",
                    _fmt(median(r["rates"])),
                )
            )
        lines += _table(
            ("solver", "rtol", "max error (fraction of full scale)", "simulated s per wall s"), rows
        )
    if s.get("message"):
        lines += [
            "",
            f"SciPy comparison {s['message']}.",
            "",
            f"Ours ({s['substeps']} RK4 substeps, kernel, 1 env): "
            f"{_fmt(median(s['ours_rates']))} simulated s per wall s.",
        ]
    return lines


def _ceiling_lines(res: dict, plan: Plan) -> list[str]:
    """The kernel's ceiling: operation costs, the measured over the ceiling, the gap."""
    lines: list[str] = []
    c = res.get("ceiling")
    if c:
        how = (
            f"one vector serves {c['lanes']} environments"
            if c["vectorised"]
            else "**a loop was not vectorised on this machine**"
        )
        lines += [
            "",
            f"## Kernel ceiling (N={res['vector']['regime_n']}, 1 thread, serial kernel)",
            "",
            "Work per environment and substep: the SIMD instructions of the compiled "
            "vectorised loops' bodies ("
            + ", ".join(f"`kernel.{f}`" for f in VECTOR_LOOPS)
            + ", each times its calls per "
            "substep in `VECTOR_LOOPS`; per vector of lanes, a body LLVM interleaved to "
            "serve several vectors counting its share; prologues, remainder loops and "
            f"wrappers not counted; {how}), divided by their lanes, and the scalar work "
            "per lane counted "
            "in `KERNEL_WORK` "
            "(`studies/speed/ceiling.py`); each at its throughput measured in a Numba loop "
            "on this machine (a SIMD instruction: the cost per element of a vectorised "
            "loop times its lanes, `vother` at the cost of an add or multiply; a scalar "
            "operation: in a loop that is not vectorised).",
            "",
        ]
        lanes = {op: c["lanes"] if op in VECTOR_OPS else 1 for op in VECTOR_OPS + OPS}
        rows = [
            (
                op,
                _fmt(c["op_ns"][op] * lanes[op]),
                _fmt(c["ops"][op] / lanes[op]),
                _fmt(c["ns"][op]),
            )
            for op in VECTOR_OPS + OPS
        ]
        rows.append(("**ceiling**", "", "", _fmt(c["total_ns"])))
        rows.append(("**measured**", "", "", _fmt(c["measured_ns"])))
        lines += _table(("operation", "ns each", "per substep and env", "ns per substep"), rows)
        ratios = c["pair_ratios"]
        lines += [
            "",
            f"The ratio in the first table is the median over {len(ratios)} pairs: "
            + ", ".join(f"{r:.2f}" for r in sorted(ratios))
            + f". Each pair is the fastest "
            f"of {PAIR_BURSTS} kernel timings ({plan.vector_s / PAIR_BURSTS:g} s each) "
            f"over the fastest of {PAIR_BURSTS} samples of each operation cost, "
            "interleaved, so that both halves see the same window of load from other "
            "processes and neither carries a burst of it (the ceiling is a rate without "
            "such load). The table above uses the medians over the pairs (and further "
            "operation samples).",
            "",
            f"Where the gap is: the RK4 loop alone (`batch_path.base_substeps_vectorised` "
            f"on the batch's first chunk, its inputs as `advance_chunk` sets them up, "
            f"timed in the same pairs) takes {_fmt(c['rk4_ns'])} ns per env-substep "
            f"against its own ceiling of {_fmt(c['rk4_ceiling_ns'])} ns (median ratio "
            f"{median(c['rk4_ratios']):.2f}); the rest of the kernel (the loops around "
            f"it, the delay reads, the constants cache, the calls per chunk) takes "
            f"{_fmt(c['measured_ns'] - c['rk4_ns'])} ns against "
            f"{_fmt(c['total_ns'] - c['rk4_ceiling_ns'])} ns.",
        ]
        lines += [
            "",
            f"Parts per substep (`kernel.refinement`, sampled): {c['parts']:.2f}; "
            f"substeps the general path redid: {c['redone']:.1%}.",
        ]
    return lines


def _method_lines(plan: Plan) -> list[str]:
    """How each quantity is measured."""
    return [
        "",
        "## How it is measured",
        "",
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
        "the first pressure rise; single envs run whole episodes.",
    ]
