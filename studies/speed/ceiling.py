"""The kernel's ceiling: the work per environment and substep (the SIMD instructions of the
compiled vectorised loops, read from their x86 assembly, and the scalar work counted in
``KERNEL_WORK``), each at its throughput measured in a Numba loop on this machine."""

from __future__ import annotations

import math
import re
import time

import numpy as np
from numba import njit, types

from pneumatic_env.physics import batch_path
from pneumatic_env.physics import kernel as K
from pneumatic_env.physics import layout as L
from pneumatic_env.physics.kernel import N_RK, OUTPUT_STATE_ROWS

from .plan import Plan, kernel_rate, median, set_threads

CEILING_PAIRS = 7  # kernel / operation-cost pairs behind the measured / ceiling ratio
# each pair interleaves this many kernel timings (of vector_s / PAIR_BURSTS each) with as
# many operation-cost samples and keeps the fastest of each: a shared machine slows a
# window at random (other processes), and the ceiling is a rate without that load
PAIR_BURSTS = 5
OPS = ("exp", "log", "sqrt", "div", "flop", "imod")  # scalar operations (KERNEL_WORK)
VECTOR_OPS = ("vdiv", "vsqrt", "vother")  # SIMD instructions of the vectorised loops

# The batch path (kernel.advance_chunk) advances an environment in two parts.
# 1. The vectorised loops (VECTOR_LOOPS, every branch computed and selected): per
#    substep, batch_path.begin_substeps (start state, piston direction, stiffness test),
#    batch_path.interpolate_row (the delayed spool position at the substep's start, middle
#    and end, from the ring buffer's rows: the benchmark's lanes share one tube delay),
#    batch_path.base_substeps_vectorised (one RK4 substep of kernel.base_derivatives for every
#    lane), batch_path.end_substeps (event test, end stops) and batch_path.copy_fast_lanes (the
#    delay history, once per channel); per control period, batch_path.fast_commands (the spool
#    play) and the state and outputs (batch_path.copy_fast_lanes per row,
#    batch_path.fast_output_forces). Their work is not counted by hand:
#    vector_loop_instructions() reads the SIMD instructions of the compiled loops
#    (divisions, square roots, the rest).
# 2. Scalar work per lane, counted here by reading pneumatic_env/physics/batch_path.py with
#    the rod clamped (no piston events) and no stiff substep. "flop" is an add, subtract,
#    multiply, compare, select, min, max, abs, floor or conversion; "div" a floating-point
#    division; "imod" an integer modulo; pow (``**``) counts as one exp and one log.
#    Expressions of the per-environment constants alone, and the work done once per chunk
#    (e.g. batch_path.delay_slots for lanes that share their delay), are not counted. Update
#    this table when advance_chunk changes.
KERNEL_WORK = {
    # per lane and substep: advance_chunk's two tests of the lane's path (general path or
    # redone)
    "lane_substep:fixed": {"flop": 2},
    # per lane and control period: kernel.refresh_constants testing the key (the substep
    # the constants were derived for; kernel.env_constants runs only when it differs),
    # batch_path.lanes_share_delay's compare and advance_chunk's test of the lane's path
    "control_step:cache": {"flop": 3},
}
# the vectorised loops in batch_path: calls per substep and per control period
VECTOR_LOOPS = {
    "begin_substeps": (1, 0),
    "interpolate_row": (3, 0),
    "base_substeps_vectorised": (1, 0),
    "end_substeps": (1, 0),
    "fast_commands": (0, 1),
    "fast_output_forces": (0, 1),
    # 3 history channels per substep; per period the RK4 state rows, the two
    # coil rows and the outputs that are state rows
    "copy_fast_lanes": (3, N_RK + 2 + len(OUTPUT_STATE_ROWS)),
}


def ceiling_pair(plan: Plan, sim, currents: np.ndarray) -> tuple:
    """One (kernel ns per env-substep, operation costs, RK4 loop ns per env-substep) triple
    behind the measured / ceiling ratio: ``PAIR_BURSTS`` short kernel timings interleaved
    with as many operation-cost samples (``op_cost_sample``) and timings of the RK4 loop
    alone (``_rk4_loop_ns``), the fastest of each (per operation)."""
    kernel_ns, samples, rk4_ns = [], [], []
    for _ in range(PAIR_BURSTS):
        rate = kernel_rate(sim, currents, plan.vector_s / PAIR_BURSTS, plan.min_steps)
        kernel_ns.append(1e9 / (rate * sim.n_substeps))
        samples.append(op_cost_sample(plan))
        rk4_ns.append(_rk4_loop_ns(sim, currents[0], plan.vector_s / PAIR_BURSTS))
    return (min(kernel_ns), {op: min(s[op] for s in samples) for op in samples[0]}, min(rk4_ns))


@njit(cache=True)
def _repeat_rk4_loop(constants, work, start, n_lanes, h, reps, run_loop):
    """``reps`` times: restore the work array from ``start``, then (with ``run_loop``) one
    call of the batch path's RK4 loop."""
    for _ in range(reps):
        work[:] = start
        if run_loop:
            batch_path.base_substeps_vectorised(constants, work, n_lanes, h)


def _rk4_loop_ns(sim, currents: np.ndarray, seconds: float) -> float:
    """ns per env-substep of the RK4 loop alone (``batch_path.base_substeps_vectorised``) on
    the batch's first chunk, its inputs set up as ``kernel.advance_chunk`` does (start
    state, direction, delayed spool positions), minus the time of restoring them."""
    n = min(K.CHUNK_ENVS, sim.n_envs)
    h = sim.control_dt_s / sim.n_substeps
    constants = sim.constants[0]
    work = K.chunk_work(sim.state, 0, n)
    work[K.W_CURRENT * K.CHUNK_ENVS : K.W_CURRENT * K.CHUNK_ENVS + n] = currents[:n]
    K.prepare_substep(
        constants,
        work,
        sim.history,
        0,
        n,
        K.ring_slot(sim.head, sim.history.shape[0]),
        batch_path.lanes_share_delay(constants, n),
        h,
    )
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
            out[j] = ((1.0 / (v + 1.0) + 1.0 / (v + 2.0)) + (1.0 / (v + 3.0) + 1.0 / (v + 4.0))) + (
                (1.0 / (v + 5.0) + 1.0 / (v + 6.0)) + (1.0 / (v + 7.0) + 1.0 / (v + 8.0))
            )


@njit(cache=True, error_model="numpy")
def _vmicro_sqrt(a, out, idx, sweeps):  # 8 square roots and 15 adds, independent
    for _ in range(sweeps):
        for j in range(a.shape[0]):
            v = a[j]
            out[j] = (
                (math.sqrt(v + 1.0) + math.sqrt(v + 2.0))
                + (math.sqrt(v + 3.0) + math.sqrt(v + 4.0))
            ) + (
                (math.sqrt(v + 5.0) + math.sqrt(v + 6.0))
                + (math.sqrt(v + 7.0) + math.sqrt(v + 8.0))
            )


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
_MICRO = {
    "exp": (_micro_exp, _micro_base, 1, 0),
    "log": (_micro_log, _micro_base, 1, 0),
    "sqrt": (_micro_sqrt, _micro_base, 1, 0),
    "div": (_micro_div, _micro_base, 1, 0),
    "flop": (_micro_flop, _micro_base, 9, 0),
    "imod": (_micro_imod, _micro_imod_base, 1, 0),
    "vother": (_vmicro_flop, _vmicro_base, 35, 0),
    "vdiv": (_vmicro_div, _vmicro_base, 8, 15),
    "vsqrt": (_vmicro_sqrt, _vmicro_base, 8, 15),
}


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
    set_threads(1)
    samples = list(samples or []) + [op_cost_sample(plan) for _ in range(max(plan.repeats, 3))]
    set_threads(plan.threads[-1])
    return {op: median([sample[op] for sample in samples]) for op in _MICRO}


def sample_regimes(sim, currents: np.ndarray, steps: int = 8, envs: int = 128) -> dict:
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
            state = tuple(float(v) for v in sim.state[: L.S_T2 + 1, env])
            n_parts = kernel.refinement(constants[int(env)], state, h)
            parts += n_parts
            split += n_parts > 1
            samples += 1
    return {"samples": samples, "parts": parts / samples, "redone": split / samples}


SIMD_REGISTERS = (("%zmm", 8), ("%ymm", 4), ("%xmm", 2))  # register name, float64 lanes


# the Numba type of each argument of the VECTOR_LOOPS, by name
_ROW = types.float64[::1]
_LOOP_ARGUMENT_TYPES = {
    "constants": _ROW,
    "work": _ROW,
    "target_row": _ROW,
    "lower_row": _ROW,
    "upper_row": _ROW,
    "row": types.int64,
    "weight": types.float64,
    "at_start": types.boolean,
    "force_row": _ROW,
    "command_row": _ROW,
    "play_row": _ROW,
    "values": _ROW,
    "key_values": _ROW,
    "differing_bits": types.int64[::1],
    "n_lanes": types.int64,
    "work_row": types.int64,
    "keep_redone": types.boolean,
    "h": types.float64,
}


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
            body = lines[label[1] + 1 : i]
            simd = [b for b in body if register in b]
            if len(simd) > len(best[1]):
                best = (body, simd)
    body, simd = best
    steps = {
        int(m.group(1))
        for m in map(_ASM_INDEX_STEP.match, body)
        if m and any(f",{m.group(2)},8)" in line for line in simd)
    }
    return simd, (steps.pop() if len(steps) == 1 else 0)


def vector_loop_instructions() -> dict:
    """SIMD instructions of the batch path's vectorised loops, by class (from their assembly).

    The functions of ``VECTOR_LOOPS`` in ``batch_path`` are compiled afresh (Numba does not
    show the assembly of cached code) with the argument types the kernel passes. The
    instructions of each one's vector loop body (``_vector_body``) on the widest vector
    registers present count, scaled to one vector of lanes (on x86 with AVX2, 4 lanes: a
    body LLVM interleaved to serve 16 elements counts a quarter). Returns the counts per
    class of each loop, the lanes per vector and whether every loop was vectorised.
    """
    loops = {}
    found = []
    for name in VECTOR_LOOPS:
        counts = loops[name] = dict.fromkeys(VECTOR_OPS, 0.0)
        py_func = getattr(batch_path, name).py_func
        fn = njit(error_model="numpy")(py_func)
        arguments = py_func.__code__.co_varnames[: py_func.__code__.co_argcount]
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
            counts[
                "vdiv"
                if op.startswith("vdivp") or op == "divpd"
                else "vsqrt"
                if op.startswith("vsqrtp") or op == "sqrtpd"
                else "vother"
            ] += lanes / elements
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
