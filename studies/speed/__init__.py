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

``plan`` holds the targets and what a run measures, ``measure`` the measurements (1-5),
``ceiling`` the kernel's ceiling (6, reading the x86 assembly of the compiled loops) and
``report`` the Markdown report; this module is the command (``add_arguments``, ``run``).
"""

from __future__ import annotations

import argparse
import os
import sys
import time

from .ceiling import kernel_ceiling, measure_op_costs, vector_loop_instructions
from .machine import machine_description
from .measure import measure_scipy, measure_single, measure_sync, measure_vector
from .plan import SYNC_MAX_N, VECTOR_SIZES, make_plan, median
from .report import report


def _positive_int(name):
    def parse(text):
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None or value < 1:
            raise argparse.ArgumentTypeError(
                f"{name} = {text!r} is not allowed: must be an integer >= 1"
            )
        return value

    return parse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--quick",
        action="store_true",
        help="a smoke run: tiny N (up to --max-n, default 8), one repeat, short measurements",
    )
    parser.add_argument(
        "--max-n",
        type=_positive_int("--max-n"),
        default=None,
        help=f"largest number of vector environments (default "
        f"{VECTOR_SIZES[-1]}; SyncVectorEnv stops at {SYNC_MAX_N})",
    )
    parser.add_argument(
        "--repeats",
        type=_positive_int("--repeats"),
        default=None,
        help="repeats of every measurement; medians are reported (default 3, --quick 1)",
    )
    parser.add_argument(
        "--out",
        metavar="FILE.md",
        default=None,
        help="also write the report (tables, command, machine) as Markdown",
    )


def _loop_ns(loop: dict, op_ns: dict) -> float:
    """A loop's instructions (per class) at the cost per operation: its ceiling, ns."""
    return sum(count * op_ns[op] for op, count in loop.items())


def _pair_ratios(measured: list, ceilings: list, median_ceiling: float) -> list:
    """measured / ceiling of each pair. A pair whose operation costs timed as zero (the
    operation's loop no slower than the copy loop, on a loaded machine) has no ceiling and
    is left out; with none left, the ceiling of the median operation costs stands in."""
    ratios = [ns / c for ns, c in zip(measured, ceilings) if c > 0.0]
    return ratios or [median(measured) / median_ceiling]


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
        serial = [
            r for r in res["vector"]["kernel"] if r["n"] == n_ref and r["kernel"] == "serial"
        ][0]
        instructions = vector_loop_instructions()
        ceiling = kernel_ceiling(instructions, op_ns, serial["substeps"])
        # measured / ceiling of each pair (kernel, operation costs and the RK4 loop alone,
        # timed interleaved); the ratios reported are their medians
        rk4 = instructions["loops"]["base_substeps_vectorised"]
        rk4_ceiling_ns = _loop_ns(rk4, op_ns)
        measured = [ns for ns, _, _ in pairs]
        rk4_measured = [ns for _, _, ns in pairs]
        ceiling.update(
            op_ns=op_ns,
            lanes=instructions["lanes"],
            vectorised=instructions["vectorised"],
            parts=regimes["parts"],
            redone=regimes["redone"],
            pair_ratios=_pair_ratios(
                measured,
                [
                    kernel_ceiling(instructions, o, serial["substeps"])["total_ns"]
                    for _, o, _ in pairs
                ],
                ceiling["total_ns"],
            ),
            measured_ns=median(measured),
            rk4_ns=median(rk4_measured),
            rk4_ceiling_ns=rk4_ceiling_ns,
            rk4_ratios=_pair_ratios(
                rk4_measured, [_loop_ns(rk4, o) for _, o, _ in pairs], rk4_ceiling_ns
            ),
        )
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
